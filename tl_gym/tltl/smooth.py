"""Smoothed robustness (paper, section V), with gradients for torch autograd.

Every max and min of the robustness definition, those over time included, is
replaced by log-sum-exp with sharpness β, nested as the definition nests (in
``φ U ψ`` the min over t'' is smoothed first and then combined with ψ). A chain of
``&`` (or ``|``) is one n-ary node. The paper's Eq. 18 is *not* this smoothing of
Eq. 17: it merges the max over time into the min (see the tests).

Implementation. The formula's plan (`tl_gym.tltl.plan`) runs the smoothing rules of
`tl_gym.tltl.operators` front to back, each returning its value and how to send a
gradient back to its operands; the gradient runs the plan back to front. Torch sees
the whole evaluation as one autograd Function. At position 0 with numba installed
(``backend="auto"``), the compiled kernel of `tl_gym.tltl.fused_smooth` runs the same rules.

Rewrites of the plan, each tested equal to the plain plan (`tests/test_smooth_fast_paths.py`):

* **position 0**: the root and the operands of Boolean connectives above temporal operators
  are smoothed at position 0 only; a top-level F, G, U or T is one reduction over time;
* **linear predicates** (``x < 5``, ``x > y``) take two passes, β·signal shared among them;
  ``&``/``|`` of such predicates sum their weights per signal before scaling;
* **F over &, G over |** at position 0 reduces the operands' extreme and divides the weights
  by their softmax total, instead of taking its logarithm;
* **gradient factors**: a step whose gradient is a constant multiple of what it receives (β for a
  predicate) has that *gradient factor* applied by its reader, to the smaller array;
* at position 0 the per-trajectory Jacobian is computed group by group during the
  forward pass and handed to torch without a copy (`_hand_over`).

Numerics. Values are kept in β-scaled units ``z = β·ρ``, where smoothing is a plain
log-sum-exp, and ±∞ (``true`` with ρ_max = ∞, ``X φ`` at the last state, an empty
max/min) is represented by ±``_INF`` = ±1e300. All arithmetic stays finite, so
neither values nor gradients can be NaN for β in (0, 1e6]; results beyond
±``_INF``/2 are reported as ±∞ with zero gradient, and a predicate whose β-scaled
value reaches ±``_INF``/2 is refused (`_Group.check_range`).

Cost. O(N·T) per node, except ``U``/``T`` needed at every position (nested under a temporal
operator): O(N·T²) in chunks of trajectories; ``form="linear"`` smooths such a ``T`` in O(N·T).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from tl_gym.errors import TraceError
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import fused_smooth, lse
from tl_gym.tltl import operators as ops
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.expressions import evaluate_with_gradient, margin_bound
from tl_gym.tltl.plan import Plan, Step, cached, chosen, compile_plan
from tl_gym.tltl.trace import Trace, check_backend, check_beta, check_rho_max, chunks, is_torch, prepare

_INF = ops.INF  # stands for +∞ in β-scaled units
_LIMIT = ops.SMOOTH_LIMIT  # |β · value| from here on cannot be told from ±∞
_MAX_QUADRATIC_ELEMENTS = 1 << 22  # cap on T²·N per chunk of a quadratic U/T
FORMS = ("nested", "linear")
_N_ARGS = 11  # non-tensor arguments of the autograd Function

# A step's function: (group, step, operand values) -> (value, backward, gradient factor)
_Result = tuple[Any, Callable[[np.ndarray], Any], float]


class _Group:
    """One group of trajectories being smoothed: time-major ``(T, n)`` signals, and the recorded pass."""

    def __init__(self, signals: dict[str, np.ndarray], n: int, length: int, beta: float, top: float, form: str,
                 magnitudes: dict[str, float], first_row: int = 0):
        self.signals = signals
        self.first_row = first_row  # index of this group's first trajectory in the caller's batch
        self.magnitudes = magnitudes  # max |signal| over the whole batch: bounds every group and prefix
        self.n = n
        self.length = length
        self.beta = beta
        self.top = top  # ρ_max in β units
        self.form = form
        self.scaled_signals: dict[str, np.ndarray] = {}  # β · signal, shared by the linear predicates
        self.signal_grads: dict[str, np.ndarray] = {}
        self.plan: Plan | None = None
        self.backs: list[Callable[[np.ndarray], Any]] = []
        self.factors: list[float] = []

    def full(self, value: float, length: int | None = None) -> np.ndarray:
        return np.full((self.length if length is None else length, self.n), value)

    def prefix(self, length: int) -> _Group:
        """The same trajectories truncated to s_0 … s_{length-1}."""
        return _Group({k: v[:length] for k, v in self.signals.items()}, self.n, length, self.beta, self.top,
                      self.form, self.magnitudes, self.first_row)

    def run(self, plan: Plan) -> Any:
        """Every step of ``plan`` in order; the root's value (its backward pass is recorded)."""
        self.plan = plan
        values: list[Any] = [None] * len(plan.steps)
        self.backs, self.factors = [], []
        for i, step in enumerate(plan.steps):
            value, back, factor = step.run(self, step, [values[j] for j in step.inputs])  # type: ignore[misc]
            values[i] = value
            self.backs.append(back)
            self.factors.append(factor)
        return values[-1]

    def backward(self, grad: np.ndarray) -> dict[str, np.ndarray]:
        """Gradients of ``Σ grad · value(root)`` wrt the signals, shape ``(T, n)`` each.

        Back to front through the plan. A step's pending gradient already includes its own
        gradient factor; when every operand of a step has the same factor, it is applied to
        the step's gradient (the smaller array) before its backward rule runs (except for the rules that
        also send gradients to the signals directly, `_DIRECT`).
        """
        plan = self.plan
        assert plan is not None
        factors = self.factors
        pending: dict[int, np.ndarray] = {len(plan.steps) - 1: grad * factors[-1] if factors[-1] != 1.0 else grad}
        self.signal_grads = {}
        for i in range(len(plan.steps) - 1, -1, -1):
            g = pending.pop(i, None)
            if g is None:
                continue
            step = plan.steps[i]
            inputs = step.inputs
            common = factors[inputs[0]] if inputs and step.run not in _DIRECT and all(
                factors[j] == factors[inputs[0]] for j in inputs) else None
            if common is not None and common != 1.0:
                g = np.multiply(g, common, out=g)
            sends = self.backs[i](g)
            if not inputs:
                continue
            for j, send in zip(inputs, sends):
                if send is None:
                    continue
                if common is None and factors[j] != 1.0:
                    send = np.multiply(send, factors[j], out=send)
                pending[j] = send if j not in pending else pending[j] + send
        return self.signal_grads

    def accumulate(self, name: str, grad: np.ndarray, scale: float, owned: bool = False) -> None:
        """Add ``scale · grad`` to the signal's gradient over its first ``len(grad)`` positions.

        ``owned``: nothing else holds ``grad``, so it may be scaled in place and kept.
        """
        if scale != 1.0:
            grad = np.multiply(grad, scale, out=grad if owned else None)
            owned = True
        target = self.signal_grads.get(name)
        if target is None and len(grad) == self.length:
            self.signal_grads[name] = grad if owned else grad.copy()
            return
        if target is None:
            target = self.signal_grads[name] = np.zeros((self.length, self.n))
        part = target[: len(grad)]
        part += grad

    def scaled(self, name: str) -> np.ndarray:
        """β · the signal, computed once per evaluation."""
        out = self.scaled_signals.get(name)
        if out is None:
            out = self.scaled_signals[name] = self.signals[name] * self.beta
        return out

    def check_range(self, node: nodes.Predicate, margin: np.ndarray) -> None:
        """Refuse finite predicate values too large for β units (±`_INF` stands for ±∞ there)."""
        with np.errstate(over="ignore"):
            too_large = np.abs(margin) * self.beta >= _LIMIT
        if too_large.any():
            t, i = np.argwhere(too_large)[0]
            raise TraceError(
                f"predicate {str(node)!r} is {margin[t, i]:.3g} at trajectory {self.first_row + i}, position {t}: "
                f"too large to smooth (|β · value| must stay below {_LIMIT:.0e}; β = {self.beta:g})"
            )

    def bad_value(self, node: nodes.Predicate, row: int, position: int) -> TraceError:
        """The error for a NaN or infinite predicate value, naming the trajectory in the caller's batch."""
        return TraceError(f"predicate {str(node)!r} is NaN or infinite at trajectory {self.first_row + row}, "
                          f"position {position}")

    def margin_bound(self, node: nodes.Predicate) -> float:
        """A bound on |margin| of the predicate over the whole batch (inf: unknown, maybe undefined)."""
        return margin_bound(node.lhs, node.rhs, tuple(self.magnitudes.items()))


