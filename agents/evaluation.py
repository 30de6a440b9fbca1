"""Evaluate any SB3-style predictor on a TLTL-rewarded env.

`evaluate_policy` works for every object with
``predict(obs, state, episode_start, deterministic) -> (action, state)``: the agents of
`tl_gym.agents` and stable-baselines3 models alike. It reads the exact robustness
from the terminal ``info["robustness"]`` that `tl_gym.TLTLRewardWrapper` sets, not
from the rewards, so reward shaping options of the wrapper (dense, smooth, an added
native reward) do not distort what it reports.
"""

from __future__ import annotations

from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from .sampling import episode_traces, terminal_info


class PolicyPredictor(Protocol):
    """Anything with stable-baselines3's ``predict`` signature."""

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = False
    ) -> tuple[Any, Any]:
        """Actions for a batch of observations and the next recurrent state."""


def evaluate_policy(
    predictor: PolicyPredictor,
    env: gym.Env | gym.vector.VectorEnv,
    n_episodes: int = 100,
    seed: int | None = None,
    deterministic: bool = True,
) -> dict[str, Any]:
    """Run ``n_episodes`` episodes and report the exact robustness of each.

    With a vector env the episodes run ``num_envs`` at a time; with seed ``s``, episode ``i``
    resets with seed ``s + i`` (batches reset with ``s + b · num_envs``; the vector env seeds
    its env ``j`` with that plus ``j``).

    Args:
        predictor: the policy, e.g. an agent or an SB3 model.
        env: a wrapped env or vector env whose terminal ``info`` holds ``robustness``.
        n_episodes: number of episodes (>= 1).
        seed: reset seed of the first episode; ``None`` for fresh randomness.
        deterministic: use the policy's mean action.

    Returns:
        ``{"mean_robustness": float, "success_rate": float, "robustness": (n_episodes,) array}``;
        success means robustness > 0.

    Raises:
        ValueError: ``n_episodes < 1``.
        RuntimeError: the env reports no robustness (not wrapped in `tl_gym.TLTLRewardWrapper`).
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    if isinstance(env, gym.vector.VectorEnv):
        robustness, _ = collect_episodes(predictor, env, n_episodes, seed, deterministic)
    elif isinstance(env, gym.Env):
        robustness = np.array([
            _evaluate_single(predictor, env, None if seed is None else seed + i, deterministic)
            for i in range(n_episodes)
        ])
    else:
        raise TypeError(f"env must be a gymnasium Env or VectorEnv, got {type(env).__name__}")
    return {
        "mean_robustness": float(np.mean(robustness)),
        "success_rate": float(np.mean(robustness > 0)),
        "robustness": robustness,
    }


def _terminal_robustness(info: dict[str, Any]) -> Any:
    if "robustness" not in info:
        raise RuntimeError("the env's terminal info holds no 'robustness': wrap it in tl_gym.TLTLRewardWrapper")
    return info["robustness"]


def _evaluate_single(predictor: PolicyPredictor, env: gym.Env, seed: int | None, deterministic: bool) -> float:
    obs, _ = env.reset(seed=seed)
    state, start = None, np.ones(1, dtype=bool)
    while True:
        action, state = predictor.predict(np.asarray(obs)[None], state=state, episode_start=start,
                                          deterministic=deterministic)
        obs, _, terminated, truncated, info = env.step(np.asarray(action)[0])
        start = np.zeros(1, dtype=bool)
        if terminated or truncated:
            return float(_terminal_robustness(info))


def collect_episodes(
    predictor: PolicyPredictor,
    venv: gym.vector.VectorEnv,
    n_episodes: int,
    seed: int | None = None,
    deterministic: bool = False,
) -> tuple[np.ndarray, dict[str, list[np.ndarray]]]:
    """Run ``n_episodes`` episodes on a vector env; return their robustness and signal traces.

    Seeding as in `evaluate_policy`. Used for the trajectory plots: with ``deterministic=False``
    the episodes are samples of the policy's trajectory distribution.

    Returns:
        ``(robustness (n_episodes,), traces)`` where ``traces[name]`` lists each episode's
        recorded values ``s_0 … s_T`` of that signal (from the wrapper's terminal ``info["trace"]``).
    """
    n_envs = venv.num_envs
    results: list[np.ndarray] = []
    traces: dict[str, list[np.ndarray]] = {}
    for start in range(0, n_episodes, n_envs):
        wanted = min(n_envs, n_episodes - start)
        obs, _ = venv.reset(seed=None if seed is None else seed + start)
        state, episode_start = None, np.ones(n_envs, dtype=bool)
        robustness = np.full(n_envs, np.nan)
        batch_traces: dict[str, list[Any]] = {}
        done = np.zeros(n_envs, dtype=bool)
        while not done.all():
            action, state = predictor.predict(obs, state=state, episode_start=episode_start,
                                              deterministic=deterministic)
            obs, _, terminated, truncated, info = venv.step(action)
            ended = (np.asarray(terminated) | np.asarray(truncated)) & ~done
            if ended.any():
                info = terminal_info(info)
                robustness[ended] = np.asarray(_terminal_robustness(info), dtype=float)[ended]
                for name, per_env in episode_traces(info, n_envs).items():
                    rows = batch_traces.setdefault(name, [None] * n_envs)
                    for i in np.flatnonzero(ended):  # once per finished episode
                        rows[i] = per_env[i]
                done |= ended
            episode_start = np.asarray(terminated) | np.asarray(truncated)
        results.append(robustness[:wanted])
        for name, rows in batch_traces.items():
            traces.setdefault(name, []).extend(rows[:wanted])
    return np.concatenate(results), traces
