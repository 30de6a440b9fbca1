"""Checks of user-given numbers, written once for the wrapper, the envs and the agents.

Each raises a ``ValueError`` that names the argument and shows the value it got, at
construction, before anything is built.

Example:
    >>> check_positive("beta", 9)
    9.0
    >>> check_positive("clip", float("inf"))
    Traceback (most recent call last):
      ...
    ValueError: clip must be a finite number > 0, got inf
"""

from __future__ import annotations

import math
import numbers
from typing import Any


def check_positive(name: str, value: Any, *, allow_inf: bool = False, allow_zero: bool = False) -> float:
    """``value`` as a float if it is a real number > 0 (>= 0 with ``allow_zero``), finite unless ``allow_inf``.

    Booleans are refused (``True`` is not a step size). The message names ``name``.
    """
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and not math.isnan(value)
    ok = ok and (value >= 0 if allow_zero else value > 0) and (allow_inf or math.isfinite(value))
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        kind = "a number" if allow_inf else "a finite number"
        raise ValueError(f"{name} must be {kind} {bound}{' (inf allowed)' if allow_inf else ''}, got {value!r}")
    return float(value)
