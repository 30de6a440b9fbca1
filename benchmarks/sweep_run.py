"""One run of a sweep: build an agent, train it, record everything on disk, mark it done.

A run is a `RunSpec`: (env, env kwargs, agent, hyperparameters, seed, iterations) plus what
to record. `execute_run` turns it into a directory::

    spec.json          the spec, written first
    history.csv        one row per iteration, appended (and flushed) as training goes
    trajectories.npz   sampled signal traces at selected iterations (Figure-2 plots), optional
    agent.zip          the trained agent (`Agent.save`), optional
    done.json          summary (final evaluation, wall time); written last, atomically

``done.json`` is the only mark of a finished run: it is written through a temporary file
and `os.replace`, so a run killed at any moment leaves either a complete run or a
directory without ``done.json``, which the next sweep wipes and runs again.
Every file is written atomically except ``history.csv``, which is live progress only.

Example:
    >>> spec = RunSpec(env="TLCarNav-v0", env_kwargs={"task": 1}, agent="tlps", label="TLPS",
    ...                hyperparameters={"beta": 9.0}, seed=0, iterations=50)
    >>> spec.run_id  # doctest: +ELLIPSIS
    'task1__tlps__seed0__...'
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import importlib
import io
import json
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Agent names a config may use besides ``"sb3:<ALGO>"`` and ``"package.module:Name"``.
BUILTIN_AGENTS = {"tlps": "tl_gym.agents:TLPS", "reps": "tl_gym.agents:REPS"}

DONE = "done.json"
SPEC = "spec.json"
HISTORY = "history.csv"
TRAJECTORIES = "trajectories.npz"
AGENT = "agent.zip"


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything that defines one training run; plain JSON values only.

    Attributes:
        env: Gymnasium env id.
        env_kwargs: env constructor arguments (the car's ``task``, ``no_revisit``...).
        agent: ``"tlps"``, ``"reps"``, ``"sb3:<ALGO>"`` (e.g. ``"sb3:PPO"``) or
            ``"package.module:Name"`` (a class or factory with the agents' signature).
        label: the curve this run belongs to (seeds of one label are aggregated).
        hyperparameters: the agent's keyword arguments.
        seed: the agent's seed.
        iterations: number of policy updates.
        evaluate_episodes: fresh episodes for the final evaluation (0: none).
        evaluate_every: also evaluate ``evaluate_episodes`` fresh episodes (deterministic policy) after
            every this many iterations and after the last, into the history columns
            ``eval_success_rate`` and ``eval_mean_robustness`` (0: never; learning curves on fresh episodes).
        trajectory_iterations: iterations after which sampled traces are recorded (0 = before training).
        trajectory_episodes: episodes per recorded iteration.
        save_agent: keep the trained agent as ``agent.zip``.
        note: free text carried to the tables (e.g. a reduced budget).
    """

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
    save_agent: bool = False
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """The spec as a JSON-able dict (`from_json` inverts it)."""
        data = dataclasses.asdict(self)
        data["env_kwargs"] = dict(self.env_kwargs)
        data["hyperparameters"] = dict(self.hyperparameters)
        data["trajectory_iterations"] = list(self.trajectory_iterations)
        return data

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunSpec:
        """Rebuild a spec from `to_json`'s output."""
        data = dict(data)
        data["trajectory_iterations"] = tuple(data.get("trajectory_iterations", ()))
        return cls(**data)

    @property
    def run_id(self) -> str:
        """Directory name: readable parts plus a hash of the whole spec.

        A changed spec (other iterations, hyperparameters...) gets a new directory, so results
        on disk never silently stand for a different experiment.
        """
        digest = hashlib.sha256(json.dumps(self.to_json(), sort_keys=True).encode()).hexdigest()[:10]
        task = self.env_kwargs.get("task")
        prefix = f"task{task}__" if task is not None else ""
        return f"{prefix}{_slug(self.label)}__seed{self.seed}__{digest}"


def _slug(text: str) -> str:
    text = text.replace("β", "beta").replace("ε", "eps")
    return re.sub(r"[^A-Za-z0-9=.+-]+", "-", text).strip("-").lower() or "run"