# --------------------------------------------------------------------------- leaves


def _constant(group: _Group, step: Step, _: list) -> _Result:
    value = group.full(group.top if step.node.value else -group.top, 1 if step.first else None)  # type: ignore[attr-defined]
    return value, lambda g: (), 1.0


def _predicate(group: _Group, step: Step, _: list) -> _Result:
    """Any predicate: its arithmetic and its vector-Jacobian product (`evaluate_with_gradient`)."""
    node: nodes.Predicate = step.node  # type: ignore[assignment]
    rows = 1 if step.first else group.length
    signals = {k: v[:rows] for k, v in group.signals.items()} if step.first else group.signals
    lhs, lhs_grad = evaluate_with_gradient(node.lhs, signals)
    rhs, rhs_grad = evaluate_with_gradient(node.rhs, signals)
    sign = ops.SIGN[node.op]  # the margin is sign · (lhs − rhs)
    with np.errstate(all="ignore"):
        difference = ops.margin(node.op, lhs, rhs)
    margin = np.broadcast_to(difference, (rows, group.n))
    if group.margin_bound(node) * group.beta >= _LIMIT:  # possibly undefined or too large: look
        with np.errstate(all="ignore"):
            suspicious = not np.isfinite(np.sum(margin))  # one cheap pass clears almost every call
        if suspicious and not np.isfinite(margin).all():
            t, i = np.argwhere(~np.isfinite(margin))[0]
            raise group.bad_value(node, i, t)
        group.check_range(node, margin)
    if isinstance(difference, np.ndarray) and difference.shape == margin.shape:  # a fresh array: scale in place
        z = np.multiply(difference, group.beta, out=difference)
    else:
        z = margin * group.beta

    def backward(g: np.ndarray) -> tuple:
        # ``g`` arrives multiplied by the factor sign·β: it is the gradient wrt lhs (wrt rhs: its negative)
        terms = rhs_grad(g, -1.0)
        terms += lhs_grad(g, 1.0, owned=not terms)
        for name, grad, coef, owned in terms:
            if np.shape(grad) != g.shape:
                grad, owned = np.broadcast_to(grad, g.shape), False
            group.accumulate(name, grad, coef, owned)
        return ()

    return z, backward, sign * group.beta


