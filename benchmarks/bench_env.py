"""Speed of TLCarNav-v0 and of TLTLRewardWrapper.

Car steps per second (single env, `SyncVectorEnv` and the batched `CarNavVectorEnv` of 40 cars, 200-step episodes)
and the wrapper's per-step costs, each the best of several repeats in CPU time of this process (fair on shared
cores) and in wall-clock time. Prints the table and writes it to ``--out`` (default ``docs/results/env_speed.md``).
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from tl_gym.envs.car import CarNavEnv
from tl_gym.envs.tasks import task_formula
from tl_gym.envs.vector import CarNavVectorEnv

import tl_gym  # noqa: F401  (registers TLCarNav-v0)
from benchmarks.results import table
from tl_gym import TLTLRewardWrapper, parse

NUM_ENVS = 40
HORIZON = 200
OUT = Path(__file__).resolve().parent.parent / "docs" / "results" / "env_speed.md"


class Idle(gym.Env):
    """A do-nothing env with a 6-vector observation: what is left is the wrapper's own cost."""

    observation_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float64)
    action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    _obs, _t = np.zeros(6), 0  # the observation every step returns (never written), steps since reset

    def reset(self, *, seed=None, options=None):  # noqa: D102
        self._t = 0
        return self._obs, {}

    def step(self, action):  # noqa: D102
        self._t += 1
        return self._obs, 0.0, False, self._t >= HORIZON, {}


Timing = tuple[float, float]  # (cpu seconds, wall seconds)
XY = {"x": 0, "y": 1}


def clocked(work: Callable[[], object], calls: int = 1) -> Timing:
    """CPU and wall-clock seconds of ``calls`` calls of ``work``."""
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(calls):
        work()
    return time.process_time() - cpu, time.perf_counter() - wall


def best(timings: Iterable[Timing]) -> Timing:
    """Smallest CPU and smallest wall time."""
    cpu, wall = zip(*timings)
    return min(cpu), min(wall)


def time_episodes(env: Any, actions: np.ndarray, episodes: int, terminal: bool = True) -> Timing:
    """Seconds for ``episodes`` episodes of ``actions``, resets untimed; without ``terminal``, per non-terminal step."""
    timed, spent = HORIZON if terminal else HORIZON - 1, np.zeros(2)

    def steps(first: int, end: int) -> None:
        for t in range(first, end):
            env.step(actions[t])

    env.reset(seed=0)
    for _ in range(episodes):
        spent += clocked(lambda: steps(0, timed))
        steps(timed, HORIZON)
        env.step(actions[0]) if isinstance(env, gym.vector.VectorEnv) else env.reset()  # NEXT_STEP autoreset
    return tuple(spent / (1 if terminal else episodes * timed))


def interleaved_steps(envs: dict[str, Any], actions: np.ndarray, rounds: int, episodes: int) -> dict[str, Timing]:
    """Best per-step time of each env, their runs interleaved so that all see the same background load."""
    runs: dict[str, list[Timing]] = {name: [] for name in envs}
    for _ in range(rounds):
        for name, env in envs.items():
            runs[name].append(time_episodes(env, actions, episodes, terminal=False))
    return {name: best(timings) for name, timings in runs.items()}


def _rate(count: float, timing: Timing) -> str:
    return f"{count / timing[0]:,.0f} | {count / timing[1]:,.0f}"


