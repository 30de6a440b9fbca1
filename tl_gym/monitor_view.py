"""The Markov view: a TLTL monitor's state as observation features (``observe_monitor=True``).

A prefix robustness is a running max/min over the past, so a reward paid from it is not a
function of the env's observation. The online monitor (`tl_gym.tltl.online.PrefixMonitor`)
carries exactly what the past contributes: running extrema, Until/Then chain progress, the
"never again" values and a few remembered states. `MonitorView` turns that state into a
vector an MLP (or VecNormalize) can use, and back:

* a ``value`` slot (a robustness value) becomes two features: the value clipped to
  ``[-clip, clip]`` and divided by ``scale`` (0 when infinite), and a flag that is ``+1``/``-1``
  when the value is ``+inf``/``-inf`` (a chain not started yet, ``true`` with ``rho_max=inf``),
  else 0;
* a ``signal`` slot (a remembered state's signal) becomes the signal divided by ``scale``, and 0
  for a state not seen yet (its bounds are the signal's, widened to hold 0);
* a ``count`` slot becomes the count divided by its bound;
* then ``first`` (1 on the reset observation, else 0: the dense reward's baseline) and, when
  the horizon ``T`` is known, ``t / T``.

Clipping loses nothing the rewards use: every monitor value is built from predicate values by
min, max and negation, which commute with a symmetric clip, and the rewards are clipped to
the same bound. So `prefix_value` and `dense_reward` recompute the wrapper's rewards from
observations alone (up to the rounding of the division by ``scale``).

Example:
    >>> from tl_gym import parse
    >>> from tl_gym.tltl.online import PrefixMonitor
    >>> view = MonitorView(PrefixMonitor(parse("F(x > 2) & G(x < 5)")), scale=2.0, clip=100.0, horizon=10)
    >>> view.size  # two values (two features each), first, t/T
    6
    >>> s0 = view.observe({"x": 0.0}, t=0)
    >>> s1 = view.observe({"x": 3.0}, t=1)
    >>> s1.tolist()
    [0.5, 0.0, 1.0, 0.0, 0.0, 0.1]
    >>> view.dense_reward(s0, s1), view.prefix_value(s1)
    (1.0, 1.0)
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from tl_gym.checks import check_count, check_positive
from tl_gym.shaping import discounted_increment, satisfaction_value
from tl_gym.tltl.codegen import CodeWriter
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.online_nodes import SIGNAL, VALUE


class MonitorView:
    """Encodes a `PrefixMonitor`'s state as a float64 feature vector, and decodes it.

    Args:
        monitor: the monitor to observe; its formula must be in the incremental fragment.
        scale: robustness values and remembered signals are divided by it (> 0): pick the size
            of a typical robustness, so that the features are of order one.
        clip: values are clipped to ``[-clip, clip]``, the wrapper's reward bound.
        horizon: the episode length ``T`` for the ``t / T`` feature (capped at 1); None leaves it out.
        signal_bounds: name -> ``(low, high)`` of each signal, for the bounds of the remembered
            states' features; unbounded when not given.

    Raises:
        ValueError: the formula is outside the incremental fragment (the message names the
            sub-formula), or a bad ``scale``, ``clip`` or ``horizon``.
    """

    def __init__(
        self,
        monitor: PrefixMonitor,
        scale: float,
        clip: float,
        horizon: int | None,
        signal_bounds: Mapping[str, tuple[float, float]] | None = None,
    ):
        if not monitor.incremental:
            monitor.state()  # raises the ValueError that names the sub-formula
        check_positive("monitor_scale", scale)
        check_count("horizon", horizon, allow_none=True)
        self.monitor = monitor
        self.scale = float(scale)
        self.clip = float(clip)
        self.horizon = None if horizon is None else int(horizon)
        self.slots = monitor.slots
        names = monitor.formula.signals
        bounds = [(signal_bounds or {}).get(n, (-np.inf, np.inf)) for n in names]
        low: list[float] = []
        high: list[float] = []
        window_position = 0  # signal slots come in whole states, in the order of `names`
        divisors: list[float] = []  # each slot's scale (a value's is applied after clipping)
        for slot in self.slots:
            if slot.kind == VALUE:
                low += [-self.clip / self.scale, -1.0]
                high += [self.clip / self.scale, 1.0]
                divisors.append(self.scale)
            elif slot.kind == SIGNAL:  # 0.0 stands for a state not seen yet: the bounds hold it too
                signal_low, signal_high = bounds[window_position % len(names)]
                low.append(min(signal_low, 0.0) / self.scale)
                high.append(max(signal_high, 0.0) / self.scale)
                divisors.append(self.scale)
                window_position += 1
            else:
                low.append(0.0)
                high.append(1.0)
                divisors.append(float(slot.bound))
        # the encoding's layout, for `encode` (written out slot by slot) and `encode_rows` (slots grouped by kind)
        self._is_value = [slot.kind == VALUE for slot in self.slots]
        self._layout = (self._is_value, divisors, self.clip, self.horizon)
        self._encode = self._written_out_encode()
        self._features = self._written_out_features()
        starts = np.cumsum([0] + [2 if is_value else 1 for is_value in self._is_value])  # each slot's first feature
        self._value_slots = np.flatnonzero(self._is_value)
        self._other_slots = np.flatnonzero(np.logical_not(self._is_value))
        self._value_features, self._other_features = starts[self._value_slots], starts[self._other_slots]
        self._flag_features = self._value_features + 1
        self._divisors = np.array(divisors)[self._other_slots].reshape(-1, 1)
        self._first = int(starts[-1])  # the feature `first`, then t / T
        low.append(0.0)  # first
        high.append(1.0)
        if self.horizon is not None:  # t / T
            low.append(0.0)
            high.append(1.0)
        self.space = spaces.Box(np.array(low), np.array(high), dtype=np.float64)
        self.size = len(low)
        self.value = math.nan  # the monitor's value after the last `observe`

    def _written_out_features(self) -> Callable[[int], list[float]]:
        """`features` as one function that reads the monitor's nodes (`PrefixMonitor.state_source`)."""
        live = CodeWriter()
        return _written_out_encoder(self.monitor.state_source(live), live, "t", *self._layout)

    def __getstate__(self) -> dict[str, Any]:
        # generated functions do not pickle, and `_features` reads this view's monitor: a copy writes
        # its own, over its copy of the monitor
        return {**self.__dict__, "_features": None, "_encode": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._encode = self._written_out_encode()
        self._features = self._written_out_features()

    def _written_out_encode(self) -> Callable[[Sequence[float], int], list[float]]:
        """`encode` as one function of an exported monitor state and ``t``."""
        return _written_out_encoder([f"state[{i}]" for i in range(len(self.slots))], CodeWriter(), "state, t",
                                    *self._layout)

    # encoding ----------------------------------------------------------------------------
    def update(self, state: Mapping[str, float], t: int) -> float:
        """Update the monitor with one state (``t = 0`` right after a reset); return its value (also ``value``)."""
        if t == 0:
            self.monitor.reset()
        self.value = self.monitor.update(state)
        return self.value

    def observe(self, state: Mapping[str, float], t: int) -> np.ndarray:
        """`update`, then return the features of the monitor's new state."""
        self.update(state, t)
        return np.array(self.features(t))

    def features(self, t: int) -> list[float]:
        """The features of the monitor's current state at step ``t``, as the list `augment` appends."""
        return self._features(t)

    def encode(self, state: Sequence[float], t: int) -> np.ndarray:
        """The features of a monitor state at step ``t`` (floats, for one monitor: `encode_rows` is its array form)."""
        return np.array(self._encode(state, t))

    def encode_rows(self, rows: np.ndarray, t: int) -> np.ndarray:
        """`encode` of n monitor states at step ``t``, given slot-major ``(len(slots), n)``: the ``(n, size)`` features.

        The same numbers as `encode` on each column (tested), in a fixed number of numpy calls:
        the encoding of `tl_gym.tltl.online_batch.BatchPrefixMonitor.rows` in the batched car.
        """
        out = np.empty((self.size, rows.shape[1]))
        values = rows[self._value_slots]
        infinite = np.isinf(values)
        clipped = np.minimum(np.maximum(values, -self.clip), self.clip)  # np.clip costs more on small arrays
        out[self._value_features] = np.where(infinite, 0.0, clipped) / self.scale
        out[self._flag_features] = np.where(infinite, np.sign(values), 0.0)
        out[self._other_features] = rows[self._other_slots] / self._divisors
        out[self._first] = 1.0 if t == 0 else 0.0
        if self.horizon is not None:
            out[self._first + 1] = min(t / self.horizon, 1.0)
        return out.T

    # decoding (pure functions of the features) ----------------------------------------------
    def decode(self, features: Any) -> tuple[list[float], bool]:
        """``(monitor state, first)`` from features (inverse of `encode`, values clipped)."""
        f = np.asarray(features, dtype=np.float64).reshape(-1)
        if f.size != self.size:
            raise ValueError(f"expected {self.size} monitor features, got {f.size}")
        state: list[float] = []
        i = 0
        for slot in self.slots:
            if slot.kind == VALUE:
                flag = f[i + 1]
                state.append(math.copysign(math.inf, flag) if flag != 0 else float(f[i]) * self.scale)
                i += 2
            elif slot.kind == SIGNAL:
                state.append(float(f[i]) * self.scale)
                i += 1
            else:
                state.append(float(round(f[i] * slot.bound)))
                i += 1
        return state, bool(f[i] == 1.0)

    def prefix_value(self, features: Any) -> float:
        """The clipped prefix robustness the features stand for."""
        state, _ = self.decode(features)
        return min(max(self.monitor.value_of_state(state), -self.clip), self.clip)

    def dense_reward(self, before: Any, after: Any, gamma: float = 1.0, bonus: float = 0.0) -> float:
        """The dense reward of the step from features ``before`` to ``after`` (``reward_mode="dense"``).

        ``γ Φ(after) − Φ(before)`` with Φ the clipped prefix robustness, 0 at the first state
        (`tl_gym.shaping.discounted_increment`; give ``gamma=1`` for the step that ends the episode),
        so that an episode's discounted rewards add up to its discounted clipped terminal robustness;
        with the wrapper's ``satisfaction_bonus`` (``bonus``), Φ is `tl_gym.shaping.satisfaction_value`.
        """
        _, first = self.decode(before)
        after_value = satisfaction_value(self.prefix_value(after), bonus)
        before_value = 0.0 if first else satisfaction_value(self.prefix_value(before), bonus)
        return discounted_increment(after_value, before_value, gamma)[0]


def augment_space(space: spaces.Space, view: MonitorView, key: str) -> spaces.Space:
    """The observation space with the monitor features: a longer Box, or a Dict with one more key.

    Raises:
        TypeError: the space is neither a 1-D Box nor a Dict, or the Dict already has ``key``.
    """
    if isinstance(space, spaces.Box) and len(space.shape) == 1:
        low = np.concatenate([space.low.astype(np.float64), view.space.low])
        high = np.concatenate([space.high.astype(np.float64), view.space.high])
        return spaces.Box(low, high, dtype=np.float64)
    if isinstance(space, spaces.Dict):
        if key in space.spaces:
            raise TypeError(f"observe_monitor adds the key {key!r}, which the Dict observation already has")
        return spaces.Dict({**space.spaces, key: view.space})
    raise TypeError(
        f"observe_monitor needs a 1-D Box or a Dict observation space, got {space}; "
        "flatten the observation first (gymnasium.wrappers.FlattenObservation)"
    )


def augment(obs: Any, features: Sequence[float], key: str) -> Any:
    """The observation with the monitor features appended (Box) or added under ``key`` (Dict), as float64.

    A Box observation's array is packed from the two lists by `struct` into a new array: in the
    single env's step that costs about a third of ``np.array`` of the same floats (1.1 µs against
    3.4 µs on 53 floats, loaded machine), since numpy first walks a list to find its shape and
    type. The bits are the same: ``d`` is the C double, which float64 is.
    """
    if isinstance(obs, np.ndarray):  # checked first: a Mapping check goes through the ABC machinery (~1 µs)
        return _packed(obs.tolist(), features)
    if isinstance(obs, Mapping):
        return {**obs, key: np.asarray(features, dtype=np.float64)}
    return _packed(np.asarray(obs).tolist(), features)


def _packed(head: list[float], tail: Sequence[float]) -> np.ndarray:
    """A new float64 array of ``head`` then ``tail`` (1-D)."""
    out = np.empty(len(head) + len(tail))
    _pack_into(out.size)(out, 0, *head, *tail)
    return out


@functools.cache
def _pack_into(size: int) -> Callable[..., None]:
    """`struct.Struct.pack_into` for ``size`` doubles (one per observation size)."""
    return struct.Struct(f"{size}d").pack_into


def split(obs: Any, view: MonitorView, key: str) -> Any:
    """The monitor features of an augmented observation (the inverse of `augment`)."""
    if isinstance(obs, Mapping):
        return np.asarray(obs[key], dtype=np.float64)
    return np.asarray(obs, dtype=np.float64)[..., -view.size :]


def _written_out_encoder(
    slots: Sequence[str], code: CodeWriter, arguments: str,
    is_value: Sequence[bool], divisors: Sequence[float], clip: float, horizon: int | None,
) -> Callable[..., list[float]]:
    """The encoding of the module docstring as one function written out slot by slot, ``slots`` its inputs.

    ``slots`` are Python expressions of the monitor state's floats: ``state[i]`` for
    `MonitorView.encode`, or `PrefixMonitor.state_source`'s expressions over the live monitor
    for `MonitorView.features`, which then reads the nodes without exporting their state first.
    The single env encodes one state a step, where a loop over the slots costs more than the
    arithmetic (docs/results/env_speed_markov_view.md). The expression does the same operations
    as `MonitorView.encode_rows` (clip, then divide; the flag; divide), so the same floats (tested).
    """
    # "v - v == 0.0 or v != v": not ±inf, in one float subtraction and comparison for the finite
    # values (cheaper than a membership test in (inf, -inf)); a NaN (unchecked arithmetic such as
    # inf - inf) passes through as NaN with flag 0, as in `encode_rows`
    clipped = "v" if math.isinf(clip) else f"({clip!r} if v > {clip!r} else {-clip!r} if v < {-clip!r} else v)"
    parts = []
    for slot, value_slot, divisor in zip(slots, is_value, divisors):
        if value_slot:
            parts.append(f"({clipped} / {divisor!r} if (v := {slot}) - v == 0.0 or v != v else 0.0)")
            parts.append("(0.0 if v - v == 0.0 or v != v else 1.0 if v > 0 else -1.0)")
        else:
            parts.append(f"{slot} / {divisor!r}")
    parts.append("1.0 if t == 0 else 0.0")
    if horizon is not None:
        parts.append(f"min(t / {horizon!r}, 1.0)")  # an env that runs past its stated horizon stays at 1
    return code.function("encode", arguments, parts)
