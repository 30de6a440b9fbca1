"""The experiment runner: a TOML config expands into runs (task × agent × hyperparameters × seed).

Every run gets a folder ``OUT/runs/<run_id>`` whose ``done.json``, written last and atomically, alone marks it
finished: a rerun skips it, resumes an unfinished run from its last checkpoint (``--checkpoint-every``) and restarts
the others from scratch. A run another runner is training (on the same ``OUT``) is left to it. ``OUT/sweep.json``
lists the config's runs for `benchmarks.results`. Command line, config keys and run files: ``docs/benchmarks.md``.

This module is the sweep and its command line: it lists the runs in ``sweep.json``, skips the finished ones and
hands the others to worker processes, to this process or to Ray. The config is read by `benchmarks.sweep_config`,
and each run is done by `benchmarks.run_one`.
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import contextlib
import csv
import dataclasses
import fnmatch
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from tl_gym.agents.serialization import write_atomic

from benchmarks.run_one import (
    HISTORY,
    RunInProgress,
    execute_run,
    install_files,
    is_done,
    read_history_rows,
    run_files,
)
from benchmarks.sweep_config import ConfigError, RunSpec, Sweep, load_config

#: Iterations between checkpoints on the command line (0: none).
DEFAULT_CHECKPOINT_EVERY = 5


# A sweep ----------------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class SweepReport:
    """What a sweep did: run ids finished, skipped, left to another runner, failed (run id -> traceback).

    Skipped: done already; left to another runner: one training them now (`RunInProgress`).
    """

    finished: list[str] = dataclasses.field(default_factory=list)
    skipped: list[str] = dataclasses.field(default_factory=list)
    busy: list[str] = dataclasses.field(default_factory=list)
    failed: dict[str, str] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0

    def attempt(self, run: RunSpec, work: Callable[[], Any]) -> None:
        """Call ``work`` and count ``run`` as finished, or as failed with the traceback of what it raised.

        ``work`` returning ``False`` (`install_files` dropping a Ray result: the run was finished meanwhile) counts
        it as skipped.
        """
        try:
            done = work()
        except RunInProgress as error:
            self.busy.append(run.run_id)
            print(f"run {error}", file=sys.stderr)
        except Exception as error:  # noqa: BLE001 - one failed run must not stop the sweep
            self.failed[run.run_id] = "".join(traceback.format_exception(type(error), error, error.__traceback__))
            print(f"run {run.run_id} failed: {type(error).__name__}: {error}", file=sys.stderr)
        else:
            if done is False:
                print(f"run {run.run_id}: finished meanwhile by another runner; this result was dropped",
                      file=sys.stderr)
            (self.skipped if done is False else self.finished).append(run.run_id)


def run_sweep(sweep: Sweep, out_dir: str | Path, workers: int | None = None, ray_address: str | None = None,
              only: Sequence[str] = (), checkpoint_every: int = 0) -> SweepReport:
    """Run every unfinished run of ``sweep`` into ``out_dir/runs/<run_id>``, and list them in ``sweep.json``.

    ``workers`` local processes (default: the CPU count; 0: here, one after the other), or Ray tasks at
    ``ray_address`` (a Ray already initialised here is used as is); ``only``: shell patterns of the labels
    to run; ``checkpoint_every``: iterations between a local run's checkpoints (`execute_run`). A failed run
    leaves no ``done.json`` and is retried by the next sweep, from its checkpoint if it has one.
    """
    out_dir = Path(out_dir)
    (out_dir / "runs").mkdir(parents=True, exist_ok=True)
    manifest = {"name": sweep.name, "description": sweep.description,
                "runs": {run.run_id: run.to_json() for run in sweep.runs}}
    write_atomic(out_dir / "sweep.json", json.dumps(manifest, indent=1).encode())
    report, pending = SweepReport(), []
    for run in sweep.runs:
        if not only or any(fnmatch.fnmatchcase(run.label, pattern) for pattern in only):
            (report.skipped.append(run.run_id) if is_done(out_dir / "runs" / run.run_id) else pending.append(run))
    start = time.perf_counter()
    if pending and ray_address is not None:
        _run_on_ray(pending, out_dir, ray_address, report, sweep.name)
    elif pending and workers == 0:
        for count, run in enumerate(pending, 1):
            report.attempt(run, lambda run=run: execute_run(run, out_dir / "runs" / run.run_id, checkpoint_every))
            print(f"{sweep.name}: {count}/{len(pending)} runs", file=sys.stderr)  # as the workers' progress says
    elif pending:
        # spawn: a fresh interpreter per worker, no torch/thread state inherited through fork
        with futures.ProcessPoolExecutor(min(workers or os.cpu_count() or 1, len(pending)),
                                         mp_context=multiprocessing.get_context("spawn")) as pool, \
                _workers_die_with_the_sweep(pool):
            jobs = {pool.submit(execute_run, run, out_dir / "runs" / run.run_id, checkpoint_every): run
                    for run in pending}
            _wait_with_progress(jobs, report, sweep.name, out_dir)
    report.wall_time = time.perf_counter() - start
    return report


def check_only(sweeps: Sequence[Sweep], only: Sequence[str]) -> None:
    """Refuse an ``--only`` pattern that matches no label of the sweeps (a typo ran nothing and exited 0).

    Commands that run several configs (`benchmarks.suite`, `benchmarks.reproduce_paper`) pass them all: a
    pattern needs to match in one of them only.

    Raises:
        ConfigError: naming the pattern and listing the labels.
    """
    labels = list(dict.fromkeys(run.label for sweep in sweeps for run in sweep.runs))
    unmatched = [p for p in only if not any(fnmatch.fnmatchcase(label, p) for label in labels)]
    if unmatched:
        names = ", ".join(sweep.name for sweep in sweeps)
        raise ConfigError(f"--only {unmatched[0]!r} matches no label of {names} (case counts): "
                          f"{', '.join(map(repr, labels))}")


def iterations_done(runs: Sequence[RunSpec], out_dir: str | Path) -> int:
    """Iterations the runs have written to their ``history.csv`` so far (a finished run: all of them)."""
    total = 0
    for run in runs:
        path = Path(out_dir) / "runs" / run.run_id / HISTORY
        with contextlib.suppress(FileNotFoundError, csv.Error):
            total += min(run.iterations, len(read_history_rows(path)))
    return total


def _wait_with_progress(jobs: Mapping[futures.Future, RunSpec], report: SweepReport, name: str, out_dir: Path,
                        poll_seconds: float = 10.0) -> None:
    """Collect the workers' runs as they end, with a progress bar over all their iterations on a terminal.

    The workers write each iteration to their run's ``history.csv``; the bar reads those every
    ``poll_seconds`` (a run of SAC on the car takes hours, and its end is the only other sign of life). Off a
    terminal (a log file) tqdm draws nothing, and the line per finished run is what the log shows.
    """
    from tqdm.auto import tqdm

    runs = list(jobs.values())
    with tqdm(total=sum(run.iterations for run in runs), initial=iterations_done(runs, out_dir), desc=name,
              unit="it", file=sys.stderr, disable=None, dynamic_ncols=True) as bar:
        waiting, finished = set(jobs), 0
        while waiting:
            done, waiting = futures.wait(waiting, timeout=poll_seconds, return_when=futures.FIRST_COMPLETED)
            for job in done:
                report.attempt(jobs[job], job.result)
                finished += 1
                bar.write(f"{name}: {finished}/{len(jobs)} runs", file=sys.stderr)
            bar.update(iterations_done(runs, out_dir) - bar.n)


@contextlib.contextmanager
def _workers_die_with_the_sweep(pool: futures.ProcessPoolExecutor) -> Iterator[None]:
    """Stop ``pool``'s worker processes when the sweep is interrupted (Ctrl-C, or SIGTERM as from ``kill``).

    The executor's own exit waits for the running runs to finish, so an interrupted sweep would
    leave its workers training on, unseen. SIGTERM is turned into `SystemExit` while the sweep
    runs (main thread only), and any interruption terminates the workers before it propagates; a
    killed run leaves no ``done.json`` and reruns next time.
    """
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        yield
    except BaseException:
        terminate = getattr(pool, "terminate_workers", None)  # Python 3.14
        if terminate is not None:
            terminate()
        else:
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _exit_on_sigterm(signum: int, frame: Any) -> None:
    raise SystemExit(128 + signum)


def _run_on_ray(pending: Sequence[RunSpec], out_dir: Path, address: str, report: SweepReport, name: str) -> None:
    try:
        import ray
    except ImportError as exc:
        raise ImportError('--ray needs Ray, which is not installed: pip install "tl_gym[ray]"') from exc
    if not ray.is_initialized():
        # the driver's import path, so local workers find `benchmarks` (cluster workers need it installed)
        ray.init(address=None if address == "local" else address,
                 runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}})
    remote = ray.remote(num_cpus=1, max_retries=0)(run_files)
    refs = {remote.remote(run): run for run in pending}
    while refs:
        (ref,), _ = ray.wait(list(refs), num_returns=1)
        run = refs.pop(ref)
        report.attempt(run, lambda ref=ref, run=run: install_files(ray.get(ref), out_dir / "runs" / run.run_id))
        print(f"{name}: {len(pending) - len(refs)}/{len(pending)} runs", file=sys.stderr)


def default_out_dir(sweep: Sweep) -> Path:
    """Where a sweep writes by default: ``runs/sweeps/<name>`` (git-ignored)."""
    return Path("runs") / "sweeps" / sweep.name


# Command lines ----------------------------------------------------------------------------------------------------
def add_sweep_options(parser: argparse.ArgumentParser) -> None:
    """The options of every command that runs sweeps (this one, `benchmarks.reproduce_paper`, `benchmarks.suite`)."""
    parser.add_argument("--workers", type=int, help="local processes (default: CPU count; 0: here, serially)")
    parser.add_argument("--ray", metavar="ADDRESS", help='run on Ray: "auto", "ray://host:10001" or "local"')
    parser.add_argument("--quick", action="store_true",
                        help="the quick variant (CI-sized); reproduce_paper and suite then write their pages in runs/")
    parser.add_argument("--variant", help="apply the configs' [variants.VARIANT] overrides")
    parser.add_argument("--only", action="append", default=[], metavar="PATTERN",
                        help='run only labels matching this shell pattern, e.g. "TLPS*" (repeatable)')
    parser.add_argument("--checkpoint-every", type=int, default=DEFAULT_CHECKPOINT_EVERY, metavar="N",
                        help="checkpoint each run every N iterations, so that a rerun resumes a stopped run there "
                             f"(default {DEFAULT_CHECKPOINT_EVERY}; 0: never; not with --ray)")


def variant_of(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str | None:
    """The config variant that `add_sweep_options`'s options ask for, after checking them."""
    if args.quick and args.variant not in (None, "quick"):
        parser.error("--quick is --variant quick; give one of them")
    if args.workers is not None and args.workers < 0:
        parser.error(f"--workers must be >= 0, got {args.workers}")
    if args.checkpoint_every < 0:
        parser.error(f"--checkpoint-every must be >= 0, got {args.checkpoint_every}")
    return "quick" if args.quick else args.variant


