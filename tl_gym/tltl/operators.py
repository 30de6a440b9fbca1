"""What every TLTL operator means, in every mode, each written once.

This is the executable definition the evaluators are derived from (`docs/engine.md`
links here; ``tests/reference.py`` is the independent naive check). For each operator:

* **exact** — its robustness (or Boolean value) at every position, from its operands'
  values at every position: arrays of shape ``(N, T)``, entry ``[i, t]`` judging
  trajectory i from position t on. One function serves robustness and the Boolean
  semantics through a `Lattice`.
* **smooth** — its log-sum-exp smoothing in β-scaled units (``z = β·ρ``, ±∞ stored as
  ±`INF`), on time-major arrays ``(T, N)``, with its derivative: a forward function
  returns ``(value, backward)`` and ``backward(g)`` the gradients wrt the operands.
  Rules may overwrite ``g`` (the caller hands over an array it owns) and an operand
  whose ``spare`` flag is set (nothing else reads it); they must return fresh arrays.
* **bracket** — Lemma 1: how far the smoothing can err, from the operands' brackets.
* **online** — how the value at position 0 of a growing prefix changes when one state
  is appended (scalars; the monitor's nodes, `tl_gym.tltl.online_nodes`, are built from these).

The compiler (`tl_gym.tltl.plan`) turns a formula into a flat list of these
operations; the evaluators' optimisations are rewrites of that list.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tl_gym.tltl import ast as nodes
from tl_gym.tltl import lse
from tl_gym.tltl.ast import Formula

INF = 1e300  # stands for +∞ in β-scaled units
#: From here on a β-scaled value cannot be told from ±∞: the smoothers refuse or read it as ±∞.
SMOOTH_LIMIT = INF / 2
Backward = Callable[[np.ndarray], Sequence[Any]]
Smoothed = tuple[np.ndarray, Backward]

# --------------------------------------------------------------------------- predicates

# The margin of ``lhs ⋈ rhs`` is SIGN[⋈] · (lhs − rhs): ``a < b`` and ``a <= b`` have robustness
# b − a, ``a > b`` and ``a >= b`` have a − b. They differ only in the Boolean semantics.
SIGN = {"<": -1.0, "<=": -1.0, ">": 1.0, ">=": 1.0}
STRICT = {"<": True, ">": True, "<=": False, ">=": False}


def margin(op: str, lhs: Any, rhs: Any) -> Any:
    """The robustness of ``lhs op rhs`` from its two sides (arrays or floats)."""
    return lhs - rhs if SIGN[op] > 0 else rhs - lhs


def margin_source(op: str, lhs: str, rhs: str) -> str:
    """`margin` as a Python expression over the two sides' expressions (for code written out; tested equal)."""
    return f"({lhs} - {rhs})" if SIGN[op] > 0 else f"({rhs} - {lhs})"


def holds(op: str, value: Any) -> Any:
    """The Boolean value of a predicate from its margin: strict comparisons need a margin > 0.

    For finite doubles a < b exactly when b − a > 0 (subtraction is exact at 0).
    """
    return value > 0 if STRICT[op] else value >= 0


# --------------------------------------------------------------------------- lattices


@dataclass(frozen=True)
class Lattice:
    """What an exact evaluation computes in: reals with max/min, or Booleans with or/and."""

    top: Any  # the value of ``true`` (ρ_max), and minus that of ``false`` and of ``X φ`` at the end
    bottom: Any
    dtype: Any
    maximum: np.ufunc
    minimum: np.ufunc
    negate: np.ufunc
    boolean: bool
    empty_max: Any  # a max over no terms (−inf / False)
    empty_min: Any  # a min over no terms (+inf / True)


def numeric(rho_max: float) -> Lattice:
    """Robustness: max/min over reals, ``true`` = ρ_max (> 0, +inf allowed)."""
    return Lattice(float(rho_max), -float(rho_max), np.float64, np.maximum, np.minimum, np.negative, False,
                   -math.inf, math.inf)


