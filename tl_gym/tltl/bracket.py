"""Error bracket of the smoothed robustness: the recursive form of the paper's Lemma 1.

For a node reducing ``n`` terms, log-sum-exp overestimates a max by at most
``log(n)/β`` and underestimates a min by at most ``log(n)/β`` (and never errs the
other way); errors of the operands pass through max/min unchanged and swap sides
under negation. Taking the worst operand at each node gives ``(below, above)`` with
``ρ - below ≤ ρ̂ ≤ ρ + above`` at every position of a trace of length ``horizon``.
"""

from __future__ import annotations

import math

from tl_gym.tltl.ast import (
    Always,
    And,
    Constant,
    Eventually,
    Formula,
    Implies,
    Next,
    Not,
    Or,
    Predicate,
    Then,
    Until,
)


def smoothing_bracket(formula: Formula, horizon: int, beta: float) -> tuple[float, float]:
    """``(below, above)`` bounds on ``ρ̂ − ρ`` for traces of length ``horizon``."""
    if not (isinstance(horizon, int) and horizon >= 1):
        raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
    if not (math.isfinite(beta) and beta > 0):
        raise ValueError(f"beta must be a positive finite number, got {beta!r}")
    below, above = _bracket(formula, horizon)
    return below / beta, above / beta


def _bracket(root: Formula, horizon: int) -> tuple[float, float]:
    """Bracket in units of 1/β, node by node from the leaves up (an explicit stack: any depth)."""
    done: dict[int, tuple[float, float]] = {}  # by node identity: a shared sub-formula is bracketed once
    stack: list[tuple[Formula, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        if id(node) in done:
            continue
        if not expanded:
            stack.append((node, True))
            stack.extend((child, False) for child in node.children if id(child) not in done)
            continue
        done[id(node)] = _node_bracket(node, [done[id(c)] for c in node.children], horizon)
    return done[id(root)]


def _node_bracket(node: Formula, parts: list[tuple[float, float]], horizon: int) -> tuple[float, float]:
    """A node's bracket from its operands' brackets ``parts``."""
    log_t = math.log(horizon)
    if isinstance(node, (Constant, Predicate)):
        return 0.0, 0.0
    if isinstance(node, Not):
        below, above = parts[0]
        return above, below
    if isinstance(node, Next):
        return parts[0]
    if isinstance(node, (And, Or, Implies)):
        if isinstance(node, Implies):
            parts[0] = parts[0][::-1]  # max(-φ, ψ): φ's error is negated
        below = max(p[0] for p in parts)
        above = max(p[1] for p in parts)
        grow = math.log(len(parts))
        return (below + grow, above) if isinstance(node, And) else (below, above + grow)
    if isinstance(node, Eventually):
        below, above = parts[0]
        return below, above + log_t
    if isinstance(node, Always):
        below, above = parts[0]
        return below + log_t, above
    if isinstance(node, (Until, Then)):
        (left_below, left_above), (right_below, right_above) = parts
        inner_terms = math.log(max(horizon - 1, 1))
        if isinstance(node, Until):  # smin over t'' of φ
            inner = (left_below + inner_terms, left_above)
        else:  # smax over t'' of φ
            inner = (left_below, left_above + inner_terms)
        # smin(ψ, inner): two terms; then smax over at most `horizon` positions t'
        below = max(right_below, inner[0]) + math.log(2)
        above = max(right_above, inner[1]) + log_t
        return below, above
    raise TypeError(f"no bracket rule for formula node {type(node).__name__}")
