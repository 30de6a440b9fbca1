"""SB3Agent: stable-baselines3 algorithms on the car, reported like TLPS and REPS."""

from __future__ import annotations

import tempfile

import numpy as np
import pytest
from stable_baselines3 import PPO, SAC
from tl_gym.agents import Agent, SB3Agent
from tl_gym.agents.sb3 import resolve_algorithm


def test_default_iteration_is_a_tlps_iteration():
    agent = SB3Agent("PPO", "TLCarNav-v0", seed=0)
    assert agent.model.n_steps * agent.model.n_envs == 40 * 200


def test_ppo_learns_reports_saves_and_loads(tmp_path):
    agent = SB3Agent("ppo", "TLCarNav-v0", seed=0, env_kwargs={"task": 1}, steps_per_iteration=800, n_envs=4,
                     batch_size=200, n_epochs=1)
    agent.learn(2)
    assert [row["env_steps"] for row in agent.history] == [800, 1600]
    for row in agent.history:
        assert row["episodes"] == 4  # 800 steps of 200-step episodes
        assert np.isfinite(row["mean_robustness"]) and 0.0 <= row["success_rate"] <= 1.0

    path = agent.save(tmp_path / "ppo.zip")
    loaded = Agent.load(path)
    assert type(loaded) is SB3Agent and isinstance(loaded.model, PPO)
    obs = loaded.observation_space.sample()[None].repeat(3, axis=0)
    np.testing.assert_array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])
    assert loaded.evaluate(4, seed=3)["robustness"].tolist() == agent.evaluate(4, seed=3)["robustness"].tolist()
    loaded.learn(1)
    assert loaded.history[-1]["iteration"] == 3 and loaded.history[-1]["env_steps"] == 2400


def test_learning_leaves_no_sb3_log_folders(tmp_path, monkeypatch):
    """SB3's default logger makes an empty SB3-<time> folder in the temp directory per learn() call."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    agent = SB3Agent("ppo", "TLCarNav-v0", seed=0, steps_per_iteration=400, n_envs=2, batch_size=100, n_epochs=1)
    agent.learn(2)
    Agent.load(agent.save(tmp_path / "a.zip")).learn(1)
    assert not list(tmp_path.glob("SB3-*"))
    logged = SB3Agent("ppo", "TLCarNav-v0", seed=0, steps_per_iteration=400, n_envs=2, batch_size=100, n_epochs=1,
                      tensorboard_log=str(tmp_path / "tb"))
    assert logged.model.tensorboard_log == str(tmp_path / "tb") and not logged.model._custom_logger


def test_off_policy_algorithm_by_class():
    agent = SB3Agent(SAC, "TLCarNav-v0", seed=0, steps_per_iteration=200, n_envs=1, learning_starts=100,
                     batch_size=32)
    agent.learn(1)
    assert agent.history[0]["env_steps"] == 200 and agent.history[0]["episodes"] == 1


def test_algorithm_names_and_budget_checks():
    assert resolve_algorithm("sac") is SAC and resolve_algorithm(PPO) is PPO
    with pytest.raises(ValueError, match="unknown algorithm 'nope'.*PPO"):
        SB3Agent("nope", "TLCarNav-v0")
    with pytest.raises(ValueError, match="5%"):
        SB3Agent("PPO", "TLCarNav-v0", n_envs=8, n_steps=3000)
    with pytest.raises(ValueError, match="n_envs"):
        SB3Agent("PPO", "TLCarNav-v0", n_envs=0)