BOOLEAN = Lattice(True, False, bool, np.logical_or, np.logical_and, np.logical_not, True, False, True)


def suffix(ufunc: np.ufunc, values: np.ndarray, axis: int = 1) -> np.ndarray:
    """``out[t] = ufunc`` over ``values[t:]`` along ``axis``: a suffix scan over time."""
    flipped = np.flip(values, axis)
    return np.flip(ufunc.accumulate(flipped, axis=axis), axis)


# --------------------------------------------------------------------------- exact semantics, every position
# Each takes the lattice and its operands' (N, T) values and returns the node's (N, T) values.
# Operands are shared: rules never modify them.


def exact_not(alg: Lattice, phi: np.ndarray) -> np.ndarray:
    """ρ(!φ, t) = −ρ(φ, t)."""
    return alg.negate(phi)


def exact_and(alg: Lattice, *operands: np.ndarray) -> np.ndarray:
    """ρ(φ1 & … & φn, t) = min_i ρ(φi, t): one n-ary min, whatever the parentheses."""
    out = alg.minimum(operands[0], operands[1])
    for operand in operands[2:]:
        alg.minimum(out, operand, out=out)
    return out


def exact_or(alg: Lattice, *operands: np.ndarray) -> np.ndarray:
    """ρ(φ1 | … | φn, t) = max_i ρ(φi, t)."""
    out = alg.maximum(operands[0], operands[1])
    for operand in operands[2:]:
        alg.maximum(out, operand, out=out)
    return out


