"""Exact robustness and Boolean semantics of TLTL, vectorised over trajectories and time.

A formula is compiled once into a plan (`tl_gym.tltl.plan`) whose steps run the rules of
`tl_gym.tltl.operators` on ``(N, T)`` arrays, group by group of trajectories. Robustness
runs them in the reals (max, min, negation, ±ρ_max), `satisfied` in the Booleans.

Rewrites of the plan, each giving the plain plan's values (`tests/test_exact_fast_paths.py`):

* **position 0**: the root, and the operands of Boolean connectives above temporal operators,
  are computed at position 0 only: a top-level F, G, U or T becomes one reduction over time
  instead of a scan (`_AT_ZERO`);
* **linear predicates**: a signal against a number (``x < 5``) is one subtraction (`_linear_predicate`);
* **monotone predicates**: F / G at position 0 of ``f(e) ⋈ c`` with f in sqrt, exp, log takes
  the extreme of e over time and applies f to it alone (`_monotone_extreme`).

Every operator costs O(N·T), except ``U``/``T`` whose left operand is temporal: that operand
must be judged on every truncated segment, O(N·T²) time (and O(N·T) memory). A prefix of a prefix
is a prefix, so such operands share their values per prefix (`_Group.on_prefix`): a chain of n
``U`` nested through their left operands runs n·T sub-plans, not T^n.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tl_gym.errors import TraceError
from tl_gym.tltl import operators as ops
from tl_gym.tltl.ast import Always, Call, Constant, Eventually, Formula, Next, Num, Predicate, Then, Until, Var
from tl_gym.tltl.expressions import evaluate_expression, margin_bound
from tl_gym.tltl.plan import Plan, Step, cached, chosen, compile_plan, prune
from tl_gym.tltl.trace import Trace, check_rho_max, chunks, prepare


@dataclass
class _Group:
    """One group of trajectories being evaluated: its ``(n, length)`` signals and the lattice."""

    alg: ops.Lattice
    signals: dict[str, np.ndarray]
    n: int
    length: int
    magnitudes: dict[str, float]
    first_row: int  # index of the group's first trajectory in the caller's batch
    on_prefix: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # shared with every prefix

    def full(self, value: Any, length: int | None = None) -> np.ndarray:
        return np.full((self.n, self.length if length is None else length), value, dtype=self.alg.dtype)

    def on(self, plan: Plan, length: int) -> np.ndarray:
        """``plan`` on the truncated s_0 … s_{length-1}, run once per plan and length (module docstring)."""
        if (id(plan), length) not in self.on_prefix:
            prefix = _Group(self.alg, {k: v[:, :length] for k, v in self.signals.items()}, self.n, length,
                            self.magnitudes, self.first_row, self.on_prefix)
            self.on_prefix[id(plan), length] = run(plan, prefix)
        return self.on_prefix[id(plan), length]


def run(plan: Plan, group: _Group) -> np.ndarray:
    """The root's values: every step in order, each from its inputs' values (callers must not modify them)."""
    values: list[Any] = [None] * len(plan.steps)
    for i, step in enumerate(plan.steps):
        values[i] = step.run(group, step, [values[j] for j in step.inputs])  # type: ignore[misc]
    return values[-1]


# --------------------------------------------------------------------------- leaves and plain rules


def _constant(group: _Group, step: Step, _: list) -> np.ndarray:
    return group.full(group.alg.top if step.node.value else group.alg.bottom, 1 if step.first else None)


def _predicate(group: _Group, step: Step, _: list) -> np.ndarray:
    node: Predicate = step.node  # type: ignore[assignment]
    signals = {k: v[:, :1] for k, v in group.signals.items()} if step.first else group.signals
    shape = (group.n, 1 if step.first else group.length)
    with np.errstate(all="ignore"):
        margin = ops.margin(node.op, evaluate_expression(node.lhs, signals), evaluate_expression(node.rhs, signals))
    margin = np.broadcast_to(margin, shape)
    # Undefined arithmetic (log of a negative, overflow...) is refused. Unless the signals' magnitudes
    # prove the margin finite, one cheap sum clears almost every call; only then look closer.
    if margin_bound(node.lhs, node.rhs, tuple(group.magnitudes.items())) >= 1e307:
        with np.errstate(all="ignore"):
            suspicious = not np.isfinite(np.sum(margin))
        if suspicious and not np.isfinite(margin).all():
            i, t = np.argwhere(~np.isfinite(margin))[0]
            raise TraceError(
                f"predicate {str(node)!r} is NaN or infinite at trajectory {group.first_row + i}, position {t} "
                "(its arithmetic is undefined there)"
            )
    return np.asarray(ops.holds(node.op, margin) if group.alg.boolean else margin, dtype=group.alg.dtype)


def _linear_predicate(group: _Group, step: Step, _: list) -> np.ndarray:
    """Rewrite: a predicate between a signal and a number or another signal (``x < 5``): one subtraction."""
    node: Predicate = step.node  # type: ignore[assignment]
    signals = group.signals
    lhs, rhs = ((signals[e.name][:, :1] if step.first else signals[e.name]) if isinstance(e, Var) else e.value
                for e in (node.lhs, node.rhs))
    if margin_bound(node.lhs, node.rhs, tuple(group.magnitudes.items())) >= 1e307:  # may overflow: the general rule
        return _predicate(group, step, [])
    margin = ops.margin(node.op, lhs, rhs)
    return ops.holds(node.op, margin) if group.alg.boolean else margin


def _operator(group: _Group, step: Step, values: list) -> np.ndarray:
    return ops.EXACT[type(step.node)](group.alg, *values)


def _on_segments(group: _Group, step: Step, values: list) -> np.ndarray:
    sub = plan_for(step.node.left, False, group.alg.boolean)  # type: ignore[attr-defined]
    out = ops.exact_on_segments(group.alg, step.node, lambda k: group.on(sub, k), values[0])  # type: ignore[arg-type]
    return out[:, :1] if step.first else out


# --------------------------------------------------------------------------- rewrites: position 0


def _next_at_zero(group: _Group, step: Step, values: list) -> np.ndarray:
    return group.full(group.alg.bottom, 1) if group.length == 1 else values[0][:, 1:2]


def _over_time_at_zero(group: _Group, step: Step, values: list) -> np.ndarray:
    pick = group.alg.maximum if isinstance(step.node, Eventually) else group.alg.minimum
    return pick.reduce(values[0], axis=1, keepdims=True)


def _binary_at_zero(group: _Group, step: Step, values: list) -> np.ndarray:
    """U: max_t' min(ψ(t'), min_{t'' < t'} φ(t'')); T: the same with max_{t'' < t'}: one prefix scan."""
    alg = group.alg
    inner, empty = (alg.minimum, alg.empty_min) if isinstance(step.node, Until) else (alg.maximum, alg.empty_max)
    before = np.empty_like(values[0])  # [:, t'] = inner over φ(0 … t' − 1), empty at t' = 0
    before[:, 0] = empty
    inner.accumulate(values[0][:, :-1], axis=1, out=before[:, 1:])
    return alg.maximum.reduce(alg.minimum(values[1], before), axis=1, keepdims=True)


_AT_ZERO: dict[type, Callable[[_Group, Step, list], np.ndarray]] = {
    Next: _next_at_zero, Eventually: _over_time_at_zero, Always: _over_time_at_zero,
    Until: _binary_at_zero, Then: _binary_at_zero,
}

# --------------------------------------------------------------------------- rewrites: monotone predicates

# Increasing functions whose extreme over time can be taken before applying them.
_MONOTONE = {"sqrt": np.sqrt, "exp": np.exp, "log": np.log}


def _monotone_parts(node: Formula) -> tuple[Call, float, bool] | None:
    """``(f(e), c, grows)`` for a predicate ``f(e) ⋈ c`` (or ``c ⋈ f(e)``) with f increasing, else None."""
    if not isinstance(node, Predicate):
        return None
    for call, number, side in ((node.lhs, node.rhs, 1), (node.rhs, node.lhs, -1)):
        if isinstance(call, Call) and call.func in _MONOTONE and isinstance(number, Num):
            return call, number.value, side * ops.SIGN[node.op] > 0
    return None


def _monotone_extreme(group: _Group, step: Step, _: list) -> np.ndarray:
    """Max (F) or min (G) over time of ``f(e) ⋈ c``: f applied to the ``(N, 1)`` extreme of e.

    Both extremes of e are checked to lie in f's domain; otherwise the predicate is evaluated
    at every position (which names the position where it is undefined).
    """
    child: Predicate = step.node.child  # type: ignore[attr-defined]
    call, constant, grows = _monotone_parts(child)  # type: ignore[misc]
    largest = isinstance(step.node, Eventually)
    with np.errstate(all="ignore"):
        inner = np.broadcast_to(evaluate_expression(call.args[0], group.signals), (group.n, group.length))
        low, high = inner.min(axis=1, keepdims=True), inner.max(axis=1, keepdims=True)
        function = _MONOTONE[call.func]
        ends = function(low), function(high)
    if not (np.isfinite(ends[0]).all() and np.isfinite(ends[1]).all()):  # the general path
        values = _predicate(group, Step(child, False, ()), [])
        return _over_time_at_zero(group, step, [values])
    extreme = ends[1] if grows == largest else ends[0]  # the extreme of the margin ±(f(e) − c)
    return extreme - constant if grows else constant - extreme


# --------------------------------------------------------------------------- compiling


REWRITES = frozenset({"at_zero", "linear", "monotone"})


def plan_for(formula: Formula, first: bool, boolean: bool, rewrite: bool | frozenset[str] = True) -> Plan:
    """The formula's plan for the exact evaluator (cached on the formula).

    ``rewrite``: True applies every rewrite (`REWRITES`), False none (the plain plan), or a set of names.
    """
    rewrites = chosen(rewrite, REWRITES)

    def build() -> Plan:
        plan = compile_plan(formula, first, at_zero="at_zero" in rewrites)
        for step in plan.steps:
            node = step.node
            if isinstance(node, Constant):
                step.run = _constant
            elif isinstance(node, Predicate):
                linear = "linear" in rewrites and (isinstance(node.lhs, Var) or isinstance(node.rhs, Var)) and all(
                    isinstance(e, (Var, Num)) for e in (node.lhs, node.rhs))
                step.run = _linear_predicate if linear else _predicate
            elif step.segments:
                step.run = _on_segments
            elif step.first and type(node) in _AT_ZERO:
                step.run = _AT_ZERO[type(node)]
                if (isinstance(node, (Eventually, Always)) and not boolean and "monotone" in rewrites
                        and _monotone_parts(node.child) is not None):
                    step.run, step.inputs = _monotone_extreme, ()
            elif type(node) in ops.EXACT:
                step.run = _operator
            else:
                raise TypeError(f"no evaluation rule for formula node {type(node).__name__}")
        return prune(plan)

    return cached(formula, ("exact", first, boolean, rewrites), build)


def _evaluate(formula: Formula, trace: Trace, alg: ops.Lattice, first: bool,
              rewrite: bool | frozenset[str] = True) -> tuple[np.ndarray, bool]:
    plan = plan_for(formula, first, alg.boolean, rewrite)
    prepared = prepare(formula.signals, trace)
    parts = [  # trajectories are independent: evaluate them group by group (see `chunks`)
        run(plan, _Group(alg, {k: v[rows] for k, v in prepared.signals.items()}, rows.stop - rows.start,
                         prepared.length, prepared.magnitudes, rows.start))
        for rows in chunks(prepared.n, prepared.length)
    ]
    values = parts[0] if len(parts) == 1 else np.concatenate(parts)
    return (values[:, :1] if first else values), prepared.batched


def robustness_over_time(formula: Formula, trace: Trace, rho_max: float = math.inf) -> np.ndarray:
    """Robustness at every position: shape ``(T,)`` or ``(N, T)`` like the signals."""
    values, batched = _evaluate(formula, trace, ops.numeric(check_rho_max(rho_max)), first=False)
    return np.array(values if batched else values[0])


def robustness(formula: Formula, trace: Trace, rho_max: float = math.inf) -> float | np.ndarray:
    """Robustness at position 0: a float, or an ``(N,)`` array for batched signals."""
    values, batched = _evaluate(formula, trace, ops.numeric(check_rho_max(rho_max)), first=True)
    return values[:, 0].copy() if batched else float(values[0, 0])


def satisfied(formula: Formula, trace: Trace) -> bool | np.ndarray:
    """Boolean semantics at position 0: a bool, or an ``(N,)`` bool array."""
    values, batched = _evaluate(formula, trace, ops.BOOLEAN, first=True)
    return values[:, 0].copy() if batched else bool(values[0, 0])
