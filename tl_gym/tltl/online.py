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
  lookahead and B temporal-free (two running values, see `_NeverAgain`),
* ``F G φ`` and ``G F φ`` for any φ: on a finite trace both equal φ judged at the last
  state alone (a one-state suffix).

Both car tasks are in it (task 2 with either reading of its no-revisit clause).
Any other formula (``G(φ -> F ψ)``, ``U`` over a temporal operand, …)
falls back to re-evaluating the whole prefix at every update: O(t) for state
``t``, O(T²) per episode (about ``T/2`` full evaluations). The monitor says which
one it uses in ``incremental``; `outside_fragment` names the sub-formula that keeps a
formula out.

Inside the fragment the monitor's *state* is finite: `PrefixMonitor.state` returns it as
floats (typed by `PrefixMonitor.slots`: robustness values, remembered signals, counts) and
`PrefixMonitor.value_of_state` recomputes the prefix robustness from it alone. The state and
the states still to come determine every later value: this is what the wrapper's
``observe_monitor=True`` shows an agent (`tl_gym.monitor_view`).

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
from typing import Any, NamedTuple

import numpy as np

from tl_gym.errors import TraceError, UnknownSignalError
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import operators
from tl_gym.tltl.ast import Expr, Formula, height
from tl_gym.tltl.codegen import CodeWriter, state_formula_source, window_formula_source, writable
from tl_gym.tltl.expressions import can_be_non_finite, evaluate_expression, postorder
from tl_gym.tltl.trace import check_rho_max

State = Mapping[str, float]
_Scalar = Callable[[State], float]


# --------------------------------------------------------------------------- temporal-free parts, on one state


# Closures nest as deep as the formula; beyond this depth a loop over the nodes takes over
# (no recursion at any depth, a little slower per node).
_CLOSURE_DEPTH = 64


def _compile_expr(expr: Expr) -> _Scalar:
    """A function computing ``expr`` on one state with Python floats."""
    if height(expr) > _CLOSURE_DEPTH:
        return _expression_loop(expr)
    return _expression_closure(expr)


def _expression_loop(expr: Expr) -> _Scalar:
    """``expr`` on one state by the array evaluator's loop over its nodes in post-order (any depth)."""
    names = tuple(dict.fromkeys(e.name for e in postorder(expr) if isinstance(e, nodes.Var)))

    def value(s: State) -> float:
        with np.errstate(all="ignore"):
            return float(evaluate_expression(expr, {n: np.float64(s[n]) for n in names}))

    return value


def _expression_closure(expr: Expr) -> _Scalar:
    """A closure computing ``expr`` on one state (recursion bounded by `_CLOSURE_DEPTH`)."""
    if isinstance(expr, nodes.Var):
        name = expr.name
        return lambda s: s[name]
    if isinstance(expr, nodes.Num):
        value = expr.value
        return lambda s: value
    if isinstance(expr, nodes.Neg):
        inner = _expression_closure(expr.operand)
        return lambda s: -inner(s)
    if isinstance(expr, nodes.BinOp):
        a, b = _expression_closure(expr.left), _expression_closure(expr.right)
        ops: dict[str, _Scalar] = {
            "+": lambda s: a(s) + b(s),
            "-": lambda s: a(s) - b(s),
            "*": lambda s: a(s) * b(s),
            "/": lambda s: a(s) / b(s),
            "^": lambda s: math.pow(a(s), b(s)),
        }
        return ops[expr.op]
    if isinstance(expr, nodes.Call):
        args = [_expression_closure(arg) for arg in expr.args]
        if expr.func in ("min", "max"):
            reduce_ = min if expr.func == "min" else max
            return lambda s: reduce_(f(s) for f in args)
        fn = {"abs": abs, "sqrt": math.sqrt, "exp": math.exp, "log": math.log}[expr.func]
        only = args[0]
        return lambda s: fn(only(s))
    raise TypeError(f"no evaluation rule for expression node {type(expr).__name__}")


