"""What TLPS and REPS share: episodic search over a time-varying linear-Gaussian policy.

Both draw each episode's feed-forward sequence k_t^i from the policy, run the N
episodes as one batch and refit ``k_t``, ``C_t`` by weighted maximum likelihood; they
differ only in how the weights are computed (`_update`).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any

import numpy as np

from .base import Agent
from .policy import LinearGaussianPolicy
from .sampling import resolve_horizon


class AbstractEpisodicSearch(Agent):
    """Abstract agent over a `LinearGaussianPolicy`; subclasses define `_make_config` and `_update`.

    The config must have the fields ``n_episodes``, ``horizon``, ``init_mean``,
    ``init_std``, ``covariance``, ``min_std`` and ``gains``.
    """

    policy: LinearGaussianPolicy
    horizon: int

    def _num_envs(self) -> int:
        return self.config.n_episodes

    def _setup(self) -> None:
        cfg = self.config
        self.horizon = resolve_horizon(cfg.horizon, self.env)
        self.policy = LinearGaussianPolicy.for_spaces(  # Algorithm 1, l.2
            self.observation_space, self.action_space, self.horizon, init_mean=cfg.init_mean,
            init_std=cfg.init_std, covariance=cfg.covariance, min_std=cfg.min_std, gains=cfg.gains,
        )

    @abc.abstractmethod
    def _update(self, iteration: int) -> dict[str, Any]:
        """One policy update (see `Agent._update`)."""

    def predict(
        self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        action, state = self.policy.predict(obs, state, episode_start, deterministic, self._predict_rng)
        return np.clip(action, self.action_space.low, self.action_space.high), state

    def _config(self) -> dict[str, Any]:
        return dataclasses.asdict(self.config)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return self.policy.arrays()

    def _extra_files(self) -> dict[str, bytes]:
        return {}

    def _load_state(self, arrays: dict[str, np.ndarray], files: dict[str, bytes]) -> None:
        self.policy.load_arrays(arrays)
