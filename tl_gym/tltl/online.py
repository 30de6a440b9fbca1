"""Robustness of a growing trace prefix, one state at a time (dense rewards).

`PrefixMonitor.update(state)` appends one state and returns the robustness of the
prefix ``s_0 … s_t`` at position 0, the value ``formula.robustness`` gives on that
prefix. Differences of consecutive values make dense rewards that sum to the
terminal robustness.

Cost. For the *incremental fragment* an update costs O(size of the formula),
independent of the trace length: Boolean combinations (``! & | ->``) of

* formulas with bounded lookahead, where ``X`` is the only temporal operator
  (temporal-free ones are judged at s_0; ``X^d`` ones at s_0 … s_d),
* ``F φ`` and ``G φ`` of such formulas (running max/min over the final positions,
  the last d positions judged on their truncated windows),
* ``φ U ψ`` with temporal-free operands (running min of φ, best
  ``min(ψ(t'), min φ(<t'))``),
* chains ``φ1 T (φ2 T (… T φm))`` of temporal-free operands (best value of every
  leading sub-chain),
* ``G(A | X G B)`` and ``G(L -> X G B)`` ("never again"), with A, L of bounded
  lookahead and B temporal-free (two running values, see `_NeverAgain`).

Both car tasks are in it (task 2 with either reading of its no-revisit clause).
Any other formula (``F G φ``, ``G(φ -> F ψ)``, ``U`` over a temporal operand, …)
falls back to re-evaluating the whole prefix at every update: O(t) for state
``t``, O(T²) per episode (about ``T/2`` full evaluations). The monitor says which
one it uses in ``incremental``.

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
from collections import deque
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
from tl_gym.tltl.trace import check_rho_max

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


# --------------------------------------------------------------------------- windowed formulas


def lookahead(formula: Formula) -> int | None:
    """How many states after position k decide ``formula`` at k, if only ``X`` occurs in it.

    0 for a temporal-free formula, the nesting depth of ``X`` for a Boolean
    combination of ``X``'s over temporal-free formulas; None when ``F G U T`` occur.
    """
    if not formula.is_temporal:
        return 0
    if isinstance(formula, Next):
        depth = lookahead(formula.child)
        return None if depth is None else depth + 1
    if isinstance(formula, (Not, And, Or, Implies)):
        depths = [lookahead(c) for c in formula.children]
        return None if any(d is None for d in depths) else max(depths)  # type: ignore[type-var]
    return None


_Window = Callable[[list, int], float]  # (states s_k … s_{k+d} (fewer at the trace's end), index) -> value


def compile_window_formula(formula: Formula, rho_max: float) -> _Window:
    """Robustness at ``window[i]`` of a formula with bounded lookahead (see `lookahead`).

    ``X φ`` beyond the end of the window is −ρ_max, the value of ``X`` at the last state.
    """
    if not formula.is_temporal:
        fn = compile_state_formula(formula, rho_max)
        return lambda w, i: fn(w[i])
    if isinstance(formula, Next):
        inner = compile_window_formula(formula.child, rho_max)
        bottom = -float(rho_max)
        return lambda w, i: inner(w, i + 1) if i + 1 < len(w) else bottom
    parts = [compile_window_formula(c, rho_max) for c in formula.children]
    if isinstance(formula, Not):
        return lambda w, i: -parts[0](w, i)
    if isinstance(formula, And):
        return lambda w, i: min(p(w, i) for p in parts)
    if isinstance(formula, Or):
        return lambda w, i: max(p(w, i) for p in parts)
    if isinstance(formula, Implies):
        return lambda w, i: max(-parts[0](w, i), parts[1](w, i))
    raise TypeError(f"{type(formula).__name__} has no bounded lookahead")


# --------------------------------------------------------------------------- incremental nodes


class _Node:
    """Robustness at position 0 of a growing prefix, for one node of the fragment."""

    def reset(self) -> None:
        raise NotImplementedError

    def update(self, s: State) -> float:
        raise NotImplementedError


class _AtStart(_Node):
    """A formula with lookahead d: judged on s_0 … s_d (truncated while the trace is shorter)."""

    def __init__(self, fn: _Window, depth: int):
        self.fn = fn
        self.depth = depth
        self.states: list[State] = []
        self.value = 0.0

    def reset(self) -> None:
        self.states = []

    def update(self, s: State) -> float:
        if len(self.states) <= self.depth:
            self.states.append(s)
            self.value = self.fn(self.states, 0)
        return self.value


class _Extremum(_Node):
    """``F φ`` (running max) or ``G φ`` (running min) of a formula with lookahead d.

    Positions k ≤ t − d are final and folded into one running value; the last d
    positions are judged on their truncated windows at every update (O(d²)).
    """

    def __init__(self, fn: _Window, depth: int, is_max: bool):
        self.fn = fn
        self.depth = depth
        self.pick = max if is_max else min
        self.empty = -math.inf if is_max else math.inf
        self.reset()

    def reset(self) -> None:
        self.window: deque[State] = deque(maxlen=self.depth + 1)
        self.final = self.empty
        self.count = 0

    def update(self, s: State) -> float:
        self.window.append(s)
        self.count += 1
        states = list(self.window)
        start = 0
        if self.count > self.depth:  # the window's first position is now final
            self.final = self.pick(self.final, self.fn(states, 0))
            start = 1
        value = self.final
        for i in range(start, len(states)):
            value = self.pick(value, self.fn(states, i))
        return value


class _NeverAgain(_Node):
    """``G(A | X G B)`` (so also ``G(¬L -> X G B)``): A with lookahead d, B temporal-free.

    At prefix length n the value is min over k of max(A_k, M_k) with M_k the min of
    B over (k, n) (−ρ_max for k = n − 1, the last state). A new state lowers every
    M_k by the same ``c = B(s_t)``, and ``min_k max(A_k, min(M_k, c))`` equals
    ``min(min_k max(A_k, M_k), max(min_k A_k, c))``: two running values carry the
    final positions, and the last ``max(d, 1)`` positions are judged directly.
    """

    def __init__(self, a: _Window, depth: int, b: _Scalar, rho_max: float):
        self.a, self.b = a, b
        self.depth = max(depth, 1)  # X G B at the last state is −ρ_max: that position is never final
        self.bottom = -float(rho_max)
        self.reset()

    def reset(self) -> None:
        self.window: deque[State] = deque(maxlen=self.depth + 1)
        self.b_values: deque[float] = deque(maxlen=self.depth + 1)
        self.final = math.inf  # min over final k of max(A_k, M_k)
        self.min_a = math.inf  # min over final k of A_k
        self.count = 0

    def update(self, s: State) -> float:
        c = self.b(s)
        self.window.append(s)
        self.b_values.append(c)
        self.count += 1
        if self.min_a < math.inf:
            self.final = min(self.final, max(self.min_a, c))
        states, bs = list(self.window), list(self.b_values)
        start = 0
        if self.count > self.depth:  # position t − depth becomes final
            a_value = self.a(states, 0)
            self.final = min(self.final, max(a_value, min(bs[1:])))
            self.min_a = min(self.min_a, a_value)
            start = 1
        value = self.final
        last = len(states) - 1
        for i in range(start, last + 1):
            later = min(bs[i + 1 :]) if i < last else self.bottom
            value = min(value, max(self.a(states, i), later))
        return value


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


class _ThenChain(_Node):
    """``φ1 T (φ2 T (… T φm))`` = max over s1 < … < sm of min(φ1(s1), …, φm(sm)).

    ``best[i]`` is that max for the first i operands; a new state updates them from
    the last to the first, each from the previous one's value before this state.
    """

    def __init__(self, fns: list[_Scalar]):
        self.fns = fns
        self.reset()

    def reset(self) -> None:
        self.best = [-math.inf] * len(self.fns)

    def update(self, s: State) -> float:
        best = self.best
        for i in range(len(self.fns) - 1, 0, -1):
            if best[i - 1] > -math.inf:
                candidate = min(best[i - 1], self.fns[i](s))
                if candidate > best[i]:
                    best[i] = candidate
        best[0] = max(best[0], self.fns[0](s))
        return best[-1]


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


def _then_chain(formula: Formula) -> list[Formula] | None:
    """The operands of ``φ1 T (φ2 T …)`` when all are temporal-free, else None."""
    operands: list[Formula] = []
    node = formula
    while isinstance(node, Then):
        if node.left.is_temporal:
            return None
        operands.append(node.left)
        node = node.right
    if node.is_temporal:
        return None
    return [*operands, node]


def _never_again_parts(child: Formula) -> tuple[Formula, Formula] | None:
    """``(A, B)`` when ``child`` is ``A | X G B`` or ``L -> X G B`` (A = !L), B temporal-free."""

    def is_next_always(f: Formula) -> bool:
        return isinstance(f, Next) and isinstance(f.child, Always) and not f.child.child.is_temporal

    if isinstance(child, Implies) and is_next_always(child.right) and lookahead(child.left) is not None:
        return Not(child.left), child.right.child.child  # type: ignore[attr-defined]
    if isinstance(child, Or):
        tails = [c for c in child.operands if is_next_always(c)]
        rest = [c for c in child.operands if not is_next_always(c)]
        if len(tails) == 1 and rest and all(lookahead(c) is not None for c in rest):
            a = rest[0] if len(rest) == 1 else Or(tuple(rest))
            return a, tails[0].child.child  # type: ignore[attr-defined]
    return None


def _compile_incremental(formula: Formula, rho_max: float) -> _Node | None:
    """The incremental monitor of ``formula``, or None outside the fragment."""
    depth = lookahead(formula)
    if depth is not None:
        return _AtStart(compile_window_formula(formula, rho_max), depth)
    if isinstance(formula, (Not, And, Or, Implies)):
        children = [_compile_incremental(c, rho_max) for c in formula.children]
        if any(c is None for c in children):
            return None
        return _Combine(type(formula), children)  # type: ignore[arg-type]
    if isinstance(formula, (Eventually, Always)):
        depth = lookahead(formula.child)
        if depth is not None:
            return _Extremum(compile_window_formula(formula.child, rho_max), depth, isinstance(formula, Eventually))
        parts = _never_again_parts(formula.child) if isinstance(formula, Always) else None
        if parts is not None:
            a, b = parts
            return _NeverAgain(
                compile_window_formula(a, rho_max), lookahead(a) or 0, compile_state_formula(b, rho_max), rho_max
            )
        return None
    if isinstance(formula, Until):
        if formula.left.is_temporal or formula.right.is_temporal:
            return None
        return _Until(compile_state_formula(formula.left, rho_max), compile_state_formula(formula.right, rho_max))
    if isinstance(formula, Then):
        chain = _then_chain(formula)
        if chain is None:
            return None
        return _ThenChain([compile_state_formula(f, rho_max) for f in chain])
    return None


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
        self.formula = formula
        self.rho_max = check_rho_max(rho_max)
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
