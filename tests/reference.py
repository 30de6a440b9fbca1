"""A naive recursive reference for TLTL, written from the definitions, not from the engine.

Sources: section II-A of the paper (Boolean and quantitative semantics), section V
(log-sum-exp smoothing) and the loose ends decided in issue 3:

* a trace is s_0 … s_{T-1}; at position t, ``F`` and ``G`` range over t' in [t, T);
* ``X φ`` at t is ρ(φ, t+1) if t+1 < T, else −ρ_max (Boolean: false);
  ``true`` is ρ_max and ``false`` is −ρ_max;
* ``φ U ψ`` at t is max over t' in [t, T) of min(ρ(ψ, t'), min over t'' in [t, t') of
  ρ(φ judged on the segment s_{t''} … s_{t'-1})); the segment is the trace truncated to
  length t', read at position t''. An empty min is +∞. ``φ T ψ`` replaces the inner
  min by a max (empty: −∞);
* ``φ -> ψ`` is max(−ρ(φ), ρ(ψ)); ``&``/``|`` are n-ary min/max over their operands;
* ``a < b`` and ``a <= b`` have robustness b − a, ``a > b`` and ``a >= b`` a − b;
  the Boolean semantics is strict for ``<``/``>`` and not for ``<=``/``>=``;
* smoothed: every max/min above (those over time included) is a log-sum-exp with
  +β (max) or −β (min), nested exactly as the definition nests.

Everything is a plain Python loop over positions of one trajectory, memoised on
(node, truncated length, position) so that nested ``U``/``T`` stay cheap on short
traces. A batch is evaluated trajectory by trajectory.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tl_gym.tltl import ast as nodes
from tl_gym.tltl.ast import Expr, Formula

INF = math.inf


class UndefinedPredicate(ValueError):
    """A predicate's arithmetic is NaN or infinite somewhere on the trace."""


# --------------------------------------------------------------------------- arithmetic


def expr_value(expr: Expr, state: Mapping[str, float]) -> float:
    """IEEE float64 value of an arithmetic expression on one state (NaN/inf allowed)."""
    with np.errstate(all="ignore"):
        return float(_expr(expr, state))


