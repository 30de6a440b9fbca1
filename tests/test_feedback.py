"""Tests of the fitted time-varying feedback (agents/feedback.py) and its use by TLPS and REPS."""

import math

import numpy as np
import pytest
from tl_gym.agents import REPS, TLPS, REPSConfig, TLPSConfig
from tl_gym.agents.feedback import fit_feedback, signal_components, window_mean, wrap_angle
from tl_gym.agents.policy import LinearGaussianPolicy
from tl_gym.agents.sampling import rollout


def synthetic(rng, n, horizon, true_gains, angle_centre=None, residual=0.05):
    """States, and drawn noise that equals ``K_t (s_t − s̄_t)`` plus a small residual."""
    dim = true_gains.shape[2]
    states = rng.normal(size=(n, horizon, dim)) * np.array([3.0, 0.2][:dim])
    if angle_centre is not None:
        states[..., -1] = wrap_angle(angle_centre + states[..., -1])
    centre = states.mean(axis=0)
    if angle_centre is not None:
        centre[:, -1] = np.arctan2(np.sin(states[..., -1]).mean(axis=0), np.cos(states[..., -1]).mean(axis=0))
    dev = states - centre
    dev[..., -1] = wrap_angle(dev[..., -1]) if angle_centre is not None else dev[..., -1]
    noise = np.einsum("taf,ntf->nta", true_gains, dev) + residual * rng.normal(size=(n, horizon, true_gains.shape[1]))
    return states, noise


def test_regression_recovers_time_varying_gains_per_step():
    rng = np.random.default_rng(0)
    horizon = 6
    true_gains = rng.normal(size=(horizon, 2, 2))
    states, noise = synthetic(rng, 3000, horizon, true_gains)
    prior = np.full((horizon, 2, 2), 0.25)
    fit = fit_feedback(states, noise, noise, np.ones(3000), prior, np.array([0, 1]), np.zeros(2, bool),
                       ridge=0.0, window=0)
    np.testing.assert_allclose(fit.gains - prior, true_gains, atol=0.02)  # the increment is the true gain
    np.testing.assert_allclose(fit.centre, states.mean(axis=0), atol=1e-12)


def test_regression_wraps_angles_and_pools_constant_gains():
    rng = np.random.default_rng(1)
    horizon = 20
    true_gains = np.broadcast_to(np.array([[0.5, -2.0]]), (horizon, 1, 2)).copy()
    states, noise = synthetic(rng, 300, horizon, true_gains, angle_centre=math.pi - 0.05)
    angles = np.array([False, True])
    fit = fit_feedback(states, noise, noise, np.ones(300), np.zeros((horizon, 1, 2)), np.array([True, True]),
                       angles, ridge=0.0, window=5)
    np.testing.assert_allclose(fit.gains, true_gains, atol=0.03)
    assert np.all(np.abs(wrap_angle(fit.centre[:, 1] - (math.pi - 0.05))) < 0.05)  # circular mean near ±π
    unwrapped = fit_feedback(states, noise, noise, np.ones(300), np.zeros((horizon, 1, 2)), np.array([True, True]),
                             np.zeros(2, bool), ridge=0.0, window=5)
    assert np.abs(unwrapped.gains[:, 0, 1] + 2.0).max() > 0.5  # without the wrap the heading gain is lost


