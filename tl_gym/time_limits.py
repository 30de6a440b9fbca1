"""Where an env's episodes end: its time limits, read from the wrapper chain.

`TLTLRewardWrapper` pays the robustness on the step that ends the episode, so it must see that step: a
``TimeLimit`` inside it (``TLTLRewardWrapper(gym.make(id, max_episode_steps=T), ...)``) ends episodes where it
judges them; one outside it (``gym.make("TLPendulum-v0", max_episode_steps=50)``: Gymnasium adds the limit
around what the entry point returns) cuts the episode before the wrapper sees an end, and no step pays the
robustness. `episode_length` reads the first kind, `limit_outside` finds the second.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np


def _is_count(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value > 0


def _layers(env: gym.Env) -> list[gym.Env]:
    """``env`` and every env it wraps, outermost first."""
    layers = [env]
    while isinstance(layers[-1], gym.Wrapper):
        layers.append(layers[-1].env)
    return layers


def episode_length(env: gym.Env) -> int | None:
    """The steps after which ``env`` ends every episode at the latest, if it states them.

    The least ``TimeLimit`` among its wrappers (one applied by hand has no spec to say so), else its spec's
    ``max_episode_steps``, else a ``horizon`` attribute (envs that own their horizon, as the car); None when
    none is stated.

    Example:
        >>> import gymnasium as gym
        >>> episode_length(gym.wrappers.TimeLimit(gym.make("Pendulum-v1").unwrapped, 7))
        7
        >>> episode_length(gym.make("Pendulum-v1")), episode_length(gym.make("Pendulum-v1").unwrapped)
        (200, None)
    """
    limits = [layer._max_episode_steps for layer in _layers(env) if isinstance(layer, gym.wrappers.TimeLimit)]
    if limits:
        return int(min(limits))
    steps = getattr(env.spec, "max_episode_steps", None) if env.spec is not None else None
    if _is_count(steps):
        return int(steps)
    try:
        horizon = env.get_wrapper_attr("horizon")
    except AttributeError:
        return None
    return int(horizon) if _is_count(horizon) else None


def limit_outside(env: gym.Env, is_reward_wrapper: Callable[[gym.Env], bool]) -> int | None:
    """A ``TimeLimit`` outside the reward wrapper that ends episodes before the wrapper sees their end.

    Returns its limit, or None when there is none, or it does not cut (it is no shorter than the episodes
    the wrapped env ends by itself), or no layer is the reward wrapper (``is_reward_wrapper`` says which is).
    """
    layers = _layers(env)
    inside = next((i for i, layer in enumerate(layers) if is_reward_wrapper(layer)), None)
    if inside is None:
        return None
    limits = [layer._max_episode_steps for layer in layers[:inside] if isinstance(layer, gym.wrappers.TimeLimit)]
    if not limits:
        return None
    own = episode_length(layers[inside].env)
    return int(min(limits)) if own is None or min(limits) < own else None