@functools.lru_cache(maxsize=1024)
def _linear_slopes(node: nodes.Predicate) -> dict[str, float] | None:
    """Each signal's slope in the margin of a predicate whose sides are signals or numbers; else None."""
    if not all(isinstance(side, (nodes.Var, nodes.Num)) for side in (node.lhs, node.rhs)):
        return None
    slopes: dict[str, float] = {}
    for side, slope in ((node.lhs, ops.SIGN[node.op]), (node.rhs, -ops.SIGN[node.op])):
        if isinstance(side, nodes.Var):
            slopes[side.name] = slopes.get(side.name, 0.0) + slope
    return {name: slope for name, slope in slopes.items() if slope}


def _linear_predicate(group: _Group, step: Step, _: list) -> _Result:
    """Rewrite: a predicate between signals and numbers (``x < 5``, ``x > y``) in two passes.

    On row 0 only when that is all that is asked; one or two passes per signal backward.
    """
    node: nodes.Predicate = step.node  # type: ignore[assignment]
    slopes: dict[str, float] = _linear_slopes(node)  # type: ignore[assignment]
    rows = 1 if step.first else group.length
    bound = group.margin_bound(node)
    low, high = (node.lhs, node.rhs) if ops.SIGN[node.op] < 0 else (node.rhs, node.lhs)  # z = β·(high − low)
    on_signal = isinstance(low, nodes.Var) or isinstance(high, nodes.Var)
    if rows == group.length and bound * group.beta < _LIMIT and on_signal:
        # one pass: β·signal is shared by every linear predicate on the signal
        high_z, low_z = (
            group.scaled(e.name) if isinstance(e, nodes.Var) else e.value * group.beta for e in (high, low)
        )
        z = np.subtract(high_z, low_z)
    else:
        high_v, low_v = (group.signals[e.name][:rows] if isinstance(e, nodes.Var) else e.value for e in (high, low))
        with np.errstate(all="ignore"):
            margin = np.subtract(high_v, low_v)
        if not bound < 1e307 and not np.isfinite(margin).all():  # the signals are finite: only overflow is left
            t, i = np.argwhere(~np.isfinite(np.broadcast_to(margin, (rows, group.n))))[0]
            raise group.bad_value(node, i, t)
        if bound * group.beta >= _LIMIT:
            group.check_range(node, np.broadcast_to(margin, (rows, group.n)))
        if isinstance(margin, np.ndarray):  # a fresh array: scale it in place
            margin *= group.beta
            z = margin
        else:  # two numbers, e.g. ``1 < 2``
            z = np.full((rows, group.n), margin * group.beta)

    def backward(g: np.ndarray) -> tuple:  # ``g`` arrives multiplied by the factor β
        for i, (name, slope) in enumerate(slopes.items()):
            group.accumulate(name, g, slope, owned=i == len(slopes) - 1)  # the last use may own g
        return ()

    return z, backward, group.beta


# --------------------------------------------------------------------------- the plain rules


