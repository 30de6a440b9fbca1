"""argus (``argus-temporal-logic``, Rust core): exact φ1, and φ2 where its operators allow.

Signals are piecewise constant (``interpolation_method="constant"``) on integer
times, which makes argus's dense-time ``F``/``G``/``U`` the discrete ones over
[t, T). Differences from the task's formula, all forced by argus 0.1.4:

* it has no ``sqrt``, so the obstacle distance ``d_o`` is computed with numpy and
  passed as a third signal ``d`` (its cost is inside the timed call);
* its ``X`` fails an internal assertion on every trace we tried, and a bounded
  ``F[a,b]``/``G[a,b]`` acts as ``F[a,]``/``G[a,]`` (``F[1,1.5] x > 0`` on x = 0, 3, 1, 5, 2
  is 5 at t = 0), so ``X`` cannot be written at all. φ2-strict needs ``X`` only in
  ``X G ¬g = G[1,] ¬g`` and ``T`` only as ``F(φ & F[1,] ψ)``; both hold the last sample
  past the end where tl_gym's ``X`` is −∞, and the benchmark's equality check decides
  whether that matters. φ2's default no-revisit clause needs ``X ¬g`` itself: not offered.
"""

from __future__ import annotations

import numpy as np

from benchmarks.formulas import Box, Task
from benchmarks.peers import Evaluator, Unsupported, per_trajectory

NAME = "argus"


def _box(b: Box) -> str:
    return f"(x > {b.x_low:.1f} && x < {b.x_high:.1f} && y > {b.y_low:.1f} && y < {b.y_high:.1f})"


def specification(task: Task) -> str:
    """The task in argus's syntax, reading signals ``x``, ``y`` and ``d`` (distance to the obstacle).

    Raises:
        ValueError: φ2 with the default no-revisit clause, which argus cannot express.
    """
    if task.key == "phi2":
        raise ValueError("argus cannot express X, which φ2's default no-revisit clause needs")
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
    clauses += [f"G({gi} -> G[1,](!{gi}))" for gi in g]  # strict no-revisit only
    clauses.append(avoid)
    return " && ".join(f"({c})" for c in clauses)


def evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact evaluator of ``task``; it has no smoothed semantics."""
    import argus

    if task.key == "phi2":
        reason = "X fails and bounded F[a,b] acts as F[a,] in argus 0.1.4: X !g cannot be written"
        return [Unsupported(NAME, "exact", reason), Unsupported(NAME, "smooth+grad", "no smoothed semantics")]
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
        expressed += "; X G as G[1,], T as F(φ & F[1,] ψ) (its X is broken)"
    return [
        Evaluator(NAME, "exact", per_trajectory(run_one), expressed),
        Unsupported(NAME, "smooth+grad", "no smoothed semantics"),
    ]