def _compile_predicate(node: nodes.Predicate) -> _Scalar:
    lhs, rhs = _compile_expr(node.lhs), _compile_expr(node.rhs)
    op = node.op
    checked = can_be_non_finite(node.lhs) or can_be_non_finite(node.rhs)
    text = str(node)

    def value(s: State) -> float:
        try:
            v = operators.margin(op, lhs(s), rhs(s))
        except (ValueError, ZeroDivisionError, OverflowError) as exc:
            raise TraceError(f"predicate {text!r} is undefined at this state ({exc})") from None
        if checked and not math.isfinite(v):
            raise TraceError(f"predicate {text!r} is NaN or infinite at this state")
        return v

    return value


def compile_state_formula(formula: Formula, rho_max: float) -> _Scalar:
    """Robustness of a temporal-free formula on one state, as a function of that state."""
    if formula.is_temporal:
        temporal_nodes = (nodes.Next, nodes.Eventually, nodes.Always, nodes.Until, nodes.Then)
        temporal = next(n for n in formula.walk() if isinstance(n, temporal_nodes))
        raise TypeError(f"{type(temporal).__name__} is temporal; compile_state_formula takes temporal-free formulas")
    if formula.depth > _CLOSURE_DEPTH:
        window = _engine_window_formula(formula, rho_max)
        return lambda s: window([s], 0)
    if writable(formula):  # one expression, 2-3x faster (docs/results/online_monitor_speed.md)
        code = CodeWriter()
        return code.scalar_function("state_formula", "s",
                                    state_formula_source(formula, rho_max, "s", code, _compile_predicate),
                                    fallback=_state_closure(formula, rho_max))
    return _state_closure(formula, rho_max)


def _engine_window_formula(formula: Formula, rho_max: float) -> _WindowFn:
    """Robustness at ``window[i]`` by the exact evaluator on the window's states (any depth).

    The window is a trace of its own, so ``X`` past its end is −ρ_max, as in `compile_window_formula`.
    """
    names = formula.signals

    def value(window: list, i: int) -> float:
        if not names:  # a formula of constants still needs a length
            trace = {"_": np.zeros(len(window))}
        else:
            trace = {n: np.array([float(state[n]) for state in window]) for n in names}
        return float(formula.robustness_over_time(trace, rho_max)[i])

    return value


