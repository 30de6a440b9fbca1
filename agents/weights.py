"""Trajectory-distribution fits and sample weights of TLPS (Algorithm 1, lines 9–13).

A trajectory τ is the recorded signal values, shape ``(T, S)``. Its distribution is
modelled as a Gaussian that is block-diagonal per time step (paper, section IV):
``N(τ | μ, Σ) = Π_t N(τ_t | μ_t, Σ_t)``, each ``Σ_t`` an ``S × S`` matrix plus a
ridge ``regularization · I``. The ridge matters: early time steps of a batch that
starts from one state have tiny variances, and without it those steps dominate Σ⁻¹.

Weights are computed from logits in log space (a softmax of densities, as the paper
writes it, underflows for 200-step trajectories):

- ``"paper"``: logit ``log N(τ^i | μ̄, Σ̄)``, the paper's weight with the density
  replaced by its log. It mostly rewards closeness to the batch mean.
- ``"importance"``: logit ``log N(τ^i | μ̄, Σ̄) − log N(τ^i | μ, Σ)``, with (μ̄, Σ̄)
  fitted to the updated trajectories and (μ, Σ) to the sampled ones: an importance
  ratio of the improved distribution over the current one. Closeness to the batch mean
  cancels; what remains is how far τ^i lies in the direction of the improvement.
- ``"hybrid"``: ``mix · z(ρ̂(τ̄^i)) + (1 − mix) · z(importance logit)``, ``z`` the
  standardisation over the batch and ρ̂(τ̄^i) the smoothed robustness of the updated
  trajectory. It keeps ranking samples near success, where the importance logits lose
  their correlation with the robustness.

The temperature α of ``w ∝ exp(α · logit)`` is either fixed or adapted so that
KL(w ‖ uniform) equals a bound (the weights' effective sample size then stays near
``N · exp(−bound)``).

Example:
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> sampled = rng.normal(size=(40, 10, 2))
    >>> updated = sampled + 0.5  # every trajectory moved the same way
    >>> logits = sample_logits("importance", sampled, updated, regularization=1.0)
    >>> alpha = adapt_alpha(logits, kl_bound=1.0)
    >>> w = softmax_weights(logits, alpha)
    >>> round(kl_to_uniform(w), 6)
    1.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tl_gym.checks import check_fraction, check_positive

Weighting = Literal["importance", "hybrid", "paper"]
WEIGHTINGS = ("importance", "hybrid", "paper")
_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class GaussianFit:
    """A block-diagonal Gaussian over trajectories of shape ``(T, S)``.

    Attributes:
        mean: μ_t per step, shape ``(T, S)``.
        cov: Σ_t per step (ridge included), shape ``(T, S, S)``.
    """

    mean: np.ndarray
    cov: np.ndarray

    def log_density(self, trajectories: np.ndarray) -> np.ndarray:
        """``log N(τ^i | μ, Σ)`` of each trajectory, shape ``(N,)``; ``trajectories`` is ``(N, T, S)``."""
        chol = np.linalg.cholesky(self.cov)  # (T, S, S)
        dev = np.asarray(trajectories, dtype=np.float64) - self.mean  # (N, T, S)
        # whitened deviations z = L⁻¹ (τ − μ), one small inverse per step
        z = np.einsum("tij,ntj->nti", np.linalg.inv(chol), dev)
        log_det = 2.0 * np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)))
        size = self.mean.size
        return -0.5 * (np.sum(z**2, axis=(1, 2)) + log_det + size * _LOG_2PI)


def fit_gaussian(trajectories: np.ndarray, regularization: float) -> GaussianFit:
    """Fit μ_t, Σ_t per time step (paper, Eq. 12) and add ``regularization · I`` to each Σ_t.

    Args:
        trajectories: shape ``(N, T, S)`` with ``N ≥ 2``.
        regularization: ridge on each Σ_t, in squared signal units (> 0).
    """
    trajectories = np.asarray(trajectories, dtype=np.float64)
    if trajectories.ndim != 3 or trajectories.shape[0] < 2:
        raise ValueError(f"trajectories must have shape (N, T, S) with N >= 2, got {trajectories.shape}")
    check_positive("regularization", regularization)
    mean = trajectories.mean(axis=0)
    dev = trajectories - mean
    cov = np.einsum("nti,ntj->tij", dev, dev) / trajectories.shape[0]  # Eq. 12 (1/N)
    cov += regularization * np.eye(trajectories.shape[2])
    return GaussianFit(mean, cov)


def is_flat(values: np.ndarray) -> bool:
    """Whether the batch's values are all equal, up to rounding (a spread of 1e-12 of their magnitude).

    Weights computed from rounding noise would pick an episode at random; both agents give uniform weights.
    """
    values = np.asarray(values, dtype=np.float64)
    return not values.std() > 1e-12 * max(1.0, float(np.abs(values).max()))


def standardise(values: np.ndarray) -> np.ndarray:
    """Zero mean and unit standard deviation over the batch (zeros when all values are equal, `is_flat`)."""
    values = np.asarray(values, dtype=np.float64)
    if is_flat(values):
        return np.zeros_like(values)
    return (values - values.mean()) / values.std()


#: The KL bound of TLPS (``kl_bound``) and REPS (``epsilon``) when none is given: at most log(n / 2) (`kl_bound_for`).
DEFAULT_KL_BOUND = 2.0


def kl_bound_for(bound: float | None, n: int) -> float:
    """The KL bound an update of ``n`` samples applies: ``bound`` as given, or by default ``min(2.0, log(n / 2))``.

    KL(w ‖ uniform) is at most log n, reached by one-hot weights, so a bound near log n cannot bind: every
    update would put all the weight on one episode, and the covariance fit collapse to its floor (the old
    fixed default 2.0 with n ≤ 7). The default keeps the weights' effective sample size, about
    ``n · exp(−bound)``, at 2 or more; with n = 2 it is 0: uniform weights, no learning. A bound given
    explicitly is applied as it is, once `check_kl_bound` has let it through.

    Example:
        >>> kl_bound_for(None, 40), round(kl_bound_for(None, 5), 4), kl_bound_for(None, 2), kl_bound_for(3.5, 40)
        (2.0, 0.9163, 0.0, 3.5)
    """
    return min(DEFAULT_KL_BOUND, math.log(n / 2.0)) if bound is None else float(bound)


def check_kl_bound(name: str, bound: float | None, n: int) -> None:
    """Refuse a KL bound that is not a number > 0, or that cannot bind with ``n`` samples (>= log n).

    Raises:
        ValueError: naming the setting, the bound and log n.
    """
    if bound is None:
        return
    check_positive(name, bound)
    if bound >= math.log(n):
        raise ValueError(
            f"{name}={bound} cannot bind with n_episodes={n}: KL(w ‖ uniform) is at most log {n} = {math.log(n):.3f}, "
            f"reached by one-hot weights, so every update would put all the weight on one episode; give {name} below "
            f"{math.log(n):.3f}, or leave it out (the default: {DEFAULT_KL_BOUND}, at most log(n_episodes / 2))")


def sample_logits(
    weighting: Weighting,
    sampled: np.ndarray,
    updated: np.ndarray,
    regularization: float,
    updated_smooth: np.ndarray | None = None,
    mix: float = 0.7,
) -> np.ndarray:
    """Log-weights (before the temperature α) of the sampled trajectories.

    Args:
        weighting: ``"importance"``, ``"hybrid"`` or ``"paper"`` (see the module docstring).
        sampled: sampled trajectories τ, shape ``(N, T, S)``.
        updated: trust-region updated trajectories τ̄, shape ``(N, T, S)``.
        regularization: ridge of both Gaussian fits.
        updated_smooth: ρ̂(τ̄^i), shape ``(N,)``; required by ``"hybrid"``.
        mix: share of the standardised ρ̂(τ̄^i) in ``"hybrid"``, in [0, 1].

    Returns:
        Logits, shape ``(N,)``.
    """
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting must be one of {WEIGHTINGS}, got {weighting!r}")
    if weighting == "hybrid" and mix == 1.0 and updated_smooth is not None:
        return standardise(updated_smooth)  # the importance share is zero: skip its two Gaussian fits
    improved = fit_gaussian(updated, regularization)  # Eq. 12 on τ̄ (l.9)
    log_bar = improved.log_density(sampled)  # l.11, in log space
    if weighting == "paper":
        return log_bar
    importance = log_bar - fit_gaussian(sampled, regularization).log_density(sampled)
    if weighting == "importance":
        return importance
    if updated_smooth is None:
        raise ValueError("the hybrid weighting needs updated_smooth, the smoothed robustness of τ̄")
    check_fraction("mix", mix, allow_zero=True)
    return mix * standardise(updated_smooth) + (1.0 - mix) * standardise(importance)


def softmax_weights(logits: np.ndarray, alpha: float) -> np.ndarray:
    """``w^i = exp(α logit^i) / Σ_j exp(α logit^j)``, computed stably (Algorithm 1, l.12)."""
    scaled = alpha * np.asarray(logits, dtype=np.float64)
    scaled -= scaled.max()
    w = np.exp(scaled)
    return w / w.sum()


def kl_to_uniform(weights: np.ndarray) -> float:
    """``KL(w ‖ uniform) = Σ w log(N w)`` (0 for uniform weights, log N for one-hot)."""
    w = np.asarray(weights, dtype=np.float64)
    positive = w[w > 0]
    return float(np.sum(positive * np.log(len(w) * positive)))


def adapt_alpha(logits: np.ndarray, kl_bound: float, alpha_max: float = 1e8) -> float:
    """The α ≥ 0 at which ``KL(softmax(α · logits) ‖ uniform)`` equals ``kl_bound``.

    KL grows monotonically with α from 0 (uniform) to ``log N − log(#ties at the max)``;
    when even ``alpha_max`` stays within the bound, ``alpha_max`` is returned. Solved by
    bisection on log α (60 halvings: relative precision far below what matters).

    Args:
        logits: shape ``(N,)``.
        kl_bound: the bound (> 0).
        alpha_max: upper limit of the search.
    """
    if not (math.isfinite(kl_bound) and kl_bound > 0):
        raise ValueError(f"kl_bound must be a positive finite number, got {kl_bound!r}")
    logits = np.asarray(logits, dtype=np.float64)
    centred = logits - logits.mean()
    scale = float(np.abs(centred).max())
    if scale == 0.0:
        return alpha_max  # all logits equal: every α gives uniform weights
    # Work with unit-scale logits; α = a / scale.
    unit = centred / scale
    hi = alpha_max * scale
    if kl_to_uniform(softmax_weights(unit, hi)) <= kl_bound:
        return alpha_max
    lo_log, hi_log = math.log(1e-12), math.log(hi)
    for _ in range(60):
        mid = 0.5 * (lo_log + hi_log)
        if kl_to_uniform(softmax_weights(unit, math.exp(mid))) > kl_bound:
            hi_log = mid
        else:
            lo_log = mid
    return math.exp(lo_log) / scale