def _expr(e: Expr, state: Mapping[str, float]) -> np.float64:
    if isinstance(e, nodes.Var):
        return np.float64(state[e.name])
    if isinstance(e, nodes.Num):
        return np.float64(e.value)
    if isinstance(e, nodes.Neg):
        return -_expr(e.operand, state)
    if isinstance(e, nodes.BinOp):
        a, b = _expr(e.left, state), _expr(e.right, state)
        ops: dict[str, Callable[[Any, Any], Any]] = {
            "+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "^": np.power,
        }
        return ops[e.op](a, b)
    if isinstance(e, nodes.Call):
        args = [_expr(a, state) for a in e.args]
        if e.func == "min":
            return np.min(args)  # NaN-propagating, like the IEEE minimum
        if e.func == "max":
            return np.max(args)
        return {"abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log}[e.func](args[0])
    raise TypeError(f"reference has no rule for expression node {type(e).__name__}")


def margin(pred: nodes.Predicate, state: Mapping[str, float]) -> float:
    """Robustness of a predicate on one state: b − a for ``a < b``, a − b for ``a > b``."""
    a, b = expr_value(pred.lhs, state), expr_value(pred.rhs, state)
    return b - a if pred.op in ("<", "<=") else a - b


def checked_margin(pred: nodes.Predicate, state: Mapping[str, float]) -> float:
    """`margin`, raising `UndefinedPredicate` where the arithmetic is NaN or infinite."""
    value = margin(pred, state)
    if not math.isfinite(value):
        raise UndefinedPredicate(f"{pred} is undefined on {state}")
    return value


def checked_holds(pred: nodes.Predicate, state: Mapping[str, float]) -> bool:
    """`holds`, raising `UndefinedPredicate` where the arithmetic is NaN or infinite."""
    checked_margin(pred, state)
    return holds(pred, state)


def holds(pred: nodes.Predicate, state: Mapping[str, float]) -> bool:
    """Boolean value of a predicate on one state (``<`` strict, ``<=`` not)."""
    a, b = expr_value(pred.lhs, state), expr_value(pred.rhs, state)
    return {"<": a < b, "<=": a <= b, ">": a > b, ">=": a >= b}[pred.op]


def check_defined(formula: Formula, trace: Mapping[str, Sequence[float]]) -> None:
    """Raise `UndefinedPredicate` if a predicate is NaN/inf at any position of the trace."""
    length = len(next(iter(trace.values())))
    for node in formula.walk():
        if isinstance(node, nodes.Predicate):
            for t in range(length):
                if not math.isfinite(margin(node, _state(trace, t))):
                    raise UndefinedPredicate(f"{node} is undefined at position {t}")


def is_defined(formula: Formula, trace: Mapping[str, Sequence[float]]) -> bool:
    """Whether the reference can evaluate ``formula`` on ``trace`` (every predicate finite where it is read)."""
    try:
        robustness_over_time(formula, trace)
    except UndefinedPredicate:
        return False
    return True


def largest_margin(formula: Formula, trace: Mapping[str, Sequence[float]]) -> float:
    """The largest |margin| of any predicate at any position of a (T,) trace."""
    length = len(next(iter(trace.values())))
    margins = [abs(margin(node, _state(trace, t)))
               for node in formula.walk() if isinstance(node, nodes.Predicate) for t in range(length)]
    return max(margins, default=0.0)


def _state(trace: Mapping[str, Sequence[float]], t: int) -> dict[str, float]:
    return {name: float(values[t]) for name, values in trace.items()}


# --------------------------------------------------------------------------- max / min


def smooth_max(values: Sequence[float], beta: float) -> float:
    """(1/β)·log Σ exp(β·x), shifted by the largest term; −∞ terms drop out, +∞ wins."""
    if any(v == INF for v in values):
        return INF
    finite = [v for v in values if v != -INF]
    if not finite:
        return -INF
    top = max(finite)
    return top + math.log(math.fsum(math.exp(beta * (v - top)) for v in finite)) / beta


def smooth_min(values: Sequence[float], beta: float) -> float:
    """−(1/β)·log Σ exp(−β·x): the smooth max of the negated terms, negated."""
    return -smooth_max([-v for v in values], beta)


@dataclass(frozen=True)
class Semantics:
    """What the recursion computes with: the paper's max/min/negation and constants."""

    top: Any  # value of `true`
    bottom: Any  # value of `false` and of `X φ` at the last state
    maximum: Callable[[list[Any]], Any]  # over a possibly empty list
    minimum: Callable[[list[Any]], Any]
    negate: Callable[[Any], Any]
    predicate: Callable[[nodes.Predicate, Mapping[str, float]], Any]


def exact_semantics(rho_max: float = INF) -> Semantics:
    """Robustness degree: max/min of reals (empty max −∞, empty min +∞)."""
    return Semantics(
        top=rho_max, bottom=-rho_max,
        maximum=lambda xs: max(xs, default=-INF), minimum=lambda xs: min(xs, default=INF),
        negate=lambda x: -x, predicate=checked_margin,
    )


def smooth_semantics(beta: float, rho_max: float = INF) -> Semantics:
    """Log-sum-exp robustness: every max/min replaced by its smooth form with sharpness β."""
    return Semantics(
        top=rho_max, bottom=-rho_max,
        maximum=lambda xs: smooth_max(xs, beta), minimum=lambda xs: smooth_min(xs, beta),
        negate=lambda x: -x, predicate=checked_margin,
    )


BOOLEAN = Semantics(
    top=True, bottom=False, maximum=any, minimum=all, negate=lambda x: not x, predicate=checked_holds,
)


# --------------------------------------------------------------------------- the recursion


class _Reference:
    """ρ(φ, s_t … s_{L-1}) for one trajectory, memoised on (node, L, t)."""

    def __init__(self, sem: Semantics, trace: Mapping[str, Sequence[float]]):
        self.sem = sem
        self.states = [_state(trace, t) for t in range(len(next(iter(trace.values()))))]
        self.memo: dict[tuple[int, int, int], Any] = {}

    def value(self, node: Formula, length: int, t: int) -> Any:
        """Value of ``node`` on the trace truncated to ``length`` states, at position ``t``."""
        key = (id(node), length, t)
        if key not in self.memo:
            self.memo[key] = self._value(node, length, t)
        return self.memo[key]

    def _value(self, node: Formula, length: int, t: int) -> Any:
        sem, v = self.sem, self.value
        if isinstance(node, nodes.Constant):
            return sem.top if node.value else sem.bottom
        if isinstance(node, nodes.Predicate):
            return sem.predicate(node, self.states[t])
        if isinstance(node, nodes.Not):
            return sem.negate(v(node.child, length, t))
        if isinstance(node, nodes.And):
            return sem.minimum([v(c, length, t) for c in node.operands])
        if isinstance(node, nodes.Or):
            return sem.maximum([v(c, length, t) for c in node.operands])
        if isinstance(node, nodes.Implies):
            return sem.maximum([sem.negate(v(node.left, length, t)), v(node.right, length, t)])
        if isinstance(node, nodes.Next):
            return v(node.child, length, t + 1) if t + 1 < length else sem.bottom
        if isinstance(node, nodes.Eventually):
            return sem.maximum([v(node.child, length, k) for k in range(t, length)])
        if isinstance(node, nodes.Always):
            return sem.minimum([v(node.child, length, k) for k in range(t, length)])
        if isinstance(node, (nodes.Until, nodes.Then)):
            inner = sem.minimum if isinstance(node, nodes.Until) else sem.maximum
            terms = []
            for k in range(t, length):  # t' = k
                # φ on the segment s_j … s_{k-1}: the trace truncated to length k, at j
                before = inner([v(node.left, k, j) for j in range(t, k)])
                terms.append(sem.minimum([v(node.right, length, k), before]))
            return sem.maximum(terms)
        raise TypeError(f"reference has no rule for formula node {type(node).__name__}")


def _rows(trace: Mapping[str, Any]) -> tuple[list[dict[str, list[float]]], bool]:
    """Split a trace into one dict of float lists per trajectory; tell whether it was batched."""
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in trace.items()}
    batched = next(iter(arrays.values())).ndim == 2
    if not batched:
        return [{k: a.tolist() for k, a in arrays.items()}], False
    n = next(iter(arrays.values())).shape[0]
    return [{k: a[i].tolist() for k, a in arrays.items()} for i in range(n)], True