def _state_closure(formula: Formula, rho_max: float) -> _Scalar:
    """Nested closures for a temporal-free formula (recursion bounded by `_CLOSURE_DEPTH`)."""
    if isinstance(formula, nodes.Constant):
        value = float(rho_max) if formula.value else -float(rho_max)
        return lambda s: value
    if isinstance(formula, nodes.Predicate):
        return _compile_predicate(formula)
    if isinstance(formula, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        parts = [_state_closure(c, rho_max) for c in formula.children]
        combine = operators.CONNECTIVES[type(formula)]
        return lambda s: combine([p(s) for p in parts])
    raise TypeError(f"{type(formula).__name__} is temporal; compile_state_formula takes temporal-free formulas")


# --------------------------------------------------------------------------- windowed formulas


def lookahead(formula: Formula) -> int | None:
    """How many states after position k decide ``formula`` at k, if only ``X`` occurs in it.

    0 for a temporal-free formula, the nesting depth of ``X`` for a Boolean
    combination of ``X``'s over temporal-free formulas; None when ``F G U T`` occur.
    Computed bottom-up on an explicit stack (any depth).
    """
    return _lookaheads(formula)[id(formula)]


_WindowFn = Callable[[list, int], float]  # (states s_k … s_{k+d} (fewer at the trace's end), index) -> value


def compile_window_formula(formula: Formula, rho_max: float) -> _WindowFn:
    """Robustness at ``window[i]`` of a formula with bounded lookahead (see `lookahead`).

    ``X φ`` beyond the end of the window is −ρ_max, the value of ``X`` at the last state.
    """
    if formula.depth > _CLOSURE_DEPTH:
        if lookahead(formula) is None:
            raise TypeError(f"{type(formula).__name__} has no bounded lookahead")
        return _engine_window_formula(formula, rho_max)
    if writable(formula):
        code = CodeWriter()
        return code.scalar_function("window_formula", "w, i",
                                    window_formula_source(formula, rho_max, code, _compile_predicate),
                                    fallback=_window_closure(formula, rho_max))
    return _window_closure(formula, rho_max)


def _window_closure(formula: Formula, rho_max: float) -> _WindowFn:
    """Nested closures for a formula with bounded lookahead (recursion bounded by `_CLOSURE_DEPTH`)."""
    if not formula.is_temporal:
        fn = _state_closure(formula, rho_max)
        return lambda w, i: fn(w[i])
    if isinstance(formula, nodes.Next):
        inner = _window_closure(formula.child, rho_max)
        bottom = -float(rho_max)
        return lambda w, i: inner(w, i + 1) if i + 1 < len(w) else bottom
    if isinstance(formula, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        parts = [_window_closure(c, rho_max) for c in formula.children]
        combine = operators.CONNECTIVES[type(formula)]
        return lambda w, i: combine([p(w, i) for p in parts])
    raise TypeError(f"{type(formula).__name__} has no bounded lookahead")


# --------------------------------------------------------------------------- incremental nodes
#
# Every node keeps a small state from which its value is a pure function (`value`); `update`
# is the transition. `source` writes that state's floats as Python expressions over the node's
# attributes, compiled into one function (`CodeWriter`), and `load` reads them back, so that the
# state can be shown to an agent (`PrefixMonitor.state`, the wrapper's ``observe_monitor``) and the
# value recomputed from it (`PrefixMonitor.value_of_state`). Slots are typed by `Slot`.

VALUE, SIGNAL, COUNT = "value", "signal", "count"


class Slot(NamedTuple):
    """One float of a monitor's state.

    ``kind`` is ``"value"`` (a robustness value, possibly ±inf), ``"signal"`` (one signal of a
    remembered state, finite) or ``"count"`` (an integer in ``[0, bound]``); ``bound`` is the
    largest count (``"count"`` slots; 0 otherwise).
    """

    kind: str
    bound: int = 0


class _Node:
    """Robustness at position 0 of a growing prefix, for one node of the fragment."""

    slots: list[Slot]

    def reset(self) -> None:
        raise NotImplementedError

    def update(self, s: State) -> float:
        """Append one state; return the new value."""
        raise NotImplementedError

    def value(self) -> float:
        """The value of the prefix seen so far, from the state alone."""
        raise NotImplementedError

    def source(self, code: CodeWriter) -> list[str]:
        """Python expressions of the state's floats (``len(self.slots)`` of them), over the node's live attributes."""
        raise NotImplementedError

    def load(self, values: list[float], pos: int) -> int:
        """Set the state from ``values[pos:]``; return the position after it."""
        raise NotImplementedError


class _Window:
    """The last ``size`` states (oldest first), shown as ``size × len(names)`` signal slots."""

    def __init__(self, names: tuple[str, ...], size: int):
        self.names, self.size = names, size
        self.states: deque[State] = deque(maxlen=size)

    @property
    def slots(self) -> list[Slot]:
        return [Slot(SIGNAL)] * (self.size * len(self.names))

    def source(self, code: CodeWriter) -> tuple[str, list[str]]:
        """How many states are remembered, and their signals (oldest first, then 0.0 for those not seen yet)."""
        states = code.local(f"{code.bind(self)}.states")
        seen = code.local(f"len({states})")
        return seen, [f"({states}[{k}][{name!r}] if {seen} > {k} else 0.0)"
                      for k in range(self.size) for name in self.names]

    def load(self, values: list[float], pos: int, count: int) -> int:
        width = len(self.names)
        self.states = deque(
            ({n: values[pos + k * width + j] for j, n in enumerate(self.names)} for k in range(count)),
            maxlen=self.size,
        )
        return pos + self.size * width


class _AtStart(_Node):
    """A formula with lookahead d: judged on s_0 … s_d (truncated while the trace is shorter)."""

    def __init__(self, fn: _WindowFn, depth: int, names: tuple[str, ...]):
        self.fn = fn
        self.depth = depth
        self.window = _Window(names, depth + 1)
        self.slots = [Slot(VALUE)] if depth == 0 else [Slot(COUNT, depth + 1), *self.window.slots]
        self.first = 0.0

    def reset(self) -> None:
        self.window.states.clear()

    def update(self, s: State) -> float:
        if len(self.window.states) <= self.depth:
            self.window.states.append(s)
            self.first = self.fn(list(self.window.states), 0)
        return self.first

    def value(self) -> float:
        return self.first

    def source(self, code: CodeWriter) -> list[str]:
        if self.depth == 0:
            return [f"{code.bind(self)}.first"]
        seen, signals = self.window.source(code)
        return [f"float({seen})", *signals]

    def load(self, values: list[float], pos: int) -> int:
        if self.depth == 0:
            self.first = values[pos]
            self.window.states = deque([{}], maxlen=1)  # s_0 seen: the value is final
            return pos + 1
        count = int(values[pos])
        pos = self.window.load(values, pos + 1, count)
        self.first = self.fn(list(self.window.states), 0) if count else 0.0
        return pos


class _Extremum(_Node):
    """``F φ`` (running max) or ``G φ`` (running min) of a formula with lookahead d.

    Positions k ≤ t − d are final and folded into one running value; the last d
    positions are judged on their truncated windows at every update (O(d²)).
    """

    def __init__(self, fn: _WindowFn, depth: int, is_max: bool, names: tuple[str, ...]):
        self.fn = fn
        self.depth = depth
        self.is_max = is_max
        self.empty = -math.inf if is_max else math.inf
        self.window = _Window(names, depth + 1)
        self.slots = [Slot(VALUE)] + ([] if depth == 0 else [Slot(COUNT, depth + 1), *self.window.slots])
        self.reset()

    def reset(self) -> None:
        self.window.states.clear()
        self.final = self.empty
        self.count = 0

    def update(self, s: State) -> float:
        self.window.states.append(s)
        self.count += 1
        if self.count > self.depth:  # the window's first position is now final
            self.final = operators.online_extremum(self.final, self.fn(list(self.window.states), 0), self.is_max)
        return self.value()

    def value(self) -> float:
        states = list(self.window.states)
        value = self.final
        for i in range(1 if self.count > self.depth else 0, len(states)):
            value = operators.online_extremum(value, self.fn(states, i), self.is_max)
        return value

    def source(self, code: CodeWriter) -> list[str]:
        node = code.bind(self)
        if not self.depth:
            return [f"{node}.final"]
        return [f"{node}.final", f"float(min({node}.count, {self.depth + 1}))", *self.window.source(code)[1]]

    def load(self, values: list[float], pos: int) -> int:
        self.final = values[pos]
        if self.depth == 0:  # the last state is folded into `final`
            self.window.states = deque(maxlen=1)
            self.count = 1
            return pos + 1
        self.count = int(values[pos + 1])
        return self.window.load(values, pos + 2, self.count)


class _AtEnd(_Node):
    """``F G φ`` or ``G F φ``, for any φ: on a finite trace both are φ judged at the last state alone.

    (The max over t of the min over t' ≥ t of φ(t') is bounded by φ(last), reached at
    t = last; dually for ``G F``.) φ at the last state sees a one-state suffix.
    """

    def __init__(self, fn: _Scalar):
        self.fn = fn
        self.slots = [Slot(VALUE)]
        self.last = 0.0

    def reset(self) -> None:
        self.last = 0.0

    def update(self, s: State) -> float:
        self.last = self.fn(s)
        return self.last

    def value(self) -> float:
        return self.last

    def source(self, code: CodeWriter) -> list[str]:
        return [f"{code.bind(self)}.last"]

    def load(self, values: list[float], pos: int) -> int:
        self.last = values[pos]
        return pos + 1


class _NeverAgain(_Node):
    """``G(A | X G B)`` (so also ``G(¬L -> X G B)``): A with lookahead d, B temporal-free.

    At prefix length n the value is min over k of max(A_k, M_k) with M_k the min of
    B over (k, n) (−ρ_max for k = n − 1, the last state): two running values carry the
    final positions (`operators.online_never_again`), and the last ``max(d, 1)`` positions
    are judged directly.
    """

    def __init__(self, a: _WindowFn, depth: int, b: _Scalar, rho_max: float, names: tuple[str, ...]):
        self.a, self.b = a, b
        self.depth = max(depth, 1)  # X G B at the last state is −ρ_max: that position is never final
        self.bottom = -float(rho_max)
        self.window = _Window(names, self.depth + 1)
        self.slots = [Slot(VALUE), Slot(VALUE), Slot(COUNT, self.depth + 1), *self.window.slots]
        self.reset()

    def reset(self) -> None:
        self.window.states.clear()
        self.b_values: deque[float] = deque(maxlen=self.depth + 1)  # B of the window's states
        self.final = math.inf  # min over final k of max(A_k, M_k)
        self.min_a = math.inf  # min over final k of A_k
        self.count = 0

    def update(self, s: State) -> float:
        c = self.b(s)
        self.window.states.append(s)
        self.b_values.append(c)
        self.count += 1
        settled = None
        if self.count > self.depth:  # position t − depth becomes final: its A and the min of B after it
            settled = self.a(list(self.window.states), 0), min(list(self.b_values)[1:])
        self.final, self.min_a = operators.online_never_again(self.final, self.min_a, c, settled)
        return self.value()

    def value(self) -> float:
        states, bs = list(self.window.states), list(self.b_values)
        value = self.final
        last = len(states) - 1
        for i in range(1 if self.count > self.depth else 0, last + 1):
            later = min(bs[i + 1 :]) if i < last else self.bottom
            value = min(value, max(self.a(states, i), later))
        return value

    def source(self, code: CodeWriter) -> list[str]:
        node = code.bind(self)
        return [f"{node}.final", f"{node}.min_a", f"float(min({node}.count, {self.depth + 1}))",
                *self.window.source(code)[1]]

    def load(self, values: list[float], pos: int) -> int:
        self.final, self.min_a = values[pos], values[pos + 1]
        self.count = int(values[pos + 2])
        pos = self.window.load(values, pos + 3, self.count)
        self.b_values = deque((self.b(x) for x in self.window.states), maxlen=self.depth + 1)
        return pos


class _Until(_Node):
    """``φ U ψ`` = max over t' of min(ψ(t'), min of φ before t')."""

    slots = [Slot(VALUE), Slot(VALUE)]

    def __init__(self, left: _Scalar, right: _Scalar):
        self.left, self.right = left, right
        self.reset()

    def reset(self) -> None:
        self.left_so_far = math.inf
        self.best = -math.inf

    def update(self, s: State) -> float:
        self.left_so_far, self.best = operators.online_until(self.left_so_far, self.best, self.left(s), self.right(s))
        return self.best

    def value(self) -> float:
        return self.best

    def source(self, code: CodeWriter) -> list[str]:
        node = code.bind(self)
        return [f"{node}.left_so_far", f"{node}.best"]

    def load(self, values: list[float], pos: int) -> int:
        self.left_so_far, self.best = values[pos], values[pos + 1]
        return pos + 2


class _ThenChain(_Node):
    """``φ1 T (φ2 T (… T φm))`` = max over s1 < … < sm of min(φ1(s1), …, φm(sm)).

    ``best[i]`` is that max for the first i operands; a new state updates them from
    the last to the first, each from the previous one's value before this state.
    """

    def __init__(self, fns: list[_Scalar]):
        self.fns = fns
        self.slots = [Slot(VALUE)] * len(fns)
        self.reset()

    def reset(self) -> None:
        self.best = [-math.inf] * len(self.fns)

    def update(self, s: State) -> float:
        operators.online_then_chain(self.best, lambda i: self.fns[i](s))
        return self.best[-1]

    def value(self) -> float:
        return self.best[-1]

    def source(self, code: CodeWriter) -> list[str]:
        best = code.local(f"{code.bind(self)}.best")
        return [f"{best}[{i}]" for i in range(len(self.fns))]

    def load(self, values: list[float], pos: int) -> int:
        self.best = list(values[pos : pos + len(self.fns)])
        return pos + len(self.fns)


class _Combine(_Node):
    """A Boolean connective over incremental children."""

    def __init__(self, kind: type[Formula], children: list[_Node]):
        self.kind = kind
        self.children = children
        self.slots = [slot for child in children for slot in child.slots]

    def reset(self) -> None:
        for child in self.children:
            child.reset()

    def update(self, s: State) -> float:
        return self._combine([child.update(s) for child in self.children])

    def value(self) -> float:
        return self._combine([child.value() for child in self.children])

    def _combine(self, values: list[float]) -> float:
        return operators.CONNECTIVES[self.kind](values)

    def source(self, code: CodeWriter) -> list[str]:
        return [expression for child in self.children for expression in child.source(code)]

    def load(self, values: list[float], pos: int) -> int:
        for child in self.children:
            pos = child.load(values, pos)
        return pos


def then_chain(formula: Formula) -> list[Formula] | None:
    """The operands of ``φ1 T (φ2 T …)`` when all are temporal-free, else None."""
    operands: list[Formula] = []
    node = formula
    while isinstance(node, nodes.Then):
        if node.left.is_temporal:
            return None
        operands.append(node.left)
        node = node.right
    if node.is_temporal:
        return None
    return [*operands, node]


def never_again_parts(child: Formula) -> tuple[Formula, Formula] | None:
    """``(A, B)`` when ``child`` is ``A | X G B`` or ``L -> X G B`` (A = !L), B temporal-free."""

    def is_next_always(f: Formula) -> bool:
        return isinstance(f, nodes.Next) and isinstance(f.child, nodes.Always) and not f.child.child.is_temporal

    if isinstance(child, nodes.Implies) and is_next_always(child.right) and lookahead(child.left) is not None:
        return nodes.Not(child.left), child.right.child.child  # type: ignore[attr-defined]
    if isinstance(child, nodes.Or):
        tails = [c for c in child.operands if is_next_always(c)]
        rest = [c for c in child.operands if not is_next_always(c)]
        if len(tails) == 1 and rest and all(lookahead(c) is not None for c in rest):
            a = rest[0] if len(rest) == 1 else nodes.Or(tuple(rest))
            return a, tails[0].child.child  # type: ignore[attr-defined]
    return None


def _compile_incremental(formula: Formula, rho_max: float, names: tuple[str, ...],
                         verdicts: dict[int, bool] | None = None) -> _Node | None:
    """The incremental monitor of ``formula`` over the signals ``names``, or None outside the fragment.

    Boolean connectives over temporal parts are compiled bottom-up on an explicit stack (any
    depth); ``verdicts`` receives, by node identity, whether each visited node is in the fragment.
    """
    lookaheads = _lookaheads(formula)
    built: list[_Node | None] = []  # compiled operands awaiting their connective (one per occurrence)
    stack: list[tuple[Formula, bool]] = [(formula, False)]
    while stack:
        node, expanded = stack.pop()
        combination = isinstance(node, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)) and lookaheads[id(node)] is None
        if combination and not expanded:
            stack.append((node, True))
            stack.extend((child, False) for child in reversed(node.children))
            continue
        if combination:
            k = len(built) - len(node.children)
            children = built[k:]
            del built[k:]
            compiled = None if any(c is None for c in children) else _Combine(type(node), children)  # type: ignore[arg-type]
        else:
            compiled = _compile_part(node, rho_max, names, lookaheads[id(node)])
        if verdicts is not None:
            verdicts[id(node)] = compiled is not None
        built.append(compiled)
    return built[0]


def _lookaheads(formula: Formula) -> dict[int, int | None]:
    """`lookahead` of every node, by identity, in one bottom-up pass."""
    done: dict[int, int | None] = {}
    for node in reversed(formula.walk()):  # children before parents
        if id(node) in done:
            continue
        if not node.is_temporal:
            done[id(node)] = 0
        elif isinstance(node, (nodes.Next, nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
            depths = [done[id(c)] for c in node.children]
            done[id(node)] = None if any(d is None for d in depths) else (
                max(depths) + (1 if isinstance(node, nodes.Next) else 0)  # type: ignore[type-var]
            )
        else:
            done[id(node)] = None
    return done


def _compile_part(formula: Formula, rho_max: float, names: tuple[str, ...], depth: int | None) -> _Node | None:
    """The incremental monitor of a formula that is not a Boolean connective over temporal parts."""
    if depth is not None:
        return _AtStart(compile_window_formula(formula, rho_max), depth, names)
    if isinstance(formula, (nodes.Eventually, nodes.Always)):
        inner = formula.child
        if isinstance(inner, (nodes.Eventually, nodes.Always)) and type(inner) is not type(formula):
            return _AtEnd(_at_last_state(inner.child, rho_max, names))  # F G φ, G F φ
        depth = lookahead(inner)
        if depth is not None:
            window = compile_window_formula(inner, rho_max)
            return _Extremum(window, depth, isinstance(formula, nodes.Eventually), names)
        parts = never_again_parts(inner) if isinstance(formula, nodes.Always) else None
        if parts is not None:
            a, b = parts
            return _NeverAgain(
                compile_window_formula(a, rho_max), lookahead(a) or 0, compile_state_formula(b, rho_max), rho_max,
                names,
            )
        return None
    if isinstance(formula, nodes.Until):
        if formula.left.is_temporal or formula.right.is_temporal:
            return None
        return _Until(compile_state_formula(formula.left, rho_max), compile_state_formula(formula.right, rho_max))
    if isinstance(formula, nodes.Then):
        chain = then_chain(formula)
        if chain is None:
            return None
        return _ThenChain([compile_state_formula(f, rho_max) for f in chain])
    return None


def _at_last_state(formula: Formula, rho_max: float, names: tuple[str, ...]) -> _Scalar:
    """``formula`` judged on the one-state trace ``[s]``, as a closure of ``s``."""
    if lookahead(formula) is not None:
        fn = compile_window_formula(formula, rho_max)
        return lambda s: fn([s], 0)
    trace_names = names or ("_",)  # a formula of constants still needs a length
    return lambda s: float(formula.robustness({n: np.array([s.get(n, 0.0)]) for n in trace_names}, rho_max))


def is_incremental(formula: Formula) -> bool:
    """Whether `PrefixMonitor` updates ``formula`` in O(1) per state (see the module docstring)."""
    return _compile_incremental(formula, math.inf, formula.signals) is not None


def outside_fragment(formula: Formula) -> Formula | None:
    """The first sub-formula (in reading order) that keeps ``formula`` out of the incremental fragment.

    None when ``formula`` is in the fragment. Boolean connectives are looked through, so the
    culprit is the smallest temporal sub-formula that has no incremental monitor.

    Example:
        >>> from tl_gym import parse
        >>> print(outside_fragment(parse("F(x > 1) & G(x > 2 -> F x < 0)")))
        G (x > 2 -> F x < 0)
    """
    verdicts: dict[int, bool] = {}
    if _compile_incremental(formula, math.inf, formula.signals, verdicts) is not None:
        return None
    stack = [formula]  # reading order: the first culprit found depth-first, left to right
    while stack:
        node = stack.pop()
        if verdicts[id(node)]:
            continue
        connective = isinstance(node, (nodes.Not, nodes.And, nodes.Or, nodes.Implies))
        if connective and not all(verdicts[id(c)] for c in node.children):
            stack.extend(reversed(node.children))
            continue
        return node
    return formula  # not reached: a connective outside the fragment has an operand outside it


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
        self._root = _compile_incremental(formula, self.rho_max, self._names)
        self.incremental = self._root is not None
        self._pure: _Node | None = None  # a second tree, for value_of_state
        self._state = self._written_out_state()
        self._history: np.ndarray = np.empty((len(self._names), 64), dtype=np.float64)
        self._length = 0

    def _written_out_state(self) -> Callable[[], list[float]] | None:
        """`state` as one function reading this monitor's nodes (None outside the fragment)."""
        if self._root is None:
            return None
        code = CodeWriter()
        return code.function("state", "", self._root.source(code))

    def __getstate__(self) -> dict[str, Any]:
        # the written-out function reads this monitor's nodes: a copy writes its own
        return {**self.__dict__, "_state": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._state = self._written_out_state()

    @property
    def length(self) -> int:
        """Number of states seen since the last `reset`."""
        return self._length

    def reset(self) -> None:
        """Forget the trace; the next `update` is s_0."""
        self._length = 0
        if self._root is not None:
            self._root.reset()

    @property
    def slots(self) -> list[Slot]:
        """What each float of `state` is (empty outside the incremental fragment)."""
        return [] if self._root is None else list(self._root.slots)

    def state(self) -> list[float]:
        """The monitor's state after the last `update`, as ``len(slots)`` numbers (``value`` slots may be ±inf).

        ``signal`` slots hold a remembered state's signals as they were given to `update`.

        Together with the states still to come, it determines every later value of the monitor:
        `value_of_state` recomputes the current one from it.

        Raises:
            ValueError: the formula is outside the incremental fragment (its state is the whole prefix).
        """
        if self._state is None:
            raise ValueError(_outside_message(self.formula))
        return self._state()

    def state_source(self, code: CodeWriter) -> list[str]:
        """`state` as expressions written by ``code``, one per slot, for generated code that reads the live state.

        Raises:
            ValueError: the formula is outside the incremental fragment.
        """
        if self._root is None:
            raise ValueError(_outside_message(self.formula))
        return self._root.source(code)

    def value_of_state(self, state: Any) -> float:
        """The prefix robustness that a monitor in ``state`` (a `state` vector) reports: a pure function.

        Example:
            >>> from tl_gym import parse
            >>> monitor = PrefixMonitor(parse("F(x > 2) & G(x < 5)"))
            >>> [monitor.update({"x": v}) for v in (0.0, 3.0)]
            [-2.0, 1.0]
            >>> monitor.state(), monitor.value_of_state([1.0, 2.0])
            ([1.0, 2.0], 1.0)
        """
        if self._root is None:
            raise ValueError(_outside_message(self.formula))
        values = [float(v) for v in np.asarray(state, dtype=np.float64).reshape(-1)]
        if len(values) != len(self._root.slots):
            raise ValueError(f"a state of this monitor has {len(self._root.slots)} floats, got {len(values)}")
        if self._pure is None:
            self._pure = _compile_incremental(self.formula, self.rho_max, self._names)
        self._pure.load(values, 0)  # type: ignore[union-attr]
        return self._pure.value()  # type: ignore[union-attr]

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


def _outside_message(formula: Formula) -> str:
    culprit = outside_fragment(formula)
    return (
        f"{str(culprit)!r} is outside the incremental fragment of tl_gym.tltl.online, so the monitor has no "
        f"finite state (only the whole prefix determines it); the fragment: Boolean combinations of X-only "
        f"formulas, F/G of them, F G φ, G F φ, U of temporal-free operands, T chains of temporal-free "
        f"operands and G(A | X G B)"
    )
