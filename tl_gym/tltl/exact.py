"""Exact robustness and Boolean semantics of TLTL, vectorised over trajectories and time.

One evaluator serves both semantics through an `_Algebra`: robustness uses
(max, min, negation, ±ρ_max), the Boolean semantics (or, and, not, true/false).
Each node maps the ``(N, T)`` values of its children to its own ``(N, T)``
values, entry ``[i, t]`` judging trajectory ``i`` from position ``t`` on
(the paper's ρ(s_{t:T}, φ)), or to its value at position 0 only when that is all
its parent needs. Every operator costs O(N·T), except ``U``/``T`` whose left
operand is temporal: that operand must be judged on every truncated segment
s_{t''..t'-1}, which costs O(N·T²) time (and O(N·T) memory).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

import numpy as np

from tl_gym.errors import TraceError
from tl_gym.tltl.ast import (
    Always,
    And,
    Call,
    Constant,
    Eventually,
    Formula,
    Implies,
    Next,
    Not,
    Num,
    Or,
    Predicate,
    Then,
    Until,
)
from tl_gym.tltl.expressions import evaluate_expression, margin_bound
from tl_gym.tltl.iterative import resolve
from tl_gym.tltl.trace import Trace, check_rho_max, chunks, prepare

# A rule that needs its operands' values yields their keys ``(node, first_only)`` and gets the values back.
_Rule = Generator[tuple[Formula, bool], np.ndarray, np.ndarray]


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
    """Robustness: max/min over reals, ``true`` = ρ_max (> 0, +inf allowed)."""
    rho_max = check_rho_max(rho_max)
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


# Increasing functions whose extreme over time can be taken before applying them.
_MONOTONE = {"sqrt": np.sqrt, "exp": np.exp, "log": np.log}


def _suffix(ufunc: np.ufunc, values: np.ndarray) -> np.ndarray:
    """``out[:, t] = ufunc`` over ``values[:, t:]``: a suffix scan along time."""
    return ufunc.accumulate(values[:, ::-1], axis=1)[:, ::-1]


def _exclusive_prefix(ufunc: np.ufunc, values: np.ndarray, empty: Any) -> np.ndarray:
    """``out[:, t] = ufunc`` over ``values[:, :t]`` (``empty`` at t = 0)."""
    out = np.empty_like(values)
    out[:, 0] = empty
    ufunc.accumulate(values[:, :-1], axis=1, out=out[:, 1:])
    return out


class _Evaluator:
    """Evaluates every node of one formula on one batch of ``(N, T)`` signals.

    A node is evaluated either at every position, shape ``(N, T)`` (entry ``[i, t]``
    judges s_t … s_{T-1}), or, when only position 0 is needed (``first_only``), shape
    ``(N, 1)``: Boolean connectives pass the request down, and a top-level F, G, U or T
    becomes one reduction over time instead of a scan.
    """

    def __init__(
        self, alg: _Algebra, signals: dict[str, np.ndarray], n: int, length: int, magnitudes: dict[str, float],
        first_row: int = 0,
    ):
        self.alg = alg
        self.first_row = first_row  # index of this group's first trajectory in the caller's batch
        self.signals = signals
        self.magnitudes = magnitudes
        self.n = n
        self.length = length
        self.cache: dict[tuple[Formula, bool], np.ndarray] = {}  # a repeated sub-formula is evaluated once

    def full(self, value: Any, length: int | None = None) -> np.ndarray:
        return np.full((self.n, self.length if length is None else length), value, dtype=self.alg.dtype)

    def __call__(self, node: Formula, first_only: bool = False) -> np.ndarray:
        """Values of ``node``; callers must not modify them in place (they are shared).

        Rules ``yield`` the ``(child, first_only)`` keys they need (`tl_gym.tltl.iterative.resolve`
        evaluates those first, without recursion, so any nesting depth works).
        """
        key = (node, first_only)
        cached = self.cache.get(key)
        if cached is not None:
            return cached
        return resolve(key, self.cache, self._start, self._finish)

    def _start(self, key: tuple[Formula, bool]) -> Any:
        node, first_only = key
        try:
            rule = _RULES[type(node)]
        except KeyError:
            raise TypeError(f"no evaluation rule for formula node {type(node).__name__}") from None
        return rule(self, node, first_only)

    def _finish(self, key: tuple[Formula, bool], values: np.ndarray) -> np.ndarray:
        self.cache[key] = values
        return values

    def on_prefix(self, node: Formula, length: int) -> np.ndarray:
        """Values of ``node`` at every position of the truncated trace s_0 … s_{length-1}."""
        signals = {k: v[:, :length] for k, v in self.signals.items()}
        sub = _Evaluator(self.alg, signals, self.n, length, self.magnitudes, self.first_row)
        return sub(node)

    # rules ----------------------------------------------------------------------------
    def constant(self, node: Constant, first_only: bool) -> np.ndarray:
        return self.full(self.alg.top if node.value else self.alg.bottom, 1 if first_only else None)

    def predicate(self, node: Predicate, first_only: bool) -> np.ndarray:
        signals = {k: v[:, :1] for k, v in self.signals.items()} if first_only else self.signals
        shape = (self.n, 1 if first_only else self.length)
        with np.errstate(all="ignore"):
            lhs = evaluate_expression(node.lhs, signals, None)
            rhs = evaluate_expression(node.rhs, signals, None)
            margin = rhs - lhs if node.op in ("<", "<=") else lhs - rhs
        margin = np.broadcast_to(margin, shape)
        # Undefined arithmetic (log of a negative, overflow...) is refused. A NaN or inf makes the
        # sum non-finite, so one cheap pass clears almost every call; only then look closer.
        with np.errstate(all="ignore"):
            suspicious = not self._cannot_overflow(node) and not np.isfinite(np.sum(margin))
        if suspicious and not np.isfinite(margin).all():
            i, t = np.argwhere(~np.isfinite(margin))[0]
            raise TraceError(
                f"predicate {str(node)!r} is NaN or infinite at trajectory {self.first_row + i}, position {t} "
                "(its arithmetic is undefined there)"
            )
        return np.asarray(self.alg.predicate(margin, node.op), dtype=self.alg.dtype)

    def _cannot_overflow(self, node: Predicate) -> bool:
        """Whether the margin is known finite from the signals' magnitudes (`margin_bound`)."""
        return margin_bound(node.lhs, node.rhs, tuple(self.magnitudes.items())) < 1e307

    def not_(self, node: Not, first_only: bool) -> _Rule:
        return self.alg.negate((yield node.child, first_only))

    def and_(self, node: And, first_only: bool) -> _Rule:
        return (yield from self._extreme_of_operands(node, first_only, self.alg.minimum))

    def or_(self, node: Or, first_only: bool) -> _Rule:
        return (yield from self._extreme_of_operands(node, first_only, self.alg.maximum))

    def _extreme_of_operands(self, node: And | Or, first_only: bool, pick: np.ufunc) -> _Rule:
        first = yield node.operands[0], first_only
        out = pick(first, (yield node.operands[1], first_only))
        for child in node.operands[2:]:
            pick(out, (yield child, first_only), out=out)
        return out

    def implies(self, node: Implies, first_only: bool) -> _Rule:
        left = yield node.left, first_only
        return self.alg.maximum(self.alg.negate(left), (yield node.right, first_only))

    def next_(self, node: Next, first_only: bool) -> _Rule:
        if first_only:
            if self.length == 1:
                return self.full(self.alg.bottom, 1)
            return (yield node.child, False)[:, 1:2]
        child = yield node.child, False
        out = np.empty_like(child)
        out[:, :-1] = child[:, 1:]
        out[:, -1] = self.alg.bottom  # no next state: the paper's "k > 0" fails
        return out

    def eventually(self, node: Eventually, first_only: bool) -> _Rule:
        if first_only:
            hoisted = self._monotone_extreme(node.child, largest=True)
            if hoisted is not None:
                return hoisted
        child = yield node.child, False
        return self.alg.maximum.reduce(child, axis=1, keepdims=True) if first_only else _suffix(self.alg.maximum, child)

    def always(self, node: Always, first_only: bool) -> _Rule:
        if first_only:
            hoisted = self._monotone_extreme(node.child, largest=False)
            if hoisted is not None:
                return hoisted
        child = yield node.child, False
        return self.alg.minimum.reduce(child, axis=1, keepdims=True) if first_only else _suffix(self.alg.minimum, child)

    def _monotone_extreme(self, node: Formula, largest: bool) -> np.ndarray | None:
        """Max (F) or min (G) over time of a predicate ``f(e) ⋈ c`` with f increasing, or None.

        For f in sqrt, exp, log the extreme over time commutes with f, so f is applied to
        the ``(N, 1)`` extreme of e instead of to every state (the obstacle clause
        ``G(sqrt(...) > r)`` of the car tasks). Both extremes of e are checked to lie in
        f's domain, so a trace that the general path would refuse takes the general path.
        """
        if self.alg.dtype is not np.float64 or not isinstance(node, Predicate):
            return None
        if isinstance(node.lhs, Call) and node.lhs.func in _MONOTONE and isinstance(node.rhs, Num):
            call, constant, grows = node.lhs, node.rhs.value, node.op in (">", ">=")
        elif isinstance(node.rhs, Call) and node.rhs.func in _MONOTONE and isinstance(node.lhs, Num):
            call, constant, grows = node.rhs, node.lhs.value, node.op in ("<", "<=")
        else:
            return None
        with np.errstate(all="ignore"):
            inner = np.broadcast_to(evaluate_expression(call.args[0], self.signals, None), (self.n, self.length))
            low, high = inner.min(axis=1, keepdims=True), inner.max(axis=1, keepdims=True)
            function = _MONOTONE[call.func]
            ends = function(low), function(high)
        if not (np.isfinite(ends[0]).all() and np.isfinite(ends[1]).all()):
            return None  # outside f's domain somewhere (or NaN): the general path names the position
        # margin = f(e) - c if it grows with f, else c - f(e); pick the extreme of the margin
        extreme = ends[1] if grows == largest else ends[0]
        return extreme - constant if grows else constant - extreme

    def until(self, node: Until, first_only: bool) -> _Rule:
        alg = self.alg
        if node.left.is_temporal:
            out = yield from self._binary_on_segments(node, alg.minimum, alg.empty_min)
        elif first_only:  # max_t' min(ψ(t'), min_{t'' < t'} φ(t'')): one prefix scan
            before = _exclusive_prefix(alg.minimum, (yield node.left, False), alg.empty_min)
            return alg.maximum.reduce(alg.minimum((yield node.right, False), before), axis=1, keepdims=True)
        else:
            left = yield node.left, False
            out = _until_scan(alg, left, (yield node.right, False))
        return out[:, :1] if first_only else out

    def then(self, node: Then, first_only: bool) -> _Rule:
        alg = self.alg
        if node.left.is_temporal:
            out = yield from self._binary_on_segments(node, alg.maximum, alg.empty_max)
            return out[:, :1] if first_only else out
        left = yield node.left, False
        right = yield node.right, False
        if first_only:  # max_t' min(ψ(t'), max_{t'' < t'} φ(t'')): one prefix scan
            before = _exclusive_prefix(alg.maximum, left, alg.empty_max)
            return alg.maximum.reduce(alg.minimum(right, before), axis=1, keepdims=True)
        # ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')): two suffix scans.
        later_right = np.empty_like(right)
        later_right[:, -1] = alg.empty_max
        later_right[:, :-1] = _suffix(alg.maximum, right)[:, 1:]
        return _suffix(alg.maximum, alg.minimum(left, later_right))

    def _binary_on_segments(self, node: Until | Then, inner: np.ufunc, inner_empty: Any) -> _Rule:
        """U/T with a temporal left operand, judged on each segment s_{t''..t'-1}: O(N·T²) time."""
        right = yield node.right, False
        out = self.full(self.alg.empty_max)
        for t_prime in range(self.length):
            # reduced[t] = inner reduction of φ(s_{t''..t'-1}) over t'' in [t, t'); empty at t = t'
            reduced = self.full(inner_empty, t_prime + 1)
            if t_prime > 0:
                reduced[:, :t_prime] = _suffix(inner, self.on_prefix(node.left, t_prime))
            term = self.alg.minimum(right[:, t_prime : t_prime + 1], reduced)
            out[:, : t_prime + 1] = self.alg.maximum(out[:, : t_prime + 1], term)
        return out