def _micro(timing: Timing, minus: Timing = (0.0, 0.0), scale: float = 1.0) -> str:
    cpu, wall = ((t - m) * scale * 1e6 for t, m in zip(timing, minus))
    return f"{cpu:.2f} us | {wall:.2f} us"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer episodes and repeats (about 20 s)")
    parser.add_argument("--out", type=Path, help=f"the table's file (default {OUT}; --quick: runs/results-quick)")
    args = parser.parse_args()
    args.out = args.out or (Path("runs/results-quick/env_speed.md") if args.quick else OUT)
    repeats, episodes = (3, 2) if args.quick else (7, 5)
    half = max(1, episodes // 2)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(HORIZON, 2)).astype(np.float32)
    batch_actions = rng.uniform(-1, 1, size=(HORIZON, NUM_ENVS, 2)).astype(np.float32)

    # --- car steps per second ----------------------------------------------------------------
    single = gym.make("TLCarNav-v0", disable_env_checker=True)
    t_single = best(time_episodes(single, actions, episodes) for _ in range(repeats))

    def vector_time(envs: gym.vector.VectorEnv, n: int) -> Timing:  # n episodes of every car
        return best(time_episodes(envs, batch_actions, n) for _ in range(repeats))

    t_sync = vector_time(gym.make_vec("TLCarNav-v0", num_envs=NUM_ENVS, vectorization_mode="sync"), half)
    t_batched = {task: vector_time(CarNavVectorEnv(num_envs=NUM_ENVS, task=task), episodes) for task in (1, 2)}
    batched_steps, sync_steps = episodes * HORIZON * NUM_ENVS, half * HORIZON * NUM_ENVS
    speedup = [(batched_steps / t_batched[1][i]) / (sync_steps / t_sync[i]) for i in (0, 1)]
    rows = [
        ("single env (gym.make, task 1), car steps/s", _rate(episodes * HORIZON, t_single)),
        (f"SyncVectorEnv({NUM_ENVS}) (task 1), car steps/s", _rate(sync_steps, t_sync)),
        *((f"CarNavVectorEnv({NUM_ENVS}) task {task}, car steps/s", _rate(batched_steps, t_batched[task]))
          for task in (1, 2)),
        (f"CarNavVectorEnv({NUM_ENVS}) / SyncVectorEnv({NUM_ENVS}) (task 1)", f"{speedup[0]:.0f}x | {speedup[1]:.0f}x"),
        (f"CarNavVectorEnv({NUM_ENVS}) task 1, one 200-step episode of {NUM_ENVS} cars",
         f"{t_batched[1][0] / episodes * 1e3:.1f} ms | {t_batched[1][1] / episodes * 1e3:.1f} ms"),
    ]

    # --- wrapper overhead ----------------------------------------------------------------------
    for name, make_bare in (("do-nothing env", Idle), ("bare car", lambda: CarNavEnv(task=1))):
        envs = {"bare": make_bare(), "wrapped": TLTLRewardWrapper(make_bare(), task_formula(1), signals=XY)}
        step = interleaved_steps(envs, actions, 3 * repeats, episodes)
        rows.append((f"wrapper overhead per step on a {name}", _micro(step["wrapped"], step["bare"])))
    rows.append(("  (bare car step)", _micro(step["bare"])))
    for task in (1, 2):
        trace = {"x": np.linspace(0, 300, HORIZON + 1), "y": np.linspace(0, 300, HORIZON + 1)}
        formula = task_formula(task)
        t_eval = best(clocked(functools.partial(formula.robustness, trace), 20) for _ in range(repeats))
        rows.append((f"terminal evaluation, task {task} (201 states)", _micro(t_eval, scale=1 / 20)))
    fallback = parse("G(x > 210 -> F(y > 225)) & F G(y > 200)")  # outside the incremental fragment
    for name, formula in (("task 1", task_formula(1)), ("task 2", task_formula(2)),
                          ("task 2 strict", task_formula(2, "strict")), (str(fallback), fallback)):
        dense = TLTLRewardWrapper(Idle(), formula, signals=XY, reward_mode="dense")
        dense_step = best(time_episodes(dense, actions, half, terminal=False) for _ in range(max(1, repeats // 2)))
        kind = "incremental" if dense._monitor.incremental else "re-evaluated prefix, O(t)"
        rows.append((f"dense mode per step, {name} ({kind})", _micro(dense_step)))

    # --- the Markov view (observe_monitor=True) --------------------------------------------------
    views = {"terminal": {}, "dense": {"reward_mode": "dense"},  # the view's scale is the car's default
             "view": {"reward_mode": "dense", "observe_monitor": True, "monitor_scale": 100.0}}
    for task in (1, 2):
        envs = {name: TLTLRewardWrapper(Idle(), task_formula(task), signals=XY, horizon=HORIZON, **kwargs)
                for name, kwargs in views.items()}
        step = interleaved_steps(envs, actions, 3 * repeats, half)
        for base in ("terminal", "dense"):
            rows.append((f"Markov view (dense + observe_monitor) per step, task {task}, over the {base} mode",
                         _micro(step["view"], step[base])))
        per_car_step, where = 1 / (half * HORIZON * NUM_ENVS), f"per car step, CarNavVectorEnv({NUM_ENVS}) task {task}"
        car = {name: vector_time(CarNavVectorEnv(num_envs=NUM_ENVS, task=task, **kwargs), half)
               for name, kwargs in views.items()}
        rows += [(f"dense mode {where}, over the terminal mode", _micro(car["dense"], car["terminal"], per_car_step)),
                 (f"Markov view {where}", _micro(car["view"], car["terminal"], per_car_step)),
                 (f"Markov view {where}, over the dense mode", _micro(car["view"], car["dense"], per_car_step))]

    _report(rows, args.quick, args.out)


def _report(rows: list[tuple[str, str]], quick: bool, out: Path) -> None:
    width = max(len(name) for name, _ in rows)
    print("\n".join(f"{name:<{width}}  {value}" for name, value in [("measurement", "CPU time | wall clock"), *rows]))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    out.parent.mkdir(parents=True, exist_ok=True)
    command = f"python -m benchmarks.bench_env{' --quick' if quick else ''}"
    out.write_text(
        "# TLCarNav-v0 and TLTLRewardWrapper speed\n\n"
        f"`{command}` on {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}, "
        f"gymnasium {gym.__version__}; 1-minute load average {load:.1f} at the end (other jobs shared the cores "
        "when it is above the core count: the CPU-time column is then the fair one). Best of several repeats; "
        "episodes of 200 steps with random actions, terminal robustness included.\n\n"
        + table(["measurement", "CPU time", "wall clock"], [(name.strip(), value) for name, value in rows]) + "\n"
    )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
