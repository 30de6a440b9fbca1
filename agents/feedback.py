"""Fitted time-varying feedback ``a_t = k_t + K_t (s_t ⊖ s̄_t)`` for the episodic agents.

The paper keeps ``K_t`` fixed (zeros: an open-loop policy), so nothing reacts to where
the system actually is; a wide start spread then defeats TLPS and REPS alike. This
module fits ``K_t`` from the same weighted batch that refits ``k_t`` and ``C_t``, in the
spirit of the guided-policy-search papers the TLPS paper cites (Chebotar et al. 2017,
Montgomery & Levine 2016): a weighted linear regression with a ridge.

One update (`fit_feedback`), given the weights ``w^i`` of the batch:

1. the centre ``s̄_t' = Σ_i w^i s_t^i`` (a circular mean for angle components);
2. the deviations ``d_t^i = s_t^i ⊖ s̄_t'`` of the chosen features (angles wrapped to
   ``[-π, π)``), centred on their weighted mean and standardised with **one** σ per feature
   for all steps (a σ per step blows the gains up where the batch is tight);
3. the gain **increment** ``ΔK_t`` regressed on the drawn exploration noise
   ``ε_t^i = k_t^i − k_t`` with the weights, the moments pooled over the steps
   ``t − window … t + window`` (one step alone has an effective sample size of ≈ 5 at
   KL 2), with ridge ``ridge · I`` in standardised units: a ridge toward the previous
   gains, not toward zero (gains that decay to zero forget what they learned);
4. ``K_t' = K_t + ΔK_t`` and ``k_t'`` the action at the new centre: the weighted mean of
   the executed (unclipped) actions minus ``K_t'`` times the weighted mean deviation;
5. ``C_t`` stays the weighted covariance of the drawn noise (per-step exploration), refit
   by `LinearGaussianPolicy.update` as in open loop.

Example: noise that was rewarded when it pushed the action against the state recovers
that gain.

    >>> rng = np.random.default_rng(0)
    >>> n, T = 4000, 3
    >>> states = rng.normal(size=(n, T, 1))
    >>> noise = rng.normal(size=(n, T, 1))
    >>> logw = -2.0 * ((noise + 0.5 * states)[..., 0] ** 2).sum(axis=1)   # best: noise ≈ -0.5 s
    >>> w = np.exp(logw - logw.max())
    >>> fit = fit_feedback(states, noise, noise, w, np.zeros((T, 1, 1)), np.array([0]), np.zeros(1, bool),
    ...                    ridge=0.0, window=1)
    >>> bool(np.allclose(fit.gains[:, 0, 0], -0.4, atol=0.05))   # the posterior slope 4·0.5 / (1 + 4)
    True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.checks import check_positive

FEEDBACK_MODES = ("open", "fitted")

#: ``feedback_features`` strings: ``"auto"`` (the signals' components and the angles) or ``"all"``.
FEATURE_CHOICES = ("auto", "all")

#: The exploration floor a fitted feedback gets when ``exploration_floor`` is left at ``None``:
#: the regression learns from the drawn noise, so the noise must not collapse (without a floor the
#: exploration std collapses within ~15 iterations and the gains freeze; docs/tlps.md).
FITTED_EXPLORATION_FLOOR = 0.1


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """``x`` wrapped to ``[-π, π)``.

    >>> float(wrap_angle(np.array(3 * np.pi / 2)))
    -1.5707963267948966
    """
    return np.mod(np.asarray(x) + math.pi, 2.0 * math.pi) - math.pi


def deviation(obs: np.ndarray, centre: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``obs ⊖ centre``: the difference, wrapped to ``[-π, π)`` on the ``angles`` mask's components."""
    dev = np.asarray(obs, dtype=float) - centre
    if angles.any():
        dev[..., angles] = wrap_angle(dev[..., angles])
    return dev


