"""Speed of TLCarNav-v0 and of TLTLRewardWrapper.

Measures car steps per second of the single env, of `SyncVectorEnv` over 40 of
them and of the batched `CarNavVectorEnv` (40 cars), full 200-step episodes with
their terminal robustness included; and the wrapper's per-step overhead over the
bare car and over a do-nothing env, with the terminal evaluation timed apart.
Each number is the best of several repeats, timed twice: CPU time of this
process (``time.process_time``, what the code costs even when other jobs share
the cores) and wall-clock time (``time.perf_counter``, what a user waits).

Usage: ``python -m benchmarks.bench_env [--quick]``; prints a table and writes
``docs/results/env_speed.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from tl_gym.envs.car import CarNavEnv
from tl_gym.envs.tasks import task_formula
from tl_gym.envs.vector import CarNavVectorEnv

import tl_gym  # noqa: F401  (registers TLCarNav-v0)
from tl_gym import TLTLRewardWrapper, parse

NUM_ENVS = 40
HORIZON = 200
OUT = Path(__file__).resolve().parent.parent / "docs" / "results" / "env_speed.md"


class Idle(gym.Env):
    """A do-nothing env with a 6-vector observation: what is left is the wrapper's own cost."""

    observation_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float64)
    action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def __init__(self) -> None:
        self._obs = np.zeros(6)
        self._t = 0

    def reset(self, *, seed=None, options=None):  # noqa: D102
        self._t = 0
        return self._obs, {}

    def step(self, action):  # noqa: D102
        self._t += 1
        return self._obs, 0.0, False, self._t >= HORIZON, {}


class Clock:
    """Accumulates wall-clock and CPU seconds over the timed sections."""

    def __init__(self) -> None:
        self.wall = 0.0
        self.cpu = 0.0
        self._start = (0.0, 0.0)

    def __enter__(self) -> Clock:
        self._start = (time.perf_counter(), time.process_time())
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall += time.perf_counter() - self._start[0]
        self.cpu += time.process_time() - self._start[1]


Timing = tuple[float, float]  # (cpu seconds, wall seconds)


def best_of(repeats: int, fn: Callable[[], Timing]) -> Timing:
    """Smallest CPU and smallest wall time over ``repeats`` runs of ``fn``."""
    runs = [fn() for _ in range(repeats)]
    return min(r[0] for r in runs), min(r[1] for r in runs)


def time_episodes(env, actions: np.ndarray, episodes: int) -> Timing:
    """Seconds for ``episodes`` full episodes (reset excluded), stepping ``actions[t]``."""
    env.reset(seed=0)
    clock = Clock()
    for _ in range(episodes):
        with clock:
            for t in range(HORIZON):
                env.step(actions[t])
        env.reset()
    return clock.cpu, clock.wall


def time_vector(envs, actions: np.ndarray, episodes: int) -> Timing:
    """Seconds for ``episodes`` episodes of every sub-env, autoreset steps excluded."""
    envs.reset(seed=0)
    clock = Clock()
    for _ in range(episodes):
        with clock:
            for t in range(HORIZON):
                envs.step(actions[t])
        envs.step(actions[0])  # the NEXT_STEP autoreset step
    return clock.cpu, clock.wall


def time_steps_split(env, actions: np.ndarray, episodes: int) -> tuple[Timing, Timing]:
    """Per-step seconds of non-terminal steps, and seconds of the terminal step."""
    body, last = Clock(), Clock()
    env.reset(seed=0)
    for _ in range(episodes):
        with body:
            for t in range(HORIZON - 1):
                env.step(actions[t])
        with last:
            env.step(actions[HORIZON - 1])
        env.reset()
    steps = episodes * (HORIZON - 1)
    return (body.cpu / steps, body.wall / steps), (last.cpu / episodes, last.wall / episodes)


def _rate(count: float, timing: Timing) -> str:
    return f"{count / timing[0]:,.0f} | {count / timing[1]:,.0f}"


