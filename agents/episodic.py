"""What TLPS and REPS share: episodic search over a time-varying linear-Gaussian policy.

Both draw each episode's feed-forward sequence k_t^i from the policy, run the N
episodes as one batch and refit the policy from the weighted batch; they differ only
in how the weights are computed (`_update`). The refit (`_refit`) is here, once: the
paper's open loop (``k_t``, ``C_t`` by weighted maximum likelihood, ``K_t`` fixed) or,
with ``feedback="fitted"``, the gains ``K_t`` and their centre ``s̄_t`` too
(`tl_gym.agents.feedback`). The config fields both agents share are `EpisodicSearchConfig`.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.checks import check_positive

from .base import Agent, check_episodic
from .feedback import FITTED_EXPLORATION_FLOOR, FeedbackSettings, fit_feedback, signal_components
from .horizon import resolve_horizon
from .policy import DEFAULT_INIT_STD, DEFAULT_MIN_STD, LinearGaussianPolicy, check_covariance
from .sampling import Rollouts, flat_observations


@dataclasses.dataclass(frozen=True, kw_only=True)
class EpisodicSearchConfig:
    """The hyperparameters TLPS and REPS share, declared and checked once; `TLPSConfig` and `REPSConfig` add their own.

    Keyword-only, so that an agent's own fields may follow these without defaults clashing.
    """

    n_episodes: int = 40
    """Episodes per update, ``N`` (>= 2; the paper's 40); the batched env runs this many at once."""
    horizon: int | None = None
    """Actions per episode, ``T``; ``None`` reads it from the env (the car's is the paper's 200)."""
    init_std: float = DEFAULT_INIT_STD
    """Initial standard deviation of every action component of ``k_t^i`` (> 0)."""
    init_mean: Any = 0.0
    """Initial feed-forward action ``k_t`` (every component, every step): a finite number, or one per action
    component (stored as a list)."""
    min_std: float = DEFAULT_MIN_STD
    """Permanent floor on the policy's standard deviation (> 0)."""
    covariance: str = "diag"
    """``"diag"`` or ``"full"`` covariance ``C_t`` per time step."""
    gains: Any = None
    """Fixed feedback gains ``K_t`` of the policy ``a = K_t s_t + k_t`` with ``feedback="open"``: an array
    (or nested lists) of shape ``(act_dim, obs_dim)`` or ``(T, act_dim, obs_dim)``; ``None`` is zeros (fixed
    gains around a mean path cancelled exploration, docs/tlps.md). Stored as lists."""
    feedback: str = "fitted"
    """``"fitted"`` (the default): time-varying gains ``K_t`` on the deviation ``s_t ⊖ s̄_t``
    from the weighted mean state, refit each update by weighted ridge regression on the drawn noise
    (`tl_gym.agents.feedback`); faster in the paper's setting and the only way to learn from a wide
    start spread (docs/tlps.md). ``"open"``: the paper's open-loop policy (``K_t`` fixed by ``gains``),
    kept for the ablation."""
    feedback_features: Any = "auto"
    """Components the fitted gains act on: ``"auto"`` (the components the formula's signals are read
    from, found in the first batch, plus the angle components; all when no signal is an observation
    component), ``"all"`` or a list of indices. Stored as a list."""
    feedback_angles: Any = "auto"
    """Angle components (deviations wrapped to [-π, π), circular centre): ``"auto"`` (Box bounds exactly
    ±π) or a list of indices (``[]`` for none). Stored as a list."""
    feedback_ridge: float = 0.01
    """Ridge on the fitted gains' increment, standardised units (>= 0): a pull toward the previous gains."""
    feedback_window: int = 5
    """The fit pools its moments over steps ``t − window … t + window`` (>= 0)."""
    exploration_floor: float | None = None
    """Std floor ``exploration_floor · 0.5^(m / exploration_halflife)`` at iteration ``m`` (>= 0, 0 is
    off); ``None``: 0.1 with ``feedback="fitted"`` (the gains learn from the drawn noise, which must
    not collapse), 0 with ``"open"``."""
    exploration_halflife: float = 10.0
    """Iterations over which the exploration floor halves (> 0)."""

    def __post_init__(self) -> None:
        """Validate and normalise the shared fields; an agent's config extends this with its own checks."""
        if self.gains is not None:  # plain lists, so that the config stays JSON
            object.__setattr__(self, "gains", np.asarray(self.gains, dtype=float).tolist())
        check_episodic(self.n_episodes, self.horizon)
        try:  # a NaN would reach the env as every action of every episode
            mean = np.asarray(self.init_mean, dtype=float)
        except (TypeError, ValueError):
            mean = np.array(np.nan)
        if isinstance(self.init_mean, (bool, str)) or mean.ndim > 1 or not np.all(np.isfinite(mean)):
            raise ValueError(f"init_mean must be a finite number or one per action component, got {self.init_mean!r}")
        if mean.ndim:  # plain lists, so that the config stays JSON
            object.__setattr__(self, "init_mean", mean.tolist())
        check_positive("init_std", self.init_std)
        check_positive("min_std", self.min_std)
        check_covariance(self.covariance)
        for name in ("feedback_features", "feedback_angles"):
            value = getattr(self, name)
            if isinstance(value, (list, tuple, np.ndarray)):  # plain lists, so that the config stays JSON
                object.__setattr__(self, name, [v.item() if isinstance(v, np.generic) else v for v in value])
        FeedbackSettings.of(self)
        if self.feedback == "fitted" and self.gains is not None:
            raise ValueError("gains (fixed K_t) and feedback='fitted' exclude each other; pass one of them")
        if self.exploration_floor is not None:
            check_positive("exploration_floor", self.exploration_floor, allow_zero=True)
        check_positive("exploration_halflife", self.exploration_halflife)

    def std_floor(self, iteration: int) -> float:
        """The policy's standard-deviation floor after update ``iteration`` (exploration schedule)."""
        floor = self.exploration_floor
        if floor is None:
            floor = FITTED_EXPLORATION_FLOOR if self.feedback == "fitted" else 0.0
        return max(self.min_std, floor * 0.5 ** (iteration / self.exploration_halflife))


class AbstractEpisodicSearch(Agent):
    """Abstract agent over a `LinearGaussianPolicy`; subclasses set `config_class` and define `_update`.

    The config is an `EpisodicSearchConfig` (a subclass of it).
    """

    policy: LinearGaussianPolicy
    horizon: int

    def _num_envs(self) -> int:
        return self.config.n_episodes

    def _setup(self) -> None:
        cfg = self.config
        self.horizon = resolve_horizon(cfg.horizon, self.env)
        self._feedback = FeedbackSettings.of(cfg)
        fitted = self._feedback.mode == "fitted"
        # a space that is no flat Box gets no angles (for_spaces reads a Dict of Boxes, refuses the rest)
        flat = isinstance(self.observation_space, gym.spaces.Box) and len(self.observation_space.shape) == 1
        angles = self._feedback.angle_mask(self.observation_space) if fitted and flat else None
        self.policy = LinearGaussianPolicy.for_spaces(  # Algorithm 1, l.2
            self.observation_space, self.action_space, self.horizon, init_mean=cfg.init_mean,
            init_std=cfg.init_std, covariance=cfg.covariance, min_std=cfg.min_std, gains=cfg.gains, angles=angles,
        )
        obs_dim = self.policy.obs_dim
        if fitted and angles is None:  # a Dict's concatenated entries: none is read as an angle
            angles = np.zeros(obs_dim, dtype=bool)
        #: the components the fitted gains act on; all false until "auto" has seen a batch
        self.feedback_features = np.zeros(obs_dim, dtype=bool)
        if fitted:
            if cfg.feedback_features == "auto":  # known after the first batch; check the likely count now
                guess = min(obs_dim, len(self.formula.signals) + int(angles.sum()))
                self._feedback.check_fittable(cfg.n_episodes, guess, "feedback_features='auto'")
            else:
                self.feedback_features = self._feedback.feature_mask(obs_dim, angles, None)
                self._feedback.check_fittable(cfg.n_episodes, int(self.feedback_features.sum()),
                                              f"feedback_features={cfg.feedback_features!r}")

    #: The config field of the weights' KL bound (TLPS's ``kl_bound``, REPS's ``epsilon``).
    kl_field: str = "kl_bound"

    @classmethod
    def _saved_config(cls, config: dict[str, Any]) -> dict[str, Any]:
        # files saved before fitted feedback existed hold open-loop policies
        config = {"feedback": "open", **config}
        # saved before 2026-12-06, a bound that cannot bind (the old fixed default 2.0 with n <= 7) was taken as
        # given, one-hot weights; it loads as today's default, which `check_kl_bound` would otherwise refuse
        bound, n = config.get(cls.kl_field), config.get("n_episodes")
        if isinstance(bound, (int, float)) and isinstance(n, int) and n >= 2 and bound >= math.log(n):
            config[cls.kl_field] = None
        return config

    @abc.abstractmethod
    def _update(self, iteration: int) -> dict[str, Any]:
        """One policy update (see `Agent._update`)."""

    def _refit(self, batch: Rollouts, feedforward: np.ndarray, weights: np.ndarray, min_std: float) -> dict[str, Any]:
        """Refit the policy to the weighted batch; returns extra history keys.

        Open loop: `LinearGaussianPolicy.update` (``k_t``, ``C_t``). Fitted: the same update gives
        ``C_t`` (the drawn noise's weighted covariance, floored at ``min_std``); `fit_feedback` gives
        ``K_t``, ``s̄_t`` and ``k_t``.
        """
        policy = self.policy
        if self._feedback.mode == "open":
            policy.update(feedforward, weights, min_std=min_std)
            return {}
        horizon = policy.horizon
        states = batch.observations[:, :horizon]
        if not self.feedback_features.any():  # "auto": the signals' components are known now
            signals = signal_components(batch.observations, batch.traces)
            mask = self._feedback.feature_mask(policy.obs_dim, policy.angles, signals)
            self._feedback.check_fittable(self.config.n_episodes, int(mask.sum()), "feedback_features='auto'")
            self.feedback_features = mask
        n = feedforward.shape[0]
        steps = np.broadcast_to(np.arange(horizon), (n, horizon)).reshape(-1)
        executed = feedforward + policy.feedback_term(steps, states.reshape(-1, policy.obs_dim)).reshape(
            n, horizon, policy.act_dim)
        fit = fit_feedback(
            states, feedforward - policy.mean, executed, weights, policy.gains, self.feedback_features,
            policy.angles, ridge=self.config.feedback_ridge, window=self.config.feedback_window,
            valid=np.arange(horizon)[None, :] < batch.lengths[:, None],
            previous_mean=policy.mean, previous_centre=policy.centre,
        )
        policy.update(feedforward, weights, min_std=min_std)
        policy.mean, policy.gains, policy.centre = fit.mean, fit.gains, fit.centre
        return {"feedback_gain": float(np.abs(fit.gains).sum(axis=2).mean())}

    def predict(
        self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        if isinstance(self.observation_space, gym.spaces.Dict):  # the policy reads the entries concatenated
            key, space = next(iter(self.observation_space.spaces.items()))
            rows = flat_observations(self.observation_space, obs)
            obs = rows[0] if np.ndim(obs[key]) == len(space.shape) else rows
        action, state = self.policy.predict(obs, state, episode_start, deterministic, self._predict_rng)
        action = np.clip(action, self.action_space.low, self.action_space.high)
        if np.issubdtype(self.action_space.dtype, np.floating):  # the space's float type, as SB3 returns actions
            action = action.astype(self.action_space.dtype)
        return action, state

    def _config(self) -> dict[str, Any]:
        return dataclasses.asdict(self.config)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        if self._feedback.mode == "open":
            return self.policy.arrays()
        return {**self.policy.arrays(centre=True), "feedback_features": self.feedback_features}

    def _extra_files(self) -> dict[str, bytes]:
        return {}

    def _load_state(self, arrays: dict[str, np.ndarray], files: dict[str, bytes]) -> None:
        self.policy.load_arrays(arrays)
        if "feedback_features" in arrays:
            self.feedback_features = np.array(arrays["feedback_features"], dtype=bool)
