"""Tests of the TLPS agent (agents/tlps.py) on the car env."""

import dataclasses
import itertools
import math

import numpy as np
import pytest
from tl_gym.agents.tlps import TLPS, TLPSConfig
from tl_gym.agents.weights import WEIGHTINGS


@pytest.mark.parametrize(
    ("hyperparameters", "culprit"),
    [
        (dict(beta=-9.0), "beta"),
        (dict(beta=0.0), "beta"),
        (dict(epsilon=0.0), "epsilon"),
        (dict(epsilon=-4.5), "epsilon"),
        (dict(n_episodes=1), "n_episodes"),
        (dict(horizon=0), "horizon"),
        (dict(weights="softmax"), "weights"),
        (dict(hybrid_mix=1.5), "hybrid_mix"),
        (dict(kl_bound=0.0), "kl_bound"),
        (dict(alpha=-1.0), "alpha"),
        (dict(regularization=0.0), "regularization"),
        (dict(solver="newton"), "solver"),
        (dict(solver_steps=0), "solver_steps"),
        (dict(solver_decay=1.0), "solver_decay"),
        (dict(init_mean=float("nan")), "init_mean"),
        (dict(init_mean="half speed"), "init_mean"),
        (dict(smoothing="cubic"), "smoothing"),
        (dict(exploration_floor=-0.1), "exploration_floor"),
        (dict(exploration_halflife=0.0), "exploration_halflife"),
        (dict(threads=0), "threads"),
        (dict(trust_adapt=1), "trust_adapt"),
        (dict(solver_warm_start="yes"), "solver_warm_start"),
    ],
)
def test_bad_hyperparameters_raise_at_construction(hyperparameters, culprit):
    with pytest.raises(ValueError, match=culprit):
        TLPSConfig(**hyperparameters)
    with pytest.raises(ValueError, match=culprit):
        TLPS("TLCarNav-v0", **hyperparameters)


def test_numpy_numbers_and_per_component_means_are_accepted_and_saved_as_json(tmp_path):
    # as a sweep over np.arange hands them over
    agent = TLPS("TLCarNav-v0", seed=0, n_episodes=4, solver_steps=np.int64(2), solver_decay=np.float32(0.5),
                 init_mean=np.array([0.2, -0.1])).learn(1)
    assert np.all(agent.history[0]["policy_std"] > 0)
    loaded = TLPS.load(agent.save(tmp_path / "agent.zip"))
    assert loaded.config == agent.config and loaded.config.init_mean == [0.2, -0.1]


def test_unknown_hyperparameter_is_a_type_error():
    with pytest.raises(TypeError, match="eps"):
        TLPS("TLCarNav-v0", eps=1.0)


def test_exploration_floor_halves_every_halflife():
    cfg = TLPSConfig(exploration_floor=0.2, exploration_halflife=5.0, min_std=1e-3)
    assert cfg.std_floor(0) == pytest.approx(0.2)
    assert cfg.std_floor(5) == pytest.approx(0.1)
    assert cfg.std_floor(10_000) == pytest.approx(1e-3)
    assert TLPSConfig(exploration_floor=0.0).std_floor(1) == TLPSConfig().min_std


def test_short_run_improves_task_1_robustness():
    agent = TLPS("TLCarNav-v0", seed=0).learn(8)
    rho = [row["mean_robustness"] for row in agent.history]
    assert np.mean(rho[-2:]) > rho[0] + 20.0, rho
    row = agent.history[-1]
    for key in ("smooth_robustness", "smooth_updated", "alpha", "kl", "weight_rank_corr", "policy_std"):
        assert np.isfinite(row[key]), key
    assert row["smooth_updated"] > row["smooth_robustness"]  # the trust region improved the samples
    assert row["kl"] == pytest.approx(2.0, rel=1e-3)  # the default bound at N = 40


def test_same_seed_same_history_and_save_load_round_trip(tmp_path):
    kwargs = dict(seed=3, n_episodes=6, solver_steps=3)
    first = TLPS("TLCarNav-v0", **kwargs).learn(2)
    second = TLPS("TLCarNav-v0", **kwargs).learn(2)
    strip = [{k: v for k, v in row.items() if k != "wall_time" and not k.startswith("time_")} for row in first.history]
    assert strip == [{k: v for k, v in row.items() if k != "wall_time" and not k.startswith("time_")}
                     for row in second.history]
    path = first.save(tmp_path / "tlps.zip")
    loaded = TLPS.load(path)
    assert dataclasses.asdict(loaded.config) == dataclasses.asdict(first.config)
    obs = np.zeros((3, 6))
    np.testing.assert_array_equal(loaded.predict(obs)[0], first.predict(obs)[0])
    first.learn(1)
    loaded.learn(1)
    assert loaded.history[-1]["mean_robustness"] == first.history[-1]["mean_robustness"]


