"""The smoothed robustness's gradient without torch against autograd, on the batch TLPS differentiates.

docs/engine.md ("The gradient without torch", "When the gradient is computed") quotes its ratios. On one batch of
task-2 car trajectories (40 × 201 states by default, random actions from seed 0) and for each backend, the best CPU
time over ``--repeats`` calls of:

- ``values``: `smooth_robustness` on numpy signals (no gradient);
- ``and_gradient``: `smooth_robustness_and_gradient` (values and the per-trajectory gradient, numpy in and out);
- ``autograd``: `smooth_robustness` on tensors that require grad, then ``.sum().backward()``;
- ``forward_with_grad``: that forward call alone (it computes the Jacobian for the backward).

    python -m benchmarks.bench_gradient                       # linear form (TLPS's), numpy and numba
    python -m benchmarks.bench_gradient --form nested --repeats 5
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence

import gymnasium as gym
import numpy as np
from tl_gym.envs.tasks import task_formula

import tl_gym  # noqa: F401  (registers TLCarNav-v0)
from tl_gym.tltl.smooth import FORMS


def car_batch(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """``{"x", "y"}``, each ``(n, 201)``: task-2 car episodes driven by a random plan plus noise."""
    envs = gym.make_vec("TLCarNav-v0", num_envs=n, vectorization_mode="vector_entry_point", task=2)
    try:
        envs.reset(seed=seed)
        rng = np.random.default_rng(seed)
        plan = rng.normal(0.0, 0.5, (200, 2))
        for t in range(200):
            actions = np.clip(plan[t] + rng.normal(0.0, 0.3, (n, 2)), -1, 1).astype(np.float32)
            *_, info = envs.step(actions)
        return {name: np.stack([info["trace"][i][name] for i in range(n)]) for name in ("x", "y")}
    finally:
        envs.close()


def best_cpu_ms(fn: Callable[[], object], repeats: int) -> float:
    """The least CPU time of ``repeats`` calls of ``fn`` (after one warm-up call), in ms."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        fn()
        best = min(best, time.process_time() - start)
    return best * 1e3


def measure(trace: dict[str, np.ndarray], backend: str, form: str, repeats: int, beta: float = 9.0) -> dict[str, float]:
    """The four timings (ms) of the module docstring for one backend and smoothing form."""
    import torch

    formula = task_formula(2)
    tensors = {name: torch.tensor(values, requires_grad=True) for name, values in trace.items()}

    def autograd() -> None:
        for tensor in tensors.values():
            tensor.grad = None
        formula.smooth_robustness(tensors, beta, form=form, backend=backend).sum().backward()

    return {
        "values": best_cpu_ms(lambda: formula.smooth_robustness(trace, beta, form=form, backend=backend), repeats),
        "and_gradient": best_cpu_ms(
            lambda: formula.smooth_robustness_and_gradient(trace, beta, form=form, backend=backend), repeats),
        "autograd": best_cpu_ms(autograd, repeats),
        "forward_with_grad": best_cpu_ms(
            lambda: formula.smooth_robustness(tensors, beta, form=form, backend=backend), repeats),
    }


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=40, help="trajectories in the batch (default 40, a TLPS batch)")
    parser.add_argument("--form", choices=FORMS, default="linear", help="smoothing form (default: TLPS's linear)")
    parser.add_argument("--backends", nargs="+", default=["numpy", "numba"], help="engine backends to time")
    parser.add_argument("--repeats", type=int, default=60, help="calls timed per measurement (the best counts)")
    parser.add_argument("--quick", action="store_true", help="3 repeats (make bench-quick)")
    args = parser.parse_args(argv)
    if args.quick:
        args.repeats = 3
    trace = car_batch(args.n)
    print(f"task 2, {args.n} x {trace['x'].shape[1]} states, form {args.form}; best CPU ms of {args.repeats}")
    for backend in args.backends:
        t = measure(trace, backend, args.form, args.repeats)
        print(f"{backend}: values {t['values']:.2f}, and_gradient {t['and_gradient']:.2f}, autograd "
              f"{t['autograd']:.2f} ({t['autograd'] / t['and_gradient']:.2f}x and_gradient), forward with grad "
              f"{t['forward_with_grad']:.2f} ({t['forward_with_grad'] / t['values']:.2f}x values)", flush=True)


if __name__ == "__main__":
    main()