def _rule(group: _Group, step: Step, values: list) -> _Result:
    """The operator's rule of `tl_gym.tltl.operators`, at every position."""
    node = step.node
    if isinstance(node, nodes.Not):
        value, back = ops.smooth_not(values[0])
    elif isinstance(node, nodes.And):
        value, back = ops.smooth_and(*values)
    elif isinstance(node, nodes.Or):
        value, back = ops.smooth_or(*values)
    elif isinstance(node, nodes.Implies):
        value, back = ops.smooth_implies(*values)
    elif isinstance(node, nodes.Next):
        value, back = ops.smooth_next(values[0], group.top)
    elif isinstance(node, (nodes.Eventually, nodes.Always)):
        value, back = ops.smooth_over_time(values[0], 1.0 if isinstance(node, nodes.Eventually) else -1.0)
    elif isinstance(node, nodes.Then) and group.form == "linear":
        value, back = ops.smooth_then_linear(*values)
    else:
        sign = -1.0 if isinstance(node, nodes.Until) else 1.0
        value, back = ops.smooth_binary(*values, sign, _MAX_QUADRATIC_ELEMENTS)
    return value, back, 1.0


def _on_segments(group: _Group, step: Step, values: list) -> _Result:
    """U / T with a temporal left operand, judged on each truncated segment s_{t''..t'-1}: O(N·T²)."""
    node: nodes.Until | nodes.Then = step.node  # type: ignore[assignment]
    sign = -1.0 if isinstance(node, nodes.Until) else 1.0
    left_plan = plan_for(node.left, False, group.form)
    subs = [group.prefix(t_prime) for t_prime in range(1, group.length)]
    matrix = np.full((group.length, group.length, group.n), -_INF)  # [t'', t', n]
    for t_prime, sub in enumerate(subs, start=1):
        matrix[:t_prime, t_prime] = sign * sub.run(left_plan)
    out, matrix_backward = ops.smooth_on_segments(matrix, values[0], sign)

    def backward(g: np.ndarray) -> tuple:
        g_matrix, g_right = matrix_backward(g)
        for t_prime, sub in enumerate(subs, start=1):
            for name, grad in sub.backward(sign * g_matrix[:t_prime, t_prime]).items():
                group.accumulate(name, grad, 1.0)  # positions 0 … t'-1
        return (g_right,)

    return (out[:1] if step.first else out), backward, 1.0


# --------------------------------------------------------------------------- rewrites at position 0


def _next_at_zero(group: _Group, step: Step, values: list) -> _Result:
    value, back = ops.smooth_next(values[0], group.top)

    def backward(g: np.ndarray) -> tuple:
        g_full = np.zeros((group.length, group.n))
        g_full[:1] = g
        return back(g_full)

    return value[:1], backward, 1.0


def _over_time_at_zero(group: _Group, step: Step, values: list) -> _Result:
    """F / G at position 0: one reduction over time (of the child's extreme and total, with ``parts``)."""
    sign = 1.0 if isinstance(step.node, nodes.Eventually) else -1.0
    if step.options.get("parts"):  # the child is extreme ∓ log(total): divide the weights by the total instead
        extreme, child_total = values[0]
        reduced, exps, total = lse.reduce_forward(extreme, 0, sign, spare=True, divisor=child_total)
    else:
        reduced, exps, total = lse.reduce_forward(values[0], 0, sign)

    def backward(g: np.ndarray) -> tuple:  # ``g`` is (1, n): the child's gradient factor is already in it
        return (lse.reduce_backward(exps, total, g[0], 0),)

    return reduced[None], backward, 1.0


def _binary_at_zero(group: _Group, step: Step, values: list) -> _Result:
    """U / T at position 0: inner(0, t') is a reduction over the prefix [0, t'): linear time."""
    sign = -1.0 if isinstance(step.node, nodes.Until) else 1.0
    left, right = sign * values[0], values[1]
    prefix = lse.prefix_forward(left)
    inner = sign * np.concatenate([group.full(-_INF, 1), prefix[:-1]])
    terms = ops.smin2(right, inner)
    reduced, exps, total = lse.reduce_forward(terms, 0)

    def backward(g: np.ndarray) -> tuple:
        g_terms = lse.reduce_backward(exps, total, g[0], 0)
        g_right, g_inner = ops.smin2_backward(right, inner, terms, g_terms)
        g_prefix = np.zeros_like(prefix)
        g_prefix[:-1] = sign * g_inner[1:]
        return sign * lse.prefix_backward(left, prefix, g_prefix), g_right

    return reduced[None], backward, 1.0


_AT_ZERO = {nodes.Next: _next_at_zero, nodes.Eventually: _over_time_at_zero, nodes.Always: _over_time_at_zero,
            nodes.Until: _binary_at_zero, nodes.Then: _binary_at_zero}


