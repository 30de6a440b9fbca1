"""The experiment runner: a TOML config expands into runs (task × agent × hyperparameters × seed).

Every run gets a folder ``OUT/runs/<run_id>`` whose ``done.json``, written last and atomically, alone marks it
finished: a rerun skips it, resumes an unfinished run from its last checkpoint (``--checkpoint-every``) and restarts
the others from scratch. ``OUT/sweep.json`` lists the config's runs for `benchmarks.results`. Command line, config
keys and run files: ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures as futures
import contextlib
import csv
import dataclasses
import fnmatch
import hashlib
import io
import itertools
import json
import multiprocessing
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tl_gym.agents.serialization import write_atomic

from tl_gym.errors import IncompatibleSaveError

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

DONE, SPEC, HISTORY, TRAJECTORIES, AGENT = "done.json", "spec.json", "history.csv", "trajectories.npz", "agent.zip"
#: A run's latest checkpoint: a folder of the agent (written last: it marks a whole checkpoint), the replay buffer
#: of an off-policy agent, the trajectories sampled so far and STATE; removed once the run is done.
CHECKPOINT, REPLAY_BUFFER, STATE = "checkpoint", "replay_buffer.pkl", "state.json"
#: Iterations between checkpoints on the command line (0: none).
DEFAULT_CHECKPOINT_EVERY = 5
#: Keys an agent entry inherits from the top level (a variant may override them at either level).
INHERITED = {"tasks": None, "seeds": None, "iterations": None, "evaluate_episodes": 0, "evaluate_every": 0,
             "trajectory_iterations": [], "trajectory_episodes": 40}
TOP_KEYS = {"name", "description", "env", "env_kwargs", "agents", "variants", *INHERITED}
AGENT_KEYS = {"label", "agent", "hyperparameters", "grid", "env_kwargs", "note", "variants", "skip", *INHERITED}
VARIANT_KEYS = TOP_KEYS - {"name", "variants", "agents"}


class ConfigError(ValueError):
    """A config that cannot be run; the message names the file and the culprit."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything that defines one training run, in JSON values (docs/benchmarks.md); a ``label``'s seeds: one curve."""

    env: str
    env_kwargs: Mapping[str, Any]
    agent: str
    label: str
    hyperparameters: Mapping[str, Any]
    seed: int
    iterations: int
    evaluate_episodes: int = 0
    evaluate_every: int = 0
    trajectory_iterations: Sequence[int] = ()
    trajectory_episodes: int = 40
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """The spec as a JSON-able dict (`from_json` inverts it)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunSpec:
        """Rebuild a spec from `to_json`'s output (or from the older sweep runner's, which had ``save_agent``)."""
        data = {key: value for key, value in data.items() if key != "save_agent"}
        return cls(**{**data, "trajectory_iterations": tuple(data.get("trajectory_iterations", ()))})

    @property
    def run_id(self) -> str:
        """Folder name: task, label and seed, plus a hash of the whole spec (a changed spec gets a new folder)."""
        digest = hashlib.sha256(json.dumps(self.to_json(), sort_keys=True).encode()).hexdigest()[:10]
        task = self.env_kwargs.get("task")
        slug = re.sub(r"[^A-Za-z0-9=.+-]+", "-", self.label.replace("β", "beta").replace("ε", "eps"))
        return f"{'' if task is None else f'task{task}__'}{slug.strip('-').lower() or 'run'}__seed{self.seed}__{digest}"


@dataclasses.dataclass(frozen=True)
class Sweep:
    """An expanded config: its name (``<name>[-<variant>]``) and its runs, in config order."""

    name: str
    description: str
    runs: tuple[RunSpec, ...]


def load_config(path: str | Path, variant: str | None = None, overrides: Mapping[str, Any] | None = None) -> Sweep:
    """Read a TOML config and expand it into runs (`expand_config`); a `ConfigError` names the file."""
    try:
        return expand_config(tomllib.loads(Path(path).read_text()), variant=variant, overrides=overrides)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"cannot read config {path}: {exc}") from exc
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def expand_config(data: Mapping[str, Any], variant: str | None = None,
                  overrides: Mapping[str, Any] | None = None) -> Sweep:
    """Expand a parsed config into its runs, checking every field first.

    ``variant`` applies ``[variants.<variant>]`` and each agent's ``variants.<variant>``; ``overrides`` are
    top-level keys set after it (e.g. ``{"seeds": 3}``). A `ConfigError` names the culprit.
    """
    _check_keys(data, TOP_KEYS, "top level")
    variants = _table(data.get("variants", {}), "variants")
    for name, table in variants.items():  # all checked, not only the one asked for
        _check_keys(table, VARIANT_KEYS, f"variants.{name}")
    if variant is not None and variant not in variants:
        raise ConfigError(f"no variant {variant!r}; the config has {sorted(variants)}")
    overrides = _check_keys(overrides or {}, VARIANT_KEYS, "overrides")
    top = {**INHERITED, "env_kwargs": {}, **data, **variants.get(variant, {}), **overrides}
    for key in ("name", "env"):
        if not isinstance(top.get(key), str) or not top[key]:
            raise ConfigError(f"'{key}' must be a non-empty string, got {top.get(key)!r}")
    if not isinstance(top.get("agents"), list) or not top["agents"]:
        raise ConfigError("no [[agents]] entries")
    runs: list[RunSpec] = []
    for index, entry in enumerate(top["agents"]):
        where = f"agents[{index}]"
        entry = _check_keys(entry, AGENT_KEYS, where)
        at = f"{where}.variants.{variant}"
        changes = _check_keys(_table(entry.get("variants", {}), f"{where}.variants").get(variant, {}), AGENT_KEYS, at)
        hyper = {**_table(entry.get("hyperparameters", {}), f"{where}.hyperparameters"),
                 **_table(changes.get("hyperparameters", {}), f"{at}.hyperparameters")}
        entry = {**entry, **changes, "hyperparameters": hyper}
        if not entry.get("skip", False):
            runs.extend(_expand_agent(entry, top, where))
    duplicates = sorted(i for i, count in collections.Counter(run.run_id for run in runs).items() if count > 1)
    if duplicates:
        raise ConfigError(f"the same run appears twice: {duplicates} (two agents with one label and hyperparameters?)")
    if not runs:
        raise ConfigError(f"variant {variant!r} skips every agent")
    return Sweep(top["name"] + (f"-{variant}" if variant else ""), str(top.get("description", "")), tuple(runs))


def _check_keys(table: Any, valid: set[str], where: str) -> dict[str, Any]:
    unknown = sorted(set(_table(table, where)) - valid)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; valid: {sorted(valid)}")
    return dict(table)


def _table(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where} must be a table, got {value!r}")
    return dict(value)


def _ints(value: Any, where: str, minimum: int) -> list[int]:
    if not isinstance(value, list) or not value or not all(
            isinstance(v, int) and not isinstance(v, bool) and v >= minimum for v in value):
        raise ConfigError(f"{where} must be a non-empty list of ints >= {minimum}, got {value!r}")
    return value


def _budget(value: Any, task: int | None, where: str) -> int:
    """An ``iterations`` value: an int, or a table by task (``{ 1 = 30, 2 = 50 }``)."""
    if isinstance(value, Mapping):
        value = value.get(str(task))
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"{where}: iterations must be an int >= 1 (or a table of them by task), got {value!r}"
                          + (f" for task {task}" if task is not None else ""))
    return value


def _check_agent(name: Any, where: str) -> str:
    from tl_gym.agents.registry import SB3_ALGORITHMS, SB3_CONTRIB_ALGORITHMS, check_agent_name, is_known_agent

    try:
        check_agent_name(name)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if not is_known_agent(name):
        raise ConfigError(f"{where}: unknown agent {name!r}: use tlps, reps, an SB3 algorithm "
                          f"({', '.join(SB3_ALGORITHMS)}), an sb3-contrib one ({', '.join(SB3_CONTRIB_ALGORITHMS)}) "
                          f"or package.module:Name")
    return name


def _expand_agent(entry: dict[str, Any], top: Mapping[str, Any], where: str) -> list[RunSpec]:
    settings = {key: entry.get(key, top.get(key)) for key in INHERITED}
    agent = _check_agent(entry.get("agent"), f"{where}.agent")
    label = entry.get("label", agent)
    grid = _table(entry.get("grid", {}), f"{where}.grid")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{where}.grid.{key} must be a non-empty list, got {values!r}")
    env_kwargs = {**_table(top["env_kwargs"], "env_kwargs"),
                  **_table(entry.get("env_kwargs", {}), f"{where}.env_kwargs")}
    tasks = [None] if settings["tasks"] is None else _ints(settings["tasks"], f"{where}.tasks", 1)
    seeds = settings["seeds"]
    if isinstance(seeds, int) and not isinstance(seeds, bool) and seeds >= 1:
        seeds = list(range(seeds))  # seeds = 5 means seeds 0..4
    seeds = _ints(seeds, f"{where}.seeds", 0)
    trajectory_iterations = settings["trajectory_iterations"] or []
    if trajectory_iterations:
        _ints(trajectory_iterations, f"{where}.trajectory_iterations", 0)
    runs = []
    for combo in itertools.product(*grid.values()):
        values = {**entry["hyperparameters"], **dict(zip(grid, combo))}
        try:
            run_label = label.format(**values)
        except (KeyError, IndexError, ValueError) as exc:
            raise ConfigError(f"{where}.label {label!r} cannot be filled from {values}: {exc}") from None
        for task in tasks:
            # an agent's own budget can only lower the config's (e.g. SAC), so a variant's cap holds for all
            iterations = min(_budget(settings["iterations"], task, where),
                             _budget(top["iterations"], task, "top level"))
            for seed in seeds:
                runs.append(RunSpec(
                    env=top["env"], env_kwargs=env_kwargs if task is None else {**env_kwargs, "task": task},
                    agent=agent, label=run_label, hyperparameters=values, seed=seed, iterations=iterations,
                    evaluate_episodes=int(settings["evaluate_episodes"]),
                    evaluate_every=int(settings["evaluate_every"]),
                    trajectory_iterations=tuple(t for t in trajectory_iterations if t <= iterations),
                    trajectory_episodes=int(settings["trajectory_episodes"]), note=str(entry.get("note", "")),
                ))
    return runs


# One run ----------------------------------------------------------------------------------------------------------
def is_done(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` holds a finished run."""
    return (Path(run_dir) / DONE).is_file()


