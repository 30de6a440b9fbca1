"""Batched episode sampling on a Gymnasium vector env.

`make_vector_env` turns what a user hands an agent (an env id, an `Env`, a
`VectorEnv`) into a `VectorEnv`: for an id, the env's own batched simulator
(its ``vector_entry_point``, one numpy call per step for all cars) rather than
`SyncVectorEnv`; an `Env` object is copied. `rollout` runs ``N`` episodes of horizon ``T`` with a linear
controller ``a_t = K_t s_t + k_t^i`` (or any feedback term ``f(t, s_t) + k_t^i``,
such as the policy's ``K_t (s_t ⊖ s̄_t)``) and returns what every agent needs: the
actions, the observations, the formula's signal traces ``(N, T+1)``, the exact
robustness and success flags read from the reward wrapper's terminal ``info``.
The Python loop runs over time steps only; all envs of a step move in one call.
"""

from __future__ import annotations

import copy
import importlib
import inspect
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator

from tl_gym.errors import EpisodeError
from tl_gym.time_limits import episode_length, is_count, time_limits
from tl_gym.tltl.ast import Formula
from tl_gym.wrapper import TLTLRewardWrapper


def registered_spec(env_id: str) -> gym.envs.registration.EnvSpec:
    """`gymnasium.spec` of an env id, Gymnasium's ``"module:EnvId"`` form included.

    As `gymnasium.make` does, the module is imported first (it registers the id), so that an agent,
    a run config or ``tl-gym train --env`` takes the ids ``gym.make`` takes.

    Example:
        >>> registered_spec("gymnasium.envs.classic_control:Pendulum-v1").id
        'Pendulum-v1'
    """
    module, _, name = env_id.rpartition(":")  # Gymnasium's ids hold no ":" themselves
    if module:
        importlib.import_module(module)
    return gym.spec(name)


