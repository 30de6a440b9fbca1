"""Smoothed robustness (paper, section V), with gradients for torch autograd.

Every max and min of the robustness definition, those over time included, is
replaced by log-sum-exp with sharpness β, nested as the definition nests (in
``φ U ψ`` the min over t'' is smoothed first and then combined with ψ). A chain of
``&`` (or ``|``) is one n-ary node. The paper's Eq. 18 is *not* this smoothing of
Eq. 17: it merges the max over time into the min (see the tests).

Implementation. A numpy forward pass over the formula records, per node, how to
send a gradient back to its operands (the log-sum-exp rules of `tl_gym.tltl.lse`);
torch sees the whole evaluation as one autograd Function. This keeps the per-call
cost to a few whole-array numpy passes per node — the trust-region step of TLPS
calls it dozens of times per iteration.

Whole-array passes are what the evaluation costs (numpy's exp is the floor), so the
rules save them where the algebra allows, each without changing a value:

* a node's *gain* (β for a predicate) is folded into the per-trajectory factor of
  the F or G above it, not multiplied into a whole array (`_Smoother.send`);
* a value read by one parent only (`_Smoother.spare`) lends its memory to that
  parent's softmax weights;
* ``&``/``|`` of linear predicates sum their weights per signal before scaling;
* F over ``&`` (G over ``|``) at position 0 reduces the operands' extreme and
  divides by their softmax total, instead of taking the total's logarithm;
* at position 0 the per-trajectory Jacobian is computed group by group during the
  forward pass and handed to torch without a copy (`_hand_over`).

Numerics. Values are kept in β-scaled units ``z = β·ρ``, where smoothing is a plain
log-sum-exp, and ±∞ (``true`` with ρ_max = ∞, ``X φ`` at the last state, an empty
max/min) is represented by ±``_INF`` = ±1e300. All arithmetic stays finite, so
neither values nor gradients can be NaN for β in (0, 1e6]; results beyond
±``_INF``/2 are reported as ±∞ with zero gradient, and a predicate whose β-scaled
value reaches ±``_INF``/2 is refused (`_Smoother.check_range`).

Cost. O(N·T) per node, except ``U``/``T`` evaluated at every position (when nested
under another temporal operator): the prescribed nesting makes their inner
max/min depend on both t and t', an O(N·T²) computation done in chunks of
trajectories. ``form="linear"`` smooths such a ``T`` through an O(N·T) identity.
A ``U``/``T`` needed only at position 0 stays linear in both forms.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Callable, Generator
from typing import Any

import numpy as np

from tl_gym.errors import TraceError
from tl_gym.tltl import lse
from tl_gym.tltl.ast import (
    Always,
    And,
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
    Var,
)
from tl_gym.tltl.expressions import evaluate_with_gradient, margin_bound
from tl_gym.tltl.iterative import resolve
from tl_gym.tltl.trace import Trace, check_rho_max, chunks, is_torch, prepare

_INF = 1e300  # stands for +∞ in β-scaled units
_MAX_QUADRATIC_ELEMENTS = 1 << 22  # cap on T²·N per chunk of a quadratic U/T
FORMS = ("nested", "linear")
_N_ARGS = 10  # non-tensor arguments of the autograd Function

_Key = tuple[Formula, bool]
_Backward = Callable[[np.ndarray], None]
# A rule that needs its operands' values yields their keys and gets the values back; it returns
# its value and its backward rule.
_Rule = Generator[_Key, np.ndarray, tuple[np.ndarray, _Backward]]


def _smin2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return -np.logaddexp(-a, -b)


def _smin2_backward(a: np.ndarray, b: np.ndarray, out: np.ndarray, grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return grad * np.exp(out - a), grad * np.exp(out - b)


class _Smoother:
    """Smoothed values, in β units, of one formula's nodes on a batch of signals.

    Signals and values are time-major, shape ``(T, N)`` (row t = position t); a node
    evaluated at position 0 only has shape ``(1, N)``.
    """

    def __init__(self, signals: dict[str, np.ndarray], n: int, length: int, beta: float, top: float, form: str,
                 magnitudes: dict[str, float], occurrences: Counter[Formula], first_row: int = 0):
        self.signals = signals
        self.occurrences = occurrences  # how often each sub-formula occurs in the formula being smoothed
        self.first_row = first_row  # index of this chunk's first trajectory in the caller's batch
        self.magnitudes = magnitudes  # max |signal| over the whole batch: bounds every chunk and prefix
        self.n = n
        self.length = length
        self.beta = beta
        self.top = top  # ρ_max in β units
        self.form = form
        self.values: dict[_Key, np.ndarray] = {}  # a repeated sub-formula is smoothed once
        self.retained: set[_Key] = set()  # nodes whose backward rule reads their own value
        # A node's gain: a factor its backward rule wants applied to the gradient it receives (β for a
        # predicate, which is β·margin). Senders that compute the gradient from a small array (F and G at
        # position 0) fold it in there; `send` applies it for the others.
        self.gains: dict[_Key, float] = {}
        # n-ary nodes whose only reader (F over &, G over |) takes their extreme and softmax total
        # instead of their value: it divides by the total instead of taking its logarithm
        self.parts_wanted: set[_Key] = set()
        self.parts: dict[_Key, tuple[np.ndarray, np.ndarray]] = {}
        self.scaled_signals: dict[str, np.ndarray] = {}  # β · signal, shared by the linear predicates
        self.tape: list[tuple[_Key, _Backward]] = []
        self.grads: dict[_Key, np.ndarray] = {}
        self.signal_grads: dict[str, np.ndarray] = {}

    # bookkeeping ------------------------------------------------------------------------
    def full(self, value: float, length: int | None = None) -> np.ndarray:
        return np.full((self.length if length is None else length, self.n), value)

    def __call__(self, node: Formula, first_only: bool = False) -> np.ndarray:
        """Smoothed values of ``node``, operands first (rules yield the keys they need: no recursion)."""
        key = (node, first_only)
        cached = self.values.get(key)
        if cached is not None:
            return cached
        return resolve(key, self.values, self._start, self._finish)

    def _start(self, key: _Key) -> Any:
        node, first_only = key
        try:
            rule = _RULES[type(node)]
        except KeyError:
            raise TypeError(f"no smoothing rule for formula node {type(node).__name__}") from None
        return rule(self, node, first_only)

    def _finish(self, key: _Key, result: tuple[np.ndarray, _Backward]) -> np.ndarray:
        value, backward = result
        self.values[key] = value
        self.tape.append((key, backward))
        return value

    def spare(self, node: Formula, first_only: bool = False) -> bool:
        """Whether the caller may overwrite this child's value.

        True when the child occurs once in the formula (so this caller is its only reader) and its
        own backward rule does not read it. The caller must not read it in its backward rule either.
        """
        return self.occurrences[node] == 1 and (node, first_only) not in self.retained

    def margin_bound(self, node: Predicate) -> float:
        """A bound on |margin| of the predicate over the whole batch (inf: unknown, maybe undefined)."""
        return margin_bound(node.lhs, node.rhs, tuple(self.magnitudes.items()))

    def check_range(self, node: Predicate, margin: np.ndarray) -> None:
        """Refuse finite predicate values too large for β units (±`_INF` stands for ±∞ there)."""
        with np.errstate(over="ignore"):
            too_large = np.abs(margin) * self.beta >= _INF / 2
        if too_large.any():
            t, i = np.argwhere(too_large)[0]
            raise TraceError(
                f"predicate {str(node)!r} is {margin[t, i]:.3g} at trajectory {self.first_row + i}, position {t}: "
                f"too large to smooth (|β · value| must stay below {_INF / 2:.0e}; β = {self.beta:g})"
            )

    def bad_value(self, node: Predicate, row: int, position: int) -> TraceError:
        """The error for a NaN or infinite predicate value, naming the trajectory in the caller's batch."""
        return TraceError(f"predicate {str(node)!r} is NaN or infinite at trajectory {self.first_row + row}, "
                          f"position {position}")

    def send(self, node: Formula, first_only: bool, grad: np.ndarray, gained: bool = False) -> None:
        """Accumulate a gradient for a child's value.

        The child's backward rule owns ``grad`` (and may scale it in place): senders pass
        arrays that nothing else holds. ``gained``: the sender already multiplied it by the
        child's gain (`gain`).
        """
        key = (node, first_only)
        if not gained:
            factor = self.gains.get(key, 1.0)
            if factor != 1.0:
                grad = np.multiply(grad, factor, out=grad)
        self.grads[key] = grad if key not in self.grads else self.grads[key] + grad

    def gain(self, node: Formula, first_only: bool = False) -> float:
        """The factor to fold into a gradient sent to this child (1 for most nodes)."""
        return self.gains.get((node, first_only), 1.0)

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

    def backward(self, root: _Key, grad: np.ndarray) -> dict[str, np.ndarray]:
        """Gradients of ``Σ grad · value(root)`` wrt the signals, shape ``(T, N)`` each."""
        factor = self.gain(*root)
        self.grads = {root: grad * factor if factor != 1.0 else grad}
        self.signal_grads = {}
        for key, backward in reversed(self.tape):  # parents were recorded after their children
            g = self.grads.pop(key, None)
            if g is not None:
                backward(g)
        return self.signal_grads

    def scaled(self, name: str) -> np.ndarray:
        """β · the signal, computed once per evaluation."""
        out = self.scaled_signals.get(name)
        if out is None:
            out = self.scaled_signals[name] = self.signals[name] * self.beta
        return out

    def on_prefix(self, length: int) -> _Smoother:
        signals = {k: v[:length] for k, v in self.signals.items()}
        return _Smoother(signals, self.n, length, self.beta, self.top, self.form, self.magnitudes, self.occurrences,
                         self.first_row)

    # rules: each returns (value, backward) ----------------------------------------------
    def constant(self, node: Constant, first_only: bool) -> tuple[np.ndarray, _Backward]:
        value = self.full(self.top if node.value else -self.top, 1 if first_only else None)
        return value, lambda g: None

    def predicate(self, node: Predicate, first_only: bool) -> tuple[np.ndarray, _Backward]:
        slopes = _linear_slopes(node)
        if slopes is not None:
            return self._linear_predicate(node, slopes, first_only)
        rows = 1 if first_only else self.length
        signals = {k: v[:rows] for k, v in self.signals.items()} if first_only else self.signals
        lhs, lhs_grad = evaluate_with_gradient(node.lhs, signals)
        rhs, rhs_grad = evaluate_with_gradient(node.rhs, signals)
        sign = -1.0 if node.op in ("<", "<=") else 1.0  # the margin is sign · (lhs − rhs)
        with np.errstate(all="ignore"):
            difference = np.subtract(lhs, rhs) if sign > 0 else np.subtract(rhs, lhs)
        margin = np.broadcast_to(difference, (rows, self.n))
        if self.margin_bound(node) * self.beta >= _INF / 2:  # possibly undefined or too large: look
            with np.errstate(all="ignore"):
                # a NaN or inf makes the sum non-finite: one cheap pass clears almost every call
                suspicious = not np.isfinite(np.sum(margin))
            if suspicious and not np.isfinite(margin).all():
                t, i = np.argwhere(~np.isfinite(margin))[0]
                raise self.bad_value(node, i, t)
            self.check_range(node, margin)
        if isinstance(difference, np.ndarray) and difference.shape == margin.shape:  # a fresh array: scale in place
            z = np.multiply(difference, self.beta, out=difference)
        else:
            z = margin * self.beta

        self.gains[(node, first_only)] = sign * self.beta

        def backward(g: np.ndarray) -> None:
            # ``g`` arrives multiplied by the gain sign·β: it is the gradient wrt lhs (wrt rhs: its negative)
            terms = rhs_grad(g, -1.0)
            terms += lhs_grad(g, 1.0, owned=not terms)
            for name, grad, coef, owned in terms:
                if np.shape(grad) != g.shape:
                    grad, owned = np.broadcast_to(grad, g.shape), False
                self.accumulate(name, grad, coef, owned)

        return z, backward

    def _linear_predicate(
        self, node: Predicate, slopes: dict[str, float], first_only: bool
    ) -> tuple[np.ndarray, _Backward]:
        """A predicate between signals and numbers (``x < 5``, ``x > y``), the common case, in few passes.

        Two passes forward (on row 0 only when that is all that is asked), one or two per signal backward.
        """
        rows = 1 if first_only else self.length
        bound = self.margin_bound(node)
        low, high = (node.lhs, node.rhs) if node.op in ("<", "<=") else (node.rhs, node.lhs)  # z = β·(high − low)
        if rows == self.length and bound * self.beta < _INF / 2 and (isinstance(low, Var) or isinstance(high, Var)):
            # one pass: β·signal is shared by every linear predicate on the signal
            high_z, low_z = (self.scaled(e.name) if isinstance(e, Var) else e.value * self.beta for e in (high, low))
            z = np.subtract(high_z, low_z)
        else:
            high_v, low_v = (self.signals[e.name][:rows] if isinstance(e, Var) else e.value for e in (high, low))
            with np.errstate(all="ignore"):
                margin = np.subtract(high_v, low_v)
            if not bound < 1e307 and not np.isfinite(margin).all():  # the signals are finite: only overflow is left
                t, i = np.argwhere(~np.isfinite(np.broadcast_to(margin, (rows, self.n))))[0]
                raise self.bad_value(node, i, t)
            if bound * self.beta >= _INF / 2:
                self.check_range(node, np.broadcast_to(margin, (rows, self.n)))
            if isinstance(margin, np.ndarray):  # a fresh array: scale it in place
                margin *= self.beta
                z = margin
            else:  # two numbers, e.g. ``1 < 2``
                z = np.full((rows, self.n), margin * self.beta)

        self.gains[(node, first_only)] = self.beta

        def backward(g: np.ndarray) -> None:  # ``g`` arrives multiplied by the gain β
            for i, (name, slope) in enumerate(slopes.items()):
                self.accumulate(name, g, slope, owned=i == len(slopes) - 1)  # the last use may own g

        return z, backward

    def not_(self, node: Not, first_only: bool) -> _Rule:
        def backward(g: np.ndarray) -> None:
            self.send(node.child, first_only, np.multiply(g, -self.gain(node.child, first_only), out=g), gained=True)

        return -(yield node.child, first_only), backward

    def _nary(self, node: And | Or, first_only: bool, sign: float) -> _Rule:
        """``sign·lse(sign·children)``: smooth max (sign = 1) or min (sign = -1)."""
        values = []
        for child in node.operands:
            values.append((yield child, first_only))
        key = (node, first_only)
        wanted = key in self.parts_wanted
        out, exps, total = lse.reduce_operands(values, sign, [self.spare(c, first_only) for c in node.operands],
                                               value=not wanted)
        if wanted:  # ``out`` is the elementwise extreme; the reader computes with it (no value is cached)
            self.parts[key] = (out, total)
        by_signal, others = _group_linear_operands(node.operands, exps)

        all_linear = not others
        if all_linear:  # every operand's gradient is a multiple of β: fold it upstream
            self.gains[(node, first_only)] = self.beta

        def backward(g: np.ndarray) -> None:
            # The weights of the operands are exps / total. A linear predicate's gradient is its weight
            # times slope·β per signal: those of one signal are summed first, then scaled once.
            scale = np.divide(g, total, out=g)  # ``g`` is this rule's own (times β when all are linear)
            for name, terms in by_signal.items():
                (first_exps, first_slope), rest = terms[0], terms[1:]
                combined = _combine(first_exps, first_slope, rest, scale)
                self.accumulate(name, combined, first_slope if all_linear else first_slope * self.beta, owned=True)
            for child, e in others:
                self.send(child, first_only, scale * e)

        return out, backward

    def and_(self, node: And, first_only: bool) -> _Rule:
        return (yield from self._nary(node, first_only, -1.0))

    def or_(self, node: Or, first_only: bool) -> _Rule:
        return (yield from self._nary(node, first_only, 1.0))

    def implies(self, node: Implies, first_only: bool) -> _Rule:
        neg_left = -(yield node.left, first_only)
        right = yield node.right, first_only
        out = np.logaddexp(neg_left, right)
        self.retained.add((node, first_only))

        def backward(g: np.ndarray) -> None:
            g_left, g_right = lse.logaddexp_backward(neg_left, right, out, g)
            self.send(node.left, first_only, -g_left)
            self.send(node.right, first_only, g_right)

        return out, backward

    def next_(self, node: Next, first_only: bool) -> _Rule:
        child = yield node.child, False
        out = np.concatenate([child[1:], self.full(-self.top, 1)])  # no next state: −ρ_max
        if first_only:
            out = out[:1]

        def backward(g: np.ndarray) -> None:
            g_child = np.zeros_like(child)
            g_child[1 : 1 + len(g)] = g[: self.length - 1]
            self.send(node.child, False, g_child)

        return out, backward

    def _over_time(self, node: Eventually | Always, first_only: bool, sign: float) -> _Rule:
        if first_only:  # one reduction over time
            if isinstance(node.child, And if sign > 0 else Or) and self.spare(node.child):
                # the child is extreme ∓ log(total): reduce the extreme, dividing the weights by the total
                self.parts_wanted.add((node.child, False))
                yield node.child, False
                extreme, child_total = self.parts.pop((node.child, False))
                reduced, exps, total = lse.reduce_forward(extreme, 0, sign, spare=True, divisor=child_total)
            else:
                child = yield node.child, False
                reduced, exps, total = lse.reduce_forward(child, 0, sign, self.spare(node.child))

            def backward_first(g: np.ndarray) -> None:  # the child's gain goes into the per-trajectory factor
                g_child = lse.reduce_backward(exps, total, g[0] * self.gain(node.child), 0)
                self.send(node.child, False, g_child, gained=True)

            return reduced[None], backward_first
        child = sign * (yield node.child, False)
        out = lse.suffix_forward(child)

        def backward(g: np.ndarray) -> None:
            g_child = lse.suffix_backward(child, out, sign * g)  # `sign * g`: the gradient wrt `out`
            self.send(node.child, False, sign * g_child)

        return sign * out, backward

    def eventually(self, node: Eventually, first_only: bool) -> _Rule:
        return (yield from self._over_time(node, first_only, 1.0))

    def always(self, node: Always, first_only: bool) -> _Rule:
        return (yield from self._over_time(node, first_only, -1.0))

    def until(self, node: Until, first_only: bool) -> _Rule:
        return (yield from self._binary(node, first_only, -1.0))

    def then(self, node: Then, first_only: bool) -> _Rule:
        return (yield from self._binary(node, first_only, 1.0))

    def _binary(self, node: Until | Then, first_only: bool, sign: float) -> _Rule:
        """smax_{t'≥t} smin(ψ(t'), inner(t, t')): the nested smoothing of U and T.

        inner is the smin (U, sign -1) or smax (T, sign +1) of φ over t'' in [t, t');
        ``sign·lse(sign·φ)`` is that inner reduction.
        """
        if node.left.is_temporal:
            return (yield from self._binary_on_segments(node, first_only, sign))
        if first_only:
            return (yield from self._binary_first(node, sign))
        if self.form == "linear" and isinstance(node, Then):
            return (yield from self._then_linear(node))
        return (yield from self._binary_quadratic(node, sign))

    def _binary_first(self, node: Until | Then, sign: float) -> _Rule:
        """Position 0 only: inner(0, t') is a reduction over the prefix [0, t'): linear time."""
        left = sign * (yield node.left, False)
        right = yield node.right, False
        prefix = lse.prefix_forward(left)
        inner = sign * np.concatenate([self.full(-_INF, 1), prefix[:-1]])
        terms = _smin2(right, inner)
        reduced, exps, total = lse.reduce_forward(terms, 0)
        out = reduced[None]

        def backward(g: np.ndarray) -> None:
            g_terms = lse.reduce_backward(exps, total, g[0], 0)
            g_right, g_inner = _smin2_backward(right, inner, terms, g_terms)
            g_prefix = np.zeros_like(prefix)
            g_prefix[:-1] = sign * g_inner[1:]
            self.send(node.left, False, sign * lse.prefix_backward(left, prefix, g_prefix))
            self.send(node.right, False, g_right)

        return out, backward

    def _then_linear(self, node: Then) -> _Rule:
        """ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')), smoothed: O(N·T)."""
        left = yield node.left, False
        right = yield node.right, False
        right_suffix = lse.suffix_forward(right)
        later = np.concatenate([right_suffix[1:], self.full(-_INF, 1)])
        inner = _smin2(left, later)
        out = lse.suffix_forward(inner)
        self.retained.add((node, False))

        def backward(g: np.ndarray) -> None:
            g_inner = lse.suffix_backward(inner, out, g)
            g_left, g_later = _smin2_backward(left, later, inner, g_inner)
            g_suffix = np.zeros_like(right_suffix)
            g_suffix[1:] = g_later[:-1]
            self.send(node.left, False, g_left)
            self.send(node.right, False, lse.suffix_backward(right, right_suffix, g_suffix))

        return out, backward

    def _binary_quadratic(self, node: Until | Then, sign: float) -> _Rule:
        """Every position, prescribed nesting: O(N·T²), in chunks of trajectories."""
        left = sign * (yield node.left, False)
        right = yield node.right, False
        chunk = max(1, _MAX_QUADRATIC_ELEMENTS // (self.length * self.length))
        parts = [slice(s, s + chunk) for s in range(0, self.n, chunk)]
        out = np.concatenate([_quadratic(left[:, p], right[:, p], sign)[0] for p in parts], axis=1)

        def backward(g: np.ndarray) -> None:
            g_left, g_right = np.zeros_like(left), np.zeros_like(right)
            for p in parts:  # recompute each chunk's intermediates instead of storing N·T² of them
                _, (g_left[:, p], g_right[:, p]) = _quadratic(left[:, p], right[:, p], sign, g[:, p])
            self.send(node.left, False, sign * g_left)
            self.send(node.right, False, g_right)

        return out, backward

    def _binary_on_segments(self, node: Until | Then, first_only: bool, sign: float) -> _Rule:
        """A temporal left operand judged on each truncated segment s_{t''..t'-1}: O(N·T²) time."""
        right = yield node.right, False
        subs = [self.on_prefix(t_prime) for t_prime in range(1, self.length)]
        matrix = np.full((self.length, self.length, self.n), -_INF)  # [t'', t', n]
        for t_prime, sub in enumerate(subs, start=1):
            matrix[:t_prime, t_prime] = sign * sub(node.left)
        out, _ = _quadratic_from_matrix(matrix, right, sign)
        if first_only:
            out = out[:1]

        def backward(g: np.ndarray) -> None:
            g_full = np.zeros((self.length, self.n))
            g_full[: len(g)] = g
            _, (g_matrix, g_right) = _quadratic_from_matrix(matrix, right, sign, g_full)
            for t_prime, sub in enumerate(subs, start=1):
                for name, grad in sub.backward((node.left, False), sign * g_matrix[:t_prime, t_prime]).items():
                    self.accumulate(name, grad, 1.0)  # positions 0 … t'-1
            self.send(node.right, False, g_right)

        return out, backward


def _quadratic(
    left: np.ndarray, right: np.ndarray, sign: float, grad: np.ndarray | None = None
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Nested U/T at every position for a temporal-free (sign-scaled) left operand."""
    length = left.shape[0]
    below = np.tri(length, length, -1, dtype=bool).T[:, :, None]  # [t'', t'] where t'' < t'
    matrix = np.where(below, left[:, None, :], -_INF)
    out, grads = _quadratic_from_matrix(matrix, right, sign, grad)
    if grads is None:
        return out, None
    g_matrix, g_right = grads
    return out, ((g_matrix * below).sum(axis=1), g_right)


def _quadratic_from_matrix(
    matrix: np.ndarray, right: np.ndarray, sign: float, grad: np.ndarray | None = None
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """``out[t] = lse_{t' ≥ t} smin(ψ(t'), sign·lse_{t'' ∈ [t, t')} matrix[t'', t'])``.

    ``matrix[t'', t', n]`` holds sign·φ(t'') judged on s_{..t'-1}, and -∞ where t'' ≥ t'.
    With ``grad`` also returns the gradients wrt ``matrix`` and ``right``.
    """
    length = matrix.shape[0]
    suffix = lse.suffix_forward(matrix)  # [t, t'] = lse over t'' ≥ t (entries t'' ≥ t' are -∞)
    inner = sign * suffix
    later = np.tri(length, length, -1, dtype=bool)[:, :, None]  # [t, t'] where t' < t: excluded
    terms = np.where(later, -_INF, _smin2(right[None], inner))
    out, exps, total = lse.reduce_forward(terms, 1)
    if grad is None:
        return out, None
    g_terms = np.where(later, 0.0, lse.reduce_backward(exps, total, grad, 1))
    g_right, g_inner = _smin2_backward(right[None], inner, terms, g_terms)
    g_matrix = lse.suffix_backward(matrix, suffix, sign * g_inner)
    return out, (g_matrix, g_right.sum(axis=0))


_RULES: dict[type, Callable[[_Smoother, Any, bool], tuple[np.ndarray, _Backward]]] = {
    Constant: _Smoother.constant,
    Predicate: _Smoother.predicate,
    Not: _Smoother.not_,
    And: _Smoother.and_,
    Or: _Smoother.or_,
    Implies: _Smoother.implies,
    Next: _Smoother.next_,
    Eventually: _Smoother.eventually,
    Always: _Smoother.always,
    Until: _Smoother.until,
    Then: _Smoother.then,
}


def _group_linear_operands(
    operands: tuple[Formula, ...], exps: list[np.ndarray]
) -> tuple[dict[str, list[tuple[np.ndarray, float]]], list[tuple[Formula, np.ndarray]]]:
    """Split an n-ary node's operands: linear predicates, as (weight, slope) terms per signal, and the rest."""
    by_signal: dict[str, list[tuple[np.ndarray, float]]] = {}
    others: list[tuple[Formula, np.ndarray]] = []
    for operand, e in zip(operands, exps):
        slopes = _linear_slopes(operand) if isinstance(operand, Predicate) else None
        if slopes is None:
            others.append((operand, e))
            continue
        for name, slope in slopes.items():  # a predicate between numbers has none: no gradient
            by_signal.setdefault(name, []).append((e, slope))
    return by_signal, others


def _combine(first: np.ndarray, first_slope: float, rest: list[tuple[np.ndarray, float]],
             scale: np.ndarray) -> np.ndarray:
    """``scale · (first + Σ (slope / first_slope) · e)`` over ``rest``: a fresh array."""
    if not rest:
        return np.multiply(first, scale)
    combined: np.ndarray | None = None
    for e, slope in rest:
        ratio = slope / first_slope
        if combined is None and ratio in (1.0, -1.0):
            combined = np.add(first, e) if ratio > 0 else np.subtract(first, e)
            continue
        if combined is None:
            combined = first.copy()
        if ratio == 1.0:
            combined += e
        elif ratio == -1.0:
            combined -= e
        else:
            combined += ratio * e
    assert combined is not None
    combined *= scale
    return combined


@functools.lru_cache(maxsize=1024)
def _linear_slopes(node: Predicate) -> dict[str, float] | None:
    """Each signal's slope in the margin of a predicate whose sides are signals or numbers; else None."""
    if not all(isinstance(side, (Var, Num)) for side in (node.lhs, node.rhs)):
        return None
    sign = -1.0 if node.op in ("<", "<=") else 1.0  # the margin is sign · (lhs − rhs)
    slopes: dict[str, float] = {}
    for side, slope in ((node.lhs, sign), (node.rhs, -sign)):
        if isinstance(side, Var):
            slopes[side.name] = slopes.get(side.name, 0.0) + slope
    return {name: slope for name, slope in slopes.items() if slope}


@functools.lru_cache(maxsize=64)
def _reductions_only(formula: Formula) -> bool:
    """Whether every temporal operator is an F or G of a temporal-free formula (as in the paper's φ1)."""
    return not any(
        isinstance(node, (Next, Until, Then)) or (isinstance(node, (Eventually, Always)) and node.child.is_temporal)
        for node in formula.walk()
    )


@functools.lru_cache(maxsize=64)
def _occurrences(formula: Formula) -> Counter[Formula]:
    """How often each sub-formula occurs in ``formula`` (a value used once may be overwritten by its user)."""
    return Counter(formula.walk())


def _to_rho(z: np.ndarray, beta: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(z) >= _INF / 2, np.sign(z) * np.inf, z / beta)


def _check(beta: float, rho_max: float, form: str) -> None:
    if isinstance(beta, bool) or not (isinstance(beta, (int, float)) and math.isfinite(beta) and beta > 0):
        raise ValueError(f"beta must be a positive finite number, got {beta!r}")
    check_rho_max(rho_max)
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")


def _evaluate(formula: Formula, signals: dict[str, np.ndarray], n: int, length: int, beta: float, rho_max: float,
              form: str, first_only: bool, magnitudes: dict[str, float],
              first_row: int = 0) -> tuple[_Smoother, np.ndarray]:
    top = min(beta * rho_max, _INF) if math.isfinite(rho_max) else _INF
    smoother = _Smoother(signals, n, length, float(beta), top, form, magnitudes, _occurrences(formula), first_row)
    return smoother, smoother(formula, first_only)


def _at_position_zero(formula: Formula, signals: dict[str, np.ndarray], n: int, length: int, beta: float,
                      rho_max: float, form: str, magnitudes: dict[str, float],
                      jacobian: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Smoothed values at position 0 in β units, shape ``(1, N)``, chunk by chunk of trajectories.

    ``signals`` are ``(N, T)``. With ``jacobian``, also each value's gradient wrt its own
    trajectory (``(N, T)`` per signal, in ρ units, zero where the value is ±∞). Trajectories
    are independent, so this Jacobian is all a vector-Jacobian product at position 0 needs:
    the backward pass is one multiplication, and the forward and backward work of a chunk
    stays in cache instead of a tape of whole-batch arrays.
    """
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
            unit = np.where(np.abs(z_part) >= _INF / 2, 0.0, 1.0 / beta)  # ±∞ results have zero gradient
            grads = smoother.backward((formula, True), unit)
            for name in grads.keys() - jac.keys():  # not written yet: no np.zeros pass over the whole batch
                jac[name] = np.empty((n, length))
                jac[name][: rows.start] = 0.0
            for name, target in jac.items():
                grad = grads.get(name)
                target[rows] = 0.0 if grad is None else grad.T
    return z, jac


def _smooth(formula: Formula, trace: Trace, beta: float, rho_max: float, form: str, first_only: bool) -> Any:
    """Shared entry: numpy in → numpy out; torch in → a differentiable torch tensor out."""
    _check(beta, rho_max, form)
    prepared = prepare(formula.signals, trace, torch_ok=True)
    names = tuple(prepared.signals)
    tensors = [prepared.signals[k] for k in names]
    if not names and any(is_torch(v) for v in trace.values()):  # torch in, torch out, even with no signal read
        import torch

        return torch.as_tensor(_smooth_numpy(formula, prepared, beta, rho_max, form, first_only), dtype=torch.float64)
    if any(is_torch(t) for t in tensors):
        import torch

        tensors = [t if is_torch(t) else torch.as_tensor(t) for t in tensors]  # a numpy signal beside tensors
        wants_grad = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
        out = _autograd_function()(formula, names, float(beta), rho_max, form, first_only, prepared.n,
                                   prepared.length, prepared.magnitudes, wants_grad, *tensors)
        out = out[0] if first_only else out.T  # (N,) or (N, T)
        return out if prepared.batched else out[0]
    return _smooth_numpy(formula, prepared, beta, rho_max, form, first_only)


def _smooth_numpy(formula: Formula, prepared: Any, beta: float, rho_max: float, form: str, first_only: bool) -> Any:
    if first_only:
        z, _ = _at_position_zero(formula, prepared.signals, prepared.n, prepared.length, beta, rho_max, form,
                                 prepared.magnitudes, jacobian=False)
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
                    *tensors: Any) -> Any:
            arrays = [t.detach().cpu().double().numpy() for t in tensors]
            if first_only:  # the gradient is computed now, chunk by chunk, as a per-trajectory Jacobian
                def at_zero(arrays: list[np.ndarray], jacobian: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
                    return _at_position_zero(formula, dict(zip(names, arrays)), n, length, beta, rho_max, form,
                                             magnitudes, jacobian=jacobian)

                z, ctx.jac = at_zero(arrays, wants_grad)
                ctx.at_zero = at_zero
                ctx.save_for_backward(*tensors)  # a repeated backward recomputes the Jacobian from them
            else:
                signals = {k: np.ascontiguousarray(a.T) for k, a in zip(names, arrays)}
                ctx.smoother, z = _evaluate(formula, signals, n, length, beta, rho_max, form, False, magnitudes)
            ctx.root, ctx.z, ctx.beta, ctx.names, ctx.first_only = (formula, first_only), z, beta, names, first_only
            ctx.meta = [(t.dtype, t.device) for t in tensors]
            return torch.from_numpy(_to_rho(z, beta)).to(dtype=tensors[0].dtype, device=tensors[0].device)

        @staticmethod
        def backward(ctx: Any, grad_out: Any) -> Any:
            g = grad_out.detach().cpu().double().numpy()
            if ctx.first_only:
                grads = _hand_over(ctx, g[0][:, None])
            else:
                g = np.where(np.abs(ctx.z) >= _INF / 2, 0.0, g / ctx.beta)  # ±∞ results have zero gradient
                grads = {name: grad.T for name, grad in ctx.smoother.backward(ctx.root, g).items()}
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
    formula: Formula, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested"
) -> Any:
    """Smoothed robustness at position 0.

    Torch tensors in, a torch tensor out (shape ``()`` or ``(N,)``) that autograd can
    differentiate; numpy arrays or lists in, a float or an ``(N,)`` float64 array out.
    ``form="linear"`` smooths ``φ T ψ`` nested under a temporal operator through the
    identity ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')) in O(T) instead of
    the prescribed O(T²) nesting (same limit as β → ∞, same Lemma 1 bracket).
    """
    return _smooth(formula, trace, beta, rho_max, form, first_only=True)


def smooth_over_time(
    formula: Formula, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested"
) -> Any:
    """Smoothed robustness at every position: ``(T,)`` or ``(N, T)`` (numpy, or torch for torch input)."""
    return _smooth(formula, trace, beta, rho_max, form, first_only=False)