# --------------------------------------------------------------------------- rewrite: & / | of linear predicates


def _nary_linear(group: _Group, step: Step, values: list) -> _Result:
    """``&`` / ``|`` with linear predicates among the operands: their weights summed per signal, then scaled.

    A linear predicate's gradient is its weight times slope·β per signal. With ``parts`` (its reader is
    F over & or G over |), the value is the operands' elementwise extreme and softmax total.
    """
    node: nodes.And | nodes.Or = step.node  # type: ignore[assignment]
    sign = -1.0 if isinstance(node, nodes.And) else 1.0
    parts = step.options.get("parts", False)
    out, exps, total = lse.reduce_operands(values, sign, value=not parts)
    by_signal: dict[str, list[tuple[np.ndarray, float]]] = {}
    others: list[int] = []
    for k, (operand, e) in enumerate(zip(node.operands, exps)):
        slopes = _linear_slopes(operand) if isinstance(operand, nodes.Predicate) else None
        if slopes is None:
            others.append(k)
            continue
        for name, slope in slopes.items():  # a predicate between numbers has none: no gradient
            by_signal.setdefault(name, []).append((e, slope))
    all_linear = not others

    def backward(g: np.ndarray) -> list:
        scale = np.divide(g, total, out=g)  # ``g`` is this rule's own (times β when all are linear)
        for name, terms in by_signal.items():
            (first_exps, first_slope), rest = terms[0], terms[1:]
            combined = _combine(first_exps, first_slope, rest, scale)
            group.accumulate(name, combined, first_slope if all_linear else first_slope * group.beta, owned=True)
        sends: list = [None] * len(exps)
        for k in others:
            sends[k] = scale * exps[k]
        return sends

    return ((out, total) if parts else out), backward, (group.beta if all_linear else 1.0)


def _combine(first: np.ndarray, first_slope: float, rest: list[tuple[np.ndarray, float]],
             scale: np.ndarray) -> np.ndarray:
    """``scale · (first + Σ (slope / first_slope) · e)`` over ``rest``: a fresh array."""
    if not rest:
        return np.multiply(first, scale)
    combined = first.copy()
    for e, slope in rest:
        ratio = slope / first_slope
        (np.add if ratio > 0 else np.subtract)(combined, e if abs(ratio) == 1.0 else abs(ratio) * e, out=combined)
    return np.multiply(combined, scale, out=combined)


# --------------------------------------------------------------------------- compiling

_DIRECT = (_nary_linear, _on_segments)  # rules whose backward also writes signal gradients itself

REWRITES = frozenset({"at_zero", "linear", "parts"})


def plan_for(formula: Formula, first: bool, form: str, rewrite: bool | frozenset[str] = True) -> Plan:
    """The formula's plan for the smoother (cached on the formula).

    ``rewrite``: True applies every rewrite (`REWRITES`), False none (the plain plan), or a set of names.
    """
    rewrites = chosen(rewrite, REWRITES)

    def build() -> Plan:
        plan = compile_plan(formula, first, at_zero="at_zero" in rewrites)
        steps = plan.steps
        for step in steps:
            node = step.node
            if isinstance(node, nodes.Constant):
                step.run = _constant
            elif isinstance(node, nodes.Predicate):
                linear = "linear" in rewrites and _linear_slopes(node) is not None
                step.run = _linear_predicate if linear else _predicate
            elif step.segments:
                step.run = _on_segments
            elif step.first and type(node) in _AT_ZERO:
                step.run = _AT_ZERO[type(node)]
            elif type(node) in ops.EXACT:
                step.run = _rule
                if "linear" in rewrites and isinstance(node, (nodes.And, nodes.Or)) and any(
                        isinstance(c, nodes.Predicate) and _linear_slopes(c) is not None for c in node.operands):
                    step.run = _nary_linear
            else:
                raise TypeError(f"no smoothing rule for formula node {type(node).__name__}")
        for step in steps:  # F over & (G over |) at position 0, the & read by F alone: "parts"
            if "parts" in rewrites and step.first and isinstance(step.node, (nodes.Eventually, nodes.Always)):
                child, inner = steps[step.inputs[0]], nodes.And if isinstance(step.node, nodes.Eventually) else nodes.Or
                if child.readers == 1 and isinstance(child.node, inner):
                    child.run, child.options["parts"], step.options["parts"] = _nary_linear, True, True
        return plan

    return cached(formula, ("smooth", first, form, rewrites), build)


