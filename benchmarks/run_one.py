"""One run of the experiment runner: train a `RunSpec`'s agent into its folder, checkpoint it, resume it.

The folder holds ``spec.json``, ``history.csv`` (a row per iteration), ``trajectories.npz`` (the episodes sampled at
the spec's ``trajectory_iterations``), ``agent.zip`` (the final agent) and ``done.json``, written last and
atomically: it alone marks the run finished (`is_done`). Until then ``checkpoint/`` holds the latest checkpoint,
from which `execute_run` resumes. A run being trained holds the lock ``<run folder>.lock`` beside its folder
(`run_lock`), so that two local runners on one results folder never train, or wipe, the same run (a Ray task trains
in a scratch folder without it; its files are installed under the lock, never over a finished run). Kept apart from
the sweep (`benchmarks.runner`), which only decides where each run executes (a worker process, this process, or a
Ray task through `run_files` and `install_files`), so that the trials that run one spec of their own
(`benchmarks.parking_demos`, `benchmarks.parking_nstep`) call it alone; the reports (`benchmarks.results`) read the
folders through the file names here. Run files: ``docs/benchmarks.md``.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import os
import pickle
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from tl_gym.agents.callbacks import ALONG_TRAINING_EVAL_SEED
from tl_gym.agents.run_folder import AGENT_FILE, HISTORY_FILE, RUNNER_DONE_FILE, RUNNER_SPEC_FILE
from tl_gym.agents.serialization import write_atomic

from benchmarks.provenance import code_version
from benchmarks.sweep_config import RunSpec

DONE, SPEC, HISTORY, AGENT = RUNNER_DONE_FILE, RUNNER_SPEC_FILE, HISTORY_FILE, AGENT_FILE
TRAJECTORIES = "trajectories.npz"
#: Reset seed of the first of the final evaluation's fresh episodes (``done.json``), plus the run's seed: apart from
#: the evaluations along training (`ALONG_TRAINING_EVAL_SEED`) and from the training episodes.
FINAL_EVAL_SEED = 10_000_019
#: The trajectory snapshot of iteration ``i`` resets with seeds from ``TRAJECTORY_SEED_STRIDE * (i + 1)`` (plus the
#: run's seed): each snapshot its own episodes, none trained on. Snapshots of iterations 9 and 19 would share seeds
#: with the final evaluation and the evaluations along training (pictures only, no number; no config asks for them).
TRAJECTORY_SEED_STRIDE = 1_000_003
#: A run's latest checkpoint: a folder of the agent (written last: it marks a whole checkpoint), the replay buffer
#: of an off-policy agent, the trajectories sampled so far and STATE; removed once the run is done.
CHECKPOINT, REPLAY_BUFFER, STATE = "checkpoint", "replay_buffer.pkl", "state.json"


class RunInProgress(RuntimeError):
    """Another process holds the run's lock: it is training that run now (`run_lock`)."""


@contextlib.contextmanager
def run_lock(run_dir: str | Path) -> Iterator[None]:
    """Hold ``<run_dir>.lock`` (an advisory ``flock``) while a process trains or installs the run in ``run_dir``.

    The lock sits beside the folder, not in it: a run that starts afresh wipes its folder. The file stays after
    the run (removing it would race with a process about to take it); the kernel frees the lock when its
    holder exits, however it exits. Where ``fcntl`` is missing (Windows) runs are not locked.

    Raises:
        RunInProgress: another process holds the lock.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    path = Path(str(Path(run_dir)) + ".lock")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            raise RunInProgress(f"{Path(run_dir).name}: its lock {path} is held, by a runner training it; this one "
                                "leaves it alone") from None
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


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
    with run_lock(run_dir):
        return _execute_locked(spec, Path(run_dir), checkpoint_every, prepare)


def _execute_locked(spec: RunSpec, run_dir: Path, checkpoint_every: int,
                    prepare: Callable[[Any], None] | None) -> dict[str, Any]:
    if is_done(run_dir):  # perhaps by the process that held the lock before
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
            result = agent.evaluate(n_episodes=spec.evaluate_episodes, seed=ALONG_TRAINING_EVAL_SEED + spec.seed)
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
    for name in (CHECKPOINT, CHECKPOINT_NEW, CHECKPOINT_OLD):
        _discard(run_dir / name)
    return summary


#: Where a checkpoint is written before it replaces the last one, and where the last one waits meanwhile.
CHECKPOINT_NEW, CHECKPOINT_OLD = f"{CHECKPOINT}.new", f"{CHECKPOINT}.old"


def save_checkpoint(agent: Any, run_dir: Path, traces: Mapping[str, np.ndarray], state: Mapping[str, Any]) -> None:
    """Write ``run_dir/checkpoint``: what `load_checkpoint` needs to go on from the agent's last iteration.

    The new checkpoint is written whole in ``checkpoint.new`` (the agent last: a folder with ``agent.zip`` is
    whole), then swapped in by two renames; the last one is removed only after. A run killed at any moment
    keeps a whole checkpoint, the new one or the last (`_whole_checkpoints` finds them).
    """
    new, current, old = run_dir / CHECKPOINT_NEW, run_dir / CHECKPOINT, run_dir / CHECKPOINT_OLD
    _discard(new)
    new.mkdir()
    if getattr(agent, "off_policy", False):
        agent.save_replay_buffer(new / REPLAY_BUFFER)
    if traces:
        write_atomic(new / TRAJECTORIES, compressed_arrays(traces))
    write_atomic(new / STATE, json.dumps(dict(state), indent=1).encode())
    agent.save(new / AGENT)
    _discard(old)
    if current.exists():
        current.rename(old)
    new.rename(current)
    _discard(old)


def _discard(folder: Path) -> None:
    """Remove a checkpoint folder, its ``agent.zip`` first.

    A removal cut short never leaves a folder that looks whole (one holding ``agent.zip``) with its other files gone.
    """
    (folder / AGENT).unlink(missing_ok=True)
    shutil.rmtree(folder, ignore_errors=True)


def _whole_checkpoints(run_dir: Path) -> list[Path]:
    """``run_dir``'s whole checkpoint folders (holding ``agent.zip``), newest first, whatever killed the last save."""
    return [run_dir / name for name in (CHECKPOINT_NEW, CHECKPOINT, CHECKPOINT_OLD)  # .new: whole once written
            if (run_dir / name / AGENT).is_file()]


