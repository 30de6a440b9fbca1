"""Robustness of a growing trace prefix, one state at a time (dense rewards).

`PrefixMonitor.update(state)` appends one state and returns the robustness of the
prefix ``s_0 … s_t`` at position 0, the value ``formula.robustness`` gives on that
prefix. Differences of consecutive values make dense rewards that sum to the
terminal robustness.

Cost. For the *incremental fragment* the update is O(1) per state (O(size of the
formula)): Boolean combinations (``! & | ->``) of

* temporal-free sub-formulas (judged at position 0, so fixed by ``s_0``),
* ``F φ``, ``G φ``, ``X φ``, ``φ U ψ``, ``φ T ψ`` whose operands are temporal-free
  (running max/min: ``φ U ψ`` keeps the min of φ so far and the best
  ``min(ψ(t'), min φ(<t'))``; ``φ T ψ`` the same with the max of φ).

Task 1 of the car, ``F goal & G avoid``, is in the fragment. Any other formula
(nested temporal operators, such as the car's task 2) falls back to re-evaluating
the whole prefix at every update: O(t) for state ``t``, O(T²) per episode (about
``T/2`` full evaluations). The monitor says which one it uses in ``incremental``.

Pure numpy and the standard library: no Gymnasium here.

Example:
    >>> from tl_gym import parse
    >>> monitor = PrefixMonitor(parse("F(x > 2) & G(x < 5)"))
    >>> monitor.incremental
    True
    >>> [monitor.update({"x": v}) for v in (0.0, 3.0, 4.5)]
    [-2.0, 1.0, 0.5]
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from tl_gym.errors import TraceError, UnknownSignalError
from tl_gym.tltl.ast import (
    Always,
    And,
    BinOp,
    Call,
    Constant,
    Eventually,
    Expr,
    Formula,
    Implies,
    Neg,
    Next,
    Not,
    Num,
    Or,
    Predicate,
    Then,
    Until,
    Var,
)
from tl_gym.tltl.expressions import can_be_non_finite

State = Mapping[str, float]
_Scalar = Callable[[State], float]


# --------------------------------------------------------------------------- temporal-free parts, on one state


def _compile_expr(expr: Expr) -> _Scalar:
    """A closure computing ``expr`` on one state with Python floats."""
    if isinstance(expr, Var):
        name = expr.name
        return lambda s: s[name]
    if isinstance(expr, Num):
        value = expr.value
        return lambda s: value
    if isinstance(expr, Neg):
        inner = _compile_expr(expr.operand)
        return lambda s: -inner(s)
    if isinstance(expr, BinOp):
        a, b = _compile_expr(expr.left), _compile_expr(expr.right)
        ops: dict[str, _Scalar] = {
            "+": lambda s: a(s) + b(s),
            "-": lambda s: a(s) - b(s),
            "*": lambda s: a(s) * b(s),
            "/": lambda s: a(s) / b(s),
            "^": lambda s: math.pow(a(s), b(s)),
        }
        return ops[expr.op]
    if isinstance(expr, Call):
        args = [_compile_expr(arg) for arg in expr.args]
        if expr.func in ("min", "max"):
            reduce_ = min if expr.func == "min" else max
            return lambda s: reduce_(f(s) for f in args)
        fn = {"abs": abs, "sqrt": math.sqrt, "exp": math.exp, "log": math.log}[expr.func]
        only = args[0]
        return lambda s: fn(only(s))
    raise TypeError(f"no evaluation rule for expression node {type(expr).__name__}")


def _compile_predicate(node: Predicate) -> _Scalar:
    lhs, rhs = _compile_expr(node.lhs), _compile_expr(node.rhs)
    less = node.op in ("<", "<=")
    checked = can_be_non_finite(node.lhs) or can_be_non_finite(node.rhs)
    text = str(node)

    def value(s: State) -> float:
        try:
            v = rhs(s) - lhs(s) if less else lhs(s) - rhs(s)
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise TraceError(f"predicate {text!r} is undefined at this state ({exc})") from None
        if checked and not math.isfinite(v):
            raise TraceError(f"predicate {text!r} is NaN or infinite at this state")
        return v

    return value


def compile_state_formula(formula: Formula, rho_max: float) -> _Scalar:
    """Robustness of a temporal-free formula on one state, as a closure of that state."""
    if isinstance(formula, Constant):
        value = float(rho_max) if formula.value else -float(rho_max)
        return lambda s: value
    if isinstance(formula, Predicate):
        return _compile_predicate(formula)
    if isinstance(formula, Not):
        inner = compile_state_formula(formula.child, rho_max)
        return lambda s: -inner(s)
    if isinstance(formula, (And, Or)):
        parts = [compile_state_formula(c, rho_max) for c in formula.operands]
        reduce_ = min if isinstance(formula, And) else max
        return lambda s: reduce_(p(s) for p in parts)
    if isinstance(formula, Implies):
        left, right = compile_state_formula(formula.left, rho_max), compile_state_formula(formula.right, rho_max)
        return lambda s: max(-left(s), right(s))
    raise TypeError(f"{type(formula).__name__} is temporal; compile_state_formula takes temporal-free formulas")


# --------------------------------------------------------------------------- incremental nodes


class _Node:
    """Robustness at position 0 of a growing prefix, for one node of the fragment."""

    def reset(self) -> None:
        raise NotImplementedError

    def update(self, s: State) -> float:
        raise NotImplementedError


class _AtStart(_Node):
    """A temporal-free formula: judged at s_0 and fixed afterwards."""

    def __init__(self, fn: _Scalar):
        self.fn = fn
        self.value: float | None = None

    def reset(self) -> None:
        self.value = None

    def update(self, s: State) -> float:
        if self.value is None:
            self.value = self.fn(s)
        return self.value


class _Eventually(_Node):
    def __init__(self, fn: _Scalar):
        self.fn = fn
        self.best = -math.inf

    def reset(self) -> None:
        self.best = -math.inf

    def update(self, s: State) -> float:
        v = self.fn(s)
        if v > self.best:
            self.best = v
        return self.best


class _Always(_Node):
    def __init__(self, fn: _Scalar):
        self.fn = fn
        self.worst = math.inf

    def reset(self) -> None:
        self.worst = math.inf

    def update(self, s: State) -> float:
        v = self.fn(s)
        if v < self.worst:
            self.worst = v
        return self.worst


class _Next(_Node):
    """``X φ``: −ρ_max on a one-state prefix, φ(s_1) from then on."""

    def __init__(self, fn: _Scalar, rho_max: float):
        self.fn = fn
        self.bottom = -float(rho_max)
        self.count = 0
        self.value = self.bottom

    def reset(self) -> None:
        self.count = 0
        self.value = self.bottom

    def update(self, s: State) -> float:
        if self.count == 1:
            self.value = self.fn(s)
        self.count += 1
        return self.value


class _Until(_Node):
    """``φ U ψ`` = max over t' of min(ψ(t'), min of φ before t')."""

    def __init__(self, left: _Scalar, right: _Scalar):
        self.left, self.right = left, right
        self.reset()

    def reset(self) -> None:
        self.left_so_far = math.inf
        self.best = -math.inf

    def update(self, s: State) -> float:
        candidate = min(self.right(s), self.left_so_far)
        if candidate > self.best:
            self.best = candidate
        self.left_so_far = min(self.left_so_far, self.left(s))
        return self.best


