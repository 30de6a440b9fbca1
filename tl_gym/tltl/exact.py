"""Exact robustness and Boolean semantics of TLTL, vectorised over trajectories and time.

One evaluator serves both semantics through an `_Algebra`: robustness uses
(max, min, negation, ±ρ_max), the Boolean semantics (or, and, not, true/false).
Each node maps the ``(N, T)`` values of its children to its own ``(N, T)``
values, entry ``[i, t]`` judging trajectory ``i`` from position ``t`` on
(the paper's ρ(s_{t:T}, φ)). Every operator costs O(N·T), except ``U``/``T`` whose
left operand is temporal: that operand must be judged on every truncated segment
s_{t''..t'-1}, which costs O(N·T²) time (and O(N·T) memory).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tl_gym.errors import TraceError
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
from tl_gym.tltl.expressions import evaluate_expression
from tl_gym.tltl.trace import Trace, prepare


@dataclass(frozen=True)
class _Algebra:
    """The lattice an evaluation runs in: numbers with max/min, or Booleans with or/and."""

    top: Any
    bottom: Any
    dtype: Any
    maximum: Callable[[Any, Any], Any]
    minimum: Callable[[Any, Any], Any]
    negate: Callable[[Any], Any]
    predicate: Callable[[Any, str], Any]  # predicate value from its numeric margin
    empty_max: Any  # value of a max over no terms (−inf / False)
    empty_min: Any  # value of a min over no terms (+inf / True)


def _numeric_predicate(margin: Any, op: str) -> Any:
    return margin


def _boolean_predicate(margin: Any, op: str) -> Any:
    # For finite doubles a < b exactly when b - a > 0 (subtraction is exact at 0).
    return margin > 0 if op in ("<", ">") else margin >= 0


def numeric_algebra(rho_max: float) -> _Algebra:
    """Robustness: max/min over reals, ``true`` = ρ_max."""
    return _Algebra(
        top=float(rho_max), bottom=-float(rho_max), dtype=np.float64,
        maximum=np.maximum, minimum=np.minimum, negate=np.negative,
        predicate=_numeric_predicate, empty_max=-math.inf, empty_min=math.inf,
    )


BOOLEAN = _Algebra(
    top=True, bottom=False, dtype=bool,
    maximum=np.logical_or, minimum=np.logical_and, negate=np.logical_not,
    predicate=_boolean_predicate, empty_max=False, empty_min=True,
)


class _Evaluator:
    """Evaluates every node of one formula on one batch of signals.

    Arrays are laid out time-major and time-reversed, shape ``(T, N)`` with row
    ``j`` holding position ``T-1-j``: suffix reductions over time (F, G, U, T) then
    become forward ``ufunc.accumulate`` passes over contiguous rows, which numpy
    vectorises across the N trajectories.
    """

    def __init__(self, alg: _Algebra, signals: dict[str, np.ndarray], n: int, length: int):
        self.alg = alg
        self.signals = signals
        self.n = n
        self.length = length
        self.cache: dict[Formula, np.ndarray] = {}  # a sub-formula repeated in the formula is evaluated once

    def full(self, value: Any, length: int | None = None) -> np.ndarray:
        return np.full((self.length if length is None else length, self.n), value, dtype=self.alg.dtype)

    def __call__(self, node: Formula) -> np.ndarray:
        """Values of ``node``; callers must not modify them in place (they are shared)."""
        cached = self.cache.get(node)
        if cached is not None:
            return cached
        try:
            rule = _RULES[type(node)]
        except KeyError:
            raise TypeError(f"no evaluation rule for formula node {type(node).__name__}") from None
        values = self.cache[node] = rule(self, node)
        return values

    def on_prefix(self, node: Formula, length: int) -> np.ndarray:
        """Values of ``node`` judged on the truncated trace s_0 … s_{length-1} (reversed layout)."""
        first_row = self.length - length  # reversed rows of positions length-1 … 0
        sub = _Evaluator(self.alg, {k: v[first_row:] for k, v in self.signals.items()}, self.n, length)
        return sub(node)

    # rules ----------------------------------------------------------------------------
    def constant(self, node: Constant) -> np.ndarray:
        return self.full(self.alg.top if node.value else self.alg.bottom)

    def predicate(self, node: Predicate) -> np.ndarray:
        sample = next(iter(self.signals.values()), np.zeros(1))
        with np.errstate(all="ignore"):
            lhs = evaluate_expression(node.lhs, self.signals, sample)
            rhs = evaluate_expression(node.rhs, self.signals, sample)
            margin = rhs - lhs if node.op in ("<", "<=") else lhs - rhs
        margin = np.broadcast_to(margin, (self.length, self.n))
        finite = np.isfinite(margin)
        if not finite.all():  # undefined arithmetic (log of a negative, overflow...): refuse in both semantics
            j, i = np.argwhere(~finite)[-1]  # the last row is the earliest position
            raise TraceError(
                f"predicate {str(node)!r} is NaN or infinite at trajectory {i}, position "
                f"{self.length - 1 - j} (its arithmetic is undefined there)"
            )
        return np.asarray(self.alg.predicate(margin, node.op), dtype=self.alg.dtype)

    def not_(self, node: Not) -> np.ndarray:
        return self.alg.negate(self(node.child))

    def and_(self, node: And) -> np.ndarray:
        out = self.alg.minimum(self(node.operands[0]), self(node.operands[1]))
        for child in node.operands[2:]:
            self.alg.minimum(out, self(child), out=out)
        return out

    def or_(self, node: Or) -> np.ndarray:
        out = self.alg.maximum(self(node.operands[0]), self(node.operands[1]))
        for child in node.operands[2:]:
            self.alg.maximum(out, self(child), out=out)
        return out

    def implies(self, node: Implies) -> np.ndarray:
        return self.alg.maximum(self.alg.negate(self(node.left)), self(node.right))

    def next_(self, node: Next) -> np.ndarray:
        child = self(node.child)
        out = np.empty_like(child)
        out[1:] = child[:-1]
        out[0] = self.alg.bottom  # no next state: the paper's "k > 0" fails
        return out

    def eventually(self, node: Eventually) -> np.ndarray:
        return self.alg.maximum.accumulate(self(node.child), axis=0)

    def always(self, node: Always) -> np.ndarray:
        return self.alg.minimum.accumulate(self(node.child), axis=0)

    def until(self, node: Until) -> np.ndarray:
        right = self(node.right)
        if node.left.is_temporal:
            return self._binary_on_segments(node, right, self.alg.minimum, self.alg.empty_min)
        return _until_scan(self.alg, self(node.left), right)

    def then(self, node: Then) -> np.ndarray:
        right = self(node.right)
        if node.left.is_temporal:
            return self._binary_on_segments(node, right, self.alg.maximum, self.alg.empty_max)
        # ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')): two scans.
        later_right = np.empty_like(right)
        later_right[0] = self.alg.empty_max
        self.alg.maximum.accumulate(right[:-1], axis=0, out=later_right[1:])
        return self.alg.maximum.accumulate(self.alg.minimum(self(node.left), later_right), axis=0)

    def _binary_on_segments(
        self, node: Until | Then, right: np.ndarray, inner: np.ufunc, inner_empty: Any
    ) -> np.ndarray:
        """U/T with a temporal left operand, judged on each segment s_{t''..t'-1}: O(N·T²).

        Works in natural time order (row = position) and returns the reversed layout.
        """
        right_natural = right[::-1]
        out = self.full(self.alg.empty_max)
        for t_prime in range(self.length):
            # reduced[t] = inner reduction of φ(s_{t''..t'-1}) over t'' in [t, t'); empty at t = t'
            reduced = self.full(inner_empty, t_prime + 1)
            if t_prime > 0:
                left = self.on_prefix(node.left, t_prime)  # reversed: row k is t'' = t'-1-k
                reduced[:t_prime] = inner.accumulate(left, axis=0)[::-1]
            term = self.alg.minimum(right_natural[t_prime], reduced)
            out[: t_prime + 1] = self.alg.maximum(out[: t_prime + 1], term)
        return np.ascontiguousarray(out[::-1])


def _until_scan(alg: _Algebra, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``U(t) = max(ψ(t), min(φ(t), U(t+1)))`` with a temporal-free φ, in vectorised steps.

    In the reversed layout row ``j`` applies the map ``x ↦ max(A, min(B, x))`` with
    ``(A, B) = (ψ, φ)`` to row ``j-1``'s value. Such maps compose associatively,
    ``(A1, B1)∘(A2, B2) = (max(A1, min(B1, A2)), min(B1, B2))``, so a doubling scan needs
    log2(T) whole-array steps; with many short trajectories a plain loop over rows
    (each vectorised over N) is cheaper, so pick by a cost estimate.
    """
    length, n = right.shape
    if length <= 1:
        return right.copy()
    steps = math.ceil(math.log2(length))
    if n * steps > 2 * n + 3000:  # the row loop's per-call overhead is worth ~3000 elements
        out = right.copy()
        for j in range(1, length):
            alg.maximum(out[j], alg.minimum(left[j], out[j - 1]), out=out[j])
        return out
    a, b = right.copy(), left.copy()
    shift = 1
    while shift < length:
        new_a = alg.maximum(a[shift:], alg.minimum(b[shift:], a[:-shift]))
        b[shift:] = alg.minimum(b[shift:], b[:-shift])
        a[shift:] = new_a
        shift *= 2
    return a


_RULES: dict[type, Callable[[_Evaluator, Any], np.ndarray]] = {
    Constant: _Evaluator.constant,
    Predicate: _Evaluator.predicate,
    Not: _Evaluator.not_,
    And: _Evaluator.and_,
    Or: _Evaluator.or_,
    Implies: _Evaluator.implies,
    Next: _Evaluator.next_,
    Eventually: _Evaluator.eventually,
    Always: _Evaluator.always,
    Until: _Evaluator.until,
    Then: _Evaluator.then,
}


def _evaluate(formula: Formula, trace: Trace, alg: _Algebra) -> tuple[np.ndarray, bool]:
    """Values in the evaluator's reversed ``(T, N)`` layout, and whether the input was batched."""
    prepared = prepare(formula.signals, trace)
    reversed_signals = {k: np.ascontiguousarray(v.T[::-1]) for k, v in prepared.signals.items()}
    values = _Evaluator(alg, reversed_signals, prepared.n, prepared.length)(formula)
    return values, prepared.batched


def robustness_over_time(formula: Formula, trace: Trace, rho_max: float = math.inf) -> np.ndarray:
    """Robustness at every position: shape ``(T,)`` or ``(N, T)`` like the signals."""
    values, batched = _evaluate(formula, trace, numeric_algebra(rho_max))
    natural = np.ascontiguousarray(values[::-1].T)
    return natural if batched else natural[0]


def robustness(formula: Formula, trace: Trace, rho_max: float = math.inf) -> float | np.ndarray:
    """Robustness at position 0: a float, or an ``(N,)`` array for batched signals."""
    values, batched = _evaluate(formula, trace, numeric_algebra(rho_max))
    return values[-1].copy() if batched else float(values[-1, 0])


def satisfied(formula: Formula, trace: Trace) -> bool | np.ndarray:
    """Boolean semantics at position 0: a bool, or an ``(N,)`` bool array."""
    values, batched = _evaluate(formula, trace, BOOLEAN)
    return values[-1].copy() if batched else bool(values[-1, 0])
