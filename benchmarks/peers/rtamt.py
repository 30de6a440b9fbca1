"""rtamt (discrete-time offline STL monitor, pure Python): exact φ1 and φ2.

rtamt's unbounded ``eventually``/``always`` range over [t, T) and its ``until`` is
tl_gym's non-strict scan ``U(t) = max(ψ(t), min(φ(t), U(t+1)))``, so φ1 and the
until clauses of φ2 are written literally. Two rewrites, both exact:

* rtamt has no ``then``: ``φ T ψ = F(φ & X F ψ)`` for temporal-free φ (the first φ
  before a later ψ), and ``g1 T (g2 T g3) = F(g1 & X F(g2 & X F g3))``;
* rtamt's ``next`` is weak (+∞ at the last sample) while tl_gym's is strong (−∞), so
  tl_gym's ``X φ`` is written ``not(next(not φ))``.

rtamt evaluates one trajectory per call on Python lists.
"""

from __future__ import annotations

import numpy as np

from benchmarks.formulas import Box, Circle, Task
from benchmarks.peers import Evaluator, Unsupported, per_trajectory

NAME = "rtamt"


def _box(b: Box) -> str:
    return f"((x > {b.x_low:.1f}) and (x < {b.x_high:.1f}) and (y > {b.y_low:.1f}) and (y < {b.y_high:.1f}))"


def _avoid(c: Circle) -> str:
    return f"always(sqrt((x - {c.cx:.1f})*(x - {c.cx:.1f}) + (y - {c.cy:.1f})*(y - {c.cy:.1f})) > {c.r:.1f})"


def _next(phi: str) -> str:
    """tl_gym's strong next (−∞ at the last state) from rtamt's weak one."""
    return f"(not(next(not({phi}))))"


def specification(task: Task) -> str:
    """The task in rtamt's STL syntax (exactly tl_gym's robustness, see the module docstring)."""
    g = [_box(b) for b in task.goals]
    if task.key == "phi1":
        return f"(eventually{g[0]}) and ({_avoid(task.obstacle)})"
    g2_then_g3 = f"eventually({g[1]} and {_next(f'eventually{g[2]}')})"
    clauses = [
        f"eventually({g[0]} and {_next(g2_then_g3)})",
        f"((not({g[1]} or {g[2]})) until {g[0]})",
        f"((not{g[2]}) until {g[1]})",
    ]
    for gi in g:
        never_again = _next(f"always(not{gi})")
        if task.strict:
            clauses.append(f"always({gi} -> {never_again})")
        else:
            clauses.append(f"always(({gi} and {_next(f'not{gi}')}) -> {never_again})")
    clauses.append(_avoid(task.obstacle))
    return " and ".join(f"({c})" for c in clauses)


def evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact evaluator of ``task``; it has no smoothed semantics."""
    import rtamt

    spec = rtamt.StlDiscreteTimeOfflineSpecification()
    spec.declare_var("x", "float")
    spec.declare_var("y", "float")
    spec.spec = specification(task)
    spec.parse()

    def run_one(x: np.ndarray, y: np.ndarray) -> float:
        out = spec.evaluate({"time": list(range(len(x))), "x": x.tolist(), "y": y.tolist()})
        return float(out[0][1])

    expressed = "" if task.key == "phi1" else "T as F(φ & X F ψ); X as not next not (exact)"
    return [
        Evaluator(NAME, "exact", per_trajectory(run_one), expressed),
        Unsupported(NAME, "smooth+grad", "no smoothed semantics"),
    ]