def _evaluate(formula: Formula, trace: Mapping[str, Any], sem: Semantics, eager: bool, first_only: bool) -> np.ndarray:
    """Values at every position (or position 0), shape ``(N, T)`` or ``(N, 1)``.

    A predicate whose arithmetic is undefined raises `UndefinedPredicate` when its
    value is needed (``eager=False``), or when it is undefined at any position of the
    trace, needed or not (``eager=True``).
    """
    rows, _ = _rows(trace)
    out = []
    for row in rows:
        if eager:
            check_defined(formula, row)
        ref = _Reference(sem, row)
        length = len(ref.states)
        out.append([ref.value(formula, length, t) for t in range(1 if first_only else length)])
    return np.array(out, dtype=object)


def _shaped(values: np.ndarray, trace: Mapping[str, Any], dtype: Any) -> np.ndarray:
    values = values.astype(dtype)
    return values if _rows(trace)[1] else values[0]


def robustness_over_time(formula: Formula, trace: Mapping[str, Any], rho_max: float = INF,
                         eager: bool = True) -> np.ndarray:
    """Exact robustness at every position: ``(T,)`` or ``(N, T)`` like the trace."""
    return _shaped(_evaluate(formula, trace, exact_semantics(rho_max), eager, False), trace, np.float64)


def smooth_over_time(formula: Formula, trace: Mapping[str, Any], beta: float, rho_max: float = INF,
                     eager: bool = True) -> np.ndarray:
    """Smoothed robustness at every position: ``(T,)`` or ``(N, T)`` like the trace."""
    return _shaped(_evaluate(formula, trace, smooth_semantics(beta, rho_max), eager, False), trace, np.float64)


