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

from tl_gym.checks import check_count

from .horizon import NO_EPISODE_LENGTH, check_time_limits, infer_horizon
from .sampling import Controller, run_episodes


class PolicyPredictor(Protocol):
    """Anything with stable-baselines3's ``predict`` signature."""

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = False
    ) -> tuple[Any, Any]:
        """Actions for a batch of observations and the next recurrent state."""


def as_vector_env(env: gym.Env) -> gym.vector.VectorEnv:
    """A one-env vector view of ``env`` itself (not a copy), so that single envs run the same episode loop.

    Closing the view would close ``env``: callers leave that to the env's owner.
    """
    return gym.vector.SyncVectorEnv([lambda: env], autoreset_mode=gym.vector.AutoresetMode.NEXT_STEP)


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
        ``{"mean_robustness": float, "success_rate": float, "robustness": (n_episodes,) array,
        "traces": {signal: [each episode's s_0 … s_T]}}``; success means robustness > 0. The
        traces are what `tl_gym.diagnosis.conjunct_breakdown` reads.

    Raises:
        ValueError: ``n_episodes < 1``, or the env's time limit sits outside its reward wrapper
            (`check_time_limits`).
        EpisodeError: (a RuntimeError) the env reports no robustness (not wrapped in `tl_gym.TLTLRewardWrapper`),
            or it states no episode length and an episode ran `UNSTATED_EPISODE_GUARD` steps without ending.
    """
    check_count("n_episodes", n_episodes)
    if isinstance(env, gym.Env):
        env = as_vector_env(env)
    elif not isinstance(env, gym.vector.VectorEnv):
        raise TypeError(f"env must be a gymnasium Env or VectorEnv, got {type(env).__name__}")
    check_time_limits(env)
    robustness, traces = collect_episodes(predictor, env, n_episodes, seed, deterministic)
    return {
        "mean_robustness": float(np.mean(robustness)),
        "success_rate": float(np.mean(robustness > 0)),
        "robustness": robustness,
        "traces": traces,
    }


def predictor_controller(predictor: PolicyPredictor, deterministic: bool) -> Controller:
    """``act(t, obs, episode_start)`` for `run_episodes` from an SB3-style predictor, carrying its state."""
    state = None

    def act(t: int, obs: Any, episode_start: np.ndarray) -> Any:
        nonlocal state
        action, state = predictor.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        return action

    return act


#: Steps after which `collect_episodes` gives up on an episode of an env that states no episode length.
UNSTATED_EPISODE_GUARD = 100_000


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
    # an env that states its episode length ends every episode by it; one that does not (an env that ends its
    # own episodes, as highway-env's) gets a guard, so that a policy that never ends one cannot run forever
    guard = None if infer_horizon(venv) is not None else UNSTATED_EPISODE_GUARD
    results: list[np.ndarray] = []
    traces: dict[str, list[np.ndarray]] = {}
    for start in range(0, n_episodes, n_envs):
        wanted = min(n_envs, n_episodes - start)
        batch = run_episodes(venv, predictor_controller(predictor, deterministic),
                             seed=None if seed is None else seed + start, wanted=wanted, max_steps=guard,
                             limit_hint=NO_EPISODE_LENGTH)
        results.append(batch.robustness[:wanted])
        for name, rows in batch.traces.items():
            traces.setdefault(name, []).extend(rows[:wanted])
    return np.concatenate(results), traces
