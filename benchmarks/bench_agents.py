"""Cost of one TLPS iteration against one REPS iteration on the car (issue 16's cost target).

The agents' iterations alternate in one process (TLPS, REPS, TLPS, ...), so that a shared machine's load falls
on both alike; each is timed in CPU seconds of this process and in wall-clock seconds, after a warm-up. TLPS's own
split (sampling, trust region) comes from its history. Prints a Markdown table; ``--quick`` is the CI smoke run.
It measures a training run's steady state: the engine's compiled smoother (``tl_gym[fast]``) is loaded first,
which ``backend="auto"`` otherwise does after a second of numpy smoothing (about six TLPS iterations).
"""

from __future__ import annotations

import argparse
import ast
import os
import time

import numpy as np
from tl_gym.agents import REPS, TLPS


def time_iterations(agents: dict[str, object], iterations: int, warmup: int) -> dict[str, np.ndarray]:
    """``{label: (iterations, 2) array of (CPU, wall) seconds}``, the agents' iterations alternating."""
    times: dict[str, list[tuple[float, float]]] = {label: [] for label in agents}
    for i in range(warmup + iterations):
        for label, agent in agents.items():
            cpu, wall = time.process_time(), time.perf_counter()
            agent.learn(1)
            if i >= warmup:
                times[label].append((time.process_time() - cpu, time.perf_counter() - wall))
    return {label: np.array(rows) for label, rows in times.items()}


def main(argv: list[str] | None = None) -> None:
    """Print one row per agent and the TLPS / REPS ratio of median CPU and wall seconds per iteration."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_agents", description=__doc__.split("\n")[0])
    parser.add_argument("--task", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tlps", nargs="*", default=[], metavar="KEY=VALUE", help="TLPS hyperparameters")
    parser.add_argument("--quick", action="store_true", help="one iteration each, no warm-up")
    args = parser.parse_args(argv)
    if args.quick:
        args.iterations, args.warmup = 1, 0
    tlps_kwargs = {key: ast.literal_eval(value) for key, value in (item.split("=", 1) for item in args.tlps)}
    env = {"task": args.task}
    agents = {"TLPS": TLPS("TLCarNav-v0", env_kwargs=env, seed=args.seed, **tlps_kwargs),
              "REPS": REPS("TLCarNav-v0", env_kwargs=env, seed=args.seed)}
    tlps = agents["TLPS"]
    tlps.formula.smooth_robustness({name: np.zeros(2) for name in tlps.formula.signals}, tlps.config.beta,
                                   form=tlps.config.smoothing, backend="numba")
    times = time_iterations(agents, args.iterations, args.warmup)
    print(f"task {args.task}, N = 40 x 200 steps, {args.iterations} iterations after {args.warmup} of warm-up, "
          f"TLPS {tlps_kwargs or 'defaults'}; load average {os.getloadavg()[0]:.1f}")
    print("| agent | CPU s per iteration (median) | wall s per iteration (median) |\n|---|---|---|")
    medians = {label: np.median(rows, axis=0) for label, rows in times.items()}
    for label, (cpu, wall) in medians.items():
        print(f"| {label} | {cpu:.3f} | {wall:.3f} |")
    cpu, wall = medians["TLPS"] / medians["REPS"]
    print(f"| TLPS / REPS | {cpu:.2f}x | {wall:.2f}x |")
    sampling, trust_region = (np.median([row[key] for row in tlps.history[-args.iterations:]])
                              for key in ("time_sampling", "time_trust_region"))
    print(f"TLPS's split (median wall s): sampling {sampling:.3f}, trust region {trust_region:.3f}")


if __name__ == "__main__":
    main()
