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

import difflib
import math
import numbers
from collections.abc import Iterable
from typing import Any, overload


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


def check_finite(name: str, value: Any) -> float:
    """``value`` as a float if it is a finite real number (not a bool); the message names ``name``.

    Example:
        >>> check_finite("threshold", -2)
        -2.0
    """
    if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


@overload
def check_count(name: str, value: Any) -> int: ...
@overload
def check_count(name: str, value: Any, *, allow_none: bool) -> int | None: ...
def check_count(name: str, value: Any, *, allow_none: bool = False) -> int | None:
    """``value`` as an int if it is an integer >= 1 (a count: steps, episodes, envs, a period); not a bool.

    With ``allow_none``, None passes through (a count the env or a default supplies).

    Example:
        >>> check_count("every", 5), check_count("horizon", None, allow_none=True)
        (5, None)
    """
    if value is None and allow_none:
        return None
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < 1:
        raise ValueError(f"{name} must be an int >= 1{' or None' if allow_none else ''}, got {value!r}")
    return int(value)


def check_floats(name: str, value: Any, size: int, what: str) -> tuple[float, ...]:
    """``value`` as ``size`` floats; a ``ValueError`` naming ``name`` for anything else (a scalar, None, text).

    Tuples such as a start or a noise level arrive as env keywords (``gym.make``, ``--env-kwargs``);
    text is refused rather than read character by character (``"123"`` is not ``(1, 2, 3)``).

    Example:
        >>> check_floats("start", [1, 2, 0.5], 3, "three numbers (x, y, θ)")
        (1.0, 2.0, 0.5)
        >>> check_floats("start", "123", 3, "three numbers (x, y, θ)")
        Traceback (most recent call last):
          ...
        ValueError: start must be three numbers (x, y, θ), got '123'
    """
    try:
        floats = () if isinstance(value, (str, bytes)) else tuple(float(v) for v in value)
    except (TypeError, ValueError):
        floats = ()
    if len(floats) != size:
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return floats


def check_fraction(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """``value`` as a float if it is a real number in (0, 1] (``[0, 1]`` with ``allow_zero``): a discount, a rate.

    Example:
        >>> check_fraction("gamma", 0.99), check_fraction("gae_lambda", 0, allow_zero=True)
        (0.99, 0.0)
        >>> check_fraction("gamma", 2.0)
        Traceback (most recent call last):
          ...
        ValueError: gamma must lie in (0, 1], got 2.0
    """
    number = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if not (number and (0 <= value if allow_zero else 0 < value) and value <= 1):
        raise ValueError(f"{name} must lie in {'[' if allow_zero else '('}0, 1], got {value!r}")
    return float(value)


def did_you_mean(name: str, options: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` with the closest of ``options`` to a misspelt ``name``; empty when none is close.

    Example:
        >>> did_you_mean("horizn", ["horizon", "up_by"]), did_you_mean("zzz", ["horizon"])
        (" (did you mean 'horizon'?)", '')
    """
    nearest = difflib.get_close_matches(name, list(options), n=1)
    return f" (did you mean {nearest[0]!r}?)" if nearest else ""
