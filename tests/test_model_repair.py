"""TLPS's action repair through a known model (agents/model_repair.py, envs/car_model.py)."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
from tl_gym.agents import TLPS
from tl_gym.agents.env_ids import find_formula, make_vector_env
from tl_gym.agents.model_repair import closed_loop, feedforward_gradient, find_model, repair_feedforward
from tl_gym.agents.policy import LinearGaussianPolicy
from tl_gym.agents.sampling import rollout
from tl_gym.envs.car_model import CarModel
from tl_gym.envs.dynamics import CarParams, car_step, wrap_angle

import tl_gym  # noqa: F401  (registers the ids)

HORIZON = 25  # short car episodes keep these tests fast


def test_the_model_is_the_env_step_and_its_jacobians_are_the_step_s_slopes():
    rng = np.random.default_rng(0)
    params, model = CarParams(), CarModel(CarParams())
    state = np.concatenate([rng.uniform(-300, 300, (64, 2)), rng.uniform(-3, 3, (64, 1)), rng.normal(size=(64, 3))], 1)
    action = rng.uniform(-1.5, 1.5, (64, 2))  # beyond the Box: both clip, and the slope there is 0
    noise = rng.normal(0, 0.2, (64, 3))
    expected = car_step(state, params.physical_action(action), params.dt, params.wheelbase, noise)
    np.testing.assert_array_equal(model.step(state, action, noise), expected)
    d_state, d_action = model.jacobians(state, action)
    eps = 1e-6
    for j in range(6):
        step = np.zeros(6)
        step[j] = eps
        diff = model.step(state + step, action, noise) - model.step(state - step, action, noise)
        diff[:, 2] = wrap_angle(diff[:, 2])  # the heading's wrap is no slope
        numeric = diff / (2 * eps)
        np.testing.assert_allclose(d_state[:, :, j], numeric, atol=1e-5)
    for j in range(2):
        step = np.zeros(2)
        step[j] = eps
        numeric = (model.step(state, action + step, noise) - model.step(state, action - step, noise)) / (2 * eps)
        inside = np.abs(action[:, j]) < 1 - eps
        np.testing.assert_allclose(d_action[inside, :, j], numeric[inside], atol=1e-4)
        assert np.all(d_action[~inside, :, j] == 0)


def test_the_adjoint_is_the_closed_loop_s_gradient():
    rng = np.random.default_rng(2)
    horizon, n = 6, 3
    policy = LinearGaussianPolicy(horizon, 6, 2, init_std=0.3, angles=np.array([0, 0, 1, 0, 0, 0], dtype=bool))
    policy.gains = rng.normal(0, 0.005, (horizon, 2, 6))
    model = CarModel(CarParams())
    start = np.concatenate([rng.uniform(0, 100, (n, 2)), rng.uniform(-1, 1, (n, 1)), np.zeros((n, 3))], 1)
    policy.centre = start.mean(axis=0) + rng.normal(0, 2.0, (horizon, 6))  # the feedback acts, the actions rarely clip
    noise, feedforward = rng.normal(0, 0.1, (n, horizon, 3)), rng.uniform(-0.6, 0.6, (n, horizon, 2))
    weights = rng.normal(size=(n, horizon + 1, 6))  # the function: Σ weights · states

    def value(k):
        return np.sum(weights * closed_loop(model, policy, start, noise, k)[0], axis=(1, 2))

    states, actions = closed_loop(model, policy, start, noise, feedforward)
    assert np.mean(np.abs(actions) < 1) > 0.9 and np.abs(actions - feedforward).max() > 0.01
    grad = feedforward_gradient(model, policy, states, actions, weights)
    assert np.mean(grad != 0) > 0.9  # zero only along the few clipped components
    eps = 1e-6
    for t in range(horizon):
        for j in range(2):
            step = np.zeros_like(feedforward)
            step[:, t, j] = eps
            numeric = (value(feedforward + step) - value(feedforward - step)) / (2 * eps)
            np.testing.assert_allclose(grad[:, t, j], numeric, rtol=1e-4, atol=1e-4)


def _batch(policy, seed=3, n=6, task=2):
    venv = make_vector_env("TLCarNav-v0", n, {"task": task, "horizon": HORIZON})
    feedforward = policy.sample_feedforward(n, np.random.default_rng(seed))
    return venv, feedforward, rollout(venv, feedforward, policy.feedback, seed=seed)


class _SteppedModel:
    """The car's model without its compiled loop: `closed_loop` and the adjoint then run step by step in numpy."""

    def __init__(self, model: CarModel):
        self.step, self.jacobians, self.noise = model.step, model.jacobians, model.noise


