"""Log-sum-exp primitives with hand-derived gradients, in numpy.

These are the only operations the smoothed robustness needs. Inputs are finite
(±1e300 stands for ±∞, see `tl_gym.tltl.smooth`), so every exponent below is of a
difference that is ≤ 0 or bounded by the log of the upstream gradient: values and
gradients stay finite for any β.

Scans run along axis 0 (time, in the smoother's time-major layout).
"""

from __future__ import annotations

import numpy as np

# exp() of arguments below about -745 underflows through a path several times slower than
# the normal one; these terms weigh less than 1e-304 relative to the largest, so clip them there.
_EXP_FLOOR = -700.0


_floor = np.full(0, _EXP_FLOOR)  # grown on demand; `np.maximum` against an array is twice as fast as against a scalar


def _floor_like(x: np.ndarray) -> np.ndarray:
    global _floor
    if _floor.size < x.size:
        _floor = np.full(x.size, _EXP_FLOOR)
    return _floor[: x.size].reshape(x.shape)


def _exp_floored(x: np.ndarray) -> np.ndarray:
    """``exp(x)`` in place, arguments clipped below at ``_EXP_FLOOR``."""
    if x.flags.c_contiguous:
        np.maximum(x, _floor_like(x), out=x)
    elif x.flags.f_contiguous:
        np.maximum(x, _floor_like(x.T).T, out=x)
    else:
        np.maximum(x, _EXP_FLOOR, out=x)
    return np.exp(x, out=x)


def reduce_forward(z: np.ndarray, axis: int, sign: float = 1.0, spare: bool = False,
                   divisor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``sign·log Σ exp(sign·z)`` along ``axis`` (removed): smooth max (sign 1) or min (sign -1).

    Also returns the softmax, kept unnormalised: ``exps = exp(sign·(z − extreme))`` and
    ``total``, their sum (``axis`` kept). The weights ``exps / total`` are the whole gradient
    (`reduce_backward`, the same for both signs), and dividing the small upstream gradient by
    ``total`` is cheaper than normalising every weight. ``spare``: ``z`` is needed no more,
    so ``exps`` may take its memory.

    ``divisor`` (shaped as ``z``, values in [1, n]): reduce ``z − log(divisor)`` instead, shifted by the
    extreme of ``z``; for the max of a smooth min (or the min of a smooth max), whose terms are
    ``peak ∓ log(total)``, this skips the logarithm.
    """
    peak = z.max(axis=axis, keepdims=True) if sign > 0 else z.min(axis=axis, keepdims=True)
    into = z if spare else None
    exps = np.subtract(z, peak, out=into) if sign > 0 else np.subtract(peak, z, out=into)
    _exp_floored(exps)
    if divisor is not None:
        np.divide(exps, divisor, out=exps)
    total = exps.sum(axis=axis, keepdims=True)
    return (peak + sign * np.log(total)).squeeze(axis), exps, total


def reduce_backward(exps: np.ndarray, total: np.ndarray, grad: np.ndarray, axis: int) -> np.ndarray:
    """Gradient of `reduce_forward` wrt ``z``: the softmax weights times the upstream gradient."""
    return (np.expand_dims(grad, axis) / total) * exps


def reduce_operands(operands: list[np.ndarray], sign: float, spare: list[bool] | None = None,
                    value: bool = True) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """``sign·log Σ_i exp(sign·operands[i])``: smooth max (sign 1) or min (sign -1), and its softmax.

    The softmax is kept unnormalised: each operand's ``exp(sign·(operand − extreme))`` and their sum.
    ``spare[i]``: operand i is needed no more, so its weights may take its memory.
    ``value=False``: return the elementwise extreme instead of the value (``extreme + sign·log(total)``).

    The same value as `reduce_forward` over the stacked operands, without building the
    stack (one full copy of every operand) or negating it: the shift is the elementwise
    extreme, and ``sign·(operand − extreme)`` is one subtraction per operand.
    """
    pick = np.maximum if sign > 0 else np.minimum
    peak = pick(operands[0], operands[1])
    for operand in operands[2:]:
        pick(peak, operand, out=peak)
    exps = []
    for i, operand in enumerate(operands):
        into = operand if spare is not None and spare[i] and operand.shape == peak.shape else None
        e = np.subtract(operand, peak, out=into) if sign > 0 else np.subtract(peak, operand, out=into)
        exps.append(_exp_floored(e))
    total = exps[0] + exps[1]
    for e in exps[2:]:
        total += e
    if not value:
        return peak, exps, total
    out = np.log(total)
    return (np.add(peak, out, out=out) if sign > 0 else np.subtract(peak, out, out=out)), exps, total


def logaddexp_backward(
    a: np.ndarray, b: np.ndarray, out: np.ndarray, grad: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of ``out = logaddexp(a, b)`` wrt ``a`` and ``b``."""
    return grad * np.exp(a - out), grad * np.exp(b - out)


def prefix_forward(z: np.ndarray) -> np.ndarray:
    """``out[t] = log Σ_{s ≤ t} exp(z[s])`` along axis 0."""
    return np.logaddexp.accumulate(z, axis=0)


def prefix_backward(z: np.ndarray, out: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Gradient of `prefix_forward`: ``gz[s] = Σ_{t ≥ s} grad[t] · exp(z[s] − out[t])``.

    The sum over t is a suffix sum of ``grad[t]·exp(−out[t])``, done in log space with
    the positive and negative parts of ``grad`` apart, so nothing overflows.
    """
    with np.errstate(divide="ignore"):
        log_pos = np.log(np.maximum(grad, 0.0)) - out
        log_neg = np.log(np.maximum(-grad, 0.0)) - out
    suffix_pos = np.logaddexp.accumulate(log_pos[::-1], axis=0)[::-1]
    suffix_neg = np.logaddexp.accumulate(log_neg[::-1], axis=0)[::-1]
    return _exp_floored(z + suffix_pos) - _exp_floored(z + suffix_neg)


def suffix_forward(z: np.ndarray) -> np.ndarray:
    """``out[t] = log Σ_{s ≥ t} exp(z[s])`` along axis 0."""
    return np.ascontiguousarray(prefix_forward(z[::-1])[::-1])


def suffix_backward(z: np.ndarray, out: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Gradient of `suffix_forward` (the mirror image of `prefix_backward`)."""
    return np.ascontiguousarray(prefix_backward(z[::-1], out[::-1], grad[::-1])[::-1])