def exact_implies(alg: Lattice, phi: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """ρ(φ -> ψ, t) = max(−ρ(φ, t), ρ(ψ, t))."""
    return alg.maximum(alg.negate(phi), psi)


def exact_next(alg: Lattice, phi: np.ndarray) -> np.ndarray:
    """ρ(X φ, t) = ρ(φ, t+1), and −ρ_max at the last state (the paper's "k > 0" fails)."""
    out = np.empty_like(phi)
    out[:, :-1] = phi[:, 1:]
    out[:, -1] = alg.bottom
    return out


def exact_eventually(alg: Lattice, phi: np.ndarray) -> np.ndarray:
    """ρ(F φ, t) = max over t' ≥ t of ρ(φ, t')."""
    return suffix(alg.maximum, phi)


def exact_always(alg: Lattice, phi: np.ndarray) -> np.ndarray:
    """ρ(G φ, t) = min over t' ≥ t of ρ(φ, t')."""
    return suffix(alg.minimum, phi)


def exact_until(alg: Lattice, phi: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """ρ(φ U ψ, t) = max_{t' ≥ t} min(ρ(ψ, t'), min_{t'' ∈ [t, t')} ρ(φ, t'')), φ temporal-free.

    Equivalently ``U(t) = max(ψ(t), min(φ(t), U(t+1)))``. Each position is the map
    ``x ↦ max(A, min(B, x))`` with ``(A, B) = (ψ(t), φ(t))``; such maps compose associatively,
    ``(A1, B1)∘(A2, B2) = (max(A1, min(B1, A2)), min(B1, B2))``, so a doubling suffix scan needs
    log2(T) whole-array steps. With many short trajectories a loop over time (each step vectorised
    over N) is cheaper.
    """
    n, length = psi.shape
    if length <= 1:
        return psi.copy()
    if n * math.ceil(math.log2(length)) > 2 * n + 3000:  # the loop's per-step overhead is worth ~3000 elements
        out = psi.copy()
        for t in range(length - 2, -1, -1):
            out[:, t] = alg.maximum(psi[:, t], alg.minimum(phi[:, t], out[:, t + 1]))
        return out
    a, b = psi.copy(), phi.copy()
    shift = 1
    while shift < length:
        new_a = alg.maximum(a[:, :-shift], alg.minimum(b[:, :-shift], a[:, shift:]))
        b[:, :-shift] = alg.minimum(b[:, :-shift], b[:, shift:])
        a[:, :-shift] = new_a
        shift *= 2
    return a


def exact_then(alg: Lattice, phi: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """ρ(φ T ψ, t) = max_{t' ≥ t} min(ρ(ψ, t'), max_{t'' ∈ [t, t')} ρ(φ, t'')), φ temporal-free.

    Equivalently max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')): two suffix scans.
    """
    later = np.empty_like(psi)
    later[:, -1] = alg.empty_max
    later[:, :-1] = suffix(alg.maximum, psi)[:, 1:]
    return suffix(alg.maximum, alg.minimum(phi, later))


def exact_on_segments(alg: Lattice, node: nodes.Until | nodes.Then, left_on_prefix: Callable[[int], np.ndarray],
                      psi: np.ndarray) -> np.ndarray:
    """U / T whose left operand φ is temporal: φ is judged on each segment s_{t''..t'-1}.

    ``left_on_prefix(k)`` gives φ at every position of the truncated trace s_0 … s_{k-1}.
    O(N·T²) time, O(N·T) memory.
    """
    inner, inner_empty = (alg.minimum, alg.empty_min) if isinstance(node, nodes.Until) else (alg.maximum, alg.empty_max)
    n, length = psi.shape
    out = np.full((n, length), alg.empty_max, dtype=alg.dtype)
    for t_prime in range(length):
        # reduced[t] = inner reduction of φ(s_{t''..t'-1}) over t'' in [t, t'); empty at t = t'
        reduced = np.full((n, t_prime + 1), inner_empty, dtype=alg.dtype)
        if t_prime > 0:
            reduced[:, :t_prime] = suffix(inner, left_on_prefix(t_prime))
        term = alg.minimum(psi[:, t_prime : t_prime + 1], reduced)
        out[:, : t_prime + 1] = alg.maximum(out[:, : t_prime + 1], term)
    return out


EXACT: dict[type, Callable[..., np.ndarray]] = {
    nodes.Not: exact_not, nodes.And: exact_and, nodes.Or: exact_or, nodes.Implies: exact_implies,
    nodes.Next: exact_next, nodes.Eventually: exact_eventually, nodes.Always: exact_always,
    nodes.Until: exact_until, nodes.Then: exact_then,
}


# --------------------------------------------------------------------------- smoothed semantics, with derivatives
# β-scaled time-major values (T, N). Every max becomes lse(z) = log Σ exp(z), every min −lse(−z).
# ``spare[i]``: operand i is read by nothing else and may be overwritten.


def smin2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smooth minimum of two terms, −log(exp(−a) + exp(−b))."""
    return -np.logaddexp(-a, -b)


def smin2_backward(a: np.ndarray, b: np.ndarray, out: np.ndarray, grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of `smin2` wrt ``a`` and ``b``."""
    return grad * np.exp(out - a), grad * np.exp(out - b)


def smooth_not(phi: np.ndarray, spare: Sequence[bool] = ()) -> Smoothed:
    """−z, derivative −1."""
    return -phi, lambda g: (np.negative(g, out=g),)


def smooth_nary(operands: Sequence[np.ndarray], sign: float, spare: Sequence[bool] = ()) -> Smoothed:
    """``sign·lse(sign·z_i)``: the smooth max (``|``, sign 1) or min (``&``, sign −1) of the operands.

    The derivative wrt operand i is its softmax weight exp(sign·(z_i − extreme)) / total.
    """
    out, exps, total = lse.reduce_operands(list(operands), sign, list(spare) or None)

    def backward(g: np.ndarray) -> list[np.ndarray]:
        scale = np.divide(g, total, out=g)
        return [scale * e for e in exps]

    return out, backward


def smooth_and(*operands: np.ndarray, spare: Sequence[bool] = ()) -> Smoothed:
    """The smooth min of the operands."""
    return smooth_nary(operands, -1.0, spare)


def smooth_or(*operands: np.ndarray, spare: Sequence[bool] = ()) -> Smoothed:
    """The smooth max of the operands."""
    return smooth_nary(operands, 1.0, spare)


def smooth_implies(phi: np.ndarray, psi: np.ndarray, spare: Sequence[bool] = ()) -> Smoothed:
    """lse(−z_φ, z_ψ): the smooth max of ¬φ and ψ."""
    neg_phi = -phi
    out = np.logaddexp(neg_phi, psi)

    def backward(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g_left, g_right = lse.logaddexp_backward(neg_phi, psi, out, g)
        return np.negative(g_left, out=g_left), g_right

    return out, backward


def smooth_next(phi: np.ndarray, top: float) -> Smoothed:
    """z_φ one position later; −ρ_max (β units) at the last state."""
    out = np.concatenate([phi[1:], np.full((1, phi.shape[1]), -top)])

    def backward(g: np.ndarray) -> tuple[np.ndarray]:
        g_child = np.zeros_like(phi)
        g_child[1:] = g[:-1]
        return (g_child,)

    return out, backward


def smooth_over_time(phi: np.ndarray, sign: float) -> Smoothed:
    """F (sign 1): lse of z_φ over t' ≥ t; G (sign −1): −lse(−z_φ) over t' ≥ t."""
    child = phi * sign
    out = lse.suffix_forward(child)

    def backward(g: np.ndarray) -> tuple[np.ndarray]:
        g_child = lse.suffix_backward(child, out, np.multiply(g, sign, out=g))
        return (np.multiply(g_child, sign, out=g_child),)

    return out * sign, backward


def smooth_binary(phi: np.ndarray, psi: np.ndarray, sign: float, chunk_elements: int = 1 << 22) -> Smoothed:
    """U (sign −1) and T (sign 1) at every position, the prescribed nesting, φ temporal-free.

    ``lse_{t' ≥ t} smin(ψ(t'), sign·lse_{t'' ∈ [t, t')} sign·φ(t''))``. O(N·T²), in chunks of
    trajectories of at most ``chunk_elements`` T² values; the backward pass recomputes each chunk.
    """
    left = sign * phi
    length, n = psi.shape
    chunk = max(1, chunk_elements // (length * length))
    parts = [slice(s, s + chunk) for s in range(0, n, chunk)]
    out = np.concatenate([_quadratic(left[:, p], psi[:, p], sign)[0] for p in parts], axis=1)

    def backward(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g_left, g_right = np.zeros_like(left), np.zeros_like(psi)
        for p in parts:
            _, (g_left[:, p], g_right[:, p]) = _quadratic(left[:, p], psi[:, p], sign, g[:, p])
        return np.multiply(g_left, sign, out=g_left), g_right

    return out, backward


def smooth_then_linear(phi: np.ndarray, psi: np.ndarray) -> Smoothed:
    """``form="linear"``: ρ(φ T ψ, t) = max_{s ≥ t} min(φ(s), max_{t' > s} ψ(t')), smoothed: O(N·T).

    A different smoothing of the same exact value, with the same Lemma 1 bracket.
    """
    right_suffix = lse.suffix_forward(psi)
    later = np.concatenate([right_suffix[1:], np.full((1, psi.shape[1]), -INF)])
    inner = smin2(phi, later)
    out = lse.suffix_forward(inner)

    def backward(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g_inner = lse.suffix_backward(inner, out, g)
        g_left, g_later = smin2_backward(phi, later, inner, g_inner)
        g_suffix = np.zeros_like(right_suffix)
        g_suffix[1:] = g_later[:-1]
        return g_left, lse.suffix_backward(psi, right_suffix, g_suffix)

    return out, backward


def smooth_on_segments(matrix: np.ndarray, psi: np.ndarray, sign: float) -> Smoothed:
    """U / T with a temporal left operand: ``matrix[t'', t']`` holds sign·φ(t'') judged on s_{..t'-1}.

    The backward pass returns the gradients wrt ``matrix`` and ``ψ``.
    """
    out, _ = _quadratic_from_matrix(matrix, psi, sign)

    def backward(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g_full = np.zeros(psi.shape)
        g_full[: len(g)] = g
        _, grads = _quadratic_from_matrix(matrix, psi, sign, g_full)
        return grads  # type: ignore[return-value]

    return out, backward


def _quadratic(left: np.ndarray, right: np.ndarray, sign: float,
               grad: np.ndarray | None = None) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Nested U/T at every position for a temporal-free (sign-scaled) left operand."""
    length = left.shape[0]
    below = np.tri(length, length, -1, dtype=bool).T[:, :, None]  # [t'', t'] where t'' < t'
    matrix = np.where(below, left[:, None, :], -INF)
    out, grads = _quadratic_from_matrix(matrix, right, sign, grad)
    if grads is None:
        return out, None
    g_matrix, g_right = grads
    return out, ((g_matrix * below).sum(axis=1), g_right)


def _quadratic_from_matrix(matrix: np.ndarray, right: np.ndarray, sign: float, grad: np.ndarray | None = None
                           ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """``out[t] = lse_{t' ≥ t} smin(ψ(t'), sign·lse_{t'' ∈ [t, t')} matrix[t'', t'])``.

    ``matrix[t'', t', n]`` is −∞ where t'' ≥ t'. With ``grad`` also the gradients wrt ``matrix`` and ``right``.
    """
    length = matrix.shape[0]
    suffix_lse = lse.suffix_forward(matrix)  # [t, t'] = lse over t'' ≥ t (entries t'' ≥ t' are -∞)
    inner = sign * suffix_lse
    later = np.tri(length, length, -1, dtype=bool)[:, :, None]  # [t, t'] where t' < t: excluded
    terms = np.where(later, -INF, smin2(right[None], inner))
    out, exps, total = lse.reduce_forward(terms, 1)
    if grad is None:
        return out, None
    g_terms = np.where(later, 0.0, lse.reduce_backward(exps, total, grad, 1))
    g_right, g_inner = smin2_backward(right[None], inner, terms, g_terms)
    g_matrix = lse.suffix_backward(matrix, suffix_lse, sign * g_inner)
    return out, (g_matrix, g_right.sum(axis=0))


# --------------------------------------------------------------------------- Lemma 1: the smoothing bracket
# In units of 1/β: ``(below, above)`` with ρ − below ≤ ρ̂ ≤ ρ + above. An lse over n terms
# overestimates a max by at most log n and a −lse(−·) underestimates a min by at most log n;
# operands' errors pass through max/min and swap sides under negation.


def bracket(node: Formula, parts: list[tuple[float, float]], horizon: int) -> tuple[float, float]:
    """A node's bracket from its operands' brackets ``parts``, for traces of length ``horizon``."""
    log_t = math.log(horizon)
    if isinstance(node, (nodes.Constant, nodes.Predicate)):
        return 0.0, 0.0
    if isinstance(node, nodes.Not):
        return parts[0][1], parts[0][0]
    if isinstance(node, nodes.Next):
        return parts[0]
    if isinstance(node, (nodes.And, nodes.Or, nodes.Implies)):
        if isinstance(node, nodes.Implies):
            parts[0] = parts[0][::-1]  # max(-φ, ψ): φ's error is negated
        below, above = max(p[0] for p in parts), max(p[1] for p in parts)
        grow = math.log(len(parts))
        return (below + grow, above) if isinstance(node, nodes.And) else (below, above + grow)
    if isinstance(node, nodes.Eventually):
        return parts[0][0], parts[0][1] + log_t
    if isinstance(node, nodes.Always):
        return parts[0][0] + log_t, parts[0][1]
    if isinstance(node, (nodes.Until, nodes.Then)):
        (left_below, left_above), (right_below, right_above) = parts
        inner_terms = math.log(max(horizon - 1, 1))
        # the inner smin (U) or smax (T) over t'', then smin with ψ (two terms), then smax over t'
        inner = (left_below + inner_terms, left_above) if isinstance(node, nodes.Until) else (
            left_below, left_above + inner_terms)
        return max(right_below, inner[0]) + math.log(2), max(right_above, inner[1]) + log_t
    raise TypeError(f"no bracket rule for formula node {type(node).__name__}")


# --------------------------------------------------------------------------- online: one more state
# ρ at position 0 of the prefix s_0 … s_t, from the value before s_t and what s_t brings.


CONNECTIVES: dict[type, Callable[[Sequence[float]], float]] = {  # the exact rules at one position, on floats
    nodes.Not: lambda v: -v[0],
    nodes.And: min,
    nodes.Or: max,
    nodes.Implies: lambda v: max(-v[0], v[1]),
}


def connective_source(kind: type, parts: Sequence[str]) -> str:
    """`CONNECTIVES` ``[kind]`` as a Python expression over its operands' expressions ``parts``.

    For code written out at construction (`tl_gym.tltl.codegen`): the same operations on the
    same floats (tested against `CONNECTIVES`).
    """
    if kind is nodes.Not:
        return f"(-{parts[0]})"
    if kind is nodes.Implies:
        return f"max(-{parts[0]}, {parts[1]})"
    if len(parts) == 1:  # an n-ary node of one operand: min/max of one float is that float
        return parts[0]
    return f"{'min' if kind is nodes.And else 'max'}({', '.join(parts)})"


def online_extremum(best: Any, new: Any, largest: bool, maximum: Callable = max, minimum: Callable = min) -> Any:
    """F (largest) / G: the running max / min of φ over the positions seen.

    The online rules take floats, or arrays of n traces updated together with ``maximum=np.maximum,
    minimum=np.minimum`` (`tl_gym.tltl.online_batch`).
    """
    return maximum(best, new) if largest else minimum(best, new)


def online_until(left_so_far: Any, best: Any, phi: Any, psi: Any, maximum: Callable = max,
                 minimum: Callable = min) -> tuple[Any, Any]:
    """φ U ψ, temporal-free operands: ``(min of φ over the earlier positions, best so far)``.

    The new position t' brings the term min(ψ(t'), min_{t'' < t'} φ(t'')).
    """
    return minimum(left_so_far, phi), maximum(best, minimum(psi, left_so_far))


def online_then_chain(best: list, value: Callable[[int], Any], maximum: Callable = max,
                      minimum: Callable = min) -> None:
    """φ1 T (φ2 T (… T φm)), temporal-free operands = max over s1 < … < sm of min(φ1(s1), …, φm(sm)).

    ``best[i]`` is that max for the first i+1 operands, updated in place, the last first, each from
    the previous one's value before this state; ``value(i)`` is φ_{i+1} at the new state.
    """
    for i in range(len(best) - 1, 0, -1):
        best[i] = maximum(best[i], minimum(best[i - 1], value(i)))
    best[0] = maximum(best[0], value(0))


def online_never_again(final: Any, min_a: Any, b_new: Any, settled: tuple[Any, Any] | None,
                       maximum: Callable = max, minimum: Callable = min) -> tuple[Any, Any]:
    """G(A | X G B), B temporal-free: ``(final, min_a)`` after a state whose B is ``b_new``.

    ``final`` is min over the final positions k of max(A_k, M_k), M_k the min of B after k, and
    ``min_a`` the min of their A_k. The new state lowers every M_k to min(M_k, c), c = ``b_new``, and
    min_k max(A_k, min(M_k, c)) = min(min_k max(A_k, M_k), max(min_k A_k, c)). ``settled`` is
    ``(A_k, M_k)`` of the position k that this state made final, if any.
    """
    final = minimum(final, maximum(min_a, b_new))
    if settled is not None:
        final = minimum(final, maximum(*settled))
        min_a = minimum(min_a, settled[0])
    return final, min_a
