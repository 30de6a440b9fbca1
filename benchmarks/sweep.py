"""Sweep runner: a grid of task × agent × hyperparameters × seed, in parallel, resumable.

Usage::

    python -m benchmarks.sweep benchmarks/configs/paper.toml              # all CPUs of this machine
    python -m benchmarks.sweep benchmarks/configs/paper.toml --workers 1
    python -m benchmarks.sweep benchmarks/configs/paper.toml --quick      # CI-sized (variant "quick")
    python -m benchmarks.sweep benchmarks/configs/paper.toml --variant session
    python -m benchmarks.sweep benchmarks/configs/paper.toml --ray auto   # on a Ray cluster

A config (TOML) names the env, the tasks, the seeds and the iterations, and lists agents
(``[[agents]]``), each with a label, an agent name, hyperparameters and an optional
``grid`` of hyperparameter lists expanded as a product; see ``benchmarks/configs/`` and
``docs/benchmarks.md``. Every run gets its own directory under ``OUT/runs/`` (see
`benchmarks.sweep_run`); the results on disk are the checkpoint: a rerun skips finished
runs and restarts unfinished ones from scratch, so killing a sweep loses at most the runs
in flight. ``OUT/sweep.json`` lists the runs of the current config, which is what
`benchmarks.results` aggregates.

Locally the runs go to a `ProcessPoolExecutor` (one torch thread each); with ``--ray``
each run is a Ray task that returns its files to the driver, so workers need no shared
filesystem, only tl_gym installed (``pip install "tl_gym[ray]"``).
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import dataclasses
import fnmatch
import itertools
import json
import multiprocessing
import os
import sys
import time
import traceback
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from benchmarks.sweep_run import (
    RunSpec,
    check_agent_name,
    execute_run,
    install_files,
    is_done,
    run_files,
    write_atomic,
)

#: Keys of a config's top level (all but name, agents and variants may be overridden in a variant).
TOP_KEYS = {
    "name", "description", "env", "tasks", "seeds", "iterations", "evaluate_episodes", "evaluate_every",
    "trajectory_iterations", "trajectory_episodes", "save_agent", "agents", "variants", "env_kwargs",
}
#: Keys of an ``[[agents]]`` entry; ``variants.<name>`` holds its overrides in that variant
#: (``skip = true`` leaves the agent out of it).
AGENT_KEYS = {
    "label", "agent", "hyperparameters", "grid", "env_kwargs", "tasks", "seeds", "iterations",
    "evaluate_episodes", "evaluate_every", "trajectory_iterations", "trajectory_episodes", "save_agent", "note",
    "variants", "skip",
}
#: Keys an agent entry inherits from the top level when it does not set them.
INHERITED = ("tasks", "seeds", "iterations", "evaluate_episodes", "evaluate_every", "trajectory_iterations",
             "trajectory_episodes", "save_agent")
DEFAULTS = {"env_kwargs": {}, "evaluate_episodes": 0, "evaluate_every": 0, "trajectory_iterations": [],
            "trajectory_episodes": 40,
            "save_agent": False}


class ConfigError(ValueError):
    """A sweep config that cannot be run; the message names the file and the culprit."""


@dataclasses.dataclass(frozen=True)
class Sweep:
    """An expanded sweep: its name and the runs it is made of, in config order."""

    name: str
    description: str
    runs: tuple[RunSpec, ...]


def load_config(path: str | Path, variant: str | None = None, overrides: Mapping[str, Any] | None = None) -> Sweep:
    """Read a TOML sweep config and expand it into runs.

    Args:
        path: the config file.
        variant: apply the overrides of ``[variants.<variant>]`` (top level) and of each agent's
            ``variants.<variant>`` table, e.g. ``"quick"`` for a CI-sized run; the sweep's name
            gets ``-<variant>`` appended, so its results go to their own directory.
        overrides: top-level keys set after the variant (e.g. ``{"seeds": 3, "iterations": 20}``).

    Raises:
        ConfigError: unknown keys, bad types or values, an agent name of no known form.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"cannot read sweep config {path}: {exc}") from exc
    return expand_config(data, variant=variant, source=str(path), overrides=overrides)


