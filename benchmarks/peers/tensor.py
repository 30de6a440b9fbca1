"""stlcg++ (``stlcgpp``, PyTorch) and its JAX twin stljax: exact and smoothed (log-sum-exp, with gradient) φ1.

Both evaluate one trajectory ``[T, 2]`` per call, batched with ``vmap`` in memory-bounded chunks (their F and G
build a ``(2T, T)`` matrix per trajectory: T above `MAX_LENGTH` is declined); their log-sum-exp smoothing with
``temperature=β`` is tl_gym's for φ1. φ2 is not offered: docs/speed.md says why.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.formulas import Task
from benchmarks.peers import Evaluator, Unsupported

MAX_LENGTH = 2_000  # the (2T, T) float64 matrix per trajectory is 64 MB here, 6.4 GB at T = 20,000
_CHUNK_ELEMENTS = 1 << 25  # trajectories per vmap chunk × 2T²  (≈ 256 MB of float64)
_NO_PHI2 = "no next (X, T); closed-interval Until smooths differently; O(T³) memory"


def formula(task: Task, stl: Any, sqrt: Callable[[Any], Any]) -> Any:
    """φ1 as a formula of ``stl`` (stlcg++'s or stljax's ``formula`` module) over a ``[T, 2]`` signal (x, y)."""
    b, c = task.goals[0], task.obstacle
    x = stl.Predicate("x", lambda s: s[..., 0])
    y = stl.Predicate("y", lambda s: s[..., 1])
    d = stl.Predicate("d_o", lambda s: sqrt((s[..., 0] - c.x) ** 2 + (s[..., 1] - c.y) ** 2))
    box = stl.And(stl.And(stl.And(stl.GreaterThan(x, b.x_low), stl.LessThan(x, b.x_high)), stl.GreaterThan(y, b.y_low)),
                  stl.LessThan(y, b.y_high))
    return stl.And(stl.Eventually(box), stl.Always(stl.GreaterThan(d, c.radius)))


def _chunk(length: int) -> int:
    return max(1, _CHUNK_ELEMENTS // (2 * length**2))


def _pair(name: str, exact: Callable, smooth: Callable, **kwargs: Any) -> list[Evaluator]:
    return [Evaluator(name, "exact", exact, max_length=MAX_LENGTH, **kwargs),
            Evaluator(name, "smooth+grad", smooth, max_length=MAX_LENGTH, **kwargs)]


def stlcgpp_evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact and smoothed-with-gradient evaluators of φ1 with stlcg++ (``torch.vmap`` in chunks)."""
    import torch

    if task.key != "phi1":
        return [Unsupported("stlcg++", "exact", _NO_PHI2), Unsupported("stlcg++", "smooth+grad", _NO_PHI2)]
    from stlcgpp import formula as stl

    phi = formula(task, stl, torch.sqrt)

    def robustness(signal: Any, **kwargs: Any) -> Any:  # (N, T, 2) -> (N,)
        old = torch.get_default_dtype()
        torch.set_default_dtype(torch.float64)  # stlcg++ builds its masks with the default dtype
        try:
            return torch.vmap(lambda s: phi.robustness(s, **kwargs), chunk_size=_chunk(signal.shape[1]))(signal)
        finally:
            torch.set_default_dtype(old)

    def run_exact(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return robustness(torch.from_numpy(np.stack([x, y], axis=-1)), approx_method="true").numpy()

    def run_smooth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        xt, yt = (torch.from_numpy(v).requires_grad_(True) for v in (x, y))
        values = robustness(torch.stack([xt, yt], dim=-1), approx_method="logsumexp", temperature=beta)
        values.sum().backward()
        return values.detach().numpy()

    return _pair("stlcg++", run_exact, run_smooth)


def stljax_evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact and smoothed-with-gradient evaluators of φ1 with stljax (``jax.jit(jax.vmap)`` on fixed-size chunks)."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    if task.key != "phi1":
        return [Unsupported("stljax", "exact", _NO_PHI2), Unsupported("stljax", "smooth+grad", _NO_PHI2)]
    from stljax import formula as stl

    phi = formula(task, stl, jnp.sqrt)
    exact = jax.jit(jax.vmap(lambda s: phi.robustness(s, approx_method="true")))

    def smooth_sum(signal: Any) -> Any:
        values = jax.vmap(lambda s: phi.robustness(s, approx_method="logsumexp", temperature=beta))(signal)
        return values.sum(), values

    smooth = jax.jit(jax.value_and_grad(smooth_sum, has_aux=True))

    def smooth_step(part: Any) -> Any:
        (_, values), grad = smooth(jnp.asarray(part))
        grad.block_until_ready()
        return values

    def chunked(step: Callable[[Any], Any], x: np.ndarray, y: np.ndarray) -> np.ndarray:
        signal, n = np.stack([x, y], axis=-1), len(x)
        chunk = min(n, _chunk(x.shape[1]))
        out = []
        for start in range(0, n, chunk):
            part = signal[start : start + chunk]
            part = np.concatenate([part, np.repeat(part[-1:], chunk - len(part), axis=0)])  # one compiled shape
            out.append(np.asarray(step(part)))
        return np.concatenate(out)[:n]

    return _pair("stljax", functools.partial(chunked, exact), functools.partial(chunked, smooth_step), compiles=True)