def test_ridge_pulls_the_increment_toward_zero_and_weights_select_samples():
    rng = np.random.default_rng(2)
    horizon = 4
    true_gains = np.ones((horizon, 1, 1))
    states, noise = synthetic(rng, 500, horizon, true_gains)
    prior = np.full((horizon, 1, 1), -1.0)
    free = fit_feedback(states, noise, noise, np.ones(500), prior, np.array([0]), np.zeros(1, bool),
                        ridge=0.0, window=1)
    ridged = fit_feedback(states, noise, noise, np.ones(500), prior, np.array([0]), np.zeros(1, bool),
                          ridge=1.0, window=1)
    np.testing.assert_allclose(free.gains, 0.0, atol=0.02)
    np.testing.assert_allclose(ridged.gains, -0.5, atol=0.02)  # half the increment: standardised λ = 1
    # the weighted mean action at the new centre: k_t' = Σ w a (the deviations average to 0)
    w = rng.uniform(size=500)
    actions = rng.normal(size=(500, horizon, 1))
    fit = fit_feedback(states, noise, actions, w, prior, np.array([0]), np.zeros(1, bool), ridge=0.0, window=1)
    np.testing.assert_allclose(fit.mean, np.einsum("n,nta->ta", w / w.sum(), actions), atol=1e-12)


def test_window_mean_pools_neighbouring_steps():
    values = np.arange(5.0)[:, None]
    np.testing.assert_allclose(window_mean(values, 1)[:, 0], [0.5, 1.0, 2.0, 3.0, 3.5])
    np.testing.assert_allclose(window_mean(values, 0), values)


def test_auto_features_are_the_signal_components_and_the_heading():
    agent = REPS("TLCarNav-v0", seed=0, n_episodes=12, feedback="fitted").learn(1)  # KL 2 < log 12: several weights
    assert np.flatnonzero(agent.feedback_features).tolist() == [0, 1, 2]  # x, y (the signals) and θ (±π bounds)
    assert agent.policy.angles.tolist() == [False, False, True, False, False, False]
    assert np.all(agent.policy.gains[:, :, 3:] == 0) and np.any(agent.policy.gains[:, :, :3] != 0)
    batch = rollout(agent.env, np.zeros((12, agent.horizon, 2)), seed=0)
    assert signal_components(batch.observations, batch.traces).tolist() == [True, True] + [False] * 4


@pytest.mark.parametrize("cls", [TLPS, REPS])
def test_save_load_keeps_gains_centre_and_features(tmp_path, cls):
    kwargs = dict(seed=1, n_episodes=12, feedback="fitted", env_kwargs={"start_std": (15, 15, 0.3)})
    if cls is TLPS:
        kwargs["solver_steps"] = 2
    agent = cls("TLCarNav-v0", **kwargs).learn(2)
    assert np.any(agent.policy.gains != 0) and np.any(agent.policy.centre != 0)
    loaded = cls.load(agent.save(tmp_path / "agent.zip"))
    np.testing.assert_array_equal(loaded.policy.gains, agent.policy.gains)
    np.testing.assert_array_equal(loaded.policy.centre, agent.policy.centre)
    np.testing.assert_array_equal(loaded.feedback_features, agent.feedback_features)
    obs = np.random.default_rng(0).normal(size=(5, 6)) * [30, 30, 1, 1, 1, 1] + [60, 60, 0, 0, 0, 0]
    state = np.array([0, 10, 50, 120, 199])
    np.testing.assert_array_equal(loaded.predict(obs, state=state)[0], agent.predict(obs, state=state)[0])
    assert loaded.evaluate(4, seed=3)["robustness"].tolist() == agent.evaluate(4, seed=3)["robustness"].tolist()


def test_predict_equals_the_sampled_actions():
    agent = TLPS("TLCarNav-v0", seed=2, n_episodes=5, solver_steps=2, feedback="fitted",
                 env_kwargs={"start_std": (15, 15, 0.3)}).learn(2)
    policy = agent.policy
    # deterministic: every episode runs the mean k_t; predict must give the actions the sampler sent
    feedforward = np.broadcast_to(policy.mean, (5, agent.horizon, 2)).copy()
    batch = rollout(agent.env, feedforward, policy.feedback, seed=7)
    for t in (0, 1, 37, 199):
        action, state = agent.predict(batch.observations[:, t], state=np.full(5, t))
        assert action.dtype == agent.action_space.dtype  # as sent to the env (the sampler records float64)
        np.testing.assert_allclose(action, batch.actions[:, t].astype(action.dtype), rtol=0, atol=1e-7)
        assert state.tolist() == [t + 1] * 5
    # stochastic: the drawn k_t^i with the policy's own act()
    feedforward = policy.sample_feedforward(5, np.random.default_rng(0))
    batch = rollout(agent.env, feedforward, policy.feedback, seed=8)
    steps = np.arange(agent.horizon)
    acted = np.stack([policy.act(batch.observations[:, t], np.full(5, t), feedforward[:, t]) for t in steps], 1)
    np.testing.assert_allclose(np.clip(acted, -1, 1), batch.actions, rtol=0, atol=1e-12)


