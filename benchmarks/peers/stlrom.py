"""STLRom (C++ online monitor, Breach's successor): exact φ1 and an attempt at φ2.

STLRom is dense-time. With ``PREVIOUS`` interpolation a signal holds each sample
until the next one, and one duplicate of the last sample at time T makes
``ev_[0, T]``/``alw_[0, T]`` range over exactly the T samples, i.e. tl_gym's
F/G over [0, T); its ``until_`` then matches tl_gym's non-strict U. Its grammar
has no ``sqrt``, so the obstacle distance is computed with numpy and passed as a
third signal ``d`` (inside the timed call). It has no next operator: φ2 writes
``X φ`` as ``ev_[1, 1.5] φ`` and ``φ T ψ`` as ``ev(φ and ev_[1, T] ψ)``, which see
the padded duplicate instead of −∞ after the last state; the benchmark's equality
check reports whether that changes φ2's value.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from benchmarks.formulas import Box, Task
from benchmarks.peers import Evaluator, Unsupported, per_trajectory

NAME = "stlrom"


def _box(b: Box) -> str:
    return f"(x[t] > {b.x_low:.1f} and x[t] < {b.x_high:.1f} and y[t] > {b.y_low:.1f} and y[t] < {b.y_high:.1f})"


def specification(task: Task, length: int) -> str:
    """The task in STLRom's syntax for trajectories of ``length`` samples (+1 duplicate)."""
    h = length
    g = [_box(b) for b in task.goals]
    avoid = f"alw_[0, {h}] (d[t] > {task.obstacle.r:.1f})"
    if task.key == "phi1":
        return f"signal x, y, d\nphi := ev_[0, {h}] {g[0]} and {avoid}\n"
    g2_then_g3 = f"ev_[0, {h}] ({g[1]} and ev_[1, {h}] {g[2]})"
    clauses = [
        f"ev_[0, {h}] ({g[0]} and ev_[1, {h}] ({g2_then_g3}))",
        f"(not ({g[1]} or {g[2]})) until_[0, {h}] {g[0]}",
        f"(not {g[2]}) until_[0, {h}] {g[1]}",
    ]
    for gi in g:
        never_again = f"alw_[1, {h}] (not {gi})"
        antecedent = gi if task.strict else f"({gi} and ev_[1, 1.5] (not {gi}))"
        clauses.append(f"alw_[0, {h}] ({antecedent} => {never_again})")
    clauses.append(avoid)
    return "signal x, y, d\nphi := " + " and ".join(f"({c})" for c in clauses) + "\n"


def evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact evaluator of ``task``; it has no smoothed semantics."""
    import stlrom


    @lru_cache(maxsize=4)
    def driver(length: int) -> Any:
        d = stlrom.STLDriver()
        d.parse_string(specification(task, length))
        d.set_interpol("PREVIOUS")
        return d

    cx, cy = task.obstacle.cx, task.obstacle.cy

    def run_one(x: np.ndarray, y: np.ndarray) -> float:
        length = len(x)
        monitor = driver(length).get_monitor("phi")  # a fresh monitor holds no samples
        d = np.hypot(x - cx, y - cy)
        samples = np.column_stack([np.arange(length + 1.0), np.append(x, x[-1]), np.append(y, y[-1]),
                                   np.append(d, d[-1])])
        for sample in samples.tolist():
            monitor.add_sample(sample)
        return float(monitor.eval_rob(0.0))

    expressed = "d_o passed as a signal (no sqrt)"
    if task.key != "phi1":
        expressed += "; X as ev_[1,1.5], T as ev(φ and ev_[1,T] ψ) (no next)"
    return [
        Evaluator(NAME, "exact", per_trajectory(run_one), expressed),
        Unsupported(NAME, "smooth+grad", "no smoothed semantics"),
    ]
