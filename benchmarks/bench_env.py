"""Speed of TLCarNav-v0 and of TLTLRewardWrapper.

Measures car steps per second of the single env, of `SyncVectorEnv` over 40 of
them and of the batched `CarNavVectorEnv` (40 cars), full 200-step episodes with
their terminal robustness included; and the wrapper's per-step overhead over the
bare car and over a do-nothing env, with the terminal evaluation timed apart.
Each number is the best of several repeats (the least disturbed by other load).

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
from tl_gym import TLTLRewardWrapper

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


def best_of(repeats: int, fn: Callable[[], float]) -> float:
    """Smallest of ``repeats`` timings returned by ``fn`` (seconds)."""
    return min(fn() for _ in range(repeats))


def time_episodes(env, actions: np.ndarray, episodes: int) -> float:
    """Seconds for ``episodes`` full episodes (reset excluded), stepping ``actions[t]``."""
    env.reset(seed=0)
    total = 0.0
    for _ in range(episodes):
        start = time.perf_counter()
        for t in range(HORIZON):
            env.step(actions[t])
        total += time.perf_counter() - start
        env.reset()
    return total


def time_vector(envs, actions: np.ndarray, episodes: int) -> float:
    """Seconds for ``episodes`` episodes of every sub-env, autoreset steps excluded."""
    envs.reset(seed=0)
    total = 0.0
    for _ in range(episodes):
        start = time.perf_counter()
        for t in range(HORIZON):
            envs.step(actions[t])
        total += time.perf_counter() - start
        envs.step(actions[0])  # the NEXT_STEP autoreset step
    return total


def time_steps_split(env, actions: np.ndarray, episodes: int) -> tuple[float, float]:
    """Per-step seconds of non-terminal steps, and seconds of the terminal step."""
    body, last = 0.0, 0.0
    env.reset(seed=0)
    for _ in range(episodes):
        start = time.perf_counter()
        for t in range(HORIZON - 1):
            env.step(actions[t])
        middle = time.perf_counter()
        env.step(actions[HORIZON - 1])
        end = time.perf_counter()
        body += middle - start
        last += end - middle
        env.reset()
    return body / (episodes * (HORIZON - 1)), last / episodes


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
    single_rate = episodes * HORIZON / t_single
    sync = gym.make_vec("TLCarNav-v0", num_envs=NUM_ENVS, vectorization_mode="sync")
    t_sync = best_of(repeats, lambda: time_vector(sync, batch_actions, max(1, episodes // 2)))
    sync_rate = max(1, episodes // 2) * HORIZON * NUM_ENVS / t_sync
    rates = {}
    for task in (1, 2):
        batched = CarNavVectorEnv(num_envs=NUM_ENVS, task=task)
        t_batched = best_of(repeats, lambda b=batched: time_vector(b, batch_actions, episodes))
        rates[task] = episodes * HORIZON * NUM_ENVS / t_batched
    batched = CarNavVectorEnv(num_envs=NUM_ENVS)
    batched.reset(seed=0)
    one_step = best_of(repeats, lambda: _time_calls(lambda: batched.step(batch_actions[0]), 150))
    rows += [
        ("single env (gym.make, task 1), car steps/s", f"{single_rate:,.0f}"),
        (f"SyncVectorEnv({NUM_ENVS}) (task 1), car steps/s", f"{sync_rate:,.0f}"),
        (f"CarNavVectorEnv({NUM_ENVS}) task 1, car steps/s", f"{rates[1]:,.0f}"),
        (f"CarNavVectorEnv({NUM_ENVS}) task 2, car steps/s", f"{rates[2]:,.0f}"),
        (f"CarNavVectorEnv({NUM_ENVS}) / SyncVectorEnv({NUM_ENVS}) (task 1)", f"{rates[1] / sync_rate:.0f}x"),
        (f"CarNavVectorEnv({NUM_ENVS}): one non-terminal step", f"{one_step * 1e6:.1f} us"),
    ]

    # --- wrapper overhead ----------------------------------------------------------------------
    for name, make_bare in (("do-nothing env", Idle), ("bare car", lambda: CarNavEnv(task=1))):
        bare_step, _ = _best_split(make_bare(), actions, repeats, episodes)
        wrapped = TLTLRewardWrapper(make_bare(), task_formula(1), signals={"x": 0, "y": 1})
        wrapped_step, wrapped_last = _best_split(wrapped, actions, repeats, episodes)
        rows.append((f"wrapper overhead per step on a {name}", f"{(wrapped_step - bare_step) * 1e6:.2f} us"))
    rows.append(("  (bare car step)", f"{bare_step * 1e6:.2f} us"))
    for task in (1, 2):
        trace = {"x": np.linspace(0, 300, HORIZON + 1), "y": np.linspace(0, 300, HORIZON + 1)}
        formula = task_formula(task)
        t_eval = best_of(repeats, lambda f=formula, tr=trace: _time_calls(lambda: f.robustness(tr), 20))
        rows.append((f"terminal evaluation, task {task} (201 states)", f"{t_eval * 1e6:.0f} us"))
    for task in (1, 2):
        dense = TLTLRewardWrapper(Idle(), task_formula(task), signals={"x": 0, "y": 1}, reward_mode="dense")
        dense_step, _ = _best_split(dense, actions, max(1, repeats // 2), max(1, episodes // 2))
        kind = "incremental O(1)" if dense._monitor.incremental else "re-evaluated prefix O(t)"
        rows.append((f"dense mode per step, task {task} ({kind})", f"{dense_step * 1e6:.1f} us"))

    _report(rows, args.quick)


def _time_calls(fn: Callable[[], object], n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n


def _best_split(env, actions: np.ndarray, repeats: int, episodes: int) -> tuple[float, float]:
    results = [time_steps_split(env, actions, episodes) for _ in range(repeats)]
    return min(r[0] for r in results), min(r[1] for r in results)


def _report(rows: list[tuple[str, str]], quick: bool) -> None:
    width = max(len(name) for name, _ in rows)
    lines = [f"{name:<{width}}  {value}" for name, value in rows]
    print("\n".join(lines))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    table = ["| measurement | value |", "|---|---|"] + [f"| {name.strip()} | {value} |" for name, value in rows]
    command = f"python -m benchmarks.bench_env{' --quick' if quick else ''}"
    OUT.write_text(
        "# TLCarNav-v0 and TLTLRewardWrapper speed\n\n"
        f"`{command}` on {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}, "
        f"gymnasium {gym.__version__}; 1-minute load average {load:.1f} at the end. Best of several repeats; "
        "episodes of 200 steps with random actions, terminal robustness included.\n\n"
        + "\n".join(table) + "\n"
    )
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