def angle_components(space: gym.spaces.Box) -> np.ndarray:
    """Components of a flat Box bounded by exactly ``[-π, π]``: read as angles (``"auto"`` angles).

    >>> angle_components(gym.spaces.Box(np.array([-1.0, -np.pi]), np.array([1.0, np.pi]), dtype=np.float64)).tolist()
    [False, True]
    """
    low, high = np.asarray(space.low, dtype=float), np.asarray(space.high, dtype=float)
    return np.isclose(low, -math.pi, rtol=0, atol=1e-6) & np.isclose(high, math.pi, rtol=0, atol=1e-6)


def matching_components(observations: np.ndarray, trace: np.ndarray) -> list[int]:
    """The observation components equal to a signal's ``(N, T+1)`` trace at every step of every episode."""
    trace = np.asarray(trace, dtype=float)
    if trace.shape != observations.shape[:2]:
        return []
    return [j for j in range(observations.shape[-1])
            if np.allclose(observations[..., j], trace, rtol=1e-9, atol=1e-9)]


def signal_components(observations: np.ndarray, traces: dict[str, np.ndarray]) -> np.ndarray:
    """Observation components that some signal's trace equals over the whole batch.

    The wrapper records each signal from the observation (or from a callable); a component
    that equals a trace at every step of every episode is where that signal is read from.

    Args:
        observations: ``(N, T+1, obs_dim)``.
        traces: signal name -> ``(N, T+1)``.

    Returns:
        A boolean mask ``(obs_dim,)``.
    """
    mask = np.zeros(observations.shape[-1], dtype=bool)
    for values in traces.values():
        mask[matching_components(observations, values)] = True
    return mask


@dataclass(frozen=True)
class FeedbackSettings:
    """The feedback fields shared by `TLPSConfig` and `REPSConfig`, checked in one place.

    Attributes mirror the config fields ``feedback``, ``feedback_features``,
    ``feedback_angles``, ``feedback_ridge`` and ``feedback_window``.
    """

    mode: str
    features: Any
    angles: Any
    ridge: float
    window: int

    @classmethod
    def of(cls, config: Any) -> FeedbackSettings:
        """Read and check the fields of an agent config; raises `ValueError` naming the bad field."""
        settings = cls(config.feedback, config.feedback_features, config.feedback_angles,
                       config.feedback_ridge, config.feedback_window)
        settings.check(config.n_episodes)
        return settings

    def check(self, n_episodes: int) -> None:
        """Validate the fields (and, for explicit features, that ``n_episodes`` can fit them)."""
        if self.mode not in FEEDBACK_MODES:
            raise ValueError(f"feedback must be one of {FEEDBACK_MODES}, got {self.mode!r}")
        if not (isinstance(self.features, str) and self.features in FEATURE_CHOICES) \
                and not _index_tuple(self.features):
            raise ValueError(f"feedback_features must be one of {FEATURE_CHOICES} or a non-empty sequence of "
                             f"distinct observation indices >= 0, got {self.features!r}")
        empty = isinstance(self.angles, Sequence) and not isinstance(self.angles, str) and len(self.angles) == 0
        if not (self.angles == "auto" or empty or _index_tuple(self.angles)):
            raise ValueError(f"feedback_angles must be 'auto' or a sequence of distinct observation indices, "
                             f"got {self.angles!r}")
        check_positive("feedback_ridge", self.ridge, allow_zero=True)
        if isinstance(self.window, bool) or not isinstance(self.window, (int, np.integer)) or self.window < 0:
            raise ValueError(f"feedback_window must be an int >= 0, got {self.window!r}")
        if not isinstance(self.features, str):
            self.check_fittable(n_episodes, len(self.features), f"feedback_features={list(self.features)}")

    def check_fittable(self, n_episodes: int, dim: int, features: str) -> None:
        """Refuse a ridge-free fit of ``dim`` features from ``n_episodes`` episodes.

        A step's weighted moment matrix of N centred deviations has rank at most N − 1, so
        without a ridge it is singular unless ``N > dim``.
        """
        if self.mode == "fitted" and self.ridge == 0 and n_episodes <= dim:
            raise ValueError(
                f"n_episodes={n_episodes} cannot fit {dim} feedback features ({features}) with "
                f"feedback_ridge=0: the regression is singular; raise n_episodes above {dim}, set "
                "feedback_ridge > 0, choose fewer feedback_features or use feedback='open'"
            )

    def angle_mask(self, space: gym.spaces.Box) -> np.ndarray:
        """The angle components of the observation (``"auto"``: bounded by ±π)."""
        if self.angles == "auto":
            return angle_components(space)
        return _mask(self.angles, space.shape[0], "feedback_angles")

    def feature_mask(self, obs_dim: int, angles: np.ndarray, signals: np.ndarray | None) -> np.ndarray:
        """The regressed components: explicit, ``"all"``, or ``"auto"`` = signal components and angles.

        ``"auto"`` falls back to all components when no signal is an observation component
        (``signals`` all false, or unknown yet).
        """
        if self.features == "all":
            return np.ones(obs_dim, dtype=bool)
        if self.features == "auto":
            if signals is None or not signals.any():
                return np.ones(obs_dim, dtype=bool)
            return signals | angles
        return _mask(self.features, obs_dim, "feedback_features")


