"""Reading a formula's signals out of an env's observations (and infos), checked once, read fast.

`tl_gym.wrapper.TLTLRewardWrapper`'s ``signals`` argument maps each signal the formula reads to a source: an index
into a Box observation, a key (or ``(key, index)``) of a Dict one, or a callable of ``(obs)`` or
``(obs, info)``; or one callable returns them all. `SignalReader` checks every source against the
observation space when the wrapper is built (a bad index, a missing key or an unmapped signal raises
then, naming the signal), checks what callables return on the first observation, and reads a row of
floats per step, raising `TraceError` on NaN or inf with the signal and the step.

Kept apart from the wrapper so that the rules of "what a signal source may be" live in one place.
"""

from __future__ import annotations

import inspect
import math
import numbers
from collections.abc import Callable, Mapping
from typing import Any, Union

import numpy as np
from gymnasium import spaces

from tl_gym.errors import TraceError, UnknownSignalError

#: Where one signal comes from: an index, a key, a ``(key, index…)`` tuple, or a callable.
SignalSource = Union[int, str, tuple, Callable[..., Any]]
#: ``signals`` of the wrapper: a mapping name -> source, or one callable returning all the values.
SignalMap = Union[Mapping[str, SignalSource], Callable[..., Mapping[str, Any]]]