def test_the_compiled_loop_jacobians_and_adjoint_give_the_numpy_numbers(monkeypatch):
    pytest.importorskip("numba")
    from tl_gym.agents import model_repair
    from tl_gym.envs import car_model

    rng = np.random.default_rng(3)
    horizon, n = 40, 8
    policy = LinearGaussianPolicy(horizon, 6, 2, init_std=0.3, angles=np.array([0, 0, 1, 0, 0, 0], dtype=bool))
    policy.gains = rng.normal(0, 0.01, (horizon, 2, 6))
    policy.centre = rng.normal(0, 20.0, (horizon, 6))
    policy.centre[:, 2] = rng.uniform(-3, 3, horizon)  # headings far apart: the deviation's wrap acts
    model = CarModel(CarParams())
    start = np.concatenate([rng.uniform(0, 100, (n, 2)), rng.uniform(-3, 3, (n, 1)), np.zeros((n, 3))], 1)
    noise, feedforward = rng.normal(0, 0.2, (n, horizon, 3)), rng.uniform(-1.3, 1.3, (n, horizon, 2))  # some clip
    compiled = closed_loop(model, policy, start, noise, feedforward)
    stepped = closed_loop(_SteppedModel(model), policy, start, noise, feedforward)
    assert model.closed_loop(start, noise, feedforward, policy.gains, policy.centre, policy.angles) is not None
    for fast, slow in zip(compiled, stepped):
        np.testing.assert_allclose(fast, slow, rtol=1e-12, atol=1e-9)
    state_gradient = rng.normal(size=compiled[0].shape)
    rows = compiled[0][:, :-1].reshape(-1, 6), compiled[1].reshape(-1, 2)
    fast_jacobians, fast = model.jacobians(*rows), feedforward_gradient(model, policy, *compiled, state_gradient)
    monkeypatch.setattr(model_repair, "_adjoint_kernel", lambda: None)
    monkeypatch.setattr(car_model, "_jacobians_kernel", lambda: None)
    for compiled_jacobian, numpy_jacobian in zip(fast_jacobians, model.jacobians(*rows)):
        np.testing.assert_allclose(compiled_jacobian, numpy_jacobian, rtol=1e-14, atol=1e-14)
    slow = feedforward_gradient(model, policy, *compiled, state_gradient)
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("with_gains", [False, True])
def test_recovered_noise_replays_the_episodes_through_the_closed_loop(with_gains):
    rng = np.random.default_rng(1)
    angles = np.array([False, False, True, False, False, False])
    policy = LinearGaussianPolicy(HORIZON, 6, 2, init_std=0.5, angles=angles)
    if with_gains:  # feedback around a centre state, heading wrapped: the path fitted feedback takes
        policy.gains = rng.normal(0, 0.05, (HORIZON, 2, 6))
        policy.centre = rng.normal(0, 3.0, (HORIZON, 6))
    venv, feedforward, batch = _batch(policy)
    model = find_model(venv)
    assert isinstance(model, CarModel)
    noise = model.noise(batch.observations, batch.actions)
    assert np.abs(noise[..., :2]).max() < 1.0  # the env's noise: std 0.15 on x, y
    replay, _ = closed_loop(model, policy, batch.observations[:, 0], noise, feedforward)
    np.testing.assert_allclose(replay, batch.observations, atol=1e-6)


