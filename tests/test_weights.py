"""Tests of the trajectory fits, logits and temperature of TLPS (agents/weights.py)."""

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal
from tl_gym.agents.weights import (
    adapt_alpha,
    fit_gaussian,
    kl_to_uniform,
    sample_logits,
    softmax_weights,
    standardise,
)


@pytest.fixture
def batch():
    return np.random.default_rng(0).normal(size=(30, 7, 2)) * [1.0, 3.0]


def test_fit_is_eq_12_per_step_plus_the_ridge(batch):
    fit = fit_gaussian(batch, regularization=0.5)
    np.testing.assert_allclose(fit.mean, batch.mean(axis=0))
    for t in range(batch.shape[1]):
        expected = np.cov(batch[:, t].T, bias=True) + 0.5 * np.eye(2)
        np.testing.assert_allclose(fit.cov[t], expected)


def test_log_density_is_the_sum_of_per_step_gaussians(batch):
    fit = fit_gaussian(batch, regularization=0.1)
    expected = sum(multivariate_normal(fit.mean[t], fit.cov[t]).logpdf(batch[:, t]) for t in range(batch.shape[1]))
    np.testing.assert_allclose(fit.log_density(batch), expected)


def test_importance_logits_vanish_when_nothing_moved(batch):
    logits = sample_logits("importance", batch, batch.copy(), regularization=1.0)
    np.testing.assert_allclose(logits, 0.0, atol=1e-9)
    np.testing.assert_allclose(softmax_weights(logits, adapt_alpha(logits, 1.0)), 1 / len(batch))


def test_importance_logits_rank_samples_along_the_improvement(batch):
    # Every trajectory moves by the same shift δ: both fits share Σ, so the log-ratio is
    # Σ_t (τ_t - μ_t)ᵀ Σ_t⁻¹ δ_t + const, the sample's projection on the improvement.
    shift = np.zeros_like(batch[0])
    shift[:, 0] = 0.3
    logits = sample_logits("importance", batch, batch + shift, regularization=1.0)
    fit = fit_gaussian(batch, 1.0)
    projection = np.einsum("nti,tij,tj->n", batch - fit.mean, np.linalg.inv(fit.cov), shift)
    np.testing.assert_allclose(logits - logits.mean(), projection - projection.mean(), rtol=1e-9, atol=1e-9)


def test_paper_logits_are_log_densities_under_the_updated_fit(batch):
    updated = batch + 0.2
    logits = sample_logits("paper", batch, updated, regularization=1.0)
    np.testing.assert_allclose(logits, fit_gaussian(updated, 1.0).log_density(batch))


def test_hybrid_mixes_standardised_parts(batch):
    updated = batch * 1.1 + 0.2
    smooth = np.random.default_rng(1).normal(size=len(batch))
    importance = sample_logits("importance", batch, updated, 1.0)
    hybrid = sample_logits("hybrid", batch, updated, 1.0, updated_smooth=smooth, mix=0.7)
    np.testing.assert_allclose(hybrid, 0.7 * standardise(smooth) + 0.3 * standardise(importance))
    only_smooth = sample_logits("hybrid", batch, updated, 1.0, updated_smooth=smooth, mix=1.0)
    np.testing.assert_allclose(only_smooth, standardise(smooth))
    with pytest.raises(ValueError, match="updated_smooth"):
        sample_logits("hybrid", batch, updated, 1.0)
    with pytest.raises(ValueError, match="mix"):
        sample_logits("hybrid", batch, updated, 1.0, updated_smooth=smooth, mix=1.5)
    with pytest.raises(ValueError, match="weighting"):
        sample_logits("softmax", batch, updated, 1.0)


@pytest.mark.parametrize("bound", [0.1, 1.0, 2.0, 3.0])
def test_adapted_alpha_meets_the_kl_bound(bound):
    logits = np.random.default_rng(2).normal(size=40) * 50.0
    alpha = adapt_alpha(logits, bound)
    assert kl_to_uniform(softmax_weights(logits, alpha)) == pytest.approx(bound, rel=1e-6)


def test_adapt_alpha_saturates_when_the_bound_cannot_be_reached():
    logits = np.array([0.0, 0.0, 1.0, 1.0])  # KL at most log 2 < 1
    assert adapt_alpha(logits, 1.0, alpha_max=1e6) == 1e6
    assert adapt_alpha(np.zeros(5), 1.0, alpha_max=7.0) == 7.0


def test_softmax_is_stable_and_kl_has_its_extremes():
    w = softmax_weights(np.array([1e300, 0.0, -1e300]), 1.0)
    np.testing.assert_allclose(w, [1.0, 0.0, 0.0])
    assert kl_to_uniform(np.full(8, 1 / 8)) == pytest.approx(0.0, abs=1e-12)
    assert kl_to_uniform(np.eye(8)[3]) == pytest.approx(math.log(8))


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="regularization"):
        fit_gaussian(np.zeros((3, 4, 2)), regularization=0.0)
    with pytest.raises(ValueError, match="N >= 2"):
        fit_gaussian(np.zeros((1, 4, 2)), regularization=1.0)
    with pytest.raises(ValueError, match="kl_bound"):
        adapt_alpha(np.arange(3.0), kl_bound=0.0)