@functools.lru_cache(maxsize=64)
def _reductions_only(formula: Formula) -> bool:
    """Whether every temporal operator is an F or G of a temporal-free formula (as in the paper's φ1)."""
    return not any(
        isinstance(node, (nodes.Next, nodes.Until, nodes.Then))
        or (isinstance(node, (nodes.Eventually, nodes.Always)) and node.child.is_temporal)
        for node in formula.walk()
    )


def _to_rho(z: np.ndarray, beta: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(z) >= _LIMIT, np.sign(z) * np.inf, z / beta)


def _check(formula: Formula, beta: float, rho_max: float, form: str, backend: str = "numpy") -> tuple[float, float]:
    """The arguments checked; ``beta`` and ``rho_max`` as Python floats (a numpy scalar is accepted and converted)."""
    beta, rho_max = check_beta(beta), check_rho_max(rho_max)
    check_smoothable_rho_max(formula, beta, rho_max)
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    check_backend(backend)
    return beta, rho_max


def check_smoothable_rho_max(formula: Formula, beta: float, rho_max: float) -> None:
    """Refuse a finite ``rho_max`` that, β-scaled, cannot be told from ∞, in a formula whose value it can be.

    ``true``, ``false`` and ``X φ`` at the last state are worth ±ρ_max: smoothed, a ρ_max with β·ρ_max ≥ 5e299
    came back as ±inf (as a predicate value that large, which is refused too). A formula without them never
    takes the value, so any ρ_max is fine there. The wrapper checks it at construction with ``reward="smooth"``.

    Raises:
        ValueError: naming ``rho_max`` and β.
    """
    if (math.isfinite(rho_max) and beta * rho_max >= _LIMIT
            and any(isinstance(node, (nodes.Constant, nodes.Next)) for node in formula.walk())):
        raise ValueError(f"rho_max={rho_max:g} is too large to smooth with β = {beta:g} (|β · rho_max| must stay "
                         f"below {_LIMIT:.0e}); pass rho_max=inf for an unbounded ⊤")


def _evaluate(formula: Formula, signals: dict[str, np.ndarray], n: int, length: int, beta: float, rho_max: float,
              form: str, first_only: bool, magnitudes: dict[str, float], first_row: int = 0,
              rewrite: bool | frozenset[str] = True) -> tuple[_Group, np.ndarray]:
    """Smoothed values (β units) of one group of time-major signals; the group can then run `backward`."""
    top = min(beta * rho_max, _INF) if math.isfinite(rho_max) else _INF
    group = _Group(signals, n, length, float(beta), top, form, magnitudes, first_row)
    plan = plan_for(formula, first_only, form, rewrite)
    z = group.run(plan)
    if first_only and not plan.root.first:  # the plain plan: every position, of which row 0 is asked
        whole = group.backward
        group.backward = lambda g: whole(np.concatenate([g, np.zeros((length - 1, n))]))  # type: ignore[method-assign]
        z = z[:1]
    return group, z


