"""Validation of the traces handed to the evaluators.

A trace maps signal names to arrays of shape ``(T,)`` (one trajectory) or
``(N, T)`` (a batch). Checks happen once, before evaluation, and every error names
its culprit: the missing signal, or the signal, trajectory and position of the
first NaN or inf.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from tl_gym.checks import check_positive
from tl_gym.errors import TraceError, UnknownSignalError

Trace = Mapping[str, Union[np.ndarray, Sequence[float], Any]]

# The evaluators work through a batch in groups of trajectories of about this many values each
# (1 MiB per float64 array): a group's temporaries stay in cache and their memory is reused,
# where whole-batch temporaries page-fault fresh memory at every node of the formula.
# Measured at N = 10,000, T = 200 in docs/speed.md ("Chunks of trajectories").
CHUNK_ELEMENTS = 1 << 17
MIN_CHUNK_ROWS = 16


def chunks(n: int, length: int) -> list[slice]:
    """Consecutive groups of the ``n`` trajectories, about `CHUNK_ELEMENTS` values each."""
    rows = max(MIN_CHUNK_ROWS, CHUNK_ELEMENTS // max(length, 1))
    return [slice(start, min(start + rows, n)) for start in range(0, n, rows)] or [slice(0, 0)]


#: The evaluators' backends: numpy's plan, numba's compiled kernel, or the first until the second pays.
BACKENDS = ("auto", "numpy", "numba")


def check_backend(backend: Any) -> str:
    """A backend name, checked (`BACKENDS`)."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    return backend


def check_beta(beta: Any) -> float:
    """The smoothing's β, checked: a finite real number > 0 (numpy's scalars too); booleans are refused."""
    return check_positive("beta", beta)


def check_rho_max(rho_max: Any) -> float:
    """The value of ``true``, checked: a real number > 0 (+inf allowed); NaN and booleans are refused.

    numpy's scalars count as real numbers (``np.float32(100)`` from a config array is accepted).
    """
    return check_positive("rho_max", rho_max, allow_inf=True)


def is_torch(value: Any) -> bool:
    """Whether ``value`` is a torch tensor, without importing torch."""
    return type(value).__module__.startswith("torch")


def _magnitude(low: float, high: float) -> float:
    """The largest |x| from the extremes (two passes, no |x| copy); NaN if either is NaN."""
    biggest = max(abs(low), abs(high))
    return biggest if low == low and high == high else math.nan


def _first_bad(name: str, finite: np.ndarray, batched: bool) -> TraceError:
    bad = np.argwhere(~finite)[0]
    if batched:
        where = f"trajectory {bad[0]}, position {bad[1]}"
    else:
        where = f"position {bad[0]}"
    return TraceError(f"signal {name!r} is NaN or infinite at {where}")


@dataclass(frozen=True)
class Prepared:
    """Checked signals, each of shape ``(N, T)``, and whether the caller passed a batch."""

    signals: dict[str, Any]
    n: int
    length: int
    batched: bool
    magnitudes: dict[str, float]  # max |value| of each signal: lets evaluators skip overflow checks


def prepare(names: tuple[str, ...], trace: Trace, *, torch_ok: bool = False) -> Prepared:
    """Check the signals a formula reads and return them as ``(N, T)`` arrays.

    The arrays are float64 numpy arrays, or the caller's torch tensors when
    ``torch_ok`` and the trace holds tensors.
    """
    if not isinstance(trace, Mapping):
        raise TypeError(f"a trace maps signal names to arrays, got {type(trace).__name__}")
    missing = [n for n in names if n not in trace]
    if missing:
        available = ", ".join(sorted(map(str, trace))) or "none"
        raise UnknownSignalError(
            f"the trace has no signal {missing[0]!r}, which the formula reads (trace has: {available})"
        )
    out: dict[str, Any] = {}
    magnitudes: dict[str, float] = {}
    shape: tuple[int, ...] | None = None
    first = names[0] if names else None
    for name in names:
        value = trace[name]
        if torch_ok and is_torch(value):
            array = value
            low, high = value.detach().aminmax() if value.numel() else (0.0, 0.0)
            magnitude = _magnitude(float(low), float(high))
        else:
            if is_torch(value):  # numpy refuses a tensor that requires grad or lives on a GPU
                value = value.detach().cpu()
            try:
                array = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise TraceError(f"signal {name!r} is not numeric: {exc}") from None
            magnitude = _magnitude(float(array.min()), float(array.max())) if array.size else 0.0
        if array.ndim not in (1, 2) or array.shape[-1] == 0:
            raise TraceError(
                f"signal {name!r} has shape {tuple(array.shape)}; expected (T,) or (N, T) with T >= 1"
            )
        if shape is None:
            shape = tuple(array.shape)
        elif tuple(array.shape) != shape:
            raise TraceError(
                f"signal {name!r} has shape {tuple(array.shape)} but {first!r} has {shape}; "
                "all signals of a trace share one shape"
            )
        if not np.isfinite(magnitude):  # a NaN or inf anywhere makes the max non-finite
            finite = value.detach().isfinite().cpu().numpy() if is_torch(array) else np.isfinite(array)
            raise _first_bad(name, finite, array.ndim == 2)
        magnitudes[name] = magnitude
        out[name] = array if array.ndim == 2 else array[None, :]
    if shape is None:  # the formula reads no signal: take the length from the trace
        shapes = [tuple(np.shape(v)) for v in trace.values()]
        shapes = [s for s in shapes if len(s) in (1, 2) and s[-1] > 0]
        if not shapes:
            raise TraceError("the formula reads no signal, so the trace must hold an array that gives its length")
        shape = shapes[0]
    return Prepared(out, shape[0] if len(shape) == 2 else 1, shape[-1], len(shape) == 2, magnitudes)