def env_keywords(env_id: str) -> frozenset[str]:
    """The keywords ``gym.make(env_id, ...)`` takes by name; empty when the id is unknown or they cannot be read.

    The entry point's named parameters, and for one that takes ``**kwargs`` the names its ``env_keywords()``
    attribute lists (tl_gym's ids declare theirs). For the messages that tell an env keyword given to an agent.

    Example:
        >>> sorted(env_keywords("Pendulum-v1"))
        ['g', 'render_mode']
    """
    try:
        spec = registered_spec(env_id)
        creator = load_env_creator(spec.entry_point) if isinstance(spec.entry_point, str) else spec.entry_point
        parameters = inspect.signature(creator).parameters
    except (gym.error.Error, ImportError, AttributeError, TypeError, ValueError):
        return frozenset()
    named = {name for name, p in parameters.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    return frozenset(named | set(getattr(creator, "env_keywords", tuple)()))


def env_keyword_hint(env: Any, names: Iterable[str], hyperparameters: Mapping[str, Any]) -> str:
    """``"; 'task' is a keyword of the env TLCarNav-v0: pass env_kwargs={'task': 2}"`` for ``names`` the env takes.

    ``""`` when ``env`` is not an id or takes none of them. Agents add it to the error of a hyperparameter they do
    not have, the usual slip being an env keyword given to the agent.
    """
    if not isinstance(env, str):
        return ""
    keywords = env_keywords(env)
    taken = [name for name in names if name in keywords]
    if not taken:
        return ""
    which = ", ".join(map(repr, taken))
    kwargs = "{" + ", ".join(f"{name!r}: {hyperparameters[name]!r}" for name in taken) + "}"
    return (f"; {which} {'is a keyword' if len(taken) == 1 else 'are keywords'} of the env {env}, not of the agent: "
            f"pass env_kwargs={kwargs}")


def unqualified_id(env_id: str) -> str:
    """``EnvId`` of an id in Gymnasium's ``"module:EnvId"`` form, the id itself otherwise (`registered_spec`'s name).

    Example:
        >>> unqualified_id("my_tasks:SwingUp-v0"), unqualified_id("Pendulum-v1")
        ('SwingUp-v0', 'Pendulum-v1')
    """
    return env_id.rpartition(":")[2]


def make_vector_env(env: Any, num_envs: int, env_kwargs: Mapping[str, Any] | None = None) -> gym.vector.VectorEnv:
    """Build a vector env of ``num_envs`` copies of ``env``.

    Args:
        env: an env id (``"TLCarNav-v0"``), an `Env` (copied, `env_copies`) or a `VectorEnv`
            (returned as is).
        num_envs: number of parallel envs wanted.
        env_kwargs: keyword arguments for the env constructor (env ids only).

    Raises:
        TypeError: ``env`` is none of the above, or ``env_kwargs`` come with an env object.
    """
    env_kwargs = dict(env_kwargs or {})
    if isinstance(env, gym.vector.VectorEnv):
        if env_kwargs:
            raise TypeError("env_kwargs can only be used with an env id, not with a VectorEnv")
        return env
    if isinstance(env, str):
        spec = registered_spec(env)
        mode = "vector_entry_point" if spec.vector_entry_point is not None else "sync"
        return gym.make_vec(env, num_envs=num_envs, vectorization_mode=mode, **env_kwargs)
    if isinstance(env, gym.Env):  # copied: only an id gets the batched simulator of its vector_entry_point
        if env_kwargs:
            raise TypeError("env_kwargs can only be used with an env id, not with an Env object")
        return gym.vector.SyncVectorEnv(env_copies(env, num_envs))
    raise TypeError(f"env must be an env id, a gymnasium Env or a VectorEnv, got {type(env).__name__}")


def env_copies(env: gym.Env, n: int) -> list[Callable[[], gym.Env]]:
    """Constructors of ``n`` copies of the env object ``env``, for the agents' vector envs.

    Copies (`copy.deepcopy`), so that what was set after ``gym.make`` stays (``env.unwrapped.configure(...)``
    of highway-env, an attribute changed by hand), as SB3 keeps the env object it is given; the user's env
    itself is not stepped. Each copy's random generator is drawn afresh: copies of an env that was seeded would
    otherwise share its stream, and their unseeded resets (an SB3 agent without seed) would play one episode
    ``n`` times. An env that cannot be copied (a live render window) is rebuilt from its spec.

    Raises:
        TypeError: the env can be neither copied nor rebuilt (naming both reasons).
    """
    try:
        copies = [copy.deepcopy(env) for _ in range(n)]
    except Exception as copy_error:  # noqa: BLE001 - any failure of a user's env to copy: try its spec
        if env.spec is None:
            raise TypeError(f"the env cannot be copied ({copy_error!r}) and has no spec to rebuild it from: "
                            "pass an env id or a factory-registered id instead") from copy_error
        try:
            gym.make(env.spec).close()
        except Exception as make_error:  # noqa: BLE001
            raise TypeError(f"the env can neither be copied ({copy_error!r}) nor rebuilt from its spec "
                            f"({make_error!r})") from make_error
        spec = env.spec
        return [lambda: gym.make(spec) for _ in range(n)]
    for duplicate in copies:
        duplicate.unwrapped.np_random = np.random.default_rng()  # fresh entropy; a seeded reset still decides
    return [lambda e=e: e for e in copies]


def find_formula(venv: gym.vector.VectorEnv) -> Formula:
    """The TLTL formula the env pays as reward (its ``formula`` attribute).

    Raises:
        TypeError: the env exposes no formula; wrap it in `tl_gym.TLTLRewardWrapper`.
    """
    formula = env_attribute(venv, "formula")
    if not isinstance(formula, Formula):
        raise TypeError(
            "the env has no `formula`: wrap it in tl_gym.TLTLRewardWrapper(env, spec, signals) "
            "so that agents can read the TLTL robustness"
        )
    return formula


@dataclass(frozen=True)
class Rollouts:
    """A batch of ``N`` finished episodes of up to ``T`` actions.

    Attributes:
        actions: actions sent to the env (clipped to its Box), shape ``(N, T, act_dim)``.
        observations: ``s_0 … s_T``, shape ``(N, T+1, obs_dim)``; an episode that ended early
            repeats its last observation.
        traces: the formula's signals recorded by the wrapper, name -> ``(N, T+1)`` (padded the same way).
        lengths: number of actions of each episode, shape ``(N,)``.
        robustness: exact robustness of each episode, shape ``(N,)``.
        satisfied: whether each episode satisfied the formula (robustness > 0), shape ``(N,)``.
        env_steps: total number of env steps taken by the ``N`` episodes.
    """

    actions: np.ndarray
    observations: np.ndarray
    traces: dict[str, np.ndarray]
    lengths: np.ndarray
    robustness: np.ndarray
    satisfied: np.ndarray
    env_steps: int

    @property
    def mean_robustness(self) -> float:
        """Mean exact robustness over the batch."""
        return float(np.mean(self.robustness))

    @property
    def success_rate(self) -> float:
        """Share of episodes with robustness > 0."""
        return float(np.mean(self.robustness > 0))


Feedback = np.ndarray | Callable[[int, np.ndarray], np.ndarray] | None


def rollout(
    venv: gym.vector.VectorEnv,
    feedforward: np.ndarray,
    gains: Feedback = None,
    seed: int | None = None,
) -> Rollouts:
    """Run one episode per row of ``feedforward`` with actions ``a_t = K_t s_t + k_t^i``.

    Episodes run ``venv.num_envs`` at a time; chunk ``c`` resets with seed
    ``seed + c * num_envs``, so episode ``i`` always sees seed ``seed + i`` (a vector env
    seeds its env ``j`` with ``seed + j``).

    Args:
        venv: a vector env whose episodes end within ``T`` steps, wrapped so that the terminal
            ``info`` holds ``robustness`` and ``trace`` (`tl_gym.TLTLRewardWrapper`).
        feedforward: per-episode action sequences ``k_t^i``, shape ``(N, T, act_dim)``.
        gains: feedback gains ``K_t``, shape ``(T, act_dim, obs_dim)``, or a function
            ``(t, obs (n, obs_dim)) -> (n, act_dim)`` added to ``k_t^i``; none for open loop.
        seed: reset seed of episode 0.

    Raises:
        EpisodeError: an episode did not end within ``T`` steps, or the env reports no robustness.
    """
    feedforward = np.asarray(feedforward, dtype=float)
    n_episodes, horizon, act_dim = feedforward.shape
    n_envs = venv.num_envs
    chunks = [
        _rollout_chunk(venv, feedforward[start:start + n_envs], gains,
                       None if seed is None else seed + start)
        for start in range(0, n_episodes, n_envs)
    ]
    if len(chunks) == 1:
        return chunks[0]
    return Rollouts(
        actions=np.concatenate([c.actions for c in chunks]),
        observations=np.concatenate([c.observations for c in chunks]),
        traces={k: np.concatenate([c.traces[k] for c in chunks]) for k in chunks[0].traces},
        lengths=np.concatenate([c.lengths for c in chunks]),
        robustness=np.concatenate([c.robustness for c in chunks]),
        satisfied=np.concatenate([c.satisfied for c in chunks]),
        env_steps=sum(c.env_steps for c in chunks),
    )


def flat_observations(space: gym.Space, obs: Any) -> np.ndarray:
    """Observations as float rows ``(n, obs_dim)``: a Box's flattened, a Dict's entries concatenated in its key order.

    ``obs`` is one observation of ``space`` or a batch of them (a vector env's); a Dict's order is
    `gymnasium.spaces.flatten`'s, so that a linear policy sees the same vector in every caller.

    Example:
        >>> space = gym.spaces.Dict({"a": gym.spaces.Box(0, 1, (2,)), "b": gym.spaces.Box(0, 1, (1,))})
        >>> flat_observations(space, {"a": np.array([0.1, 0.2]), "b": np.array([0.3])}).tolist()
        [[0.1, 0.2, 0.3]]
    """
    if isinstance(space, gym.spaces.Dict):
        missing = [key for key in space.spaces if key not in obs]
        if missing:
            raise KeyError(f"the observation has no key {missing[0]!r} (the space's keys: {', '.join(space.spaces)})")
        parts = [np.asarray(obs[key], dtype=float) for key in space.spaces]
        single = all(p.shape == sub.shape for p, sub in zip(parts, space.spaces.values()))
        # a batch's size: the first entry that is not one observation's says it
        batched = [p for p, sub in zip(parts, space.spaces.values()) if p.shape != sub.shape and p.ndim]
        rows = 1 if single or not batched else batched[0].shape[0]
        for part, (key, sub) in zip(parts, space.spaces.items()):
            if part.shape != sub.shape and part.shape != (rows, *sub.shape):
                raise ValueError(f"observation[{key!r}] has shape {part.shape}: the space's is {sub.shape}, a batch "
                                 f"of {rows} is ({rows}, {', '.join(map(str, sub.shape))})")
        return np.concatenate([p.reshape(rows, -1) for p in parts], axis=1)
    array = np.asarray(obs, dtype=float)
    return array.reshape(-1, int(np.prod(space.shape))) if space.shape else array.reshape(-1, 1)


Controller = Callable[[int, Any, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class EpisodeBatch:
    """The first episode of every env of a vector env, each run to its end (`run_episodes`).

    Attributes:
        lengths: actions each episode took, shape ``(n_envs,)``.
        robustness: exact robustness from each episode's terminal ``info``, shape ``(n_envs,)``.
        traces: the formula's signals the wrapper recorded, name -> one array ``s_0 … s_T`` per env.
        observations: flat observations ``(n_envs, steps + 1, obs_dim)`` when recorded (a row past
            its episode's end holds the next episode's, to be padded by the caller), else ``None``.
        actions: the actions sent, ``(n_envs, steps, act_dim)`` when recorded, else ``None``.
    """

    lengths: np.ndarray
    robustness: np.ndarray
    traces: dict[str, list[np.ndarray | None]]
    observations: np.ndarray | None = None
    actions: np.ndarray | None = None


def run_episodes(venv: gym.vector.VectorEnv, act: Controller, seed: int | None = None, max_steps: int | None = None,
                 record: bool = False, wanted: int | None = None, limit_hint: str | None = None) -> EpisodeBatch:
    """Run one episode in every env of ``venv`` to its end: the one episode loop of the library.

    Every caller (training batches, evaluation, trace plots, the command line's GIF) runs its
    episodes here, so the terminal-info contract is read in one place: the robustness and the
    trace come from the wrapper's terminal ``info`` (under same-step autoreset, from
    ``info["final_info"]``), and each env's first episode is the one reported.

    Args:
        venv: a vector env wrapped so that the terminal ``info`` holds ``robustness`` (and ``trace``).
        act: ``act(t, obs, episode_start) -> actions`` for the whole batch; ``episode_start`` marks the
            envs whose observation starts an episode (all at ``t = 0``), as stable-baselines3's ``predict`` wants.
        seed: reset seed (env ``j`` gets ``seed + j``).
        max_steps: raise if some episode is still running after this many steps.
        limit_hint: what the error of an episode outliving ``max_steps`` advises (default: the agent's horizon).
        record: keep the flat observations and the actions sent.
        wanted: stop once the first ``wanted`` envs' episodes ended (the others are padding; their
            lengths may stay ``-1``); default all.

    Raises:
        EpisodeError: the env reports no robustness, or an episode outlived ``max_steps`` (a RuntimeError).
    """
    n_envs = venv.num_envs
    obs_space = venv.single_observation_space
    action_dtype = venv.single_action_space.dtype  # actions are recorded as computed, sent in the space's dtype
    obs, _ = venv.reset(seed=seed)
    start = np.ones(n_envs, dtype=bool)
    lengths = np.full(n_envs, -1)
    robustness = np.full(n_envs, np.nan)
    traces: dict[str, list[np.ndarray | None]] = {}
    observations = [flat_observations(obs_space, obs)] if record else []
    actions = []
    t = 0
    while np.any(lengths[:wanted] < 0):
        if max_steps is not None and t >= max_steps:
            raise EpisodeError(
                f"{int(np.sum(lengths[:wanted] < 0))} episode(s) did not end within {max_steps} steps; "
                + (limit_hint or f"set the agent's horizon (now {max_steps}) to the number of steps the env's "
                   "episodes take")
            )
        action = act(t, obs, start)
        obs, _, terminated, truncated, info = venv.step(np.asarray(action).astype(action_dtype, copy=False))
        start = np.asarray(terminated) | np.asarray(truncated)
        ended = start & (lengths < 0)
        if record:
            actions.append(np.asarray(action, dtype=float).reshape(n_envs, -1))
            observations.append(flat_observations(obs_space, obs))
            if ended.any() and "final_obs" in info:  # same-step autoreset: obs holds the next episode's s_0
                for i in np.flatnonzero(ended):
                    observations[-1][i] = flat_observations(obs_space, info["final_obs"][i])[0]
        t += 1
        if not ended.any():
            continue
        info = ended_info(info)
        require_robustness(info)
        lengths[ended] = t
        robustness[ended] = np.asarray(info["robustness"], dtype=float)[ended]
        for name, per_env in episode_traces(info, n_envs).items():
            rows = traces.setdefault(name, [None] * n_envs)
            for i in np.flatnonzero(ended):
                rows[i] = per_env[i]
    return EpisodeBatch(lengths, robustness, traces,
                        np.stack(observations, axis=1) if record else None,
                        np.stack(actions, axis=1) if record else None)


def _rollout_chunk(venv: gym.vector.VectorEnv, feedforward: np.ndarray, gains: Feedback, seed: int | None) -> Rollouts:
    """Run at most ``num_envs`` episodes at once (the rows past ``n`` are padding)."""
    n, horizon, act_dim = feedforward.shape
    n_envs = venv.num_envs
    space = venv.single_action_space
    low, high = np.asarray(space.low, dtype=float), np.asarray(space.high, dtype=float)
    ff = np.zeros((n_envs, horizon, act_dim))
    ff[:n] = feedforward
    obs_space = venv.single_observation_space

    def act(t: int, obs: Any, episode_start: np.ndarray) -> np.ndarray:
        action = ff[:, t]
        if callable(gains):
            action = action + gains(t, flat_observations(obs_space, obs))
        elif gains is not None:
            flat = flat_observations(obs_space, obs)
            action = action + np.einsum("nij,nj->ni", np.broadcast_to(gains[t], (n_envs, *gains.shape[1:])), flat)
        return np.clip(action, low, high)

    batch = run_episodes(venv, act, seed, max_steps=horizon, record=True, wanted=n)
    lengths = batch.lengths[:n]
    # pad episodes that ended early with their last observation / signal value
    idx = np.minimum(np.arange(horizon + 1), lengths[:, None])
    rows = np.arange(n)[:, None]
    steps = batch.observations.shape[1]
    observations = np.zeros((n, horizon + 1, batch.observations.shape[2]))
    observations[:, :steps] = batch.observations[:n]
    actions = np.zeros((n, horizon, act_dim))
    actions[:, : steps - 1] = batch.actions[:n]
    traces = {}
    for name, per_env in batch.traces.items():
        values = np.zeros((n, horizon + 1))
        for i, episode in enumerate(per_env[:n]):
            episode = episode[: horizon + 1]
            values[i, : len(episode)] = episode
        traces[name] = values[rows, idx]
    robustness = batch.robustness[:n]
    return Rollouts(
        actions=actions if lengths.min() == horizon else _zero_after(actions, lengths),
        observations=observations[rows, idx],
        traces=traces,
        lengths=lengths,
        robustness=robustness,
        satisfied=robustness > 0,
        env_steps=int(lengths.sum()),
    )


def _zero_after(actions: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Zero the actions of steps after an episode ended (they went to the next episode)."""
    mask = np.arange(actions.shape[1])[None, :] < lengths[:, None]
    return actions * mask[:, :, None]


def ended_info(info: Mapping[str, Any]) -> Mapping[str, Any]:
    """The info of the episodes that just ended: ``info`` itself, or its ``final_info`` under same-step autoreset."""
    final = info.get("final_info")
    return final if isinstance(final, Mapping) else info


def require_robustness(info: Mapping[str, Any]) -> None:
    """Refuse the terminal info of an env that is not TL-rewarded (every agent reads the robustness there)."""
    if "robustness" not in info:
        raise EpisodeError("the env's terminal info holds no 'robustness': wrap it in tl_gym.TLTLRewardWrapper")


def episode_traces(info: Mapping[str, Any], n_envs: int) -> dict[str, list[np.ndarray | None]]:
    """Each env's recorded trace in a vector env's terminal ``info``: name -> one array per env (None if none ended).

    Reads both layouts: the wrapper's per-episode mapping, which Gymnasium batches as an object
    array (episodes of different lengths can end on one step), and a dict of batched ``(n_envs, T+1)``
    arrays with ``_name`` masks (`CarNavVectorEnv`, whose episodes all have one length).
    """
    trace = info.get("trace")
    out: dict[str, list[np.ndarray | None]] = {}
    if trace is None:
        return out
    if isinstance(trace, np.ndarray):  # one mapping (or None) per env
        for i, episode in enumerate(trace):
            for name, values in (episode or {}).items():
                out.setdefault(name, [None] * n_envs)[i] = np.asarray(values, dtype=float)
        return out
    for name, values in trace.items():
        if name.startswith("_"):
            continue
        mask = np.asarray(trace.get(f"_{name}", np.ones(n_envs, dtype=bool)))
        rows = np.asarray(values, dtype=float)
        out[name] = [rows[i] if mask[i] else None for i in range(n_envs)]
    return out


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

