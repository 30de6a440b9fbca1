"""The incremental monitor's nodes: one per shape of the incremental fragment, O(1) per state each.

`compile_incremental` builds the tree of nodes that `tl_gym.tltl.online.PrefixMonitor` steps
for a formula of the fragment (the fragment and its costs: `tl_gym.tltl.online`), and None
outside it; `is_incremental` and `outside_fragment` answer for a formula without a monitor.
Boolean connectives over temporal parts are `CombineNode`; the other parts are

* `AtStartNode`: a formula with bounded lookahead d, judged on s_0 … s_d;
* `ExtremumNode`: ``F φ`` / ``G φ`` of such a formula (a running max/min);
* `AtEndNode`: ``F G φ`` / ``G F φ`` for any φ: φ judged at the last state alone;
* `NeverAgainNode`: ``G(A | X G B)`` and ``G(L -> X G B)`` (`never_again_parts`);
* `UntilNode`: ``φ U ψ`` of temporal-free operands;
* `ThenChainNode`: ``φ1 T (φ2 T (… T φm))`` of temporal-free operands (`then_chain`).

The formulas they judge on one state or on a window are compiled by `tl_gym.tltl.windowed`;
their updates are the online rules of `tl_gym.tltl.operators`. `tl_gym.tltl.online_batch`
mirrors these nodes on arrays of n traces.

Every node keeps a small state from which its value is a pure function (`value`); `update`
is the transition. `source` writes that state's floats as Python expressions over the node's
attributes, compiled into one function (`CodeWriter`), and `load` reads them back, so that the
state can be shown to an agent (`tl_gym.tltl.online.PrefixMonitor.state`, the wrapper's
``observe_monitor``) and the value recomputed from it
(`tl_gym.tltl.online.PrefixMonitor.value_of_state`). Slots are typed by `Slot`.

Pure numpy and the standard library: no Gymnasium here.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

from tl_gym.tltl import ast as nodes
from tl_gym.tltl import operators
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.codegen import CodeWriter
from tl_gym.tltl.windowed import (
    State,
    StateFn,
    WindowFn,
    compile_state_formula,
    compile_window_formula,
    lookahead,
    lookaheads_by_node,
)

VALUE, SIGNAL, COUNT = "value", "signal", "count"


class Slot(NamedTuple):
    """One float of a monitor's state.

    ``kind`` is ``"value"`` (a robustness value, possibly ±inf), ``"signal"`` (one signal of a
    remembered state, finite) or ``"count"`` (an integer in ``[0, bound]``); ``bound`` is the
    largest count (``"count"`` slots; 0 otherwise).
    """

    kind: str
    bound: int = 0


class MonitorNode:
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


class StateWindow:
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


class AtStartNode(MonitorNode):
    """A formula with lookahead d: judged on s_0 … s_d (truncated while the trace is shorter)."""

    def __init__(self, fn: WindowFn, depth: int, names: tuple[str, ...]):
        self.fn = fn
        self.depth = depth
        self.window = StateWindow(names, depth + 1)
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


class ExtremumNode(MonitorNode):
    """``F φ`` (running max) or ``G φ`` (running min) of a formula with lookahead d.

    Positions k ≤ t − d are final and folded into one running value; the last d
    positions are judged on their truncated windows at every update (O(d²)).
    """

    def __init__(self, fn: WindowFn, depth: int, is_max: bool, names: tuple[str, ...]):
        self.fn = fn
        self.depth = depth
        self.is_max = is_max
        self.empty = -math.inf if is_max else math.inf
        self.window = StateWindow(names, depth + 1)
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


class AtEndNode(MonitorNode):
    """``F G φ`` or ``G F φ``, for any φ: on a finite trace both are φ judged at the last state alone.

    (The max over t of the min over t' ≥ t of φ(t') is bounded by φ(last), reached at
    t = last; dually for ``G F``.) φ at the last state sees a one-state suffix.
    """

    def __init__(self, fn: StateFn):
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


class NeverAgainNode(MonitorNode):
    """``G(A | X G B)`` (so also ``G(¬L -> X G B)``): A with lookahead d, B temporal-free.

    At prefix length n the value is min over k of max(A_k, M_k) with M_k the min of
    B over (k, n) (−ρ_max for k = n − 1, the last state): two running values carry the
    final positions (`operators.online_never_again`), and the last ``max(d, 1)`` positions
    are judged directly.
    """

    def __init__(self, a: WindowFn, depth: int, b: StateFn, rho_max: float, names: tuple[str, ...]):
        self.a, self.b = a, b
        self.depth = max(depth, 1)  # X G B at the last state is −ρ_max: that position is never final
        self.bottom = -float(rho_max)
        self.window = StateWindow(names, self.depth + 1)
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


class UntilNode(MonitorNode):
    """``φ U ψ`` = max over t' of min(ψ(t'), min of φ before t')."""

    slots = [Slot(VALUE), Slot(VALUE)]

    def __init__(self, left: StateFn, right: StateFn):
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


