"""The paper's time-varying linear-Gaussian policy (section IV).

``π(a_t | s_t) = N(k_t + K_t (s_t ⊖ s̄_t), C_t)`` for ``t = 0 … T-1``, ``s̄_t`` a centre
(zeros unless set: the paper's ``K_t s_t + k_t``) and ``⊖`` the difference, wrapped to
``[-π, π)`` on angle components. The paper keeps the feedback gains ``K_t`` fixed (zeros
unless given); the agents' ``feedback="fitted"`` option refits them, with the centre, by
weighted regression (`tl_gym.agents.feedback`). The feed-forward terms ``k_t`` and the
covariances ``C_t`` are learned. Exploration is per episode: each episode ``i``
draws its own feed-forward sequence ``k_t^i ~ N(k_t, C_t)`` and keeps it for the
whole episode, so that the update can credit each episode's parameters
(Deisenroth et al. 2013, episode-based policy search). A weighted
maximum-likelihood step then refits ``k_t`` and ``C_t`` to the drawn ``k_t^i``.

Actions live in the env's normalised Box (``[-1, 1]`` on the car); the sampler
clips what it sends to the env but the update uses the drawn ``k_t^i``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.checks import check_positive

from .feedback import deviation

#: Default initial standard deviation of every action component. On a ``[-1, 1]``
#: action Box, 0.5 keeps about 95% of the draws inside the box while letting
#: headings, which integrate the steering, spread over the whole arena within a
#: 200-step episode.
DEFAULT_INIT_STD = 0.5

#: Default floor on the policy's standard deviation, so that the covariance never
#: collapses to a singular matrix (the likelihood step would then freeze).
DEFAULT_MIN_STD = 1e-3


#: The covariance structures of the policy's per-step Gaussians.
COVARIANCES = ("diag", "full")


def check_covariance(covariance: Any) -> None:
    """Refuse a covariance structure the policy has not (one check for the policy and the agents' configs)."""
    if covariance not in COVARIANCES:
        raise ValueError(f"covariance must be 'diag' or 'full', got {covariance!r}")


class LinearGaussianPolicy:
    """Time-varying linear-Gaussian policy with per-episode feed-forward exploration.

    Args:
        horizon: number of actions per episode, ``T``.
        obs_dim: size of the (flat) observation ``s_t``.
        act_dim: size of the action ``a_t``.
        init_mean: initial ``k_t``: a scalar, an ``(act_dim,)`` vector or a ``(T, act_dim)`` array.
        init_std: initial standard deviation of each action component (scalar or ``(act_dim,)``).
        gains: fixed feedback gains ``K_t``, shape ``(T, act_dim, obs_dim)`` or ``(act_dim, obs_dim)``
            (the same for every step); zeros by default (an open-loop policy).
        covariance: ``"diag"`` (independent action components) or ``"full"``.
        min_std: floor on the standard deviation (on the eigenvalues of ``C_t`` when full).
        angles: boolean mask ``(obs_dim,)`` of the observation components that are angles:
            their deviation from the centre is wrapped to ``[-π, π)``; none by default.

    Attributes:
        mean: the feed-forward terms ``k_t``, shape ``(T, act_dim)``.
        cov: the covariances ``C_t``, shape ``(T, act_dim, act_dim)``.
        gains: the feedback gains ``K_t``, shape ``(T, act_dim, obs_dim)``.
        centre: the states ``s̄_t`` the gains act around, shape ``(T, obs_dim)`` (zeros by default).

    Example:
        >>> import numpy as np
        >>> policy = LinearGaussianPolicy(horizon=3, obs_dim=2, act_dim=1, init_std=0.5)
        >>> k = policy.sample_feedforward(4, np.random.default_rng(0))
        >>> k.shape
        (4, 3, 1)
        >>> policy.update(k, np.array([1.0, 0.0, 0.0, 0.0]))  # all weight on episode 0
        >>> bool(np.allclose(policy.mean, k[0]))
        True
    """

    def __init__(
        self,
        horizon: int,
        obs_dim: int,
        act_dim: int,
        *,
        init_mean: Any = 0.0,
        init_std: Any = DEFAULT_INIT_STD,
        gains: Any = None,
        covariance: str = "diag",
        min_std: float = DEFAULT_MIN_STD,
        angles: Any = None,
    ):
        check_covariance(covariance)
        check_positive("min_std", min_std)
        std = np.broadcast_to(np.asarray(init_std, dtype=float), (act_dim,))
        for value in std.tolist():
            check_positive("init_std", value)
        try:
            mean = np.broadcast_to(np.asarray(init_mean, dtype=float), (horizon, act_dim)).copy()
        except ValueError:
            raise ValueError(
                f"init_mean must broadcast to (horizon, act_dim) = {(horizon, act_dim)}, "
                f"got shape {np.shape(init_mean)}"
            ) from None
        if gains is None:
            gains = np.zeros((horizon, act_dim, obs_dim))
        gains = np.asarray(gains, dtype=float)
        if gains.shape == (act_dim, obs_dim):
            gains = np.broadcast_to(gains, (horizon, act_dim, obs_dim))
        if gains.shape != (horizon, act_dim, obs_dim):
            raise ValueError(
                f"gains must have shape (act_dim, obs_dim) = {(act_dim, obs_dim)} or "
                f"(horizon, act_dim, obs_dim) = {(horizon, act_dim, obs_dim)}, got {gains.shape}"
            )
        angles = np.zeros(obs_dim, dtype=bool) if angles is None else np.asarray(angles, dtype=bool)
        if angles.shape != (obs_dim,):
            raise ValueError(f"angles must be a boolean mask of shape ({obs_dim},), got shape {angles.shape}")
        self.horizon = horizon
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        self.covariance = covariance
        self.min_std = float(min_std)
        self.mean = mean
        self.cov = np.broadcast_to(np.diag(std**2), (horizon, act_dim, act_dim)).copy()
        self.gains = gains.copy()
        self.centre = np.zeros((horizon, obs_dim))
        self.angles = angles

    @classmethod
    def for_spaces(cls, observation_space: Any, action_space: Any, horizon: int, **kwargs: Any) -> LinearGaussianPolicy:
        """A policy sized for the spaces (``kwargs`` as for the constructor).

        The action space must be a flat Box; the observation space a flat Box, or a Dict of Boxes
        whose entries the policy reads concatenated (`tl_gym.agents.sampling.flat_observations`).

        Raises:
            TypeError: a space the linear policy cannot read as a vector.
        """
        if isinstance(observation_space, gym.spaces.Dict) and all(
                isinstance(sub, gym.spaces.Box) for sub in observation_space.spaces.values()):
            observation_space = gym.spaces.flatten_space(observation_space)
        for name, space in (("observation", observation_space), ("action", action_space)):
            if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
                raise TypeError(f"a linear-Gaussian policy needs flat Box spaces (or a Dict of Boxes for "
                                f"observations); the {name} space is {space}")
        return cls(horizon, observation_space.shape[0], action_space.shape[0], **kwargs)

    @property
    def feedback(self) -> Callable[[int, np.ndarray], np.ndarray] | None:
        """The feedback term ``(t, obs) -> K_t (obs ⊖ s̄_t)`` for `sampling.rollout`.

        ``None`` when all gains are zero (samplers then skip the product).
        """
        return self.feedback_term if np.any(self.gains) else None

    def feedback_term(self, t: int | np.ndarray, obs: np.ndarray) -> np.ndarray:
        """``K_t (s ⊖ s̄_t)`` for a batch of observations ``(n, obs_dim)`` at step(s) ``t`` (an int or ``(n,)``)."""
        t = np.minimum(t, self.horizon - 1)
        if np.ndim(t) == 0:  # one step for all rows (the samplers, the model repair): one matrix product
            return deviation(obs, self.centre[t], self.angles) @ self.gains[t].T
        gains = np.broadcast_to(self.gains[t], (obs.shape[0], self.act_dim, self.obs_dim))
        return np.einsum("nij,nj->ni", gains, deviation(obs, self.centre[t], self.angles))

    # Sampling ---------------------------------------------------------------------
    @property
    def std(self) -> np.ndarray:
        """Standard deviation of each action component per step, shape ``(T, act_dim)``."""
        return np.sqrt(np.diagonal(self.cov, axis1=1, axis2=2))

    def sample_feedforward(self, n_episodes: int, rng: np.random.Generator) -> np.ndarray:
        """Draw each episode's feed-forward sequence ``k_t^i ~ N(k_t, C_t)``.

        Returns:
            An array of shape ``(n_episodes, T, act_dim)``.
        """
        noise = rng.standard_normal((n_episodes, self.horizon, self.act_dim))
        return self.mean + np.einsum("tij,ntj->nti", self._cholesky(), noise)

    def act(self, obs: np.ndarray, t: np.ndarray, feedforward: np.ndarray) -> np.ndarray:
        """Actions ``k + K_t (s_t ⊖ s̄_t)`` for a batch.

        Args:
            obs: observations, shape ``(n, obs_dim)``.
            t: time index of each row, shape ``(n,)`` (clipped to ``T - 1``).
            feedforward: feed-forward term of each row, shape ``(n, act_dim)``.
        """
        return self.feedback_term(np.asarray(t), np.asarray(obs, dtype=float)) + feedforward

    def predict(
        self,
        obs: np.ndarray,
        state: Any,
        episode_start: Any,
        deterministic: bool,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        """SB3-style prediction; ``state`` holds each row's time index.

        ``obs`` of shape ``(obs_dim,)`` gives one action ``(act_dim,)``; ``(n, obs_dim)`` gives
        ``(n, act_dim)``. ``state`` is ``None`` (time 0), an int or an ``(n,)`` array; rows with
        ``episode_start`` true restart at time 0. The returned state is the next time index.
        A stochastic action adds ``N(0, C_t)`` noise, which has the same distribution as
        drawing ``k_t^i`` per episode, since the ``k_t^i`` of different steps are independent.
        """
        obs = np.asarray(obs, dtype=float)
        if obs.ndim == 0 or obs.shape[-1] != self.obs_dim:  # before a reshape could regroup the numbers
            raise ValueError(f"obs must have {self.obs_dim} components (last axis), got shape {obs.shape}")
        single = obs.ndim == 1
        batch = obs.reshape(-1, self.obs_dim)
        n = batch.shape[0]
        t = np.zeros(n, dtype=np.int64) if state is None else np.broadcast_to(np.asarray(state), (n,)).astype(np.int64)
        if episode_start is not None:
            t = np.where(np.broadcast_to(np.asarray(episode_start, dtype=bool), (n,)), 0, t)
        ff = self.mean[np.minimum(t, self.horizon - 1)]
        if not deterministic:
            noise = rng.standard_normal((n, self.act_dim))
            ff = ff + np.einsum("nij,nj->ni", self._cholesky()[np.minimum(t, self.horizon - 1)], noise)
        action = self.act(batch, t, ff)
        if single:
            return action[0], int(t[0]) + 1
        return action, t + 1

    # Update -----------------------------------------------------------------------
    def update(self, feedforward: np.ndarray, weights: np.ndarray, min_std: float | None = None) -> None:
        """Weighted maximum-likelihood refit of ``k_t`` and ``C_t`` (paper, section IV).

        ``k_t' = Σ_i w^i k_t^i`` and ``C_t' = Σ_i w^i (k_t^i - k_t')(k_t^i - k_t')^T``, then the
        floor ``min_std`` (this policy's unless given) is applied to the standard deviations
        (diagonal) or to the eigenvalues (full).

        Args:
            feedforward: the episodes' ``k_t^i``, shape ``(N, T, act_dim)``.
            weights: non-negative weights, shape ``(N,)``; normalised here.
            min_std: this update's floor, for exploration schedules.
        """
        feedforward = np.asarray(feedforward, dtype=float)
        w = np.asarray(weights, dtype=float)
        if feedforward.shape[1:] != (self.horizon, self.act_dim) or w.shape != (feedforward.shape[0],):
            raise ValueError(
                f"feedforward must be (N, {self.horizon}, {self.act_dim}) and weights (N,); "
                f"got {feedforward.shape} and {w.shape}"
            )
        if not (np.all(np.isfinite(w)) and np.all(w >= 0) and w.sum() > 0):
            raise ValueError("weights must be finite, non-negative and not all zero")
        w = w / w.sum()
        mean = np.einsum("n,nti->ti", w, feedforward)
        dev = feedforward - mean
        cov = np.einsum("n,nti,ntj->tij", w, dev, dev)
        self.mean = mean
        self.cov = self._floored(cov, self.min_std if min_std is None else float(min_std))

    def _floored(self, cov: np.ndarray, min_std: float) -> np.ndarray:
        floor = min_std**2
        if self.covariance == "diag":
            var = np.maximum(np.diagonal(cov, axis1=1, axis2=2), floor)
            return var[:, :, None] * np.eye(self.act_dim)
        eigval, eigvec = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))
        eigval = np.maximum(eigval, floor)
        return np.einsum("tij,tj,tkj->tik", eigvec, eigval, eigvec)

    def _cholesky(self) -> np.ndarray:
        if self.covariance == "diag":
            return np.sqrt(np.diagonal(self.cov, axis1=1, axis2=2))[:, :, None] * np.eye(self.act_dim)
        return np.linalg.cholesky(self.cov)

    # State ------------------------------------------------------------------------
    def arrays(self, centre: bool = False) -> dict[str, np.ndarray]:
        """The policy's parameters by name, for saving.

        The centre ``s̄_t`` only with ``centre=True``: a policy whose centre never moves (open
        loop) leaves it out, so that files saved before the centre existed still load.
        """
        arrays = {"policy_mean": self.mean, "policy_cov": self.cov, "policy_gains": self.gains}
        if centre:
            arrays["policy_centre"] = self.centre
        return arrays

    def load_arrays(self, arrays: dict[str, np.ndarray]) -> None:
        """Set the parameters from `arrays` (shapes checked by the caller)."""
        self.mean = np.array(arrays["policy_mean"], dtype=float)
        self.cov = np.array(arrays["policy_cov"], dtype=float)
        self.gains = np.array(arrays["policy_gains"], dtype=float)
        if "policy_centre" in arrays:
            self.centre = np.array(arrays["policy_centre"], dtype=float)