def _until_scan(alg: _Algebra, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``U(t) = max(ψ(t), min(φ(t), U(t+1)))`` at every position, temporal-free φ.

    Each position is the map ``x ↦ max(A, min(B, x))`` with ``(A, B) = (ψ(t), φ(t))``;
    such maps compose associatively, ``(A1, B1)∘(A2, B2) = (max(A1, min(B1, A2)), min(B1, B2))``,
    so a doubling suffix scan needs log2(T) whole-array steps. With many short
    trajectories a backward loop over time (each step vectorised over N) is cheaper.
    """
    n, length = right.shape
    if length <= 1:
        return right.copy()
    if n * math.ceil(math.log2(length)) > 2 * n + 3000:  # the loop's per-step overhead is worth ~3000 elements
        out = right.copy()
        for t in range(length - 2, -1, -1):
            out[:, t] = alg.maximum(right[:, t], alg.minimum(left[:, t], out[:, t + 1]))
        return out
    a, b = right.copy(), left.copy()
    shift = 1
    while shift < length:
        new_a = alg.maximum(a[:, :-shift], alg.minimum(b[:, :-shift], a[:, shift:]))
        b[:, :-shift] = alg.minimum(b[:, :-shift], b[:, shift:])
        a[:, :-shift] = new_a
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


def _evaluate(formula: Formula, trace: Trace, alg: _Algebra, first_only: bool) -> tuple[np.ndarray, bool]:
    prepared = prepare(formula.signals, trace)
    parts = [  # trajectories are independent: evaluate them group by group (see `chunks`)
        _Evaluator(alg, {k: v[rows] for k, v in prepared.signals.items()}, rows.stop - rows.start,
                   prepared.length, prepared.magnitudes, rows.start)(formula, first_only)
        for rows in chunks(prepared.n, prepared.length)
    ]
    return (parts[0] if len(parts) == 1 else np.concatenate(parts)), prepared.batched


def robustness_over_time(formula: Formula, trace: Trace, rho_max: float = math.inf) -> np.ndarray:
    """Robustness at every position: shape ``(T,)`` or ``(N, T)`` like the signals."""
    values, batched = _evaluate(formula, trace, numeric_algebra(rho_max), first_only=False)
    return np.array(values if batched else values[0])


def robustness(formula: Formula, trace: Trace, rho_max: float = math.inf) -> float | np.ndarray:
    """Robustness at position 0: a float, or an ``(N,)`` array for batched signals."""
    values, batched = _evaluate(formula, trace, numeric_algebra(rho_max), first_only=True)
    return values[:, 0].copy() if batched else float(values[0, 0])


def satisfied(formula: Formula, trace: Trace) -> bool | np.ndarray:
    """Boolean semantics at position 0: a bool, or an ``(N,)`` bool array."""
    values, batched = _evaluate(formula, trace, BOOLEAN, first_only=True)
    return values[:, 0].copy() if batched else bool(values[0, 0])