def expand_config(
    data: Mapping[str, Any],
    variant: str | None = None,
    source: str = "<config>",
    overrides: Mapping[str, Any] | None = None,
) -> Sweep:
    """Expand a parsed config (see `load_config`) into its runs, checking every field first."""
    def fail(message: str) -> ConfigError:
        return ConfigError(f"{source}: {message}")

    unknown = sorted(set(data) - TOP_KEYS)
    if unknown:
        raise fail(f"unknown key(s) {unknown}; valid: {sorted(TOP_KEYS)}")
    top = {**DEFAULTS, **data}
    variants = _table(top.get("variants", {}), "variants", fail)
    for name, table in variants.items():  # all checked, not only the one asked for
        bad = sorted(set(_table(table, f"variants.{name}", fail)) - (TOP_KEYS - {"name", "variants", "agents"}))
        if bad:
            raise fail(f"variants.{name}: unknown key(s) {bad}")
    if variant is not None:
        if variant not in variants:
            raise fail(f"no variant {variant!r}; the config has {sorted(variants)}")
        top.update(variants[variant])
    bad = sorted(set(overrides or {}) - (TOP_KEYS - {"name", "variants", "agents"}))
    if bad:
        raise fail(f"overrides: unknown key(s) {bad}")
    top.update(overrides or {})
    for key in ("name", "env"):
        if not isinstance(top.get(key), str) or not top[key]:
            raise fail(f"'{key}' must be a non-empty string, got {top.get(key)!r}")
    agents = top.get("agents")
    if not isinstance(agents, list) or not agents:
        raise fail("no [[agents]] entries")
    runs: list[RunSpec] = []
    for index, entry in enumerate(agents):
        where = f"agents[{index}]"
        entry = _table(entry, where, fail)
        bad = sorted(set(entry) - AGENT_KEYS)
        if bad:
            raise fail(f"{where}: unknown key(s) {bad}; valid: {sorted(AGENT_KEYS)}")
        own = _table(entry.get("variants", {}), f"{where}.variants", fail)
        if variant is not None and variant in own:
            changes = _table(own[variant], f"{where}.variants.{variant}", fail)
            bad = sorted(set(changes) - AGENT_KEYS)
            if bad:
                raise fail(f"{where}.variants.{variant}: unknown key(s) {bad}")
            hyper = {**_table(entry.get("hyperparameters", {}), f"{where}.hyperparameters", fail),
                     **_table(changes.get("hyperparameters", {}), f"{where}.variants.{variant}.hyperparameters",
                              fail)}
            entry = {**entry, **changes, "hyperparameters": hyper}
        if entry.get("skip", False):
            continue
        runs.extend(_expand_agent(entry, top, where, fail))
    ids = [run.run_id for run in runs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise fail(f"the same run appears twice: {duplicates} (two agents with one label and hyperparameters?)")
    if not runs:
        raise fail(f"variant {variant!r} skips every agent")
    name = top["name"] + (f"-{variant}" if variant else "")
    return Sweep(name=name, description=str(top.get("description", "")), runs=tuple(runs))


def _table(value: Any, where: str, fail: Any) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise fail(f"{where} must be a table, got {value!r}")
    return dict(value)


def _int_list(value: Any, where: str, fail: Any, minimum: int) -> list[int]:
    if not isinstance(value, list) or not value or not all(
            isinstance(v, int) and not isinstance(v, bool) and v >= minimum for v in value):
        raise fail(f"{where} must be a non-empty list of ints >= {minimum}, got {value!r}")
    return value


def _expand_agent(entry: dict[str, Any], top: Mapping[str, Any], where: str, fail: Any) -> list[RunSpec]:
    settings = {key: entry.get(key, top.get(key)) for key in INHERITED}
    agent = entry.get("agent")
    if not isinstance(agent, str):
        raise fail(f"{where}.agent must be a string, got {agent!r}")
    try:
        check_agent_name(agent)
    except ValueError as exc:
        raise fail(f"{where}: {exc}") from None
    label = entry.get("label", agent)
    hyper = _table(entry.get("hyperparameters", {}), f"{where}.hyperparameters", fail)
    grid = _table(entry.get("grid", {}), f"{where}.grid", fail)
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise fail(f"{where}.grid.{key} must be a non-empty list, got {values!r}")
    env_kwargs = {**_table(top.get("env_kwargs", {}), "env_kwargs", fail),
                  **_table(entry.get("env_kwargs", {}), f"{where}.env_kwargs", fail)}
    tasks = _int_list(settings["tasks"], f"{where}.tasks", fail, 1) if settings["tasks"] is not None else [None]
    seeds = settings["seeds"]
    if isinstance(seeds, int) and not isinstance(seeds, bool) and seeds >= 1:
        seeds = list(range(seeds))  # seeds = 5 means seeds 0..4
    seeds = _int_list(seeds, f"{where}.seeds", fail, 0)
    for key, value in (("iterations", settings["iterations"]), ("top-level iterations", top.get("iterations"))):
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise fail(f"{where}: {key} must be an int >= 1, got {value!r}")
    # an agent's own budget can only lower the sweep's (e.g. SAC), so a variant's cap holds for all
    iterations = min(settings["iterations"], top["iterations"])
    trajectory_iterations = settings["trajectory_iterations"] or []
    if trajectory_iterations:
        trajectory_iterations = _int_list(trajectory_iterations, f"{where}.trajectory_iterations", fail, 0)
    runs = []
    for combo in itertools.product(*grid.values()):
        values = {**hyper, **dict(zip(grid, combo))}
        try:
            run_label = label.format(**values)
        except (KeyError, IndexError, ValueError) as exc:
            raise fail(f"{where}.label {label!r} cannot be filled from {values}: {exc}") from None
        for task in tasks:
            kwargs = dict(env_kwargs) if task is None else {**env_kwargs, "task": task}
            for seed in seeds:
                runs.append(RunSpec(
                    env=top["env"], env_kwargs=kwargs, agent=agent, label=run_label, hyperparameters=values,
                    seed=seed, iterations=iterations, evaluate_episodes=int(settings["evaluate_episodes"]),
                    evaluate_every=int(settings["evaluate_every"]),
                    trajectory_iterations=tuple(t for t in trajectory_iterations if t <= iterations),
                    trajectory_episodes=int(settings["trajectory_episodes"]),
                    save_agent=bool(settings["save_agent"]), note=str(entry.get("note", "")),
                ))
    return runs


@dataclasses.dataclass
class SweepReport:
    """What a sweep did: runs finished now, skipped as already done, and failures (run id -> traceback)."""

    finished: list[str] = dataclasses.field(default_factory=list)
    skipped: list[str] = dataclasses.field(default_factory=list)
    failed: dict[str, str] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0


def run_sweep(
    sweep: Sweep,
    out_dir: str | Path,
    workers: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
    only: Sequence[str] = (),
) -> SweepReport:
    """Run every unfinished run of ``sweep`` into ``out_dir/runs/<run_id>``.

    Args:
        sweep: from `load_config`.
        out_dir: results directory (created); ``out_dir/sweep.json`` lists this sweep's runs.
        workers: local processes (default: the CPU count); 0 runs in this process, one run after
            the other (for debugging); ignored with ``ray_address``.
        ray_address: run on Ray instead (``"auto"``, ``"ray://host:10001"``, ``"local"`` to start one
            here); if Ray is already initialised in this process, that instance is used.
        progress: show a tqdm bar over runs.
        only: run only the runs whose label matches one of these shell patterns (``"TLPS*"``);
            ``sweep.json`` still lists every run of the config.

    Returns:
        A `SweepReport`; a failed run leaves no ``done.json`` and is retried by the next sweep.
    """
    out_dir = Path(out_dir)
    (out_dir / "runs").mkdir(parents=True, exist_ok=True)
    manifest = {"name": sweep.name, "description": sweep.description,
                "runs": {run.run_id: run.to_json() for run in sweep.runs}}
    write_atomic(out_dir / "sweep.json", json.dumps(manifest, indent=1).encode())
    report = SweepReport()
    pending = []
    selected = [run for run in sweep.runs if not only or any(fnmatch.fnmatchcase(run.label, p) for p in only)]
    for run in selected:
        (report.skipped if is_done(out_dir / "runs" / run.run_id) else pending).append(run)
    report.skipped = [run.run_id for run in report.skipped]
    start = time.perf_counter()
    with tqdm(total=len(selected), initial=len(report.skipped), disable=not progress, unit="run",
              desc=sweep.name, dynamic_ncols=True) as bar:
        if ray_address is not None:
            _run_on_ray(pending, out_dir, ray_address, report, bar)
        elif workers == 0:
            for run in pending:  # in this process, one after the other (debugging)
                try:
                    execute_run(run, out_dir / "runs" / run.run_id)
                except Exception as error:  # noqa: BLE001 - one failed run must not stop the sweep
                    _settle(run, error, report, bar)
                else:
                    _settle(run, None, report, bar)
        elif pending:
            _run_locally(pending, out_dir, workers or os.cpu_count() or 1, report, bar)
    report.wall_time = time.perf_counter() - start
    return report


def _run_locally(pending: Sequence[RunSpec], out_dir: Path, workers: int, report: SweepReport, bar: tqdm) -> None:
    # spawn: a fresh interpreter per worker, no torch/thread state inherited through fork
    context = multiprocessing.get_context("spawn")
    with futures.ProcessPoolExecutor(max_workers=min(workers, len(pending)), mp_context=context) as pool:
        jobs = {pool.submit(execute_run, run.to_json(), str(out_dir / "runs" / run.run_id)): run
                for run in pending}
        for job in futures.as_completed(jobs):
            _settle(jobs[job], job.exception(), report, bar)


def _settle(run: RunSpec, error: BaseException | None, report: SweepReport, bar: tqdm) -> None:
    if error is None:
        report.finished.append(run.run_id)
    else:
        text = "".join(traceback.format_exception(type(error), error, error.__traceback__))
        report.failed[run.run_id] = text
        bar.write(f"run {run.run_id} failed: {type(error).__name__}: {error}")
    bar.update(1)


def _run_on_ray(pending: Sequence[RunSpec], out_dir: Path, address: str, report: SweepReport, bar: tqdm) -> None:
    try:
        import ray
    except ImportError as exc:
        raise ImportError('--ray needs Ray, which is not installed: pip install "tl_gym[ray]"') from exc
    if not ray.is_initialized():
        # the driver's import path, so local workers find `benchmarks` (cluster workers need it installed)
        runtime_env = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}}
        ray.init(address=None if address == "local" else address, runtime_env=runtime_env)
    remote = ray.remote(num_cpus=1, max_retries=0)(run_files)
    refs = {remote.remote(run.to_json()): run for run in pending}
    while refs:
        ready, _ = ray.wait(list(refs), num_returns=1)
        for ref in ready:
            run = refs.pop(ref)
            try:
                install_files(ray.get(ref), out_dir / "runs" / run.run_id)
            except Exception as error:  # noqa: BLE001 - one failed run must not stop the sweep
                _settle(run, error, report, bar)
            else:
                _settle(run, None, report, bar)


