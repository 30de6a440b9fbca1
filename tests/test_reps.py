"""Episodic REPS: the dual's solution and learning on the car's task 1."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tl_gym.agents import REPS
from tl_gym.agents.reps import reps_weights

returns_strategy = st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=2, max_size=60).map(np.array)


@settings(max_examples=40, deadline=None)
@given(returns=returns_strategy, epsilon=st.floats(0.05, 3.0))
def test_dual_solution_respects_the_kl_bound(returns, epsilon):
    weights, eta, kl = reps_weights(returns, epsilon)
    assert np.all(np.isfinite(weights)) and np.isclose(weights.sum(), 1.0)
    assert kl <= epsilon + 1e-9
    uniform_kl = np.sum(weights * np.log(weights * len(returns) + 1e-300))
    assert np.isclose(kl, uniform_kl, atol=1e-9)
    order = np.argsort(returns, kind="stable")
    assert np.all(np.diff(weights[order]) >= -1e-12)  # better episodes never weigh less


def test_kl_bound_is_active_when_it_can_be():
    returns = np.random.default_rng(0).normal(size=40)
    for epsilon in (0.1, 0.5, 1.0, 2.0):
        _, _, kl = reps_weights(returns, epsilon)
        assert kl == pytest.approx(epsilon, abs=1e-4)  # epsilon < log(40): the optimum sits on the bound


def test_dual_is_invariant_to_the_scale_and_offset_of_returns():
    returns = np.random.default_rng(1).normal(size=20)
    w, eta, _ = reps_weights(returns, 1.0)
    w2, eta2, _ = reps_weights(1000.0 * returns - 5e4, 1.0)
    np.testing.assert_allclose(w, w2, rtol=1e-6)
    assert eta2 == pytest.approx(1000.0 * eta, rel=1e-6)


def test_equal_returns_give_uniform_weights():
    weights, eta, kl = reps_weights(np.full(5, -3.0), 2.0)
    np.testing.assert_allclose(weights, 0.2)
    assert kl == 0.0


def test_infinite_returns_get_the_limit_of_the_exponential_weights():
    # a robustness of -inf (X at the last state with rho_max=inf) is no reason to stop: it weighs nothing
    finite = np.random.default_rng(3).normal(size=9)
    returns = np.append(finite, -np.inf)
    weights, eta, kl = reps_weights(returns, 1.0)
    assert weights[-1] == 0.0 and np.isfinite(eta) and kl == pytest.approx(1.0, abs=1e-4)
    alone, _, _ = reps_weights(finite, 1.0 - np.log(10 / 9))  # the bound left for the finite ones
    np.testing.assert_allclose(weights[:-1], alone)
    weights, _, kl = reps_weights(returns, 0.05)  # below log(10/9): uniform over the finite ones
    np.testing.assert_allclose(weights, np.append(np.full(9, 1 / 9), 0.0))
    assert kl == pytest.approx(np.log(10 / 9))
    weights, _, _ = reps_weights(np.array([np.inf, 0.0, np.inf, -np.inf]), 2.0)
    np.testing.assert_allclose(weights, [0.5, 0.0, 0.5, 0.0])
    weights, _, kl = reps_weights(np.full(3, -np.inf), 2.0)
    np.testing.assert_allclose(weights, 1 / 3)
    with pytest.raises(ValueError, match=r"NaN return .* \[1\]"):
        reps_weights(np.array([0.0, np.nan, 1.0]), 2.0)


def test_dual_solution_is_the_minimum():
    returns = np.random.default_rng(2).normal(size=30)
    epsilon = 0.7
    _, eta, _ = reps_weights(returns, epsilon)

    def dual(e):
        z = returns / e
        return e * epsilon + e * (np.log(np.mean(np.exp(z - z.max()))) + z.max())

    assert dual(eta) <= min(dual(eta * 0.9), dual(eta * 1.1))


def test_reps_improves_task_1_within_a_few_iterations():
    agent = REPS("TLCarNav-v0", seed=0, env_kwargs={"task": 1})
    before = agent.evaluate(n_episodes=40, seed=100)["mean_robustness"]
    agent.learn(8)
    after = agent.evaluate(n_episodes=40, seed=100)["mean_robustness"]
    rho = [row["mean_robustness"] for row in agent.history]
    assert after > before + 20.0  # robustness is in arena units (300 x 300)
    assert np.mean(rho[-2:]) > rho[0] + 20.0
    assert all(row["kl"] <= 2.0 + 1e-6 for row in agent.history)  # the default bound at N = 40
    assert agent.history[-1]["policy_std"] < agent.config.init_std  # exploration narrows as it learns


@pytest.mark.parametrize("agent", ["reps", "tlps"])
@pytest.mark.parametrize(("name", "value"), [("epsilon", float("inf")), ("init_std", 0.0), ("min_std", float("nan")),
                                             ("exploration_halflife", True)])
def test_both_episodic_agents_refuse_the_same_bad_numbers(agent, name, value):
    """One positive-number check (tl_gym.checks): REPS no longer accepts an infinite KL bound."""
    from tl_gym.agents.registry import agent_class

    with pytest.raises(ValueError, match=f"{name}.*must be a finite number > 0"):
        agent_class(agent)._make_config({name: value})


def test_returns_equal_up_to_rounding_give_uniform_weights():
    returns = np.full(8, 0.5)
    returns[3] += 1.1e-16  # rounding noise must not pick an episode
    weights, _, kl = reps_weights(returns, epsilon=2.0)
    np.testing.assert_allclose(weights, 1 / 8)
    assert kl == 0.0


@pytest.mark.parametrize(("agent", "bound"), [("reps", "epsilon"), ("tlps", "kl_bound")])
@pytest.mark.parametrize("n", [3, 5])
def test_the_default_kl_bound_leaves_two_episodes_or_more_the_weight_and_one_that_cannot_bind_is_refused(
        agent, bound, n):
    """KL(w ‖ uniform) <= log n: the old fixed default 2.0 with n <= 7 episodes put all the weight on one."""
    from tl_gym.agents import TLPS

    cls = REPS if agent == "reps" else TLPS
    model = cls("TLCarNav-v0", seed=0, n_episodes=n, horizon=20, env_kwargs={"task": 1, "horizon": 20}).learn(1)
    assert 0 < model.history[-1]["kl"] <= np.log(n / 2) + 1e-9  # one-hot weights have KL log n
    with pytest.raises(ValueError, match=rf"{bound}=2.0 cannot bind with n_episodes={n}: .* below {np.log(n):.3f}"):
        cls("TLCarNav-v0", n_episodes=n, **{bound: 2.0})
    explicit = cls("TLCarNav-v0", seed=0, n_episodes=40, horizon=20, env_kwargs={"task": 1, "horizon": 20},
                   **{bound: 3.5}).learn(1)
    assert explicit.history[-1]["kl"] == pytest.approx(3.5, rel=1e-3)  # a bound given is applied as it is
