"""argus (``argus-temporal-logic``, Rust core): exact φ1, and φ2 where its operators allow.

Signals are piecewise constant (``interpolation_method="constant"``) on integer
times, which makes argus's dense-time ``F``/``G``/``U`` the discrete ones over
[t, T). Differences from the task's formula, all forced by argus 0.1.4:

* it has no ``sqrt``, so the obstacle distance ``d_o`` is computed with numpy and
  passed as a third signal ``d`` (its cost is inside the timed call);
* its ``X`` fails an internal assertion on every trace we tried, so tl_gym's ``X φ``
  becomes ``F[1,1.5] φ`` (the signal is constant on [t+1, t+2)), and ``T`` becomes
  ``F(φ & F[1,] ψ)``; past the last sample argus holds the last value where tl_gym's
  ``X`` is −∞. This can change φ2's value only at the last state; the benchmark's
  equality check decides whether it does.
"""

from __future__ import annotations

import numpy as np

from benchmarks.formulas import Box, Task
from benchmarks.peers import Evaluator, Unsupported, per_trajectory

NAME = "argus"


def _box(b: Box) -> str:
    return f"(x > {b.x_low:.1f} && x < {b.x_high:.1f} && y > {b.y_low:.1f} && y < {b.y_high:.1f})"


def specification(task: Task) -> str:
    """The task in argus's syntax, reading signals ``x``, ``y`` and ``d`` (distance to the obstacle)."""
    g = [_box(b) for b in task.goals]
    avoid = f"G(d > {task.obstacle.r:.1f})"
    if task.key == "phi1":
        return f"F{g[0]} && {avoid}"
    g2_then_g3 = f"F({g[1]} && F[1,]{g[2]})"
    clauses = [
        f"F({g[0]} && F[1,]{g2_then_g3})",
        f"((!({g[1]} || {g[2]})) U {g[0]})",
        f"((!{g[2]}) U {g[1]})",
    ]
    for gi in g:
        never_again = f"G[1,](!{gi})"
        antecedent = gi if task.strict else f"({gi} && F[1,1.5](!{gi}))"
        clauses.append(f"G({antecedent} -> {never_again})")
    clauses.append(avoid)
    return " && ".join(f"({c})" for c in clauses)


def evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact evaluator of ``task``; it has no smoothed semantics."""
    import argus

    expr = argus.parse_expr(specification(task))
    cx, cy = task.obstacle.cx, task.obstacle.cy

    def signal(times: list[float], values: np.ndarray) -> argus.FloatSignal:
        return argus.FloatSignal.from_samples(list(zip(times, values.tolist())), interpolation_method="constant")

    def run_one(x: np.ndarray, y: np.ndarray) -> float:
        times = [float(t) for t in range(len(x))]
        d = np.hypot(x - cx, y - cy)
        trace = argus.Trace({"x": signal(times, x), "y": signal(times, y), "d": signal(times, d)})
        return float(argus.eval_robust_semantics(expr, trace, interpolation_method="constant").at(0.0))

    expressed = "d_o passed as a signal (no sqrt)"
    if task.key != "phi1":
        expressed += "; X as F[1,1.5], T as F(φ & F[1,] ψ) (its X is broken)"
    return [
        Evaluator(NAME, "exact", per_trajectory(run_one), expressed),
        Unsupported(NAME, "smooth+grad", "no smoothed semantics"),
    ]