def satisfied_over_time(formula: Formula, trace: Mapping[str, Any], eager: bool = True) -> np.ndarray:
    """Boolean semantics at every position: ``(T,)`` or ``(N, T)`` bools like the trace."""
    return _shaped(_evaluate(formula, trace, BOOLEAN, eager, False), trace, bool)


def robustness(formula: Formula, trace: Mapping[str, Any], rho_max: float = INF, eager: bool = True) -> Any:
    """Exact robustness at position 0: a float, or ``(N,)`` for a batch."""
    return _shaped(_evaluate(formula, trace, exact_semantics(rho_max), eager, True), trace, np.float64)[..., 0]


def smooth_robustness(formula: Formula, trace: Mapping[str, Any], beta: float, rho_max: float = INF,
                      eager: bool = True) -> Any:
    """Smoothed robustness at position 0: a float, or ``(N,)`` for a batch."""
    values = _evaluate(formula, trace, smooth_semantics(beta, rho_max), eager, True)
    return _shaped(values, trace, np.float64)[..., 0]


def satisfied(formula: Formula, trace: Mapping[str, Any], eager: bool = True) -> Any:
    """Boolean semantics at position 0: a bool, or ``(N,)`` bools for a batch."""
    return _shaped(_evaluate(formula, trace, BOOLEAN, eager, True), trace, bool)[..., 0]


# --------------------------------------------------------------------------- Lemma 1 bracket


def bracket(formula: Formula, horizon: int, beta: float) -> tuple[float, float]:
    """Lemma 1, recursively: ``(below, above)`` with ρ − below ≤ ρ̂ ≤ ρ + above.

    A smooth max of n terms overestimates by at most log(n)/β and never
    underestimates; a smooth min the mirror image. Errors of the terms pass through
    max/min unchanged, so each node keeps the worst of its operands' errors and adds
    its own; negation swaps the two sides. Terms per node, for a trace of length
    ``horizon``: n for an n-ary ``&``/``|``, 2 for ``->``, ``horizon`` for ``F``/``G`` and
    for the max over t' of ``U``/``T``, 2 for the min combining ψ with the inner
    reduction, and ``horizon - 1`` for the inner min (``U``) or max (``T``) over t''.
    """
    below, above = _bracket(formula, horizon)
    return below / beta, above / beta


def _worst(parts: list[tuple[float, float]]) -> tuple[float, float]:
    return max(p[0] for p in parts), max(p[1] for p in parts)


def _bracket(node: Formula, horizon: int) -> tuple[float, float]:
    def log(n: int) -> float:
        return math.log(max(n, 1))

    if isinstance(node, (nodes.Constant, nodes.Predicate)):
        return 0.0, 0.0
    if isinstance(node, nodes.Not):
        below, above = _bracket(node.child, horizon)
        return above, below
    if isinstance(node, nodes.Next):
        return _bracket(node.child, horizon)
    if isinstance(node, nodes.And):
        below, above = _worst([_bracket(c, horizon) for c in node.operands])
        return below + log(len(node.operands)), above
    if isinstance(node, nodes.Or):
        below, above = _worst([_bracket(c, horizon) for c in node.operands])
        return below, above + log(len(node.operands))
    if isinstance(node, nodes.Implies):
        left_below, left_above = _bracket(node.left, horizon)
        below, above = _worst([(left_above, left_below), _bracket(node.right, horizon)])
        return below, above + log(2)
    if isinstance(node, nodes.Eventually):
        below, above = _bracket(node.child, horizon)
        return below, above + log(horizon)
    if isinstance(node, nodes.Always):
        below, above = _bracket(node.child, horizon)
        return below + log(horizon), above
    if isinstance(node, (nodes.Until, nodes.Then)):
        below, above = _bracket(node.left, horizon)
        if isinstance(node, nodes.Until):
            inner = (below + log(horizon - 1), above)
        else:
            inner = (below, above + log(horizon - 1))
        below, above = _worst([inner, _bracket(node.right, horizon)])
        return below + log(2), above + log(horizon)
    raise TypeError(f"reference has no bracket rule for formula node {type(node).__name__}")
