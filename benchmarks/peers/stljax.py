"""stljax (JAX twin of stlcg++): exact and smoothed (log-sum-exp, with gradient) φ1.

Same formula and the same ``(2T, T)`` masked matrices per trajectory as stlcg++
(see `benchmarks.peers.stlcgpp`), batched with ``jax.vmap`` and compiled with
``jax.jit`` on fixed-size chunks (float64 via ``jax_enable_x64``). The first call
on a chunk size compiles it; the benchmark warms every evaluator up before timing.
φ2 is not offered, for stlcg++'s reasons (no next; closed-interval Until).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.formulas import Task
from benchmarks.peers import Evaluator, Unsupported

NAME = "stljax"
MAX_LENGTH = 2_000  # (2T, T) float64 per trajectory: 64 MB at T = 2,000
_CHUNK_ELEMENTS = 1 << 25


def formula(task: Task) -> Any:
    """φ1 as an stljax formula over a ``[T, 2]`` signal (columns x, y)."""
    import jax.numpy as jnp
    from stljax import formula as stl

    b, c = task.goals[0], task.obstacle
    x = stl.Predicate("x", lambda s: s[..., 0])
    y = stl.Predicate("y", lambda s: s[..., 1])
    d = stl.Predicate("d_o", lambda s: jnp.sqrt((s[..., 0] - c.cx) ** 2 + (s[..., 1] - c.cy) ** 2))
    box = stl.And(
        stl.And(stl.And(stl.GreaterThan(x, b.x_low), stl.LessThan(x, b.x_high)), stl.GreaterThan(y, b.y_low)),
        stl.LessThan(y, b.y_high),
    )
    return stl.And(stl.Eventually(box), stl.Always(stl.GreaterThan(d, c.r)))


def _chunked(step: Callable[[Any], Any], length: int) -> Callable[[np.ndarray], np.ndarray]:
    """Apply a jitted ``(chunk, T, 2) -> (chunk,)`` step to a batch, padding the last chunk."""

    def run(signal: np.ndarray) -> np.ndarray:
        n = signal.shape[0]
        chunk = max(1, min(n, _CHUNK_ELEMENTS // (2 * length**2)))
        out = []
        for start in range(0, n, chunk):
            part = signal[start : start + chunk]
            if len(part) < chunk:  # keep one compiled shape
                part = np.concatenate([part, np.repeat(part[-1:], chunk - len(part), axis=0)])
            out.append(np.asarray(step(part)))
        return np.concatenate(out)[:n]

    return run


def evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact and smoothed-with-gradient evaluators of φ1."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    if task.key != "phi1":
        reason = "no next (X, T); closed-interval Until smooths differently; O(T³) memory"
        return [Unsupported(NAME, "exact", reason), Unsupported(NAME, "smooth+grad", reason)]
    phi = formula(task)
    exact = jax.jit(jax.vmap(lambda s: phi.robustness(s, approx_method="true")))

    def smooth_sum(signal: Any) -> Any:
        values = jax.vmap(lambda s: phi.robustness(s, approx_method="logsumexp", temperature=beta))(signal)
        return values.sum(), values

    smooth = jax.jit(jax.value_and_grad(smooth_sum, has_aux=True))

    def run_exact(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return _chunked(exact, x.shape[1])(np.stack([x, y], axis=-1))

    def smooth_step(part: Any) -> Any:
        (_, values), grad = smooth(jnp.asarray(part))
        grad.block_until_ready()
        return values

    def run_smooth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return _chunked(smooth_step, x.shape[1])(np.stack([x, y], axis=-1))

    return [
        Evaluator(NAME, "exact", run_exact, max_length=MAX_LENGTH, compiles=True),
        Evaluator(NAME, "smooth+grad", run_smooth, max_length=MAX_LENGTH, compiles=True),
    ]
