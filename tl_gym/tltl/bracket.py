"""Error bracket of the smoothed robustness: the paper's Lemma 1, node by node.

The rule of each operator is `tl_gym.tltl.operators.bracket`; this runs it over the
formula's plan (operands first, a shared sub-formula once, no recursion).
"""

from __future__ import annotations

import numbers

from tl_gym.tltl import operators
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.plan import compile_plan
from tl_gym.tltl.trace import check_beta


def smoothing_bracket(formula: Formula, horizon: int, beta: float) -> tuple[float, float]:
    """``(below, above)`` bounds on ``ρ̂ − ρ`` for traces of length ``horizon``: ρ − below ≤ ρ̂ ≤ ρ + above."""
    # numbers.Integral admits numpy's integers (np.int64 from a shape or a sweep), as check_beta its reals
    if isinstance(horizon, bool) or not (isinstance(horizon, numbers.Integral) and horizon >= 1):
        raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
    beta = check_beta(beta)
    done: list[tuple[float, float]] = []
    for step in compile_plan(formula, False, segments=False).steps:
        done.append(operators.bracket(step.node, [done[i] for i in step.inputs], horizon))
    return done[-1][0] / beta, done[-1][1] / beta