def _micro(timing: Timing, scale: float = 1.0) -> str:
    return f"{timing[0] * scale * 1e6:.2f} us | {timing[1] * scale * 1e6:.2f} us"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer episodes and repeats (about 20 s)")
    args = parser.parse_args()
    repeats, episodes = (3, 2) if args.quick else (7, 5)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(HORIZON, 2)).astype(np.float32)
    batch_actions = rng.uniform(-1, 1, size=(HORIZON, NUM_ENVS, 2)).astype(np.float32)
    rows: list[tuple[str, str]] = []

    # --- car steps per second ----------------------------------------------------------------
    single = gym.make("TLCarNav-v0", disable_env_checker=True)
    t_single = best_of(repeats, lambda: time_episodes(single, actions, episodes))
    sync = gym.make_vec("TLCarNav-v0", num_envs=NUM_ENVS, vectorization_mode="sync")
    sync_episodes = max(1, episodes // 2)
    t_sync = best_of(repeats, lambda: time_vector(sync, batch_actions, sync_episodes))
    t_batched = {}
    for task in (1, 2):
        batched = CarNavVectorEnv(num_envs=NUM_ENVS, task=task)
        t_batched[task] = best_of(repeats, lambda b=batched: time_vector(b, batch_actions, episodes))
    batched_steps = episodes * HORIZON * NUM_ENVS
    sync_steps = sync_episodes * HORIZON * NUM_ENVS
    speedup = [(batched_steps / t_batched[1][i]) / (sync_steps / t_sync[i]) for i in (0, 1)]
    rows += [
        ("single env (gym.make, task 1), car steps/s", _rate(episodes * HORIZON, t_single)),
        (f"SyncVectorEnv({NUM_ENVS}) (task 1), car steps/s", _rate(sync_steps, t_sync)),
        (f"CarNavVectorEnv({NUM_ENVS}) task 1, car steps/s", _rate(batched_steps, t_batched[1])),
        (f"CarNavVectorEnv({NUM_ENVS}) task 2, car steps/s", _rate(batched_steps, t_batched[2])),
        (f"CarNavVectorEnv({NUM_ENVS}) / SyncVectorEnv({NUM_ENVS}) (task 1)", f"{speedup[0]:.0f}x | {speedup[1]:.0f}x"),
        (f"CarNavVectorEnv({NUM_ENVS}) task 1, one 200-step episode of {NUM_ENVS} cars",
         f"{t_batched[1][0] / episodes * 1e3:.1f} ms | {t_batched[1][1] / episodes * 1e3:.1f} ms"),
    ]

    # --- wrapper overhead ----------------------------------------------------------------------
    for name, make_bare in (("do-nothing env", Idle), ("bare car", lambda: CarNavEnv(task=1))):
        bare, wrapped = make_bare(), TLTLRewardWrapper(make_bare(), task_formula(1), signals={"x": 0, "y": 1})
        bare_runs, wrapped_runs = [], []
        for _ in range(3 * repeats):  # interleaved, so that both see the same background load
            bare_runs.append(time_steps_split(bare, actions, episodes)[0])
            wrapped_runs.append(time_steps_split(wrapped, actions, episodes)[0])
        bare_step = (min(r[0] for r in bare_runs), min(r[1] for r in bare_runs))
        wrapped_step = (min(r[0] for r in wrapped_runs), min(r[1] for r in wrapped_runs))
        overhead = (wrapped_step[0] - bare_step[0], wrapped_step[1] - bare_step[1])
        rows.append((f"wrapper overhead per step on a {name}", _micro(overhead)))
    rows.append(("  (bare car step)", _micro(bare_step)))
    for task in (1, 2):
        trace = {"x": np.linspace(0, 300, HORIZON + 1), "y": np.linspace(0, 300, HORIZON + 1)}
        formula = task_formula(task)
        t_eval = best_of(repeats, lambda f=formula, tr=trace: _time_calls(lambda: f.robustness(tr), 20))
        rows.append((f"terminal evaluation, task {task} (201 states)", _micro(t_eval)))
    fallback = parse("G(x > 210 -> F(y > 225)) & F G(y > 200)")  # outside the incremental fragment
    for name, formula in (("task 1", task_formula(1)), ("task 2", task_formula(2)),
                          ("task 2 strict", task_formula(2, "strict")), (str(fallback), fallback)):
        dense = TLTLRewardWrapper(Idle(), formula, signals={"x": 0, "y": 1}, reward_mode="dense")
        dense_step, _ = _best_split(dense, actions, max(1, repeats // 2), max(1, episodes // 2))
        kind = "incremental" if dense._monitor.incremental else "re-evaluated prefix, O(t)"
        rows.append((f"dense mode per step, {name} ({kind})", _micro(dense_step)))

    # --- the Markov view (observe_monitor=True) --------------------------------------------------
    for task in (1, 2):
        def wrap(task: int = task, **kwargs: object) -> TLTLRewardWrapper:
            return TLTLRewardWrapper(Idle(), task_formula(task), signals={"x": 0, "y": 1}, horizon=HORIZON, **kwargs)

        envs = {"terminal": wrap(), "dense": wrap(reward_mode="dense"),
                "view": wrap(reward_mode="dense", observe_monitor=True, monitor_scale=100.0)}
        runs: dict[str, list[Timing]] = {name: [] for name in envs}
        for _ in range(3 * repeats):  # interleaved, so that all see the same background load
            for name, env in envs.items():
                runs[name].append(time_steps_split(env, actions, max(1, episodes // 2))[0])
        best = {name: (min(r[0] for r in rs), min(r[1] for r in rs)) for name, rs in runs.items()}
        for base in ("terminal", "dense"):
            overhead = (best["view"][0] - best[base][0], best["view"][1] - best[base][1])
            rows.append((f"Markov view (dense + observe_monitor) per step, task {task}, over the {base} mode",
                         _micro(overhead)))
        plain = CarNavVectorEnv(num_envs=NUM_ENVS, task=task)
        viewed = CarNavVectorEnv(num_envs=NUM_ENVS, task=task, observe_monitor=True, reward_mode="dense")
        t_plain = best_of(repeats, lambda b=plain: time_vector(b, batch_actions, max(1, episodes // 2)))
        t_viewed = best_of(repeats, lambda b=viewed: time_vector(b, batch_actions, max(1, episodes // 2)))
        car_steps = max(1, episodes // 2) * HORIZON * NUM_ENVS
        per_car = ((t_viewed[0] - t_plain[0]) / car_steps, (t_viewed[1] - t_plain[1]) / car_steps)
        rows.append((f"Markov view per car step, CarNavVectorEnv({NUM_ENVS}) task {task}", _micro(per_car)))

    _report(rows, args.quick)


def _time_calls(fn: Callable[[], object], n: int) -> Timing:
    clock = Clock()
    with clock:
        for _ in range(n):
            fn()
    return clock.cpu / n, clock.wall / n


def _best_split(env, actions: np.ndarray, repeats: int, episodes: int) -> tuple[Timing, Timing]:
    results = [time_steps_split(env, actions, episodes) for _ in range(repeats)]
    body = (min(r[0][0] for r in results), min(r[0][1] for r in results))
    last = (min(r[1][0] for r in results), min(r[1][1] for r in results))
    return body, last


def _report(rows: list[tuple[str, str]], quick: bool) -> None:
    width = max(len(name) for name, _ in rows)
    lines = [f"{'measurement':<{width}}  CPU time | wall clock"]
    lines += [f"{name:<{width}}  {value}" for name, value in rows]
    print("\n".join(lines))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    table = ["| measurement | CPU time | wall clock |", "|---|---|---|"]
    table += [f"| {name.strip()} | {value} |" for name, value in rows]
    command = f"python -m benchmarks.bench_env{' --quick' if quick else ''}"
    OUT.write_text(
        "# TLCarNav-v0 and TLTLRewardWrapper speed\n\n"
        f"`{command}` on {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}, "
        f"gymnasium {gym.__version__}; 1-minute load average {load:.1f} at the end (other jobs shared the cores "
        "when it is above the core count: the CPU-time column is then the fair one). Best of several repeats; "
        "episodes of 200 steps with random actions, terminal robustness included.\n\n"
        + "\n".join(table) + "\n"
    )
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
