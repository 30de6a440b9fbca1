"""Smoothed robustness (paper, section V), differentiable by torch autograd.

Every max and min of the robustness definition, those over time included, is
replaced by log-sum-exp with sharpness β, nested as the definition nests (in
``φ U ψ`` the min over t'' is smoothed first and then combined with ψ). A chain of
``&`` (or ``|``) is one n-ary node. The paper's Eq. 18 is *not* this smoothing of
Eq. 17: it merges the max over time into the min (see the tests).

Numerics. The evaluator works in β-scaled units ``z = β·ρ``, where smoothing is a
plain log-sum-exp, and represents ±∞ (``true`` with ρ_max = ∞, ``X φ`` at the last
state, an empty max/min) by ±``_INF`` = ±1e300. All arithmetic then stays finite,
so neither the values nor the gradients can be NaN for any β in (0, 1e6]; values
beyond ±``_INF``/2 are reported as ±∞ with zero gradient.

Cost. O(N·T) per node, except ``U``/``T`` evaluated at every position (when nested
under another temporal operator): the prescribed nesting makes their inner
max/min depend on both t and t', an O(N·T²) tensor, processed in chunks of
trajectories to bound memory. A ``U``/``T`` needed only at position 0 stays linear.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tl_gym.tltl.ast import (
    Always,
    And,
    Constant,
    Eventually,
    Formula,
    Implies,
    Next,
    Not,
    Or,
    Predicate,
    Then,
    Until,
)
from tl_gym.tltl.expressions import evaluate_expression
from tl_gym.tltl.trace import Trace, is_torch, prepare

_INF = 1e300  # stands for +∞ in β-scaled units
_MAX_QUADRATIC_ELEMENTS = 1 << 23  # cap on N·T² per chunk of a quadratic U/T


def _torch() -> Any:
    import torch

    return torch


def _lse(z: Any, dim: int) -> Any:
    """Smooth max in β units: log Σ exp(z) (finite inputs, so finite gradients)."""
    return _torch().logsumexp(z, dim=dim)


def _suffix_lse(z: Any, dim: int) -> Any:
    """``out[..., t, ...] = log Σ_{t' ≥ t} exp(z[..., t', ...])`` along ``dim``."""
    torch = _torch()
    return torch.flip(torch.logcumsumexp(torch.flip(z, (dim,)), dim=dim), (dim,))


def _smin2(a: Any, b: Any) -> Any:
    torch = _torch()
    return -torch.logaddexp(-a, -b)


class _Smoother:
    """Smoothed values, in β units, of one formula's nodes on a batch of signals."""

    def __init__(self, signals: dict[str, Any], n: int, length: int, beta: float, top: float, form: str):
        self.torch = _torch()
        self.signals = signals
        self.n = n
        self.length = length
        self.beta = beta
        self.top = top  # ρ_max in β units
        self.form = form
        self.cache: dict[tuple[Formula, bool], Any] = {}  # a repeated sub-formula is smoothed once

    def full(self, value: float, length: int | None = None) -> Any:
        length = self.length if length is None else length
        return self.torch.full((self.n, length), value, dtype=self.torch.float64)

    def __call__(self, node: Formula, first_only: bool = False) -> Any:
        """``(N, T)`` values, or ``(N, 1)`` (position 0) when ``first_only``."""
        key = (node, first_only)
        cached = self.cache.get(key)
        if cached is not None:
            return cached
        try:
            rule = _RULES[type(node)]
        except KeyError:
            raise TypeError(f"no smoothing rule for formula node {type(node).__name__}") from None
        values = self.cache[key] = rule(self, node, first_only)
        return values

    def on_prefix(self, node: Formula, length: int) -> Any:
        signals = {k: v[:, :length] for k, v in self.signals.items()}
        return _Smoother(signals, self.n, length, self.beta, self.top, self.form)(node)

    # rules ---------------------------------------------------------------------------
    def constant(self, node: Constant, first_only: bool) -> Any:
        return self.full(self.top if node.value else -self.top, 1 if first_only else None)

    def predicate(self, node: Predicate, first_only: bool) -> Any:
        torch = self.torch
        sample = next(iter(self.signals.values()), torch.zeros(1, dtype=torch.float64))
        lhs = evaluate_expression(node.lhs, self.signals, sample)
        rhs = evaluate_expression(node.rhs, self.signals, sample)
        value = rhs - lhs if node.op in ("<", "<=") else lhs - rhs
        value = torch.as_tensor(value, dtype=torch.float64).expand(self.n, self.length)
        if not bool(torch.isfinite(value.detach()).all()):
            from tl_gym.errors import TraceError

            i, t = np.argwhere(~np.isfinite(value.detach().cpu().numpy()))[0]
            raise TraceError(f"predicate {str(node)!r} is NaN or infinite at trajectory {i}, position {t}")
        z = self.beta * value
        return z[:, :1] if first_only else z

    def not_(self, node: Not, first_only: bool) -> Any:
        return -self(node.child, first_only)

    def and_(self, node: And, first_only: bool) -> Any:
        stacked = self.torch.stack([-self(c, first_only) for c in node.operands])
        return -_lse(stacked, 0)

    def or_(self, node: Or, first_only: bool) -> Any:
        return _lse(self.torch.stack([self(c, first_only) for c in node.operands]), 0)

    def implies(self, node: Implies, first_only: bool) -> Any:
        return self.torch.logaddexp(-self(node.left, first_only), self(node.right, first_only))

    def next_(self, node: Next, first_only: bool) -> Any:
        child = self(node.child)
        last = self.full(-self.top, 1)
        shifted = self.torch.cat([child[:, 1:], last], dim=1)
        return shifted[:, :1] if first_only else shifted

    def eventually(self, node: Eventually, first_only: bool) -> Any:
        child = self(node.child)
        return _lse(child, 1)[:, None] if first_only else _suffix_lse(child, 1)

    def always(self, node: Always, first_only: bool) -> Any:
        child = -self(node.child)
        return -(_lse(child, 1)[:, None] if first_only else _suffix_lse(child, 1))

    def until(self, node: Until, first_only: bool) -> Any:
        return self._binary(node, first_only, inner_sign=-1.0)

    def then(self, node: Then, first_only: bool) -> Any:
        return self._binary(node, first_only, inner_sign=1.0)

    def _binary(self, node: Until | Then, first_only: bool, inner_sign: float) -> Any:
        """smax_{t'≥t} smin(ψ(t'), inner(t, t')), inner = smin (U) or smax (T) of φ over [t, t').

        ``inner_sign`` is -1 for U (smin, empty = +∞) and +1 for T (smax, empty = -∞);
        smin(x) = -lse(-x), so the inner reduction is ``inner_sign · lse(inner_sign · φ)``.
        """
        torch = self.torch
        right = self(node.right)
        if first_only and not node.left.is_temporal:
            # inner(0, t') = reduction over the exclusive prefix [0, t'): linear time.
            left = inner_sign * self(node.left)
            prefix = inner_sign * torch.logcumsumexp(left, dim=1)
            inner = torch.cat([self.full(-inner_sign * _INF, 1), prefix[:, :-1]], dim=1)
            return _lse(_smin2(right, inner), 1)[:, None]
        if self.form == "linear" and isinstance(node, Then) and not node.left.is_temporal:
            # The exact identity ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')), smoothed:
            # linear time, a different smoothing with the same limit and the same bracket.
            later = torch.cat([_suffix_lse(right, 1)[:, 1:], self.full(-_INF, 1)], dim=1)
            return _suffix_lse(_smin2(self(node.left), later), 1)
        length = self.length
        # matrix[n, t'', t'] = sign·φ(t'') judged on s_{..t'-1}, or -∞ where t'' ≥ t'
        if node.left.is_temporal:
            columns = [self.full(-_INF, length)]
            for t_prime in range(1, length):
                col = inner_sign * self.on_prefix(node.left, t_prime)
                columns.append(torch.cat([col, self.full(-_INF, length - t_prime)], dim=1))
            matrix = torch.stack(columns, dim=2)
        else:
            left = inner_sign * self(node.left)
            mask = torch.ones(length, length, dtype=torch.bool).triu(1)  # t'' < t'
            matrix = torch.where(mask, left[:, :, None], torch.tensor(-_INF, dtype=torch.float64))
        chunk = max(1, _MAX_QUADRATIC_ELEMENTS // (length * length))
        outputs = []
        valid = torch.ones(length, length, dtype=torch.bool).triu(0)  # t' ≥ t
        for start in range(0, self.n, chunk):
            block = matrix[start : start + chunk]
            # inner[n, t, t'] = sign·lse over t'' in [t, t') (suffix along t'')
            # (where t ≥ t' every entry is -∞, so inner is the empty value ∓∞ there)
            inner = inner_sign * _suffix_lse(block, 1)
            terms = _smin2(right[start : start + chunk, None, :], inner)
            terms = torch.where(valid, terms, torch.tensor(-_INF, dtype=torch.float64))
            outputs.append(_lse(terms, 2))
        out = torch.cat(outputs, dim=0)
        return out[:, :1] if first_only else out


_RULES = {
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


def _to_rho(z: Any, beta: float) -> Any:
    torch = _torch()
    inf = torch.tensor(math.inf, dtype=torch.float64)
    big = z.detach().abs() >= _INF / 2
    return torch.where(big, torch.where(z.detach() > 0, inf, -inf), z / beta)


FORMS = ("nested", "linear")


def _smoother(formula: Formula, trace: Trace, beta: float, rho_max: float, form: str) -> tuple[_Smoother, Any]:
    if isinstance(beta, bool) or not (isinstance(beta, (int, float)) and math.isfinite(beta) and beta > 0):
        raise ValueError(f"beta must be a positive finite number, got {beta!r}")
    if not rho_max > 0:
        raise ValueError(f"rho_max must be positive, got {rho_max!r}")
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    torch = _torch()
    prepared = prepare(formula.signals, trace, torch_ok=True)
    signals = {k: v if is_torch(v) else torch.as_tensor(v, dtype=torch.float64) for k, v in prepared.signals.items()}
    top = min(beta * rho_max, _INF) if math.isfinite(rho_max) else _INF
    return _Smoother(signals, prepared.n, prepared.length, float(beta), top, form), prepared


def smooth_over_time(
    formula: Formula, trace: Trace, beta: float, rho_max: float = math.inf, form: str = "nested"
) -> Any:
    """Smoothed robustness at every position, as a torch tensor ``(T,)`` or ``(N, T)``."""
    smoother, prepared = _smoother(formula, trace, beta, rho_max, form)
    rho = _to_rho(smoother(formula), beta)
    return rho if prepared.batched else rho[0]


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
    smoother, prepared = _smoother(formula, trace, beta, rho_max, form)
    torch = smoother.torch
    use_torch = any(is_torch(trace[k]) for k in prepared.signals)
    with torch.set_grad_enabled(use_torch and torch.is_grad_enabled()):
        rho = _to_rho(smoother(formula, first_only=True)[:, 0], beta)
    if use_torch:
        return rho if prepared.batched else rho[0]
    values = rho.detach().cpu().numpy()
    return values.copy() if prepared.batched else float(values[0])