def is_done(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` holds a finished run."""
    return (Path(run_dir) / DONE).is_file()


def check_agent_name(name: str) -> None:
    """Check that ``name`` has one of the accepted forms, without importing anything.

    Raises:
        ValueError: it has none (the message lists them).
    """
    if name in BUILTIN_AGENTS or (name.startswith("sb3:") and len(name) > 4) or (
            not name.startswith("sb3:") and ":" in name.strip(":")):
        return
    raise ValueError(
        f"unknown agent {name!r}: use one of {sorted(BUILTIN_AGENTS)}, sb3:<ALGO> (e.g. sb3:PPO) "
        "or package.module:Name"
    )


def resolve_agent(name: str) -> Any:
    """The class or factory an agent name stands for, ``f(env, *, seed, env_kwargs, **hp)``.

    Raises:
        ValueError: a name of none of the accepted forms.
        ImportError: the module or attribute does not exist (or the ``sb3`` extra is missing).
    """
    check_agent_name(name)
    if name.startswith("sb3:"):
        algo = name[4:]
        from tl_gym.agents import SB3Agent

        def make_sb3(env: Any, **kwargs: Any) -> Any:
            return SB3Agent(algo, env, **kwargs)

        return make_sb3
    module_name, _, attribute = BUILTIN_AGENTS.get(name, name).partition(":")
    module = importlib.import_module(module_name)
    try:
        return getattr(module, attribute)
    except AttributeError as exc:
        raise ImportError(f"agent {name!r}: module {module_name!r} has no {attribute!r}") from exc


def execute_run(spec: RunSpec | Mapping[str, Any], run_dir: str | Path) -> dict[str, Any]:
    """Run ``spec`` into ``run_dir`` unless it is finished there already; return its summary.

    An unfinished directory (no ``done.json``) is wiped and the run starts from scratch.

    Returns:
        The content of ``done.json``.
    """
    spec = spec if isinstance(spec, RunSpec) else RunSpec.from_json(spec)
    run_dir = Path(run_dir)
    if is_done(run_dir):
        return json.loads((run_dir / DONE).read_text())
    if run_dir.exists():
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True)
    write_atomic(run_dir / SPEC, json.dumps(spec.to_json(), indent=1).encode())
    _limit_threads()
    start = time.perf_counter()
    factory = resolve_agent(spec.agent)
    agent = factory(spec.env, seed=spec.seed, env_kwargs=dict(spec.env_kwargs), **dict(spec.hyperparameters))
    recorder = _Recorder(spec, run_dir / HISTORY)
    try:
        if 0 in spec.trajectory_iterations:
            recorder.record_traces(agent, 0)
        agent.learn(spec.iterations, callback=recorder)
        summary = _summarise(spec, agent, time.perf_counter() - start)
        if recorder.traces:
            buffer = io.BytesIO()
            np.savez_compressed(buffer, **recorder.traces)
            write_atomic(run_dir / TRAJECTORIES, buffer.getvalue())
        if spec.save_agent:
            agent.save(run_dir / AGENT)
    finally:
        recorder.close()
        close = getattr(agent, "close", None)
        if close is not None:
            close()
    write_atomic(run_dir / DONE, json.dumps(summary, indent=1).encode())
    return summary


def _limit_threads() -> None:
    """One BLAS/torch thread per run: runs are parallel processes, more threads only contend.

    Set through the environment before torch is imported (importing it here would cost
    seconds for agents that never use it).
    """
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


class _Recorder:
    """The training callback: appends history rows to the CSV, samples traces when asked."""

    def __init__(self, spec: RunSpec, path: Path):
        self.spec = spec
        self.file = path.open("w", newline="")
        self.writer: csv.DictWriter | None = None
        self.traces: dict[str, np.ndarray] = {}

    def __call__(self, agent: Any, row: Mapping[str, Any]) -> bool:
        every = self.spec.evaluate_every
        row = {**row, "eval_success_rate": np.nan, "eval_mean_robustness": np.nan}
        if every and self.spec.evaluate_episodes and (row["iteration"] % every == 0
                                                       or row["iteration"] == self.spec.iterations):
            result = agent.evaluate(n_episodes=self.spec.evaluate_episodes, seed=20_000_033 + self.spec.seed)
            row["eval_success_rate"] = float(result["success_rate"])
            row["eval_mean_robustness"] = float(result["mean_robustness"])
        if self.writer is None:
            self.writer = csv.DictWriter(self.file, fieldnames=list(row), extrasaction="ignore")
            self.writer.writeheader()
        self.writer.writerow(row)
        self.file.flush()
        if row["iteration"] in self.spec.trajectory_iterations:
            self.record_traces(agent, int(row["iteration"]))
        return True

    def record_traces(self, agent: Any, iteration: int) -> None:
        traces, robustness = sample_traces(agent, self.spec.env, self.spec.env_kwargs,
                                           self.spec.trajectory_episodes,
                                           seed=1_000_003 * (iteration + 1) + self.spec.seed)
        for name, values in traces.items():
            self.traces[f"it{iteration}_{name}"] = values.astype(np.float32)
        self.traces[f"it{iteration}_robustness"] = robustness

    def close(self) -> None:
        self.file.close()


def sample_traces(
    agent: Any, env: str, env_kwargs: Mapping[str, Any], n_episodes: int, seed: int
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Sample ``n_episodes`` episodes with the agent's stochastic policy on a fresh vector env.

    The traces are the formula's signals as the reward wrapper recorded them (terminal
    ``info["trace"]``), so they are what the robustness was computed on. The agent's own
    env and training generator are left untouched (only ``predict`` is called).

    Args:
        agent: anything with the agents' ``predict``.
        env: env id.
        env_kwargs: its constructor arguments (the run's).
        n_episodes: episodes, all run at once.
        seed: reset seed of the vector env.

    Returns:
        ``({signal: (n_episodes, T+1) array}, (n_episodes,) exact robustness)``.
    """
    from tl_gym.agents.sampling import episode_traces, make_vector_env

    venv = make_vector_env(env, n_episodes, dict(env_kwargs))
    try:
        obs, _ = venv.reset(seed=seed)
        state, start = None, np.ones(n_episodes, dtype=bool)
        ended = np.zeros(n_episodes, dtype=bool)
        traces: dict[str, np.ndarray] = {}
        robustness = np.full(n_episodes, np.nan)
        while not ended.all():
            action, state = agent.predict(obs, state=state, episode_start=start, deterministic=False)
            obs, _, terminated, truncated, info = venv.step(action)
            start = np.asarray(terminated) | np.asarray(truncated)
            new = start & ~ended
            if new.any():
                robustness[new] = np.asarray(info["robustness"], dtype=float)[new]
                for name, per_env in episode_traces(info, n_episodes).items():
                    width = max(len(v) for v in per_env if v is not None)
                    rows = traces.setdefault(name, np.full((n_episodes, width), np.nan))
                    for i in np.flatnonzero(new):
                        values = per_env[i][: rows.shape[1]]
                        rows[i, : len(values)] = values
                ended |= new
    finally:
        venv.close()
    return traces, robustness


def _summarise(spec: RunSpec, agent: Any, elapsed: float) -> dict[str, Any]:
    history = agent.history
    last = history[-1] if history else {}
    summary: dict[str, Any] = {
        "run_id": spec.run_id,
        "label": spec.label,
        "iterations": len(history),
        "env_steps": int(last.get("env_steps", 0)),
        "train_wall_time": float(last.get("wall_time", 0.0)),
        "total_wall_time": elapsed,
        "final_mean_robustness": float(last.get("mean_robustness", np.nan)),
        "final_success_rate": float(last.get("success_rate", np.nan)),
        "note": spec.note,
        "code": code_version(),
    }
    if spec.evaluate_episodes > 0:
        for deterministic in (True, False):
            result = agent.evaluate(n_episodes=spec.evaluate_episodes, seed=10_000_019 + spec.seed,
                                    deterministic=deterministic)
            key = "eval_deterministic" if deterministic else "eval_stochastic"
            summary[key] = {"mean_robustness": float(result["mean_robustness"]),
                            "success_rate": float(result["success_rate"]),
                            "episodes": spec.evaluate_episodes}
    return summary


def code_version() -> str:
    """The tl_gym version and, in a git checkout, the commit (``+dirty`` if library code is modified)."""
    import subprocess

    import tl_gym

    version = tl_gym.__version__
    root = Path(tl_gym.__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "tl_gym", "agents", "envs"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return version
    return f"{version} ({commit}{'+dirty' if dirty else ''})"


def write_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and `os.replace` (all or nothing)."""
    path = Path(path)
    handle = tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", delete=False)
    try:
        with handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(handle.name, path)
    except BaseException:
        Path(handle.name).unlink(missing_ok=True)
        raise


def run_files(spec: Mapping[str, Any]) -> dict[str, bytes]:
    """Run ``spec`` in a scratch directory and return its files (``done.json`` included).

    The Ray path uses this: workers need no shared filesystem; the driver installs the
    files with `install_files`.
    """
    with tempfile.TemporaryDirectory(prefix="tl_gym_run_") as scratch:
        run_dir = Path(scratch) / "run"
        execute_run(spec, run_dir)
        return {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}


def install_files(files: Mapping[str, bytes], run_dir: str | Path) -> None:
    """Write a finished run's files into ``run_dir``, ``done.json`` last.

    Raises:
        ValueError: ``files`` has no ``done.json`` (not a finished run).
    """
    if DONE not in files:
        raise ValueError(f"not a finished run: no {DONE} among {sorted(files)}")
    run_dir = Path(run_dir)
    if run_dir.exists() and not is_done(run_dir):
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        if name != DONE:
            write_atomic(run_dir / name, data)
    write_atomic(run_dir / DONE, files[DONE])
