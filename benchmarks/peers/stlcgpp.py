"""stlcg++ (``stlcgpp``, PyTorch): exact and smoothed (log-sum-exp, with gradient) φ1.

stlcg++ evaluates one trajectory ``[T, 2]`` per call and batches with ``torch.vmap``
(chunked to bound memory). Its unbounded ``Eventually``/``Always`` build a
``(2T, T)`` masked matrix per trajectory, so memory grows as T²: the adapter
declines T above `MAX_LENGTH`. With ``approx_method="logsumexp"`` and
``temperature=β`` every max/min is ``±log Σ exp(±β·)/β``, and a chain of ``And``
is one n-ary min, exactly as tl_gym smooths φ1, so values must agree to rounding.

φ2 is not offered: stlcg++ has no next (so neither ``X`` nor ``T`` can be written),
and its ``Until`` includes φ at the witness position t' (closed [t, t']) where
tl_gym's excludes it, which changes the smoothed value; its cost is also O(T³)
memory per trajectory.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from benchmarks.formulas import Task
from benchmarks.peers import Evaluator, Unsupported

NAME = "stlcg++"
MAX_LENGTH = 2_000  # the (2T, T) float64 matrix per trajectory is 64 MB here, 6.4 GB at T = 20,000
_CHUNK_ELEMENTS = 1 << 25  # trajectories per vmap chunk × 2T²  (≈ 256 MB of float64)


@contextmanager
def _float64() -> Iterator[None]:
    """stlcg++ builds its masks with the default dtype; make it float64 like the signals."""
    import torch

    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        yield
    finally:
        torch.set_default_dtype(old)


def formula(task: Task) -> Any:
    """φ1 as an stlcg++ formula over a ``[T, 2]`` signal (columns x, y)."""
    import torch
    from stlcgpp import formula as stl

    b, c = task.goals[0], task.obstacle
    x = stl.Predicate("x", lambda s: s[..., 0])
    y = stl.Predicate("y", lambda s: s[..., 1])
    d = stl.Predicate("d_o", lambda s: torch.sqrt((s[..., 0] - c.cx) ** 2 + (s[..., 1] - c.cy) ** 2))
    box = stl.And(
        stl.And(stl.And(stl.GreaterThan(x, b.x_low), stl.LessThan(x, b.x_high)), stl.GreaterThan(y, b.y_low)),
        stl.LessThan(y, b.y_high),
    )
    return stl.And(stl.Eventually(box), stl.Always(stl.GreaterThan(d, c.r)))


def _batched(phi: Any, **kwargs: Any) -> Callable[[Any], Any]:
    import torch

    def run(signal: Any) -> Any:  # (N, T, 2) -> (N,)
        chunk = max(1, _CHUNK_ELEMENTS // (2 * signal.shape[1] ** 2))
        with _float64():
            return torch.vmap(lambda s: phi.robustness(s, **kwargs), chunk_size=chunk)(signal)

    return run


def evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact and smoothed-with-gradient evaluators of φ1."""
    import torch

    if task.key != "phi1":
        reason = "no next (X, T); closed-interval Until smooths differently; O(T³) memory"
        return [Unsupported(NAME, "exact", reason), Unsupported(NAME, "smooth+grad", reason)]
    phi = formula(task)
    exact = _batched(phi, approx_method="true")
    smooth = _batched(phi, approx_method="logsumexp", temperature=beta)

    def run_exact(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return exact(torch.from_numpy(np.stack([x, y], axis=-1))).numpy()

    def run_smooth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        xt = torch.from_numpy(x).requires_grad_(True)
        yt = torch.from_numpy(y).requires_grad_(True)
        values = smooth(torch.stack([xt, yt], dim=-1))
        values.sum().backward()
        return values.detach().numpy()

    return [
        Evaluator(NAME, "exact", run_exact, max_length=MAX_LENGTH),
        Evaluator(NAME, "smooth+grad", run_smooth, max_length=MAX_LENGTH),
    ]