def test_every_weighting_runs_with_a_fixed_alpha_and_steers_the_refit():
    """The same seed samples the same batch; each weighting then refits the policy to its own weights."""
    means, kls = {}, {}
    for weights in WEIGHTINGS:
        agent = TLPS("TLCarNav-v0", seed=1, n_episodes=6, solver_steps=2, weights=weights, alpha=0.5).learn(1)
        row = agent.history[-1]
        assert row["alpha"] == 0.5
        assert 0.0 < row["kl"] <= np.log(6)  # not uniform, within KL's bound against 6 episodes
        means[weights], kls[weights] = agent.policy.mean.copy(), row["kl"]
    for a, b in itertools.combinations(WEIGHTINGS, 2):
        assert not np.allclose(means[a], means[b]), (a, b)
        assert kls[a] != kls[b], (a, b)


def test_slsqp_solver_runs():
    agent = TLPS("TLCarNav-v0", seed=1, n_episodes=3, horizon=200, solver="slsqp", solver_steps=2).learn(1)
    assert agent.history[-1]["smooth_updated"] >= agent.history[-1]["smooth_robustness"]


def test_runs_on_any_wrapped_env_through_its_signals():
    # Pendulum's obs is [cos θ, sin θ, θ̇]: the trajectory TLPS works on is the one signal
    # the formula reads, whatever the env's state.
    import gymnasium as gym

    from tl_gym import TLTLRewardWrapper

    env = TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=30), "F (cos_th > 0.5)", {"cos_th": 0})
    agent = TLPS(env, seed=0, n_episodes=4, solver_steps=3).learn(2)
    assert agent.signal_names == ("cos_th",)
    assert agent.horizon == 30
    assert all(np.isfinite(row["smooth_updated"]) for row in agent.history)


def test_fixed_feedback_gains_are_used_saved_and_checked(tmp_path):
    gains = np.zeros((2, 6))
    gains[1, 2] = -0.1  # steer against the heading
    agent = TLPS("TLCarNav-v0", seed=0, n_episodes=4, solver_steps=2, gains=gains, feedback="open").learn(1)
    assert agent.policy.feedback is not None and agent.policy.gains.shape == (200, 2, 6)
    assert np.all(agent.policy.gains[:, 1, 2] == -0.1)
    agent.save(tmp_path / "agent.zip")
    loaded = TLPS.load(tmp_path / "agent.zip")
    np.testing.assert_array_equal(loaded.policy.gains, agent.policy.gains)
    with pytest.raises(ValueError, match="gains must have shape"):
        TLPS("TLCarNav-v0", n_episodes=4, gains=np.zeros((3, 3)), feedback="open")


def test_the_adapted_trust_region_follows_realised_gains_and_is_saved(tmp_path):
    agent = TLPS("TLCarNav-v0", seed=1, n_episodes=6, solver_steps=3, trust_adapt=True).learn(3)
    rows = agent.history
    assert rows[0]["trust_scale"] == 1.0  # nothing promised yet
    for before, after in zip(rows, rows[1:]):  # each scale is the rule applied to the previous update's promise
        promised = before["smooth_updated"] - before["smooth_robustness"]
        ratio = (after["smooth_robustness"] - before["smooth_robustness"]) / promised
        factor = 0.5 if ratio < 0.25 else 2.0 if ratio > 0.75 else 1.0
        assert after["trust_scale"] == before["trust_scale"] * factor
    loaded = TLPS.load(agent.save(tmp_path / "adapt.zip"))
    assert loaded._radius == agent._radius
    agent.learn(1)
    loaded.learn(1)
    assert loaded.history[-1]["trust_scale"] == agent.history[-1]["trust_scale"]
    assert loaded.history[-1]["mean_robustness"] == agent.history[-1]["mean_robustness"]
    assert "trust_scale" not in TLPS("TLCarNav-v0", seed=1, n_episodes=6, solver_steps=3).learn(1).history[0]


def test_the_warm_started_solver_starts_where_the_last_update_stopped_and_is_saved(tmp_path):
    kwargs = dict(seed=2, n_episodes=6, solver_steps=3, action_repair="model")
    agent = TLPS("TLCarNav-v0", solver_warm_start=True, **kwargs).learn(2)
    assert 0 < agent._moved < math.sqrt(agent.config.action_epsilon)
    loaded = TLPS.load(agent.save(tmp_path / "warm.zip"))
    assert loaded._moved == agent._moved
    agent.learn(1)
    loaded.learn(1)
    # (approx: the engine may switch from its numpy smoother to its compiled one between two calls)
    assert loaded.history[-1]["smooth_updated"] == pytest.approx(agent.history[-1]["smooth_updated"], rel=1e-9)
    cold = TLPS("TLCarNav-v0", **kwargs).learn(2)
    assert cold.history[0]["smooth_updated"] == pytest.approx(agent.history[0]["smooth_updated"], rel=1e-9)
    assert cold.history[1]["smooth_updated"] != pytest.approx(agent.history[1]["smooth_updated"], rel=1e-6)


def test_a_fixed_alpha_leaves_the_kl_bound_unchecked_and_unused():
    assert TLPS("TLCarNav-v0", n_episodes=4, alpha=3.0, kl_bound=1.5).config.kl_bound == 1.5
    with pytest.raises(ValueError, match="kl_bound=1.5 cannot bind with n_episodes=4"):
        TLPS("TLCarNav-v0", n_episodes=4, kl_bound=1.5)
