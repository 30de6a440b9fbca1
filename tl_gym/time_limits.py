"""Where an env's episodes end: the episode length it states, read from the wrapper chain.

`TLTLRewardWrapper` pays the robustness on the step that ends the episode, so it must see that step: a
``TimeLimit`` inside it (``TLTLRewardWrapper(gym.make(id, max_episode_steps=T), ...)``) ends episodes where it
judges them; one outside it (``gym.make("TLPendulum-v0", max_episode_steps=50)``: Gymnasium adds the limit
around what the entry point returns) cuts the episode before the wrapper sees an end, and no step pays the
robustness. The wrapper records `episode_length` of the env it wraps as its attribute of that name, so that an
agent can compare it with the limit outside (`tl_gym.agents.horizon.check_time_limits`), in this process or
in an `AsyncVectorEnv`'s workers.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np


def is_count(value: object) -> bool:
    """Whether ``value`` is an int (a numpy one too, not a bool) >= 1: a stated number of steps."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value > 0


def time_limits(env: gym.Env, until: Callable[[gym.Env], bool] | None = None) -> list[int]:
    """The ``max_episode_steps`` of every ``TimeLimit`` in ``env``'s wrapper chain, outermost first.

    With ``until``, only those outside the first layer it accepts (the reward wrapper: the limits that cut its
    episodes).
    """
    limits, layer = [], env
    while until is None or not until(layer):
        if isinstance(layer, gym.wrappers.TimeLimit):
            limits.append(int(layer._max_episode_steps))
        if not isinstance(layer, gym.Wrapper):
            break
        layer = layer.env
    return limits


def episode_length(env: gym.Env) -> int | None:
    """The steps after which ``env`` ends every episode at the latest, if it states them; else None.

    The least of what it states: every ``TimeLimit`` among its wrappers (one applied by hand has no spec to say
    so), its unwrapped spec's ``max_episode_steps`` (set by hand: ``gym.make`` states the length by its
    ``TimeLimit``) and a ``horizon`` attribute (envs that own their horizon, as the car).

    Example:
        >>> import gymnasium as gym
        >>> episode_length(gym.wrappers.TimeLimit(gym.make("Pendulum-v1").unwrapped, 7))
        7
        >>> episode_length(gym.make("Pendulum-v1")), episode_length(gym.make("Pendulum-v1").unwrapped)
        (200, None)
    """
    stated = time_limits(env)
    # the unwrapped env's spec: a wrapper's `spec` caches itself on every layer, and read while a reward wrapper is
    # built (inside an entry point) it would keep the inner id (Pendulum-v1) once gym.make sets the outer one
    spec = env.unwrapped.spec
    steps = getattr(spec, "max_episode_steps", None) if spec is not None else None
    if is_count(steps):
        stated.append(int(steps))
    try:
        horizon = env.get_wrapper_attr("horizon")
    except AttributeError:
        horizon = None
    if is_count(horizon):
        stated.append(int(horizon))
    return min(stated) if stated else None
