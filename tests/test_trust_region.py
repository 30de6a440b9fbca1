"""Tests of the trust-region trajectory update (agents/trust_region.py)."""

import math

import numpy as np
import pytest
from tl_gym.agents.trust_region import improve_trajectories, projected_ascent, smooth_value_and_grad

from tl_gym import parse

SOLVERS = ("projected", "slsqp")


@pytest.mark.parametrize("solver", SOLVERS)
def test_linear_objective_moves_to_the_boundary_along_the_gradient(solver):
    # ρ = x + y on a one-state trace: the optimum moves √ε along (1, 1)/√2, a gain of √(2ε).
    phi = parse("x + y > 0")
    tau = np.array([[[0.3, -0.1]], [[-2.0, 1.0]]])
    epsilon = 0.09
    result = improve_trajectories(phi, ("x", "y"), tau, beta=5.0, epsilon=epsilon, solver=solver)
    np.testing.assert_allclose(result.smooth_after - result.smooth_before, math.sqrt(2 * epsilon), rtol=1e-6)
    np.testing.assert_allclose(result.updated - tau, math.sqrt(epsilon / 2), rtol=1e-5)


@pytest.mark.parametrize("solver", SOLVERS)
def test_updates_stay_in_the_trust_region_and_never_lose(solver):
    phi = parse("F (x > 4 & y > 4) & G (sqrt((x - 2)^2 + (y - 2)^2) > 1)")
    rng = np.random.default_rng(1)
    tau = np.cumsum(rng.normal(0.2, 0.3, size=(4, 15, 2)), axis=1)
    epsilon = 0.5
    result = improve_trajectories(phi, ("x", "y"), tau, beta=10.0, epsilon=epsilon, solver=solver, steps=10)
    assert np.all(np.sum((result.updated - tau) ** 2, axis=(1, 2)) <= epsilon * (1 + 1e-9))
    assert np.all(result.smooth_after > result.smooth_before)
    values, _ = smooth_value_and_grad(phi, ("x", "y"), result.updated, 10.0)
    np.testing.assert_allclose(values, result.smooth_after)


def test_projected_reaches_slsqp_within_one_percent_of_the_gain():
    phi = parse("F (x > 4 & x < 5 & y > 4 & y < 5) & G (sqrt((x - 2)^2 + (y - 2.5)^2) > 1)")
    rng = np.random.default_rng(2)
    tau = np.cumsum(rng.normal(0.25, 0.3, size=(5, 20, 2)), axis=1)
    kwargs = dict(beta=9.0, epsilon=0.3)
    slsqp = improve_trajectories(phi, ("x", "y"), tau, solver="slsqp", **kwargs)
    projected = improve_trajectories(phi, ("x", "y"), tau, solver="projected", **kwargs)
    gain_slsqp = np.mean(slsqp.smooth_after - slsqp.smooth_before)
    gain_projected = np.mean(projected.smooth_after - projected.smooth_before)
    assert gain_projected >= 0.99 * gain_slsqp


def test_the_projected_solver_asks_gradients_only_of_the_points_it_moves_to():
    # f(x) = −‖x − c‖² per row: some steps overshoot and are undone; their gradients are never asked for
    centre = np.array([0.3, -0.2, 0.05])[:, None, None] * np.ones((3, 4, 2))
    calls = []  # per evaluation: [rows, values, the selection its gradient was asked for (None: never)]

    def evaluate(x, rows):
        values = -np.sum((x - centre[rows]) ** 2, axis=(1, 2))
        call = [rows, values.copy(), None]  # the solver updates its best values in place
        calls.append(call)

        def gradient(chosen):
            call[2] = rows[chosen]
            return -2.0 * (x[chosen] - centre[rows][chosen])

        return values, gradient

    tau = np.zeros((3, 4, 2))
    result = projected_ascent(evaluate, tau, epsilon=4.0, steps=8, decay=0.5)
    (_, best, asked), *moves = calls
    np.testing.assert_array_equal(asked, np.arange(3))  # the start: every point
    for rows, values, asked in moves:
        improved = rows[values > best[rows]]
        best[improved] = values[values > best[rows]]
        np.testing.assert_array_equal(asked if asked is not None else [], improved)
    assert sum(len(a) for _, _, a in moves if a is not None) < sum(len(rows) for rows, _, _ in moves)
    np.testing.assert_allclose(result.updated, centre, atol=0.05)


def test_the_first_step_length_can_be_given():
    phi = parse("x + y > 0")
    tau = np.zeros((2, 3, 2))
    cold = improve_trajectories(phi, ("x", "y"), tau, beta=5.0, epsilon=1.0, steps=1)
    warm = improve_trajectories(phi, ("x", "y"), tau, beta=5.0, epsilon=1.0, steps=1, first_step=0.1)
    np.testing.assert_allclose(np.sqrt(np.sum((cold.updated - tau) ** 2, axis=(1, 2))), 1.0)
    np.testing.assert_allclose(np.sqrt(np.sum((warm.updated - tau) ** 2, axis=(1, 2))), 0.1)
    capped = improve_trajectories(phi, ("x", "y"), tau, beta=5.0, epsilon=1.0, steps=1, first_step=7.0)
    np.testing.assert_allclose(capped.updated, cold.updated)  # never beyond √ε