def run_with_options(sweep: Sweep, out_dir: str | Path, args: argparse.Namespace) -> SweepReport:
    """`run_sweep` with `add_sweep_options`'s options; the failed runs' tracebacks go to stderr."""
    report = run_sweep(sweep, out_dir, workers=args.workers, ray_address=args.ray, only=args.only,
                       checkpoint_every=args.checkpoint_every)
    for run_id, text in report.failed.items():
        print(f"--- {run_id} failed:\n{text}", file=sys.stderr)
    return report


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.runner", description=__doc__.split("\n")[0])
    parser.add_argument("config", help="a TOML config, e.g. benchmarks/configs/paper.toml")
    parser.add_argument("--out", type=Path, help="results folder (default runs/sweeps/<name>[-<variant>])")
    add_sweep_options(parser)
    args = parser.parse_args(argv)
    try:
        sweep = load_config(args.config, variant=variant_of(parser, args))
    except ConfigError as exc:
        parser.error(str(exc))
    out_dir = args.out or default_out_dir(sweep)
    blocked = next((p for p in (out_dir, *out_dir.parents) if p.exists() and not p.is_dir()), None)
    if blocked is not None:
        parser.error(f"--out {out_dir}: {blocked} is a file: name a folder for the results")
    try:
        check_only([sweep], args.only)
    except ConfigError as exc:
        parser.error(str(exc))
    try:
        report = run_with_options(sweep, out_dir, args)
    except KeyboardInterrupt:  # the workers are stopped (`_workers_die_with_the_sweep`); say how to go on
        resume = (f"resume the others from their last checkpoints (--checkpoint-every {args.checkpoint_every})"
                  if args.checkpoint_every else "run the others again (--checkpoint-every 0 wrote no checkpoint)")
        print(f"\ninterrupted: finished runs keep their done.json; rerun the same command to {resume}",
              file=sys.stderr)
        return 130
    busy = f"{len(report.busy)} left to another runner training them, " if report.busy else ""
    print(f"{sweep.name}: {len(report.finished)} run(s) finished, {len(report.skipped)} already done, {busy}"
          f"{len(report.failed)} failed, {report.wall_time:.1f} s; results in {out_dir}")
    return 1 if report.failed else 0


if __name__ == "__main__":
    sys.exit(main())
