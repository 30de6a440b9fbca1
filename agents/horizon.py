"""The episode length an agent runs by: read from the env, checked against a time limit outside the wrapper."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from tl_gym.time_limits import episode_length, is_count, time_limits
from tl_gym.wrapper import TLTLRewardWrapper


def infer_horizon(venv: gym.vector.VectorEnv) -> int | None:
    """The env's episode length if it states one: the least it states.

    What the reward wrapper recorded of the env it wraps (its ``episode_length``: time limits inside it, the
    spec's ``max_episode_steps``, a ``horizon`` attribute; read from an `AsyncVectorEnv`'s workers too), a
    ``horizon`` attribute (on the vector env, else on its sub-envs; a batched simulator's), ``params.horizon``
    (the car's parameters) and, for a `SyncVectorEnv`, its first sub-env's `episode_length` (an env that reports
    its robustness itself); only when none says anything, the vector env's spec. A time limit outside the wrapper
    that cuts its episodes is refused by `check_time_limits` before this is asked.
    """
    params = env_attribute(venv, "params")
    stated = [env_attribute(venv, "episode_length"), env_attribute(venv, "horizon"), getattr(params, "horizon", None)]
    if isinstance(venv, gym.vector.SyncVectorEnv):  # in this process: a sub-env's own time limits, wrapper or not
        stated.append(episode_length(venv.envs[0]))
    counts = [int(value) for value in stated if is_count(value)]
    if counts:
        return min(counts)
    # what the envs say is what they do: gym.make_vec(id, max_episode_steps=T) keeps T in the spec's kwargs and
    # the registry's value in its max_episode_steps; only an env that says nothing is read from the vector spec
    spec = getattr(venv, "spec", None)
    steps = None if spec is None else spec.kwargs.get("max_episode_steps", spec.max_episode_steps)
    return int(steps) if is_count(steps) else None


def check_time_limits(venv: gym.vector.VectorEnv) -> None:
    """Refuse envs whose ``TimeLimit`` sits outside their `TLTLRewardWrapper` and cuts its episodes.

    Such a limit (``gym.make("TLPendulum-v0", max_episode_steps=50)``: Gymnasium wraps what the id's entry
    point returns) ends episodes before the wrapper sees their end, so no step pays the robustness and an agent
    would fail at its first update, blaming a missing wrapper. The outermost ``TimeLimit`` of a sub-env
    (``_max_episode_steps`` as Gymnasium's attribute lookup finds it, outside in) is compared with the episode
    length the wrapper recorded of the env it wraps: shorter, or the only limit there is, is refused. Sub-envs of
    a `SyncVectorEnv` and an `AsyncVectorEnv` are asked alike; a batched simulator has no wrappers.

    Raises:
        ValueError: naming the limit and where the episode length belongs instead.
    """
    if not isinstance(venv, (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv)):
        return
    if not venv.call("has_wrapper_attr", "episode_length")[0]:  # no TLTLRewardWrapper: the env's own business
        return
    own = venv.get_attr("episode_length")[0]
    if isinstance(venv, gym.vector.SyncVectorEnv):  # in this process: every TimeLimit outside the wrapper
        outside = time_limits(venv.envs[0], until=lambda layer: isinstance(layer, TLTLRewardWrapper))
        limit = min(outside) if outside else None
    else:  # another process's env: the outermost TimeLimit, as Gymnasium's attribute lookup finds it
        limit = env_attribute(venv, "_max_episode_steps")
    if limit is None or (own is not None and limit >= own):
        return
    raise ValueError(
        f"a TimeLimit of {limit} steps wraps the env's TLTLRewardWrapper from outside (gym.make(tl_id, "
        f"max_episode_steps={limit}) puts it there): it ends episodes before the wrapper sees their end, so no "
        f"step pays the robustness. Set the episode length inside the wrapper: the task's own keyword "
        f"(horizon={limit} on TLCarNav-v0 and the suite's ids; TLPendulum-v0's up_by must stay below it), or "
        f"TLTLRewardWrapper(gym.make(base_id, max_episode_steps={limit}), ...)"
    )


def env_attribute(venv: gym.vector.VectorEnv, name: str) -> Any:
    """Attribute ``name`` of the vector env, or of its first sub-env; ``None`` when absent."""
    value = getattr(venv, name, None)
    if value is None and isinstance(venv, (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv)):
        # asked first: an AsyncVectorEnv's workers shut down on an attribute their env lacks
        if venv.call("has_wrapper_attr", name)[0]:
            value = venv.get_attr(name)[0]
    return value


#: What to do about an env whose episodes have no stated length (agents, evaluation): one message for both.
NO_EPISODE_LENGTH = ("the env states no episode length: give it a time limit inside its TLTLRewardWrapper, "
                     "TLTLRewardWrapper(gym.make(id, max_episode_steps=T), ...)")


def resolve_horizon(horizon: int | None, env: Any) -> int:
    """The agent's horizon: the configured one, checked against the env's, or the env's own.

    Raises:
        ValueError: the two disagree, or neither is known.
    """
    stated = infer_horizon(env)
    if horizon is None:
        if stated is None:
            raise ValueError(f"{NO_EPISODE_LENGTH}; or, if its episodes end on their own after T steps, give the "
                             "agent horizon=T (the number of actions per episode; the wrapper's horizon= only "
                             "scales the monitor's t/T)")
        return stated
    if stated is not None and stated != horizon:
        raise ValueError(f"horizon={horizon} but the env's episodes last {stated} steps; pass horizon={stated}")
    return int(horizon)