def _at_position_zero(formula: Formula, signals: dict[str, np.ndarray], n: int, length: int, beta: float,
                      rho_max: float, form: str, magnitudes: dict[str, float],
                      jacobian: bool, backend: str = "numpy") -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Smoothed values at position 0 in β units, shape ``(1, N)``, chunk by chunk of trajectories.

    ``signals`` are ``(N, T)``. With ``jacobian``, also each value's gradient wrt its own
    trajectory (``(N, T)`` per signal, in ρ units, zero where the value is ±∞). Trajectories
    are independent, so this Jacobian is all a vector-Jacobian product at position 0 needs:
    the backward pass is one multiplication, and the forward and backward work of a chunk
    stays in cache instead of a tape of whole-batch arrays. ``backend`` other than "numpy":
    the compiled kernel of `tl_gym.tltl.fused_smooth` answers where it covers the formula.
    """
    if backend != "numpy":  # the compiled kernel where it applies and pays, else this function with "numpy"
        return fused_smooth.or_numpy(backend, formula, signals, beta, rho_max, form, jacobian,
                                     lambda: _at_position_zero(formula, signals, n, length, beta, rho_max, form,
                                                               magnitudes, jacobian=jacobian))
    z = np.empty((1, n))
    jac: dict[str, np.ndarray] = {}
    signals = {k: np.ascontiguousarray(v) for k, v in signals.items()}  # a no-op for the usual (N, T) arrays
    column_major = _reductions_only(formula)
    for rows in chunks(n, length):
        # Time-major (T, n) arrays. Where time is only reduced (F and G over temporal-free formulas),
        # views without a copy: column-major, which numpy keeps through elementwise work, so the
        # reductions read contiguous memory and the Jacobian's rows go back without a transpose.
        # Scans over time (X, U, T, nested F/G) run step by step along time: row-major copies.
        part = {k: v[rows].T if column_major else np.ascontiguousarray(v[rows].T) for k, v in signals.items()}
        smoother, z_part = _evaluate(formula, part, rows.stop - rows.start, length, beta, rho_max, form, True,
                                     magnitudes, first_row=rows.start)
        z[:, rows] = z_part
        if jacobian:
            unit = np.where(np.abs(z_part) >= _LIMIT, 0.0, 1.0 / beta)  # ±∞ results have zero gradient
            grads = smoother.backward(unit)
            for name in grads.keys() - jac.keys():  # not written yet: no np.zeros pass over the whole batch
                jac[name] = np.empty((n, length))
                jac[name][: rows.start] = 0.0
            for name, target in jac.items():
                grad = grads.get(name)
                target[rows] = 0.0 if grad is None else grad.T
    return z, jac


def _smooth(formula: Formula, trace: Trace, beta: float, rho_max: float, form: str, first_only: bool,
            backend: str = "numpy") -> Any:
    """Shared entry: numpy in → numpy out; torch in → a differentiable torch tensor out."""
    beta, rho_max = _check(formula, beta, rho_max, form, backend)
    prepared = prepare(formula.signals, trace, torch_ok=True)
    names = tuple(prepared.signals)
    tensors = [prepared.signals[k] for k in names]
    if not names and any(is_torch(v) for v in trace.values()):  # torch in, torch out, even with no signal read
        import torch

        return torch.as_tensor(_smooth_numpy(formula, prepared, beta, rho_max, form, first_only, backend),
                               dtype=torch.float64)
    if any(is_torch(t) for t in tensors):
        import torch

        tensors = [t if is_torch(t) else torch.as_tensor(t) for t in tensors]  # a numpy signal beside tensors
        wants_grad = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
        out = _autograd_function()(formula, names, float(beta), rho_max, form, first_only, prepared.n,
                                   prepared.length, prepared.magnitudes, wants_grad, backend, *tensors)
        out = out[0] if first_only else out.T  # (N,) or (N, T)
        return out if prepared.batched else out[0]
    return _smooth_numpy(formula, prepared, beta, rho_max, form, first_only, backend)


def _smooth_numpy(formula: Formula, prepared: Any, beta: float, rho_max: float, form: str, first_only: bool,
                  backend: str) -> Any:
    if first_only:
        z, _ = _at_position_zero(formula, prepared.signals, prepared.n, prepared.length, beta, rho_max, form,
                                 prepared.magnitudes, jacobian=False, backend=backend)
    else:
        signals = {k: np.ascontiguousarray(v.T) for k, v in prepared.signals.items()}
        _, z = _evaluate(formula, signals, prepared.n, prepared.length, beta, rho_max, form, False,
                         prepared.magnitudes)
    rho = _to_rho(z, beta)
    if first_only:
        return rho[0].copy() if prepared.batched else float(rho[0, 0])
    return np.ascontiguousarray(rho.T) if prepared.batched else rho[:, 0].copy()


_FUNCTION: Any = None


def _autograd_function() -> Any:
    """The torch autograd Function around the numpy evaluator (built on first use)."""
    global _FUNCTION
    if _FUNCTION is not None:
        return _FUNCTION.apply
    import torch

    class SmoothRobustness(torch.autograd.Function):
        @staticmethod
        def forward(ctx: Any, formula: Formula, names: tuple[str, ...], beta: float, rho_max: float, form: str,
                    first_only: bool, n: int, length: int, magnitudes: dict[str, float], wants_grad: bool,
                    backend: str, *tensors: Any) -> Any:
            arrays = [t.detach().cpu().double().numpy() for t in tensors]
            if first_only:  # the gradient is computed now, chunk by chunk, as a per-trajectory Jacobian
                def at_zero(arrays: list[np.ndarray], jacobian: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
                    return _at_position_zero(formula, dict(zip(names, arrays)), n, length, beta, rho_max, form,
                                             magnitudes, jacobian=jacobian, backend=backend)

                z, ctx.jac = at_zero(arrays, wants_grad)
                ctx.at_zero = at_zero
                ctx.save_for_backward(*tensors)  # a repeated backward recomputes the Jacobian from them
            else:
                signals = {k: np.ascontiguousarray(a.T) for k, a in zip(names, arrays)}
                ctx.smoother, z = _evaluate(formula, signals, n, length, beta, rho_max, form, False, magnitudes)
            ctx.root, ctx.z, ctx.beta, ctx.names, ctx.first_only = (formula, first_only), z, beta, names, first_only
            ctx.meta = [(t.dtype, t.device) for t in tensors]
            # the first signal's float dtype; integer or bool signals give float64 (a cast to theirs truncated
            # the values and turned ±inf into garbage)
            dtype = tensors[0].dtype if tensors[0].is_floating_point() else torch.float64
            return torch.from_numpy(_to_rho(z, beta)).to(dtype=dtype, device=tensors[0].device)

        @staticmethod
        def backward(ctx: Any, grad_out: Any) -> Any:
            if torch.is_grad_enabled():  # create_graph=True: the gradient would be a constant, its own gradient 0
                raise RuntimeError(
                    "the smooth robustness is differentiable once: its gradient is computed by numpy, so "
                    "create_graph=True (a gradient penalty, a Hessian) cannot differentiate it again"
                )
            g = grad_out.detach().cpu().double().numpy()
            if ctx.first_only:
                grads = _hand_over(ctx, g[0][:, None])
            else:
                g = np.where(np.abs(ctx.z) >= _LIMIT, 0.0, g / ctx.beta)  # ±∞ results have zero gradient
                grads = {name: grad.T for name, grad in ctx.smoother.backward(g).items()}
            out = []
            for name, (dtype, device) in zip(ctx.names, ctx.meta):
                grad = grads.get(name)
                if grad is not None:
                    grad = torch.from_numpy(_plain(grad)).to(dtype=dtype, device=device)
                out.append(grad)
            return (None,) * _N_ARGS + tuple(out)

    _FUNCTION = SmoothRobustness
    return _FUNCTION.apply


def _plain(array: np.ndarray) -> np.ndarray:
    """``array`` C-contiguous with no negative stride, as `torch.from_numpy` needs.

    numpy calls a reversed array with a dimension of size 1 contiguous; torch refuses it.
    """
    if array.flags.c_contiguous and min(array.strides, default=0) >= 0:
        return array
    return np.array(array, order="C")


def _hand_over(ctx: Any, scale: np.ndarray) -> dict[str, np.ndarray]:
    """The position-0 Jacobian times ``scale`` (one weight per trajectory), computed in place.

    The first backward takes the Jacobian over (no copy: torch may keep the array as
    ``.grad``); a repeated one (``retain_graph=True``) recomputes it from the saved inputs.
    """
    jac = ctx.jac
    if jac is None:
        _, jac = ctx.at_zero([t.detach().cpu().double().numpy() for t in ctx.saved_tensors], True)
    ctx.jac = None
    if not (scale == 1.0).all():  # ``values.sum().backward()`` sends ones: nothing to scale
        for grad in jac.values():
            grad *= scale
    return jac


def smooth_robustness(
    formula: Formula, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested",
    backend: str = "auto",
) -> Any:
    """Smoothed robustness at position 0.

    Torch tensors in, a torch tensor out (shape ``()`` or ``(N,)``) that autograd can
    differentiate; numpy arrays or lists in, a float or an ``(N,)`` float64 array out.
    ``form="linear"`` smooths ``φ T ψ`` nested under a temporal operator through the
    identity ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')) in O(T) instead of
    the prescribed O(T²) nesting (same limit as β → ∞, same Lemma 1 bracket).
    ``backend``: "numba" runs the compiled kernel of `tl_gym.tltl.fused_smooth` where it covers the
    formula (warning once if numba is missing); "auto" does so once it pays (`fused_smooth.or_numpy`);
    "numpy" always runs the plan.
    """
    return _smooth(formula, trace, beta, rho_max, form, first_only=True, backend=backend)


def smooth_robustness_and_gradient(
    formula: Formula, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested",
    backend: str = "auto",
) -> tuple[Any, dict[str, np.ndarray]]:
    """`smooth_robustness` of numpy signals and, per signal, its gradient by the reverse pass (no autograd).

    A float and ``{signal: (T,)}``, or ``(N,)`` and ``{signal: (N, T)}`` for a batch; zero gradient
    for a signal the value does not depend on (`Formula.smooth_robustness_and_gradient`).
    """
    beta, rho_max = _check(formula, beta, rho_max, form, backend)
    prepared = prepare(formula.signals, trace)
    z, jac = _at_position_zero(formula, prepared.signals, prepared.n, prepared.length, beta, rho_max, form,
                               prepared.magnitudes, jacobian=True, backend=backend)
    values = _to_rho(z, beta)[0]
    shape = (prepared.n, prepared.length)
    grads = {name: jac[name] if name in jac else np.zeros(shape) for name in prepared.signals}
    if prepared.batched:
        return values.copy(), grads
    return float(values[0]), {name: grad[0] for name, grad in grads.items()}


def smooth_over_time(
    formula: Formula, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested"
) -> Any:
    """Smoothed robustness at every position: ``(T,)`` or ``(N, T)`` (numpy, or torch for torch input)."""
    return _smooth(formula, trace, beta, rho_max, form, first_only=False)
