"""`BatchPrefixMonitor`: n copies of `PrefixMonitor` stepped together, one numpy call per operation.

A vector env (the batched car, `tl_gym.envs.vector.CarNavVectorEnv`) grows n traces in
lockstep: every update appends one state to each of them. Running one Python monitor per
trace costs the monitor's whole update n times; this class runs every operation once, on
arrays with a leading batch axis, and reports what n `PrefixMonitor`'s would: the same
values and the same state, laid out as `PrefixMonitor.state` (one row per trace, columns
typed by `PrefixMonitor.slots`), so `tl_gym.monitor_view.MonitorView` encodes it as it
encodes one monitor's.

Nothing is written twice. The fragment, and which node monitors which sub-formula, come
from `PrefixMonitor` itself: the batch mirrors its tree of nodes. Each node's update is the
online rule of `tl_gym.tltl.operators` called with ``np.maximum``/``np.minimum`` instead of
the scalar max/min; Boolean connectives are the exact rules of the same module at one
position. The temporal-free and ``X``-only parts the nodes read are evaluated together, each
distinct sub-formula once, on a window of the last states (as many as the deepest ``X``
needs): where a scalar node evaluates a part on its own window of states, the batch reads the
same position of that shared evaluation.

Cost: a fixed number of numpy calls per update, whatever n. Leaves of one kind (the car's
three "never again" clauses, its two Untils) are updated together, on ``(k, n)`` arrays, and
their state is stored group by group; `rows` and `state` put it back in the order of `slots`.

Pure numpy: no Gymnasium here.

Example:
    >>> import numpy as np
    >>> from tl_gym import parse
    >>> monitor = BatchPrefixMonitor(parse("F(x > 2) & G(x < 5)"), 3)
    >>> for xs in ([0.0, 3.0, 6.0], [3.0, 4.5, 1.0]):
    ...     values = monitor.update({"x": np.array(xs)})
    >>> values.tolist()  # what three PrefixMonitor's report after their two states
    [1.0, 0.5, -1.0]
    >>> monitor.state().tolist()  # per trace: the running max of x - 2 and min of 5 - x
    [[1.0, 2.0], [2.5, 0.5], [4.0, -1.0]]
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from tl_gym.checks import check_count
from tl_gym.errors import TraceError, UnknownSignalError
from tl_gym.tltl import online_nodes, operators
from tl_gym.tltl.ast import And, Constant, Formula, Next, Num, Or, Predicate, Var
from tl_gym.tltl.expressions import can_be_non_finite, evaluate_expression
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.online_nodes import Slot
from tl_gym.tltl.windowed import lookahead

# The online rules of `operators` on arrays: the same code as on floats, with numpy's max and min.
ARRAY = (np.maximum, np.minimum)


class _Parts:
    """The temporal-free and ``X``-only formulas the nodes read, on the window of the last states.

    Every distinct sub-formula is one step (operands first), evaluated on ``(n, L)`` arrays:
    column ``j`` is the formula at the ``j``-th state of the window, ``X`` past the window's
    end (the trace's last state) being −ρ_max, as in the monitor's own windows.
    """

    def __init__(self, alg: operators.Lattice):
        self.alg = alg
        self.index: dict[Formula, int] = {}
        self.steps: list[Callable[[_Window, list], np.ndarray]] = []
        self.inputs_of: list[tuple[int, ...]] = []  # the steps each step reads
        self.reads: dict[Formula, _Reads] = {}  # the states at which each predicate is read
        self.values: list[Any] = []

    def add(self, formula: Formula, judged: str = "every") -> int:
        """Register ``formula`` (bounded lookahead) and its sub-formulas; return its step.

        ``judged``: the positions its node judges it at, "every" one, s_0 alone ("start") or the last ("end").
        """
        stack: list[tuple[Formula, bool]] = [(formula, False)]
        while stack:  # post-order on an explicit stack: any depth
            node, expanded = stack.pop()
            if node in self.index:
                continue
            if not expanded:
                stack.append((node, True))
                stack.extend((child, False) for child in reversed(node.children) if child not in self.index)
                continue
            self.index[node] = len(self.steps)
            inputs = self._inputs(node)
            self.inputs_of.append(inputs)
            self.steps.append(self._compile(node, inputs))
        self.values = [None] * len(self.steps)
        depths: list[tuple[Formula, int]] = [(formula, 0)]
        while depths:  # each predicate under how many X's
            node, depth = depths.pop()
            if isinstance(node, Predicate):
                self.reads[node].add(depth, judged)
            depths.extend((child, depth + isinstance(node, Next)) for child in node.children)
        return self.index[formula]

    def _inputs(self, node: Formula) -> tuple[int, ...]:
        """The steps ``node`` is computed from: its operands', or a registered node's and the rest.

        For ``&`` / ``|``, a registered node of the same kind over a subset of the operands stands for
        them (min and max do not mind the grouping): ``g & X !g``, g a conjunction of four
        predicates (car task 2), costs one min more than g instead of four.
        """
        inputs = tuple(self.index[child] for child in node.children)
        if not isinstance(node, (And, Or)):
            return inputs
        operands = set(node.children)
        known = [other for other in self.index if type(other) is type(node) and other is not node
                 and set(other.children) < operands]
        if not known:
            return inputs
        largest = max(known, key=lambda other: len(other.children))
        rest = [self.index[child] for child in dict.fromkeys(node.children) if child not in set(largest.children)]
        return (self.index[largest], *rest)

    def _compile(self, node: Formula, inputs: tuple[int, ...]) -> Callable[[_Window, list], np.ndarray]:
        """The step computing ``node`` from the window and the values of its operands' steps."""
        alg = self.alg
        if isinstance(node, Predicate):
            return _predicate(node, self.reads.setdefault(node, _Reads()))
        if isinstance(node, Constant):
            value = alg.top if node.value else alg.bottom
            return lambda window, values: np.full(window.shape, value)
        rule = operators.EXACT[type(node)]
        if len(inputs) == 1:
            (i,) = inputs
            return lambda window, values: rule(alg, values[i])
        if len(inputs) == 2:
            i, j = inputs
            return lambda window, values: rule(alg, values[i], values[j])
        return lambda window, values: rule(alg, *(values[k] for k in inputs))

    def closure(self, steps: Iterable[int]) -> list[int]:
        """``steps`` and every step they read, in the order they run (operands first)."""
        needed, stack = set(), list(steps)
        while stack:
            i = stack.pop()
            if i not in needed:
                needed.add(i)
                stack.extend(self.inputs_of[i])
        return sorted(needed)

    def run(self, window: _Window, only: list[int] | None = None) -> None:
        """Evaluate every step on the window, or the steps ``only`` lists (a `closure`)."""
        values, steps = self.values, self.steps
        with np.errstate(all="ignore"):
            for i in range(len(steps)) if only is None else only:
                values[i] = steps[i](window, values)


class _Window:
    """The signals of the window's states, ``name -> (n, L)``, with what errors name."""

    def __init__(self, signals: dict[str, np.ndarray], shape: tuple[int, int], position: int):
        self.signals, self.shape, self.position = signals, shape, position


class _Reads:
    """The states at which the formula reads a predicate: from ``since`` on, and at the positions ``at``.

    A part judged at every position reads a predicate under k ``X``'s at every state from k on; one judged on
    s_0 alone (`_AtStart`) reads it at state k alone; one judged at the last state (`_AtEnd`) only where k = 0.
    Undefined arithmetic raises only at a state read, as in `PrefixMonitor`, whose nodes evaluate no other.
    """

    def __init__(self) -> None:
        self.since: float = math.inf
        self.at: set[int] = set()

    def __call__(self, t: int) -> bool:
        return t >= self.since or t in self.at

    def add(self, depth: int, judged: str) -> None:
        """A part judged at ``judged`` ("every", "start" or "end") reads the predicate under ``depth`` X's."""
        if judged == "every" or (judged == "end" and depth == 0):
            self.since = min(self.since, depth)
        elif judged == "start":
            self.at.add(depth)


def _predicate(node: Predicate, reads: _Reads) -> Callable[[_Window, list], np.ndarray]:
    """A predicate's margin on the window; a NaN or infinite one at the new state, if it ``reads``, raises."""
    op, lhs, rhs = node.op, node.lhs, node.rhs
    if isinstance(lhs, Var) and isinstance(rhs, Num):  # the common ``x > 5``: one subtraction
        name, number = lhs.name, np.float64(rhs.value)
        return lambda window, values: operators.margin(op, window.signals[name], number)
    if isinstance(lhs, Num) and isinstance(rhs, Var):
        name, number = rhs.name, np.float64(lhs.value)
        return lambda window, values: operators.margin(op, number, window.signals[name])
    checked = can_be_non_finite(lhs) or can_be_non_finite(rhs)

    def margin(window: _Window, values: list) -> np.ndarray:
        out = operators.margin(op, evaluate_expression(lhs, window.signals), evaluate_expression(rhs, window.signals))
        if np.shape(out) != window.shape:  # a predicate of numbers alone
            out = np.broadcast_to(out, window.shape)
        if (checked and not math.isfinite(out[:, -1].sum()) and not np.isfinite(out[:, -1]).all()
                and reads(window.position)):
            trace = int(np.argwhere(~np.isfinite(out[:, -1]))[0, 0])
            raise TraceError(f"predicate {str(node)!r} is NaN or infinite at trace {trace}, position {window.position}")
        return out

    return margin


class _Step:
    """What one update hands every group: the clock, the window and the parts' values."""

    def __init__(self, parts: _Parts, window: np.ndarray, names: tuple[str, ...]):
        self.t = -1  # position of the new state (0 right after a reset)
        self.width = 0  # states in the window: min(t + 1, L)
        self.values = parts.values  # each part's (n, width) values on the window, by step index
        self.window = window  # the last L states, (L, len(names), n), oldest first (the first `width` are set)
        self.new = window[0]  # the new state, (len(names), n)
        self.row = {name: i for i, name in enumerate(names)}  # a signal's row in `new` (the formula's order)


class _Group:
    """The k leaves of `PrefixMonitor`'s tree that are nodes of one kind with the same parameters.

    They are updated together, on ``(k, n)`` arrays. ``block`` is their state, ``(size, k, n)``:
    row r of leaf j at ``block[r, j]``, r as in `PrefixMonitor.state`. ``parts[j]`` lists the
    parts leaf j reads.
    """

    size: int  # state rows per leaf

    def __init__(self, parts: list[tuple[int, ...]]):
        self.parts = parts

    def bind(self, block: np.ndarray) -> None:
        self.block = block

    def window(self, start: int, depth: int, names: int) -> np.ndarray:
        """Rows ``start …`` as the leaves' windows of ``depth + 1`` states: ``(depth + 1, names, k, n)``."""
        return self.block[start:].reshape(depth + 1, names, *self.block.shape[1:])

    def inputs(self, step: _Step, which: int) -> np.ndarray:
        """Part ``which`` of every leaf on the window: ``(k, n, width)``."""
        if len(self.parts) == 1:
            return step.values[self.parts[0][which]][None]
        return np.array([step.values[parts[which]] for parts in self.parts])  # np.stack costs 3x more

    def reset(self) -> None:
        raise NotImplementedError

    def update(self, step: _Step) -> np.ndarray:
        """Append one state to every trace; return the leaves' ``(k, n)`` new values."""
        raise NotImplementedError


def _last_states(window: np.ndarray, step: _Step) -> None:
    """Fill windows of the last states (``(size, names, k, n)``, oldest first, zeros after them)."""
    count = min(step.t + 1, window.shape[0])
    window[:count] = step.window[step.width - count : step.width, :, None, :]


def _column_min(values: np.ndarray, start: int, stop: int) -> np.ndarray:
    """The min of columns ``start`` … ``stop - 1`` (at least one) of ``(…, L)`` values."""
    return values[..., start] if stop - start == 1 else np.minimum.reduce(values[..., start:stop], axis=-1)


class _AtStart(_Group):
    """Formulas with lookahead d, judged on s_0 … s_d (`online_nodes.AtStartNode`)."""

    def __init__(self, parts: list[tuple[int, ...]], depth: int, names: int):
        super().__init__(parts)
        self.depth, self.names = depth, names
        self.size = 1 if depth == 0 else 1 + (depth + 1) * names
        self.value: np.ndarray | None = None

    def reset(self) -> None:
        self.block[:] = 0.0

    def update(self, step: _Step) -> np.ndarray:
        if step.t <= self.depth:  # the window still holds s_0
            self.value = self.inputs(step, 0)[..., 0]
            if self.depth == 0:
                self.block[0] = self.value
            else:
                self.block[0] = step.t + 1
                self.window(1, self.depth, self.names)[step.t] = step.new[:, None, :]
        return self.value  # type: ignore[return-value]


class _Extremum(_Group):
    """``F φ`` / ``G φ``, φ with lookahead d: the positions ≤ t − d folded, the last d judged.

    The batched `online_nodes.ExtremumNode`.
    """

    def __init__(self, parts: list[tuple[int, ...]], depth: int, is_max: bool, names: int):
        super().__init__(parts)
        self.depth, self.is_max, self.names = depth, is_max, names
        self.size = 1 if depth == 0 else 2 + (depth + 1) * names

    def reset(self) -> None:
        self.block[:] = 0.0
        self.block[0] = -math.inf if self.is_max else math.inf

    def update(self, step: _Step) -> np.ndarray:
        phi, depth, width, final = self.inputs(step, 0), self.depth, step.width, self.block[0]
        if step.t >= depth:  # position t − d is final
            final[:] = operators.online_extremum(final, phi[..., width - 1 - depth], self.is_max, *ARRAY)
        value = final
        for j in range(max(0, width - depth), width):
            value = operators.online_extremum(value, phi[..., j], self.is_max, *ARRAY)
        if depth:
            if step.t <= depth:
                self.block[1] = step.t + 1  # the count, min(t + 1, d + 1)
            _last_states(self.window(2, depth, self.names), step)
        return value


class _AtEnd(_Group):
    """``F G φ`` / ``G F φ``: φ judged at the last state alone (`online_nodes.AtEndNode`).

    ``formulas`` are the φ's without bounded lookahead, judged by the exact engine on the
    one-state trace; the others are parts.
    """

    size = 1

    def __init__(self, parts: list[tuple[int, ...]], formulas: list[Formula] | None, rho_max: float):
        super().__init__(parts)
        self.formulas, self.rho_max = formulas, rho_max

    def reset(self) -> None:
        self.block[:] = 0.0

    def update(self, step: _Step) -> np.ndarray:
        if self.formulas is None:  # parts: their value at the window's last state
            self.block[0] = self.inputs(step, 0)[..., step.width - 1]
            return self.block[0]
        for j, phi in enumerate(self.formulas):
            names = phi.signals
            # rows follow the whole formula's signals, of which φ's are a subset in any order
            trace = {n: step.new[step.row[n]][:, None] for n in names} if names else {
                "_": np.zeros((step.new.shape[1], 1))}
            self.block[0, j] = phi.robustness(trace, self.rho_max)
        return self.block[0]


class _NeverAgain(_Group):
    """``G(A | X G B)``: two running values and the last d positions judged (`online_nodes.NeverAgainNode`)."""

    def __init__(self, parts: list[tuple[int, ...]], depth: int, bottom: float, names: int):
        super().__init__(parts)
        self.depth, self.bottom, self.names = depth, bottom, names
        self.size = 3 + (depth + 1) * names

    def reset(self) -> None:
        self.block[:] = 0.0
        self.block[0:2] = math.inf

    def update(self, step: _Step) -> np.ndarray:
        a, b, depth, width = self.inputs(step, 0), self.inputs(step, 1), self.depth, step.width
        settled = None
        if step.t >= depth:  # position k = t − d is final: its A and the min of B after it
            k = width - 1 - depth
            settled = a[..., k], _column_min(b, k + 1, width)
        self.block[0], self.block[1] = operators.online_never_again(
            self.block[0], self.block[1], b[..., width - 1], settled, *ARRAY)
        value = self.block[0]
        for j in range(max(0, width - depth), width):  # the positions not final yet
            later = _column_min(b, j + 1, width) if j < width - 1 else self.bottom
            value = np.minimum(value, np.maximum(a[..., j], later))
        if step.t <= depth:
            self.block[2] = step.t + 1  # the count, min(t + 1, d + 1)
        _last_states(self.window(3, depth, self.names), step)
        return value


class _Until(_Group):
    """``φ U ψ``, temporal-free operands (`online_nodes.UntilNode`)."""

    size = 2

    def reset(self) -> None:
        self.block[0], self.block[1] = math.inf, -math.inf

    def update(self, step: _Step) -> np.ndarray:
        self.block[0], self.block[1] = operators.online_until(
            self.block[0], self.block[1], self.inputs(step, 0)[..., -1], self.inputs(step, 1)[..., -1], *ARRAY)
        return self.block[1]


class _ThenChain(_Group):
    """``φ1 T (φ2 T (… T φm))``, temporal-free operands (`online_nodes.ThenChainNode`)."""

    def __init__(self, parts: list[tuple[int, ...]], length: int):
        super().__init__(parts)
        self.size = length

    def reset(self) -> None:
        self.block[:] = -math.inf

    def update(self, step: _Step) -> np.ndarray:
        best = list(self.block)
        operators.online_then_chain(best, lambda i: self.inputs(step, i)[..., -1], *ARRAY)
        self.block[:] = best
        return self.block[-1]


class BatchPrefixMonitor:
    """``n`` `PrefixMonitor`'s of one formula, for ``n`` traces that grow in lockstep.

    Args:
        formula: the formula to monitor; it must be in the incremental fragment.
        n: how many traces.
        rho_max: the value of ``true`` (and minus that of ``X φ`` at the last state).

    Raises:
        ValueError: the formula is outside the incremental fragment (the message names the
            sub-formula), or ``n`` < 1.
    """

    def __init__(self, formula: Formula, n: int, rho_max: float = math.inf):
        scalar = PrefixMonitor(formula, rho_max)
        if not scalar.incremental:
            scalar.state()  # raises the ValueError that names the sub-formula
        check_count("n", n)
        self.formula = formula
        self.n = int(n)
        self.rho_max = scalar.rho_max
        self.names = formula.signals
        self.slots: list[Slot] = scalar.slots
        self._parts = _Parts(operators.numeric(self.rho_max))
        self._lookahead = 0  # the deepest X among the parts: the window keeps that many states more
        self._build(formula, scalar._root)  # type: ignore[arg-type]
        self._window = np.zeros((self._lookahead + 1, len(self.names), self.n))  # the last states, oldest first
        self._new = np.zeros((len(self.names), self.n))
        self._windows = [  # the signals of its first `width` states, (n, width) views, for each width
            _Window({name: self._window[:width, i].T for i, name in enumerate(self.names)}, (self.n, width), 0)
            for width in range(1, self._lookahead + 2)
        ]
        self._step = _Step(self._parts, self._window, self.names)
        self._t = -1

    # building ------------------------------------------------------------------------------
    def _build(self, formula: Formula, root: online_nodes.MonitorNode) -> None:
        """Mirror the scalar tree: leaves grouped by kind, connectives as a flat program over their values.

        The leaves are visited depth-first, left to right (the order of `PrefixMonitor.state`);
        value ids: the leaves' first, then one per connective, the root's last.
        """
        leaves: list[tuple[tuple, tuple[int, ...], Formula | None, int]] = []  # (group key, parts, φ, slots)
        combine: list[tuple[Callable[..., np.ndarray], list[int]]] = []  # (rule, operand value ids)
        built: list[tuple[bool, int]] = []  # (is a leaf, index) of each finished sub-tree
        stack: list[tuple[Formula, online_nodes.MonitorNode, bool]] = [(formula, root, False)]
        while stack:  # post-order on an explicit stack: any depth
            f, node, expanded = stack.pop()
            if not isinstance(node, online_nodes.CombineNode):
                leaves.append(self._leaf(f, node))
                built.append((True, len(leaves) - 1))
            elif not expanded:
                stack.append((f, node, True))
                stack.extend((c, s, False) for c, s in reversed(list(zip(f.children, node.children))))
            else:
                k = len(built) - len(node.children)
                operands = built[k:]
                del built[k:]
                combine.append((operators.EXACT[type(f)], operands))  # type: ignore[arg-type]
                built.append((False, len(combine) - 1))
        # value ids: leaf i is i, connective c is len(leaves) + c
        self._program = [(rule, [i if leaf else len(leaves) + i for leaf, i in operands])
                         for rule, operands in combine]
        keys = list(dict.fromkeys(key for key, *_ in leaves))
        self._groups: list[_Group] = []
        self._members: list[list[int]] = []  # the leaves of each group
        for key in keys:
            members = [i for i, leaf in enumerate(leaves) if leaf[0] == key]
            self._groups.append(_make_group(key, [leaves[i][1] for i in members], [leaves[i][2] for i in members],
                                            self.rho_max))
            self._members.append(members)
        # storage: group after group, each (size, k, n); `_order[r]` is the storage row of state slot r
        self._store = np.zeros((len(self.slots), self.n))
        leaf_start = np.cumsum([0] + [slots for *_, slots in leaves])
        self._order = np.empty(len(self.slots), dtype=np.intp)
        start = 0
        for group, members in zip(self._groups, self._members):
            k = len(members)
            group.bind(self._store[start : start + group.size * k].reshape(group.size, k, self.n))
            for j, leaf in enumerate(members):
                self._order[leaf_start[leaf] : leaf_start[leaf] + group.size] = start + np.arange(group.size) * k + j
            start += group.size * k
        self._leaf_values: list[Any] = [None] * (len(leaves) + len(combine))
        # A formula judged on s_0 … s_d reads its parts until t = d only: later states are not evaluated for it, as
        # its scalar node does not (``log(x) > 0`` must not raise at a state x <= 0 it never reads).
        starts = [group for group in self._groups if isinstance(group, _AtStart)]
        self._start_depth = max((group.depth for group in starts), default=-1)
        self._late_parts = self._parts.closure(
            i for group in self._groups if not isinstance(group, _AtStart) for parts in group.parts for i in parts)

    def _part(self, formula: Formula, judged: str = "every") -> int:
        self._lookahead = max(self._lookahead, lookahead(formula) or 0)
        return self._parts.add(formula, judged)

    def _leaf(
        self, formula: Formula, node: online_nodes.MonitorNode
    ) -> tuple[tuple, tuple[int, ...], Formula | None, int]:
        """``(group key, parts, φ judged by the engine or None, number of slots)`` of a leaf of the scalar tree."""
        width, slots = len(self.names), len(node.slots)
        if isinstance(node, online_nodes.AtStartNode):
            return (_AtStart, node.depth, width), (self._part(formula, "start"),), None, slots
        if isinstance(node, online_nodes.ExtremumNode):
            return (_Extremum, node.depth, node.is_max, width), (self._part(formula.child),), None, slots  # type: ignore[attr-defined]
        if isinstance(node, online_nodes.AtEndNode):
            phi = formula.child.child  # type: ignore[attr-defined]
            if lookahead(phi) is not None:
                return (_AtEnd, True), (self._part(phi, "end"),), None, slots
            return (_AtEnd, False), (), phi, slots
        if isinstance(node, online_nodes.NeverAgainNode):
            a, b = online_nodes.never_again_parts(formula.child)  # type: ignore[attr-defined, misc]
            self._lookahead = max(self._lookahead, node.depth)
            return (_NeverAgain, node.depth, node.bottom, width), (self._part(a), self._part(b)), None, slots
        if isinstance(node, online_nodes.UntilNode):
            return (_Until,), (self._part(formula.left), self._part(formula.right)), None, slots  # type: ignore[attr-defined]
        if isinstance(node, online_nodes.ThenChainNode):
            chain = [self._part(f) for f in online_nodes.then_chain(formula)]  # type: ignore[union-attr]
            return (_ThenChain, len(chain)), tuple(chain), None, slots
        raise TypeError(f"no batched twin of {type(node).__name__}")  # not reached: every node kind is above

    # running -------------------------------------------------------------------------------
    @property
    def length(self) -> int:
        """Number of states of each trace since the last `reset`."""
        return self._t + 1

    def reset(self) -> None:
        """Forget the traces; the next `update` brings s_0."""
        self._t = -1

    def update(self, signals: Mapping[str, Any]) -> np.ndarray:
        """Append one state to every trace (signal name -> ``(n,)`` values); return the ``(n,)`` prefix robustness.

        Raises:
            UnknownSignalError: a signal the formula reads is missing.
            TraceError: a signal is NaN or infinite, or a predicate's arithmetic is undefined.
        """
        missing = [name for name in self.names if name not in signals]
        if missing:
            raise UnknownSignalError(f"the state has no signal {missing[0]!r}, which the formula reads")
        t = self._t + 1
        new = self._new
        for i, name in enumerate(self.names):
            new[i] = _numbers(name, signals[name], self.n)
        if not math.isfinite(new.sum()) and not np.isfinite(new).all():  # one sum clears almost every call
            i, trace = np.argwhere(~np.isfinite(new))[0]
            raise TraceError(f"signal {self.names[i]!r} is NaN or infinite at trace {trace}, position {t}")
        if t == 0:
            for group in self._groups:
                group.reset()
        _push(self._window, t, new)
        width = min(t + 1, len(self._windows))
        window = self._windows[width - 1]
        window.position = t
        self._parts.run(window, None if t <= self._start_depth else self._late_parts)
        step = self._step
        self._t = step.t = t
        step.width, step.new = width, self._window[width - 1]
        values = self._leaf_values
        for group, members in zip(self._groups, self._members):
            out = group.update(step)
            for j, leaf in enumerate(members):
                values[leaf] = out[j]
        position = len(values) - len(self._program)
        for rule, operands in self._program:
            values[position] = rule(self._parts.alg, *(values[i] for i in operands))
            position += 1
        return values[-1] if self._program else values[-1].copy()  # a lone leaf's value is a view of its state

    @property
    def rows(self) -> np.ndarray:
        """The state after the last `update`, slot-major: ``(len(slots), n)``, in the order of `slots`."""
        return self._store[self._order]

    def state(self) -> np.ndarray:
        """The state after the last `update`: ``(n, len(slots))``, row i as `PrefixMonitor.state` of trace i."""
        return self.rows.T.copy()

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        """Pickled and copied as its formula and state: the groups hold closures and views of the state."""
        values = [group.value if isinstance(group, _AtStart) else None for group in self._groups]
        return _restore, (self.formula, self.n, self.rho_max, self._store.copy(), self._window.copy(), self._t, values)


def _numbers(name: str, value: Any, n: int) -> Any:
    """``value`` if it is ``n`` real numbers (or one, for every trace); else a TraceError naming the signal.

    A numeric array passes with one type test (the batched car's every step); anything else is looked at,
    so that a string, None or an array of another length is refused as `PrefixMonitor` refuses them rather
    than converted by numpy ("7" as 7.0, None as NaN) or failing in its words.
    """
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf" and value.shape == (n,):
        return value
    array = np.asarray(value) if not isinstance(value, (str, bytes)) else None
    if array is None or array.dtype.kind not in "biuf":
        raise TraceError(f"signal {name!r} must be numbers, got {type(value).__name__}: {value!r}")
    if array.shape not in ((), (1,), (n,)):  # one value stands for every trace, as numpy broadcasts it
        raise TraceError(f"signal {name!r} must hold {n} values (one per trace) or one, got shape {array.shape}")
    return array


def _push(block: np.ndarray, t: int, new: np.ndarray) -> None:
    """Append state ``t`` to a window of the last ``size`` states (``(size, …)``, oldest first)."""
    size = block.shape[0]
    if t < size:
        block[t] = new
    else:
        block[:-1] = block[1:]
        block[-1] = new


def _make_group(key: tuple, parts: list[tuple[int, ...]], formulas: list[Formula | None], rho_max: float) -> _Group:
    kind, *params = key
    if kind is _AtEnd:
        return _AtEnd(parts, None if params[0] else formulas, rho_max)  # type: ignore[arg-type]
    return kind(parts, *params)  # type: ignore[no-any-return]


def _restore(formula: Formula, n: int, rho_max: float, store: np.ndarray, window: np.ndarray, t: int,
             values: list[np.ndarray | None]) -> BatchPrefixMonitor:
    monitor = BatchPrefixMonitor(formula, n, rho_max)
    monitor._store[:], monitor._window[:], monitor._t = store, window, t
    for group, value in zip(monitor._groups, values):
        if isinstance(group, _AtStart):
            group.value = value
    return monitor