def test_rollout_takes_gains_as_an_array_as_it_takes_them_as_a_function():
    """``gains`` as ``K_t`` of shape (T, act_dim, obs_dim) acts as the function ``(t, s) -> K_t s`` does."""
    agent = REPS("TLCarNav-v0", seed=0, n_episodes=3, env_kwargs={"start_std": (15, 15, 0.3)})
    obs_dim = agent.env.single_observation_space.shape[0]
    gains = np.random.default_rng(0).normal(0.0, 0.01, (agent.horizon, 2, obs_dim))
    feedforward = np.random.default_rng(1).uniform(-0.5, 0.5, (3, agent.horizon, 2))
    by_array = rollout(agent.env, feedforward, gains, seed=4)
    by_function = rollout(agent.env, feedforward, lambda t, s: s @ gains[t].T, seed=4)
    open_loop = rollout(agent.env, feedforward, None, seed=4)
    np.testing.assert_allclose(by_array.actions, by_function.actions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(by_array.robustness, by_function.robustness, rtol=0, atol=1e-9)
    assert not np.allclose(by_array.actions, open_loop.actions)  # the gains did act


def test_policy_centre_and_angles_shape_the_feedback():
    policy = LinearGaussianPolicy(horizon=2, obs_dim=2, act_dim=1, gains=np.array([[1.0, 10.0]]),
                                  angles=np.array([False, True]))
    policy.centre[:] = [1.0, math.pi - 0.1]
    action, _ = policy.predict(np.array([2.0, -math.pi + 0.1]), None, None, True, np.random.default_rng(0))
    np.testing.assert_allclose(action, [1.0 + 10.0 * 0.2])  # the heading error is +0.2, not -2π + 0.2
    with pytest.raises(ValueError, match="angles"):
        LinearGaussianPolicy(horizon=2, obs_dim=2, act_dim=1, angles=np.array([True]))


@pytest.mark.parametrize("config", [TLPSConfig, REPSConfig])
def test_unfittable_config_is_refused_naming_the_fields(config):
    with pytest.raises(ValueError, match=r"n_episodes=3.*feedback_features=\[0, 1, 2\].*feedback_ridge=0"):
        config(n_episodes=3, feedback="fitted", feedback_features=[0, 1, 2], feedback_ridge=0.0)
    config(n_episodes=3, feedback="fitted", feedback_features=[0, 1, 2], feedback_ridge=0.01)  # a ridge fits
    config(n_episodes=3, feedback="open", feedback_features=[0, 1, 2], feedback_ridge=0.0)  # nothing to fit


@pytest.mark.parametrize("cls", [TLPS, REPS])
def test_unfittable_agent_is_refused_at_construction(cls):
    with pytest.raises(ValueError, match=r"n_episodes=6.*feedback_features='all'.*feedback_ridge=0"):
        cls("TLCarNav-v0", n_episodes=6, feedback="fitted", feedback_features="all", feedback_ridge=0.0)
    with pytest.raises(ValueError, match=r"n_episodes=3.*feedback_features='auto'.*feedback_ridge=0"):
        cls("TLCarNav-v0", n_episodes=3, feedback="fitted", feedback_ridge=0.0)  # x, y and θ on the car
    with pytest.raises(ValueError, match="feedback_features=\\[7\\] names a component past"):
        cls("TLCarNav-v0", n_episodes=4, feedback="fitted", feedback_features=[7])


def test_explicit_feedback_components_are_what_auto_picks_on_the_car_and_others_change_the_fit():
    """On the car "auto" regresses on the signals' components x, y (0, 1) and the ±π-bounded θ (2), θ as an angle."""
    kwargs = dict(seed=3, n_episodes=8, env_kwargs={"start_std": (15, 15, 0.3)})
    auto = REPS("TLCarNav-v0", **kwargs).learn(2)
    explicit = REPS("TLCarNav-v0", feedback_features=(0, 1, 2), feedback_angles=(2,), **kwargs).learn(2)
    np.testing.assert_array_equal(explicit.policy.gains, auto.policy.gains)
    assert [r["mean_robustness"] for r in explicit.history] == [r["mean_robustness"] for r in auto.history]
    xy = REPS("TLCarNav-v0", feedback_features=(0, 1), **kwargs).learn(2)
    assert not np.array_equal(xy.policy.gains, auto.policy.gains)
    assert not xy.policy.gains[..., 2:].any()  # only x and y are regressed on
    with pytest.raises(ValueError, match=r"feedback_features=\[0, 9\] names a component past the observation's 6"):
        REPS("TLCarNav-v0", feedback_features=(0, 9), **kwargs)


@pytest.mark.parametrize(
    ("hyperparameters", "culprit"),
    [
        (dict(feedback="closed"), "feedback must"),
        (dict(feedback_features=[0, 0]), "feedback_features"),
        (dict(feedback_features="signals"), "feedback_features"),
        (dict(feedback_angles="none"), "feedback_angles"),
        (dict(feedback_ridge=-1.0), "feedback_ridge"),
        (dict(feedback_window=-1), "feedback_window"),
        (dict(exploration_floor=-0.1), "exploration_floor"),
        (dict(exploration_halflife=0.0), "exploration_halflife"),
        (dict(feedback="fitted", gains=np.zeros((2, 6))), "gains"),
    ],
)
def test_bad_feedback_fields_raise(hyperparameters, culprit):
    for config in (TLPSConfig, REPSConfig):
        with pytest.raises(ValueError, match=culprit):
            config(**hyperparameters)


def test_exploration_floor_defaults_follow_the_feedback():
    assert REPSConfig(feedback="fitted").std_floor(10) == pytest.approx(0.05)
    assert REPSConfig(feedback="open").std_floor(10) == REPSConfig().min_std
    assert TLPSConfig(feedback="open", exploration_floor=0.2).std_floor(10) == pytest.approx(0.1)


def test_steps_no_episode_reached_keep_the_current_fit():
    rng = np.random.default_rng(3)
    horizon = 5
    true_gains = np.tile(np.array([[[0.8, -0.4]]]), (horizon, 1, 1))  # one gain for all steps
    states, noise = synthetic(rng, 400, horizon, true_gains)
    actions = noise + 0.7
    valid = np.ones((400, horizon), bool)
    valid[:, 3:] = False  # every episode ended after 3 steps
    previous_mean, previous_centre = np.full((horizon, 1), 0.7), np.full((horizon, 2), 5.0)
    prior = np.zeros((horizon, 1, 2))
    fit = fit_feedback(states, noise, actions, np.ones(400), prior, np.array([0, 1]), np.zeros(2, bool),
                       ridge=0.0, window=2, valid=valid, previous_mean=previous_mean, previous_centre=previous_centre)
    np.testing.assert_array_equal(fit.mean[3:], previous_mean[3:])
    np.testing.assert_array_equal(fit.centre[3:], previous_centre[3:])
    np.testing.assert_array_equal(fit.gains[3:], prior[3:])
    # the reached steps pool only reached neighbours: the gain is not shrunk by the empty steps
    np.testing.assert_allclose(fit.gains[:3], true_gains[:3], atol=0.05)
    np.testing.assert_allclose(fit.mean[:3], 0.7, atol=0.05)