class _Then(_Node):
    """``φ T ψ`` = max over t' of min(ψ(t'), max of φ before t')."""

    def __init__(self, left: _Scalar, right: _Scalar):
        self.left, self.right = left, right
        self.reset()

    def reset(self) -> None:
        self.left_so_far = -math.inf
        self.best = -math.inf

    def update(self, s: State) -> float:
        candidate = min(self.right(s), self.left_so_far)
        if candidate > self.best:
            self.best = candidate
        self.left_so_far = max(self.left_so_far, self.left(s))
        return self.best


class _Combine(_Node):
    """A Boolean connective over incremental children."""

    def __init__(self, kind: type[Formula], children: list[_Node]):
        self.kind = kind
        self.children = children

    def reset(self) -> None:
        for child in self.children:
            child.reset()

    def update(self, s: State) -> float:
        values = [child.update(s) for child in self.children]
        if self.kind is Not:
            return -values[0]
        if self.kind is And:
            return min(values)
        if self.kind is Or:
            return max(values)
        return max(-values[0], values[1])  # Implies


def _compile_incremental(formula: Formula, rho_max: float) -> _Node | None:
    """The incremental monitor of ``formula``, or None outside the fragment."""
    if not formula.is_temporal:
        return _AtStart(compile_state_formula(formula, rho_max))
    if isinstance(formula, (Not, And, Or, Implies)):
        children = [_compile_incremental(c, rho_max) for c in formula.children]
        if any(c is None for c in children):
            return None
        return _Combine(type(formula), children)  # type: ignore[arg-type]
    if any(child.is_temporal for child in formula.children):
        return None
    fns = [compile_state_formula(c, rho_max) for c in formula.children]
    if isinstance(formula, Eventually):
        return _Eventually(fns[0])
    if isinstance(formula, Always):
        return _Always(fns[0])
    if isinstance(formula, Next):
        return _Next(fns[0], rho_max)
    if isinstance(formula, Until):
        return _Until(fns[0], fns[1])
    if isinstance(formula, Then):
        return _Then(fns[0], fns[1])
    raise TypeError(f"no incremental rule for formula node {type(formula).__name__}")