def _index_tuple(value: Any) -> bool:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) == 0:
        return False
    ok = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0 for v in value)
    return ok and len(set(value)) == len(value)


def _mask(indices: Sequence[int], size: int, field: str) -> np.ndarray:
    if any(i >= size for i in indices):
        raise ValueError(f"{field}={list(indices)} names a component past the observation's {size}")
    mask = np.zeros(size, dtype=bool)
    mask[list(indices)] = True
    return mask


@dataclass(frozen=True)
class FeedbackFit:
    """One fitted update of the policy's mean part.

    Attributes:
        gains: ``K_t'``, ``(T, act_dim, obs_dim)`` (zero outside the features).
        centre: ``s̄_t'``, ``(T, obs_dim)``.
        mean: ``k_t'``, the action at the new centre, ``(T, act_dim)``.
    """

    gains: np.ndarray
    centre: np.ndarray
    mean: np.ndarray


def weighted_centre(states: np.ndarray, w: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Per-step weighted mean of ``states`` ``(N, T, D)`` with weights ``w`` ``(N, T)`` summing to 1 per step.

    Angle components get the circular mean ``atan2(Σ w sin, Σ w cos)``.
    """
    centre = np.einsum("nt,ntd->td", w, states)
    if angles.any():
        a = states[..., angles]
        centre[:, angles] = np.arctan2(np.einsum("nt,ntd->td", w, np.sin(a)), np.einsum("nt,ntd->td", w, np.cos(a)))
    return centre


def window_mean(moments: np.ndarray, window: int) -> np.ndarray:
    """Mean of ``moments`` ``(T, ...)`` over the steps ``t − window … t + window`` (clipped to the horizon)."""
    horizon = moments.shape[0]
    cumulative = np.concatenate([np.zeros((1, *moments.shape[1:])), np.cumsum(moments, axis=0)])
    t = np.arange(horizon)
    low, high = np.maximum(t - window, 0), np.minimum(t + window + 1, horizon)
    count = (high - low).reshape(-1, *([1] * (moments.ndim - 1)))
    return (cumulative[high] - cumulative[low]) / count


def fit_feedback(
    states: np.ndarray,
    noise: np.ndarray,
    actions: np.ndarray,
    weights: np.ndarray,
    gains: np.ndarray,
    features: np.ndarray,
    angles: np.ndarray,
    *,
    ridge: float,
    window: int,
    valid: np.ndarray | None = None,
    previous_mean: np.ndarray | None = None,
    previous_centre: np.ndarray | None = None,
) -> FeedbackFit:
    """Refit ``K_t``, the centre ``s̄_t`` and ``k_t`` from a weighted batch (module docstring, steps 1–4).

    Args:
        states: ``s_t^i`` at which each action was taken, ``(N, T, obs_dim)``.
        noise: the drawn exploration noise ``ε_t^i = k_t^i − k_t``, ``(N, T, act_dim)``.
        actions: the executed actions before clipping, ``(N, T, act_dim)``.
        weights: the samples' weights ``(N,)`` (normalised here).
        gains: the current ``K_t``, ``(T, act_dim, obs_dim)``.
        features: indices of the regressed components (or a boolean mask ``(obs_dim,)``).
        angles: boolean mask ``(obs_dim,)`` of angle components.
        ridge: ridge on ``ΔK_t`` in standardised units (>= 0).
        window: pooling half-width in steps (>= 0).
        valid: ``(N, T)`` true where the step happened (episodes that ended early); all by default.
        previous_mean: the current ``k_t`` ``(T, act_dim)``, kept (with the gains) at the steps no
            episode of the batch reached; zeros there when not given.
        previous_centre: the current ``s̄_t`` ``(T, obs_dim)``, kept at those steps likewise.
    """
    states = np.asarray(states, dtype=float)
    n, horizon, obs_dim = states.shape
    feats = np.flatnonzero(features) if np.asarray(features).dtype == bool else np.asarray(features, dtype=int)
    valid = np.ones((n, horizon), dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    w = np.asarray(weights, dtype=float)[:, None] * valid  # (N, T)
    reached = w.sum(axis=0) > 0  # steps some weighted episode reached; the others keep the current fit
    w = w / np.maximum(w.sum(axis=0, keepdims=True), 1e-300)
    steps = reached.astype(float)

    centre = weighted_centre(states, w, angles)
    dev = deviation(states, centre[None], angles)  # (N, T, D)
    d = dev[..., feats]
    d = d - np.einsum("nt,ntf->tf", w, d)[None]  # centred on the weighted mean at t
    sigma = np.sqrt(np.einsum("nt,ntf->f", w, d**2) / max(steps.sum(), 1.0))
    sigma = np.where(sigma > 1e-12, sigma, 1.0)  # a constant component carries nothing; ΔK stays 0 there
    z = d / sigma
    e = np.asarray(noise, dtype=float)
    e = e - np.einsum("nt,nta->ta", w, e)[None]

    share = np.maximum(window_mean(steps, window), 1e-300)[:, None, None]  # pooled over reached steps only
    zz = window_mean(np.einsum("nt,ntf,ntg->tfg", w, z, z), window) / share
    ez = window_mean(np.einsum("nt,nta,ntf->taf", w, e, z), window) / share
    lhs = zz + ridge * np.eye(len(feats))
    # ΔK_t = ez_t lhs_t⁻¹, solved as lhs_t ΔK_tᵀ = ez_tᵀ (lhs symmetric); a pseudo-inverse if a step is singular
    try:
        delta = np.swapaxes(np.linalg.solve(lhs, np.swapaxes(ez, 1, 2)), 1, 2)
    except np.linalg.LinAlgError:
        delta = np.einsum("taf,tfg->tag", ez, np.linalg.pinv(lhs, hermitian=True))
    new_gains = np.array(gains, dtype=float)
    new_gains[:, :, feats] += delta / sigma * steps[:, None, None]

    mean_action = np.einsum("nt,nta->ta", w, np.asarray(actions, dtype=float))
    mean_dev = np.einsum("nt,ntd->td", w, dev)
    mean = mean_action - np.einsum("tad,td->ta", new_gains, mean_dev)
    if previous_mean is not None:
        mean = np.where(reached[:, None], mean, previous_mean)
    if previous_centre is not None:
        centre = np.where(reached[:, None], centre, previous_centre)
    return FeedbackFit(gains=new_gains, centre=centre, mean=mean)
