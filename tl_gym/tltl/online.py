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
  lookahead and B temporal-free (two running values, see `tl_gym.tltl.online_nodes.NeverAgainNode`),
* ``F G φ`` and ``G F φ`` for any φ: on a finite trace both equal φ judged at the last
  state alone (a one-state suffix).

Both car tasks are in it (task 2 with either reading of its no-revisit clause).
Any other formula (``G(φ -> F ψ)``, ``U`` over a temporal operand, …)
falls back to re-evaluating the whole prefix at every update: O(t) for state
``t``, O(T²) per episode (about ``T/2`` full evaluations). The monitor says which
one it uses in ``incremental``; `is_incremental` tells it for a formula without building a
monitor, and `outside_fragment` names the sub-formula that keeps a formula out.

Inside the fragment the monitor's *state* is finite: `PrefixMonitor.state` returns it as
floats (typed by `PrefixMonitor.slots`: robustness values, remembered signals, counts) and
`PrefixMonitor.value_of_state` recomputes the prefix robustness from it alone. The state and
the states still to come determine every later value: this is what the wrapper's
``observe_monitor=True`` shows an agent (`tl_gym.monitor_view`).

The monitor is three modules, each importing only those before it: `tl_gym.tltl.windowed`
compiles the parts judged on one state or on a window of states, `tl_gym.tltl.online_nodes`
builds the incremental nodes over them (one per shape of the fragment), and this module steps
their tree, or replays the prefix outside the fragment. `Slot`, `is_incremental` and
`outside_fragment` live in `tl_gym.tltl.online_nodes` and are importable from here too, beside
`PrefixMonitor`, whose public interface they belong to.

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
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.codegen import CodeWriter
from tl_gym.tltl.online_nodes import MonitorNode, Slot, compile_incremental, is_incremental, outside_fragment
from tl_gym.tltl.trace import check_rho_max

__all__ = ["PrefixMonitor", "Slot", "is_incremental", "outside_fragment"]


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
        self._root = compile_incremental(formula, self.rho_max, self._names)
        self.incremental = self._root is not None
        self._pure: MonitorNode | None = None  # a second tree, for value_of_state
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
        """A copy or a pickle keeps the formula and where the monitor stands, not its nodes.

        The nodes hold generated functions (compiled predicates, the written-out `state`), which do
        not pickle and would read the original's nodes if shared; a copy compiles its own and loads
        the exported state, which determines every later value (or, outside the fragment, the prefix).
        """
        inside = self._root is not None
        return {"formula": self.formula, "rho_max": self.rho_max, "length": self._length,
                "state": self.state() if inside and self._length else None,
                "prefix": None if inside else self._history[:, : self._length].copy()}

    def __setstate__(self, saved: dict[str, Any]) -> None:
        self.__init__(saved["formula"], saved["rho_max"])  # type: ignore[misc]
        self._length = saved["length"]
        if saved["state"] is not None:
            self._root.load(list(saved["state"]), 0)  # type: ignore[union-attr]
        if saved["prefix"] is not None and self._length:
            self._history = np.empty((len(self._names), max(64, 2 * self._length)), dtype=np.float64)
            self._history[:, : self._length] = saved["prefix"]

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
            self._pure = compile_incremental(self.formula, self.rho_max, self._names)
        self._pure.load(values, 0)  # type: ignore[union-attr]
        return self._pure.value()  # type: ignore[union-attr]

    def update(self, state: Mapping[str, Any]) -> float:
        """Append one state (signal name -> number) and return the prefix's robustness.

        Inside the fragment the numbers are used as given, with no conversion on this hot path:
        pass Python floats (as the wrapper does). A numpy float32 computes, and returns, in float32,
        so it can differ from ``formula.robustness`` (float64) in the last bits.
        """
        missing = [n for n in self._names if n not in state]
        if missing:
            raise UnknownSignalError(f"the state has no signal {missing[0]!r}, which the formula reads")
        try:  # one try around the loop: no cost unless raised
            for name in self._names:
                if not math.isfinite(state[name]):
                    raise TraceError(f"signal {name!r} is NaN or infinite at position {self._length}")
        except TypeError:
            raise _not_a_number(self._names, state) from None
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


def _not_a_number(names: tuple[str, ...], state: Mapping[str, Any]) -> TraceError:
    """The error for a state holding something `math.isfinite` refuses (a string, None, a length-1 array)."""
    for name in names:
        value = state[name]
        try:
            math.isfinite(value)
        except TypeError:
            shape = f" of shape {np.shape(value)}" if np.ndim(value) else ""
            return TraceError(f"signal {name!r} must be one number, got {type(value).__name__}{shape}: {value!r}")
    return TraceError("the state holds a value that is not a number")  # unreachable: some name raised


def _outside_message(formula: Formula) -> str:
    culprit = outside_fragment(formula)
    return (
        f"{str(culprit)!r} is outside the incremental fragment of tl_gym.tltl.online, so the monitor has no "
        f"finite state (only the whole prefix determines it); the fragment: Boolean combinations of X-only "
        f"formulas, F/G of them, F G φ, G F φ, U of temporal-free operands, T chains of temporal-free "
        f"operands and G(A | X G B)"
    )