class ThenChainNode(MonitorNode):
    """``φ1 T (φ2 T (… T φm))`` = max over s1 < … < sm of min(φ1(s1), …, φm(sm)).

    ``best[i]`` is that max for the first i operands; a new state updates them from
    the last to the first, each from the previous one's value before this state.
    """

    def __init__(self, fns: list[StateFn]):
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


class CombineNode(MonitorNode):
    """A Boolean connective over incremental children."""

    def __init__(self, kind: type[Formula], children: list[MonitorNode]):
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


def compile_incremental(formula: Formula, rho_max: float, names: tuple[str, ...],
                         verdicts: dict[int, bool] | None = None) -> MonitorNode | None:
    """The incremental monitor of ``formula`` over the signals ``names``, or None outside the fragment.

    Boolean connectives over temporal parts are compiled bottom-up on an explicit stack (any
    depth); ``verdicts`` receives, by node identity, whether each visited node is in the fragment.
    """
    lookaheads = lookaheads_by_node(formula)
    built: list[MonitorNode | None] = []  # compiled operands awaiting their connective (one per occurrence)
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
            compiled = None if any(c is None for c in children) else CombineNode(type(node), children)  # type: ignore[arg-type]
        else:
            compiled = _compile_part(node, rho_max, names, lookaheads[id(node)])
        if verdicts is not None:
            verdicts[id(node)] = compiled is not None
        built.append(compiled)
    return built[0]


def _compile_part(formula: Formula, rho_max: float, names: tuple[str, ...], depth: int | None) -> MonitorNode | None:
    """The incremental monitor of a formula that is not a Boolean connective over temporal parts."""
    if depth is not None:
        return AtStartNode(compile_window_formula(formula, rho_max), depth, names)
    if isinstance(formula, (nodes.Eventually, nodes.Always)):
        inner = formula.child
        if isinstance(inner, (nodes.Eventually, nodes.Always)) and type(inner) is not type(formula):
            return AtEndNode(_at_last_state(inner.child, rho_max, names))  # F G φ, G F φ
        depth = lookahead(inner)
        if depth is not None:
            window = compile_window_formula(inner, rho_max)
            return ExtremumNode(window, depth, isinstance(formula, nodes.Eventually), names)
        parts = never_again_parts(inner) if isinstance(formula, nodes.Always) else None
        if parts is not None:
            a, b = parts
            return NeverAgainNode(
                compile_window_formula(a, rho_max), lookahead(a) or 0, compile_state_formula(b, rho_max), rho_max,
                names,
            )
        return None
    if isinstance(formula, nodes.Until):
        if formula.left.is_temporal or formula.right.is_temporal:
            return None
        return UntilNode(compile_state_formula(formula.left, rho_max), compile_state_formula(formula.right, rho_max))
    if isinstance(formula, nodes.Then):
        chain = then_chain(formula)
        if chain is None:
            return None
        return ThenChainNode([compile_state_formula(f, rho_max) for f in chain])
    return None


def _at_last_state(formula: Formula, rho_max: float, names: tuple[str, ...]) -> StateFn:
    """``formula`` judged on the one-state trace ``[s]``, as a closure of ``s``."""
    if lookahead(formula) is not None:
        fn = compile_window_formula(formula, rho_max)
        return lambda s: fn([s], 0)
    trace_names = names or ("_",)  # a formula of constants still needs a length
    return lambda s: float(formula.robustness({n: np.array([s.get(n, 0.0)]) for n in trace_names}, rho_max))


def is_incremental(formula: Formula) -> bool:
    """Whether `tl_gym.tltl.online.PrefixMonitor` updates ``formula`` in O(1) per state (the fragment: its module)."""
    return compile_incremental(formula, math.inf, formula.signals) is not None


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
    if compile_incremental(formula, math.inf, formula.signals, verdicts) is not None:
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