def test_repair_raises_every_smoothed_robustness_within_the_action_trust_region():
    policy = LinearGaussianPolicy(HORIZON, 6, 2, init_std=0.5)
    venv, feedforward, batch = _batch(policy, task=1)
    formula = find_formula(venv)
    repair = repair_feedforward(find_model(venv), policy, batch, feedforward, formula, epsilon=0.5, beta=9.0,
                                steps=5)
    assert np.all(repair.smooth_after >= repair.smooth_before)
    assert np.mean(repair.smooth_after - repair.smooth_before) > 0.1
    moved = np.sum((repair.feedforward - feedforward) ** 2, axis=(1, 2))
    assert np.all(moved <= 0.5 + 1e-9)
    # the repaired states are the repaired actions' episodes, and their ρ̂ is the reported one
    again = formula.smooth_robustness({"x": repair.observations[..., 0], "y": repair.observations[..., 1]}, 9.0,
                                      math.inf, "linear")
    np.testing.assert_allclose(again, repair.smooth_after, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(repair.traces["x"], repair.observations[..., 0])


def test_tlps_with_model_repair_learns_saves_and_loads(tmp_path):
    kwargs = dict(seed=0, env_kwargs={"task": 1, "horizon": HORIZON}, n_episodes=8, solver_steps=3,
                  action_repair="model", action_epsilon=0.5)
    agent = TLPS("TLCarNav-v0", **kwargs).learn(2)
    assert all(row["smooth_updated"] > row["smooth_robustness"] for row in agent.history)
    agent.save(tmp_path / "agent.zip")
    loaded = TLPS.load(tmp_path / "agent.zip")
    assert loaded.config.action_repair == "model" and loaded.config.action_epsilon == 0.5
    same = TLPS("TLCarNav-v0", **kwargs).learn(2)  # seeded: the repair is deterministic
    assert [r["mean_robustness"] for r in same.history] == [r["mean_robustness"] for r in agent.history]


@pytest.mark.parametrize(
    ("env", "kwargs", "match"),
    [
        ("TLCarNav-v0", {"action_repair": "fitted"}, "action_repair must be one of"),
        ("TLCarNav-v0", {"action_repair": "model", "solver": "slsqp"}, "projected solver"),
        ("TLCarNav-v0", {"action_epsilon": 0.0}, "action_epsilon"),
        ("TLCarNav-v0", {"action_repair": "model", "weights": "importance"}, "ranks the repaired episodes"),
        ("TLPendulum-v0", {"action_repair": "model"}, "'TLPendulum-v0' has none"),
    ],
)
def test_bad_repair_settings_are_refused_at_construction(env, kwargs, match):
    with pytest.raises(ValueError, match=match):
        TLPS(env, n_episodes=8, **kwargs)


def test_an_env_without_a_model_has_none():
    assert find_model(make_vector_env(gym.make("TLPendulum-v0"), 2)) is None


def test_a_batch_the_model_cannot_replay_is_refused_with_a_clear_error():
    policy = LinearGaussianPolicy(HORIZON, 6, 2, init_std=0.5)
    venv, feedforward, batch = _batch(policy, task=1, n=3)
    formula, model = find_formula(venv), find_model(venv)

    def repair(b):
        return repair_feedforward(model, policy, b, feedforward, formula, epsilon=0.5, beta=9.0, steps=1)

    with pytest.raises(RuntimeError, match="full horizon"):
        repair(dataclasses.replace(batch, lengths=batch.lengths - 1))
    with pytest.raises(ValueError, match="signal 'x' is not one"):
        repair(dataclasses.replace(batch, traces={**batch.traces, "x": batch.traces["x"] + 1.0}))
    scaled = batch.actions * 3.0  # what a RescaleAction wrapper would have sent, unknown to the model
    with pytest.raises(ValueError, match="does not reproduce its episodes"):
        repair(dataclasses.replace(batch, actions=scaled))


def test_the_repaired_episodes_are_what_the_policy_is_refit_to():
    agent = TLPS("TLCarNav-v0", seed=0, env_kwargs={"task": 1, "horizon": HORIZON}, n_episodes=6, solver_steps=3,
                 action_repair="model", action_epsilon=0.5, feedback="open")
    seen = {}
    original = agent._refit

    def spy(batch, feedforward, weights, floor):
        seen.update(batch=batch, feedforward=feedforward, weights=weights)
        return original(batch, feedforward, weights, floor)

    agent._refit = spy
    agent.learn(1)
    batch, feedforward, weights = seen["batch"], seen["feedforward"], seen["weights"]
    # open loop: the new mean is the weighted mean of the repaired feed-forwards, not of the drawn ones
    np.testing.assert_allclose(agent.policy.mean, np.einsum("n,ntj->tj", weights, feedforward), atol=1e-12)
    # the batch it saw is the repaired one, played by the model: its states are the repaired actions' states
    model = find_model(agent.env)
    replay, _ = closed_loop(model, agent.policy, batch.observations[:, 0],  # open loop: no gains
                            model.noise(batch.observations, batch.actions), feedforward)
    np.testing.assert_allclose(replay, batch.observations, atol=1e-6)
    # the history reports the sampled episodes' exact robustness, not the repaired ones'
    repaired = agent.formula.robustness({"x": batch.traces["x"], "y": batch.traces["y"]})
    assert agent.history[0]["mean_robustness"] == pytest.approx(float(np.mean(batch.robustness)))
    assert agent.history[0]["mean_robustness"] < float(np.mean(repaired))