def execute_run(spec: RunSpec, run_dir: str | Path, checkpoint_every: int = 0,
                prepare: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """Run ``spec`` into ``run_dir``; return ``done.json``'s content.

    A finished run is returned as it is; an unfinished one resumes from its checkpoint when ``run_dir`` has one
    of the same spec, else starts from scratch. ``checkpoint_every``: iterations between checkpoints (0: none).
    A resumed run is not bit-identical to an uninterrupted one (episodes in progress restart, and SB3 keeps no
    random state); ``done.json``'s ``resumed_at`` lists the iterations it resumed after.
    ``prepare``: called with a new agent before its first iteration (a trial's extra set-up, such as
    demonstrations in a replay buffer); not on a resumed run, whose checkpoint holds what it did.
    """
    run_dir = Path(run_dir)
    if is_done(run_dir):
        return json.loads((run_dir / DONE).read_text())
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # runs are parallel processes: one thread each
        os.environ.setdefault(name, "1")
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    from tl_gym.agents.callbacks import HistoryCSV
    from tl_gym.agents.registry import make_agent

    start, code = time.perf_counter(), code_version()  # the code this process imports now, not at the end
    history = HistoryCSV(run_dir / HISTORY)
    resumed = load_checkpoint(spec, run_dir)
    if resumed is None:
        shutil.rmtree(run_dir, ignore_errors=True)
        run_dir.mkdir(parents=True)
        write_atomic(run_dir / SPEC, json.dumps(spec.to_json(), indent=1).encode())
        agent = make_agent(spec.agent, spec.env, seed=spec.seed, env_kwargs=dict(spec.env_kwargs),
                           **dict(spec.hyperparameters))
        if prepare is not None:
            prepare(agent)
        traces: dict[str, np.ndarray] = {}
        state: dict[str, Any] = {"resumed_at": [], "wall_time": 0.0, "code": code}
    else:
        agent, traces, state = resumed
        state["resumed_at"].append(len(agent.history))
        history.rows = read_history_rows(run_dir / HISTORY)[: len(agent.history)]  # written before the checkpoint

    def record(agent: Any, row: Mapping[str, Any]) -> bool:
        row = {**row, "eval_success_rate": np.nan, "eval_mean_robustness": np.nan}
        every, iteration = spec.evaluate_every, row["iteration"]
        if every and spec.evaluate_episodes and (iteration % every == 0 or iteration == spec.iterations):
            result = agent.evaluate(n_episodes=spec.evaluate_episodes, seed=20_000_033 + spec.seed)
            row.update(eval_success_rate=float(result["success_rate"]),
                       eval_mean_robustness=float(result["mean_robustness"]))
        history.on_iteration(agent, row)
        if iteration in spec.trajectory_iterations:
            traces.update(sample_traces(agent, spec, int(iteration)))
        if checkpoint_every and iteration % checkpoint_every == 0 and iteration < spec.iterations:
            save_checkpoint(agent, run_dir, traces, {**state, "wall_time": state["wall_time"] + time.perf_counter()
                                                     - start})
        return True

    with contextlib.closing(agent):
        if resumed is None and 0 in spec.trajectory_iterations:
            traces.update(sample_traces(agent, spec, 0))
        agent.learn(spec.iterations - len(agent.history), callback=record)
        started_with = state["code"] if state["code"] == code else f"{state['code']}, resumed with {code}"
        summary = _summarise(spec, agent, state["wall_time"] + time.perf_counter() - start, started_with)
        summary["resumed_at"] = state["resumed_at"]
        agent.save(run_dir / AGENT)  # the final agent, for `tl-gym eval RUN_DIR --why` (not kept in git)
    if traces:
        write_atomic(run_dir / TRAJECTORIES, compressed_arrays(traces))
    write_atomic(run_dir / DONE, json.dumps(summary, indent=1).encode())
    shutil.rmtree(run_dir / CHECKPOINT, ignore_errors=True)
    return summary


def save_checkpoint(agent: Any, run_dir: Path, traces: Mapping[str, np.ndarray], state: Mapping[str, Any]) -> None:
    """Write ``run_dir/checkpoint``: what `load_checkpoint` needs to go on from the agent's last iteration."""
    folder = run_dir / CHECKPOINT
    folder.mkdir(exist_ok=True)
    (folder / AGENT).unlink(missing_ok=True)  # until the new agent is written, the checkpoint is not whole
    if getattr(agent, "off_policy", False):
        agent.save_replay_buffer(folder / REPLAY_BUFFER)
    (folder / TRAJECTORIES).unlink(missing_ok=True)
    if traces:
        write_atomic(folder / TRAJECTORIES, compressed_arrays(traces))
    write_atomic(folder / STATE, json.dumps(dict(state), indent=1).encode())
    agent.save(folder / AGENT)


def load_checkpoint(spec: RunSpec, run_dir: Path) -> tuple[Any, dict[str, np.ndarray], dict[str, Any]] | None:
    """The agent, sampled trajectories and state of ``run_dir``'s checkpoint; ``None`` if it has none for ``spec``."""
    from tl_gym.agents.registry import agent_class

    folder = run_dir / CHECKPOINT
    try:
        same_spec = json.loads((run_dir / SPEC).read_text()) == json.loads(json.dumps(spec.to_json()))
    except (OSError, ValueError):
        return None
    if not same_spec or not (folder / AGENT).is_file():
        return None
    try:
        agent = agent_class(spec.agent).load(folder / AGENT)
    except IncompatibleSaveError as error:  # saved by code that differs too much: start again
        print(f"{run_dir}: checkpoint not loadable ({error}); restarting the run", file=sys.stderr)
        return None
    if (folder / REPLAY_BUFFER).is_file():
        agent.load_replay_buffer(folder / REPLAY_BUFFER)
    traces = {}
    if (folder / TRAJECTORIES).is_file():
        with np.load(folder / TRAJECTORIES) as saved:
            traces = {name: saved[name] for name in saved.files}
    return agent, traces, json.loads((folder / STATE).read_text())


def read_history_rows(path: str | Path) -> list[dict[str, str]]:
    """The rows of a ``history.csv`` as written (text values): to write them again, or to read as numbers."""
    with Path(path).open(newline="") as file:
        return list(csv.DictReader(file))


def compressed_arrays(arrays: Mapping[str, np.ndarray]) -> bytes:
    """``arrays`` as the bytes of a compressed ``.npz``."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def sample_traces(agent: Any, spec: RunSpec, iteration: int) -> dict[str, np.ndarray]:
    """``trajectory_episodes`` episodes of the stochastic policy on the agent's own env view.

    ``it<k>_<signal>`` (the signals ρ was computed on) -> ``(episodes, T+1)`` float32, NaN-padded; ``it<k>_robustness``.
    """
    from tl_gym.agents.evaluation import collect_episodes
    from tl_gym.agents.sampling import make_vector_env

    n = spec.trajectory_episodes
    with contextlib.closing(make_vector_env(spec.env, n, getattr(agent, "env_kwargs", spec.env_kwargs))) as venv:
        robustness, traces = collect_episodes(agent, venv, n, seed=1_000_003 * (iteration + 1) + spec.seed)
    out = {f"it{iteration}_robustness": robustness}
    for name, episodes in traces.items():
        padded = np.full((n, max(len(e) for e in episodes)), np.nan)
        for i, values in enumerate(episodes):
            padded[i, : len(values)] = values
        out[f"it{iteration}_{name}"] = padded.astype(np.float32)
    return out


def _summarise(spec: RunSpec, agent: Any, elapsed: float, code: str) -> dict[str, Any]:
    last = agent.history[-1] if agent.history else {}
    summary: dict[str, Any] = {
        "run_id": spec.run_id, "label": spec.label, "iterations": len(agent.history),
        "env_steps": int(last.get("env_steps", 0)), "train_wall_time": float(last.get("wall_time", 0.0)),
        "total_wall_time": elapsed, "final_mean_robustness": float(last.get("mean_robustness", np.nan)),
        "final_success_rate": float(last.get("success_rate", np.nan)), "note": spec.note, "code": code,
    }
    for deterministic in (True, False) if spec.evaluate_episodes > 0 else ():
        result = agent.evaluate(n_episodes=spec.evaluate_episodes, seed=10_000_019 + spec.seed,
                                deterministic=deterministic)
        summary["eval_deterministic" if deterministic else "eval_stochastic"] = {
            "mean_robustness": float(result["mean_robustness"]), "success_rate": float(result["success_rate"]),
            "episodes": spec.evaluate_episodes}
    return summary


def code_version() -> str:
    """The tl_gym version and, in a git checkout, the commit (``+dirty`` if library code is modified)."""
    import tl_gym

    root = Path(tl_gym.__file__).resolve().parents[1]
    commit = git("rev-parse", "--short", "HEAD", cwd=root)
    if commit is None:
        return tl_gym.__version__
    dirty = git("status", "--porcelain", "--", "tl_gym", "agents", "envs", cwd=root)
    return f"{tl_gym.__version__} ({commit}{'+dirty' if dirty else ''})"


def git(*args: str, cwd: str | Path | None = None) -> str | None:
    """The output of ``git ARGS`` (stripped), or None outside a checkout or without git."""
    try:
        return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def run_files(spec: RunSpec) -> dict[str, bytes]:
    """Run ``spec`` in a scratch folder and return its files (the Ray path: no shared filesystem)."""
    with tempfile.TemporaryDirectory(prefix="tl_gym_run_") as scratch:
        execute_run(spec, Path(scratch) / "run")
        return {p.name: p.read_bytes() for p in (Path(scratch) / "run").iterdir() if p.is_file()}


def install_files(files: Mapping[str, bytes], run_dir: str | Path) -> None:
    """Write a finished run's files (from `run_files`) into ``run_dir``, ``done.json`` last (ValueError if none)."""
    if DONE not in files:
        raise ValueError(f"not a finished run: no {DONE} among {sorted(files)}")
    run_dir = Path(run_dir)
    if not is_done(run_dir):
        shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in sorted(files, key=lambda n: n == DONE):
        write_atomic(run_dir / name, files[name])


# A sweep ----------------------------------------------------------------------------------------------------------
@dataclasses.dataclass
class SweepReport:
    """What a sweep did: run ids finished now, skipped as done already, and failed (run id -> traceback)."""

    finished: list[str] = dataclasses.field(default_factory=list)
    skipped: list[str] = dataclasses.field(default_factory=list)
    failed: dict[str, str] = dataclasses.field(default_factory=dict)
    wall_time: float = 0.0

    def attempt(self, run: RunSpec, work: Callable[[], Any]) -> None:
        """Call ``work`` and count ``run`` as finished, or as failed with the traceback of what it raised."""
        try:
            work()
        except Exception as error:  # noqa: BLE001 - one failed run must not stop the sweep
            self.failed[run.run_id] = "".join(traceback.format_exception(type(error), error, error.__traceback__))
            print(f"run {run.run_id} failed: {type(error).__name__}: {error}", file=sys.stderr)
        else:
            self.finished.append(run.run_id)


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
        _run_on_ray(pending, out_dir, ray_address, report)
    elif pending and workers == 0:
        for run in pending:
            report.attempt(run, lambda run=run: execute_run(run, out_dir / "runs" / run.run_id, checkpoint_every))
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


def _run_on_ray(pending: Sequence[RunSpec], out_dir: Path, address: str, report: SweepReport) -> None:
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
    report = run_with_options(sweep, out_dir, args)
    print(f"{sweep.name}: {len(report.finished)} run(s) finished, {len(report.skipped)} already done, "
          f"{len(report.failed)} failed, {report.wall_time:.1f} s; results in {out_dir}")
    return 1 if report.failed else 0


if __name__ == "__main__":
    sys.exit(main())