def is_incremental(formula: Formula) -> bool:
    """Whether `PrefixMonitor` updates ``formula`` in O(1) per state (see the module docstring)."""
    return _compile_incremental(formula, math.inf) is not None


# --------------------------------------------------------------------------- the monitor


class PrefixMonitor:
    """Robustness at position 0 of the trace seen so far, updated one state at a time.

    Args:
        formula: the formula to monitor.
        rho_max: the value of ``true`` (and minus that of ``X φ`` at the last state).

    Attributes:
        incremental: True when updates are O(1); False when each update re-evaluates
            the prefix with ``formula.robustness`` (O(t)).
    """

    def __init__(self, formula: Formula, rho_max: float = math.inf):
        if not isinstance(formula, Formula):
            raise TypeError(f"formula must be a Formula, got {type(formula).__name__}")
        if not rho_max > 0:
            raise ValueError(f"rho_max must be > 0, got {rho_max!r}")
        self.formula = formula
        self.rho_max = float(rho_max)
        self._names = formula.signals
        self._root = _compile_incremental(formula, self.rho_max)
        self.incremental = self._root is not None
        self._history: np.ndarray = np.empty((len(self._names), 64), dtype=np.float64)
        self._length = 0

    @property
    def length(self) -> int:
        """Number of states seen since the last `reset`."""
        return self._length

    def reset(self) -> None:
        """Forget the trace; the next `update` is s_0."""
        self._length = 0
        if self._root is not None:
            self._root.reset()

    def update(self, state: Mapping[str, Any]) -> float:
        """Append one state (signal name -> number) and return the prefix's robustness."""
        missing = [n for n in self._names if n not in state]
        if missing:
            raise UnknownSignalError(f"the state has no signal {missing[0]!r}, which the formula reads")
        for name in self._names:
            if not math.isfinite(state[name]):
                raise TraceError(f"signal {name!r} is NaN or infinite at position {self._length}")
        if self._root is not None:
            self._length += 1
            return self._root.update(state)
        return self._replay(state)

    def _replay(self, state: Mapping[str, Any]) -> float:
        if self._length == self._history.shape[1]:
            grown = np.empty((len(self._names), 2 * self._length), dtype=np.float64)
            grown[:, : self._length] = self._history
            self._history = grown
        for i, name in enumerate(self._names):
            self._history[i, self._length] = state[name]
        self._length += 1
        trace = {name: self._history[i, : self._length] for i, name in enumerate(self._names)}
        if not self._names:  # a formula of constants still needs a length
            trace = {"_": np.zeros(self._length)}
        return float(self.formula.robustness(trace, self.rho_max))