def load_checkpoint(spec: RunSpec, run_dir: Path) -> tuple[Any, dict[str, np.ndarray], dict[str, Any]] | None:
    """The agent, sampled trajectories and state of ``run_dir``'s checkpoint; ``None`` if it has none for ``spec``.

    The newest whole checkpoint that loads; one that does not (a file lost to a kill, code too different) gives
    way to the one before it.
    """
    try:
        same_spec = json.loads((run_dir / SPEC).read_text()) == json.loads(json.dumps(spec.to_json()))
    except (OSError, ValueError):
        return None
    if not same_spec:
        return None
    for folder in _whole_checkpoints(run_dir):
        try:
            return _read_checkpoint(spec, folder)
        except (OSError, ValueError, EOFError, pickle.UnpicklingError) as error:  # IncompatibleSaveError: ValueError
            print(f"{folder}: checkpoint not loadable ({error}); trying an earlier one", file=sys.stderr)
    return None


def _read_checkpoint(spec: RunSpec, folder: Path) -> tuple[Any, dict[str, np.ndarray], dict[str, Any]]:
    from tl_gym.agents.registry import agent_class

    state = json.loads((folder / STATE).read_text())  # read first: a folder without it is not whole
    agent = agent_class(spec.agent).load(folder / AGENT)
    if getattr(agent, "off_policy", False):
        agent.load_replay_buffer(folder / REPLAY_BUFFER)  # an off-policy agent's buffer is part of its state
    traces = {}
    if (folder / TRAJECTORIES).is_file():
        with np.load(folder / TRAJECTORIES) as saved:
            traces = {name: saved[name] for name in saved.files}
    return agent, traces, state


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
    from tl_gym.agents.env_ids import make_vector_env
    from tl_gym.agents.evaluation import collect_episodes

    n = spec.trajectory_episodes
    with contextlib.closing(make_vector_env(spec.env, n, getattr(agent, "env_kwargs", spec.env_kwargs))) as venv:
        robustness, traces = collect_episodes(agent, venv, n, seed=TRAJECTORY_SEED_STRIDE * (iteration + 1) + spec.seed)
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
        result = agent.evaluate(n_episodes=spec.evaluate_episodes, seed=FINAL_EVAL_SEED + spec.seed,
                                deterministic=deterministic)
        summary["eval_deterministic" if deterministic else "eval_stochastic"] = {
            "mean_robustness": float(result["mean_robustness"]), "success_rate": float(result["success_rate"]),
            "episodes": spec.evaluate_episodes}
    return summary


def run_files(spec: RunSpec) -> dict[str, bytes]:
    """Run ``spec`` in a scratch folder and return its files (the Ray path: no shared filesystem)."""
    with tempfile.TemporaryDirectory(prefix="tl_gym_run_") as scratch:
        execute_run(spec, Path(scratch) / "run")
        return {p.name: p.read_bytes() for p in (Path(scratch) / "run").iterdir() if p.is_file()}


def install_files(files: Mapping[str, bytes], run_dir: str | Path) -> bool:
    """Write a finished run's files (from `run_files`) into ``run_dir``, ``done.json`` last (ValueError if none).

    A run finished there meanwhile (a local runner on the same folder: Ray tasks train without its lock) is kept,
    and these files are dropped: the return value says whether they were installed. Raises `RunInProgress` when
    a local process is training the same run there.
    """
    if DONE not in files:
        raise ValueError(f"not a finished run: no {DONE} among {sorted(files)}")
    run_dir = Path(run_dir)
    with run_lock(run_dir):
        if is_done(run_dir):
            return False
        shutil.rmtree(run_dir, ignore_errors=True)
        run_dir.mkdir(parents=True, exist_ok=True)
        for name in sorted(files, key=lambda n: n == DONE):
            write_atomic(run_dir / name, files[name])
    return True