def default_out_dir(sweep: Sweep) -> Path:
    """Where a sweep writes by default: ``runs/sweeps/<name>`` (git-ignored)."""
    return Path("runs") / "sweeps" / sweep.name


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``python -m benchmarks.sweep CONFIG [--ray ADDRESS] [--workers K] [--quick | --variant V]``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.sweep", description=__doc__.split("\n")[0])
    parser.add_argument("config", help="sweep config (TOML), e.g. benchmarks/configs/paper.toml")
    parser.add_argument("--out", help="results directory (default runs/sweeps/<name>[-<variant>])")
    parser.add_argument("--workers", type=int, default=None,
                        help="local worker processes (default: CPU count; 0: serial, in this process)")
    parser.add_argument("--ray", metavar="ADDRESS", help='run on Ray: "auto", "ray://host:10001", or "local"')
    parser.add_argument("--quick", action="store_true", help="same as --variant quick (CI-sized)")
    parser.add_argument("--variant", help="apply the config's [variants.VARIANT] overrides")
    parser.add_argument("--only", action="append", default=[], metavar="PATTERN",
                        help='run only labels matching this shell pattern, e.g. "TLPS*" (repeatable)')
    parser.add_argument("--list", action="store_true", help="list the runs and whether they are done, then exit")
    args = parser.parse_args(argv)
    if args.workers is not None and args.workers < 0:
        parser.error(f"--workers must be >= 0, got {args.workers}")
    try:
        if args.quick and args.variant not in (None, "quick"):
            parser.error("--quick is --variant quick; give one of them")
        sweep = load_config(args.config, variant="quick" if args.quick else args.variant)
    except ConfigError as exc:
        parser.error(str(exc))
    out_dir = Path(args.out) if args.out else default_out_dir(sweep)
    if args.list:
        for run in sweep.runs:
            print(("done " if is_done(out_dir / "runs" / run.run_id) else "todo ") + run.run_id)
        return 0
    report = run_sweep(sweep, out_dir, workers=args.workers, ray_address=args.ray, only=args.only)
    print(f"{sweep.name}: {len(report.finished)} run(s) finished, {len(report.skipped)} already done, "
          f"{len(report.failed)} failed, {report.wall_time:.1f} s; results in {out_dir}")
    for run_id, text in report.failed.items():
        print(f"--- {run_id} failed:\n{text}", file=sys.stderr)
    return 1 if report.failed else 0


if __name__ == "__main__":
    sys.exit(main())