def test_gradient_matches_finite_differences():
    phi = parse("F (x > 1) & G (y < 2)")
    rng = np.random.default_rng(3)
    tau = rng.normal(size=(2, 6, 2))
    values, grad = smooth_value_and_grad(phi, ("x", "y"), tau, beta=3.0)
    h = 1e-6
    bumped = tau.copy()
    bumped[1, 2, 0] += h
    values_h, _ = smooth_value_and_grad(phi, ("x", "y"), bumped, beta=3.0)
    assert values_h[0] == values[0]  # trajectories do not interact
    np.testing.assert_allclose((values_h[1] - values[1]) / h, grad[1, 2, 0], rtol=1e-4)


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        (dict(epsilon=0.0), "epsilon"),
        (dict(epsilon=-1.0), "epsilon"),
        (dict(epsilon=math.inf), "epsilon"),
        (dict(beta=-9.0), "beta"),
        (dict(solver="adam"), "solver"),
        (dict(steps=0), "steps"),
        (dict(decay=1.0), "decay"),
    ],
)
def test_bad_settings_raise_naming_the_culprit(kwargs, culprit):
    settings = dict(beta=9.0, epsilon=1.0) | kwargs
    with pytest.raises(ValueError, match=culprit):
        improve_trajectories(parse("x > 0"), ("x",), np.zeros((2, 3, 1)), **settings)


def test_bad_shape_raises():
    with pytest.raises(ValueError, match="shape"):
        improve_trajectories(parse("x > 0"), ("x",), np.zeros((3, 1)), beta=9.0, epsilon=1.0)


@pytest.mark.parametrize("solver", ["projected", "slsqp"])
def test_episodes_that_ended_early_are_judged_and_moved_on_their_own_states(solver):
    """A padded trace repeats its last state: ρ̂ would count it once per copy, and the step would move copies."""
    from tl_gym.agents.trust_region import smooth_by_length

    phi = parse("F(x > 1) & G(y < 2)")
    rng = np.random.default_rng(0)
    lengths = np.array([6, 2, 6, 4])  # actions: 7, 3, 7 and 5 states of the 7 recorded
    tau = rng.normal(size=(4, 7, 2))
    for i, length in enumerate(lengths):
        tau[i, length + 1:] = tau[i, length]  # as rollout pads them
    result = improve_trajectories(phi, ("x", "y"), tau, beta=5.0, epsilon=0.5, solver=solver, lengths=lengths)
    for i, length in enumerate(lengths):
        alone = improve_trajectories(phi, ("x", "y"), tau[i : i + 1, : length + 1], beta=5.0, epsilon=0.5,
                                     solver=solver)
        np.testing.assert_allclose(result.updated[i, : length + 1], alone.updated[0], atol=1e-12)
        np.testing.assert_allclose(result.updated[i, length + 1 :], alone.updated[0, -1:].repeat(6 - length, 0))
        assert result.smooth_before[i] == pytest.approx(alone.smooth_before[0], abs=1e-12)
        assert result.smooth_after[i] == pytest.approx(alone.smooth_after[0], abs=1e-12)
    padded = phi.smooth_robustness({"x": tau[1:2, :, 0], "y": tau[1:2, :, 1]}, 5.0)[0]
    assert result.smooth_before[1] != pytest.approx(padded)  # what the padding would have said
    np.testing.assert_allclose(smooth_by_length(phi, ("x", "y"), tau, 5.0, lengths), result.smooth_before)


@pytest.mark.parametrize("lengths", [[2, 4], [2, -1, 4], [1.0, 2.0, 3.0], [4, 4, 9]])
def test_lengths_that_do_not_fit_the_trajectories_are_refused(lengths):
    with pytest.raises(ValueError, match=r"lengths must be 3 ints in \[0, 4\]"):
        improve_trajectories(parse("F(x > 1)"), ("x",), np.zeros((3, 5, 1)), beta=5.0, epsilon=0.5,
                             lengths=np.array(lengths))


def test_episodes_of_length_zero_or_the_whole_horizon_are_judged_on_what_they_hold():
    phi = parse("F(x > 1)")
    tau = np.random.default_rng(1).normal(size=(3, 5, 1))
    tau[0, 1:] = tau[0, 0]  # an episode that ended at once: s_0 alone
    result = improve_trajectories(phi, ("x",), tau, beta=5.0, epsilon=0.5, lengths=np.array([0, 4, 4]))
    alone = improve_trajectories(phi, ("x",), tau[:1, :1], beta=5.0, epsilon=0.5)
    np.testing.assert_allclose(result.updated[0], np.repeat(alone.updated[0], 5, axis=0), atol=1e-12)
    whole = improve_trajectories(phi, ("x",), tau[1:], beta=5.0, epsilon=0.5)
    np.testing.assert_allclose(result.smooth_after[1:], whole.smooth_after, atol=1e-12)