def _is_index(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _accepts_info(fn: Callable[..., Any]) -> bool:
    """Whether ``fn`` takes ``(obs, info)`` rather than ``(obs)``.

    It does when it needs a second positional argument, or names its second positional one ``info``, or takes
    ``*args``. A second parameter with a default that is not called ``info`` is the function's own
    (``np.linalg.norm``'s ``ord``, ``def dist(obs, goal=GOAL)``), and a keyword-only ``info`` cannot be handed
    positionally: such a function is called with the observation alone.

    Example:
        >>> _accepts_info(lambda obs, info: 0.0), _accepts_info(lambda obs, info=None: 0.0)
        (True, True)
        >>> _accepts_info(lambda obs, goal=3.0: 0.0), _accepts_info(lambda obs: 0.0)
        (False, False)
    """
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # builtins without a signature: assume (obs)
        return False
    if any(p.kind == p.VAR_POSITIONAL for p in params):
        return True
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    if len(positional) < 2:
        return False
    second = positional[1]
    return second.default is second.empty or second.name == "info"


def _box_index(name: str, space: spaces.Space, index: tuple, where: str) -> tuple:
    """Check that ``index`` picks one element of the Box ``space``; return it normalised."""
    if not isinstance(space, spaces.Box):
        raise TypeError(f"signal {name!r}: {where} is a {type(space).__name__} space, which an index cannot address")
    if len(index) != len(space.shape) or not all(_is_index(i) for i in index):
        hint = ": its one number is the index ()" if space.shape == () else ""
        raise ValueError(
            f"signal {name!r}: index {index if len(index) != 1 else index[0]!r} does not pick one element of "
            f"{where}, a Box of shape {space.shape}{hint}"
        )
    for i, size in zip(index, space.shape):
        if not -size <= i < size:
            raise ValueError(
                f"signal {name!r}: index {index if len(index) != 1 else index[0]!r} lies outside {where}, "
                f"a Box of shape {space.shape}"
            )
    return tuple(int(i) % size for i, size in zip(index, space.shape))


class SignalReader:
    """Reads the formula's signals from an observation (and info), checking each value."""

    def __init__(self, names: tuple[str, ...], signals: SignalMap, space: spaces.Space):
        self.names = names
        self._all_at_once: Callable[..., Any] | None = None
        self._getters: list[Callable[[Any, dict], Any]] = []
        self._fast_index: np.ndarray | None = None
        self._pending_check = False
        if callable(signals) and not isinstance(signals, Mapping):
            self._all_at_once = signals
            self._pending_check = True
            return
        if not isinstance(signals, Mapping):
            raise TypeError(f"signals must be a mapping name -> source or one callable, got {type(signals).__name__}")
        missing = [n for n in names if n not in signals]
        if missing:
            raise UnknownSignalError(
                f"the formula reads signal {missing[0]!r}, which `signals` does not map "
                f"(mapped: {', '.join(map(str, signals)) or 'none'})"
            )
        getters = {str(key): self._getter(str(key), source, space) for key, source in signals.items()}
        self._getters = [getters[n] for n in names]
        self._pending_check = any(callable(signals[n]) for n in names)
        flat = [signals[n] for n in names]
        if isinstance(space, spaces.Box) and len(space.shape) == 1 and all(_is_index(s) for s in flat):
            self._fast_index = np.array([int(s) % space.shape[0] for s in flat], dtype=np.intp)

    @staticmethod
    def _getter(name: str, source: Any, space: spaces.Space) -> Callable[[Any, dict], Any]:
        if callable(source):
            return _CallableGetter(name, source, _accepts_info(source))
        if isinstance(source, list):  # a (key, index) tuple after a JSON round trip (an EnvSpec, a saved agent)
            source = tuple(source)
        if _is_index(source) or (isinstance(source, tuple) and all(_is_index(i) for i in source)):  # () for a 0-D Box
            index = _box_index(name, space, source if isinstance(source, tuple) else (source,), "the observation")
            return _KeyGetter(None, index)
        if isinstance(source, str) or (isinstance(source, tuple) and source and isinstance(source[0], str)):
            key, rest = (source, ()) if isinstance(source, str) else (source[0], tuple(source[1:]))
            if not isinstance(space, spaces.Dict):
                raise TypeError(
                    f"signal {name!r}: key {key!r} needs a Dict observation space, got {type(space).__name__}"
                )
            if key not in space.spaces:
                raise ValueError(
                    f"signal {name!r}: the observation has no key {key!r} (keys: {', '.join(space.spaces)})")
            sub = space.spaces[key]
            if not rest:
                if not isinstance(sub, spaces.Box):  # no index reaches into it: only a callable can read it
                    raise ValueError(
                        f"signal {name!r}: key {key!r} holds a {type(sub).__name__} space, and a key reads a Box "
                        f"entry holding one number; read it with a callable such as lambda obs: float(obs[{key!r}])"
                    )
                if int(np.prod(sub.shape)) != 1:
                    example = (key, *(0,) * len(sub.shape))  # one index per axis
                    raise ValueError(
                        f"signal {name!r}: key {key!r} holds {type(sub).__name__} of shape {sub.shape}, not one "
                        f"number; pick an element with a tuple such as {example!r}"
                    )
                return _KeyGetter(key, (0,) * len(sub.shape))
            return _KeyGetter(key, _box_index(name, sub, rest, f"observation[{key!r}]"))
        raise TypeError(
            f"signal {name!r}: expected an index, a key, a (key, index) tuple or a callable, got {source!r}"
        )

    def bounds(self, space: spaces.Space) -> dict[str, tuple[float, float]]:
        """``(low, high)`` of the signals read by index from a Box (others are unbounded)."""
        out: dict[str, tuple[float, float]] = {}
        for name, getter in zip(self.names, self._getters):
            if isinstance(getter, _KeyGetter):
                box = space if getter.key is None else space.spaces[getter.key]  # type: ignore[attr-defined]
                out[name] = (float(box.low[getter.index]), float(box.high[getter.index]))
        return out

    def first(self, obs: Any, info: dict) -> list[float]:
        """Read s_0; on the first call, check what callables return (calling each once, as every read does)."""
        if not self._pending_check:
            return self.read(obs, info, 0)
        self._pending_check = False
        if self._all_at_once is not None:
            values = self._call_all_at_once(obs, info)
            self._check_mapping(values)
            return self._finite([float(values[n]) for n in self.names], 0)
        raw = [getter(obs, info) for getter in self._getters]
        for name, value in zip(self.names, raw):
            _check_scalar(name, value)
        return self._finite([float(value) for value in raw], 0)

    def _check_mapping(self, values: Any) -> None:
        """What the one signals callable returned: a mapping holding a real number for each signal read."""
        if not isinstance(values, Mapping):
            raise TypeError(f"the signals callable must return a mapping name -> number, got {type(values).__name__}")
        missing = [n for n in self.names if n not in values]
        if missing:
            raise UnknownSignalError(
                f"the signals callable returned no {missing[0]!r}, which the formula reads "
                f"(returned: {', '.join(map(str, values)) or 'none'})"
            )
        for name in self.names:
            _check_scalar(name, values[name])

    def _call_all_at_once(self, obs: Any, info: dict) -> Any:
        try:
            return self._all_at_once(obs, info)  # type: ignore[misc]
        except Exception as error:
            _add_note(error, "raised by the signals callable, called as fn(obs, info)")
            raise

    def read(self, obs: Any, info: dict, step: int) -> list[float]:
        """The signal values of one observation, as floats; NaN or inf raises `TraceError`."""
        if self._fast_index is not None:
            row = obs[self._fast_index].tolist()
        elif self._all_at_once is not None:
            values = self._call_all_at_once(obs, info)
            row = [float(values[n]) for n in self.names]
        else:
            row = [float(g(obs, info)) for g in self._getters]
        return self._finite(row, step)

    def _finite(self, row: list[float], step: int) -> list[float]:
        """``row``, or a `TraceError` naming the first signal that is NaN or infinite."""
        total = sum(row)
        if total - total != 0.0:  # NaN or inf somewhere (or an overflowing sum): find it
            for name, value in zip(self.names, row):
                if not math.isfinite(value):
                    raise TraceError(
                        f"signal {name!r} is {value} at step {step} of the recorded trace (s_0 is step 0)"
                    )
        return row


class _KeyGetter:
    """Reads ``obs[index]`` or ``obs[key][index]`` (a class rather than a lambda, so the wrapper pickles)."""

    def __init__(self, key: str | None, index: tuple[int, ...]):
        self.key = key
        self.index = index

    def __call__(self, obs: Any, info: dict) -> Any:
        return (obs if self.key is None else obs[self.key])[self.index]


class _CallableGetter:
    """Calls a user's signal function with ``(obs)`` or ``(obs, info)``; its errors say which signal's it is."""

    def __init__(self, name: str, fn: Callable[..., Any], with_info: bool):
        self.name = name
        self.fn = fn
        self.with_info = with_info

    def __call__(self, obs: Any, info: dict) -> Any:
        try:
            return self.fn(obs, info) if self.with_info else self.fn(obs)
        except Exception as error:
            called = "(obs, info)" if self.with_info else "(obs)"
            _add_note(error, f"raised by the callable of signal {self.name!r}, called as fn{called}")
            raise


def _add_note(error: BaseException, note: str) -> None:
    """PEP 678's ``add_note`` where Python has it (3.11+); on 3.10 the error goes on without the note."""
    if hasattr(error, "add_note"):
        error.add_note(note)


def _check_scalar(name: str, value: Any) -> None:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.ndarray, np.generic)):
        raise TypeError(f"signal {name!r} must be a real number, got {type(value).__name__}: {value!r}")
    if np.ndim(value) != 0 or np.asarray(value).dtype.kind not in "iuf":
        raise ValueError(
            f"signal {name!r} must be one real number, got an array of shape {np.shape(value)} "
            f"and dtype {np.asarray(value).dtype}"
        )
