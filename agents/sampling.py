"""Batched episode sampling on a Gymnasium vector env.

`rollout` runs ``N`` episodes of horizon ``T`` with a linear
controller ``a_t = K_t s_t + k_t^i`` (or any feedback term ``f(t, s_t) + k_t^i``,
such as the policy's ``K_t (s_t ⊖ s̄_t)``) and returns what every agent needs: the
actions, the observations, the formula's signal traces ``(N, T+1)``, the exact
robustness and success flags read from the reward wrapper's terminal ``info``.
`run_episodes` runs any controller until the episodes end. The Python loop runs over
time steps only; all envs of a step move in one call. The vector env comes from
`tl_gym.agents.env_ids.make_vector_env`, the horizon from `tl_gym.agents.horizon`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.errors import EpisodeError


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
