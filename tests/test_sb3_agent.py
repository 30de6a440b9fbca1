"""SB3Agent: stable-baselines3 algorithms on the car, reported like TLPS and REPS."""

from __future__ import annotations

import importlib.util
import pickle
import sys
import tempfile
import warnings
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import VecNormalize
from tl_gym.agents import Agent, SB3Agent
from tl_gym.agents.sb3 import VECNORMALIZE_MEMBER, one_torch_thread
from tl_gym.agents.sb3_settings import (
    TL_REWARD_ENV_KWARGS,
    SB3Config,
    find_hyperparams,
    load_hyperparams,
    parse_normalize,
    resolve_algorithm,
)

import tl_gym
from tl_gym.relabel import find_wrapper

#: A budget small enough for fast tests (PPO: one rollout of 2 envs x 32 steps).
TINY = {"steps_per_iteration": 64, "n_envs": 2, "batch_size": 32, "n_epochs": 1}


def test_default_iteration_is_a_tlps_iteration():
    agent = SB3Agent("TLCarNav-v0", "PPO", seed=0)
    assert agent.model.n_steps * agent.model.n_envs == 40 * 200


def test_ppo_learns_reports_saves_and_loads(tmp_path):
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, env_kwargs={"task": 1}, steps_per_iteration=400, n_envs=2,
                     batch_size=100, n_epochs=1)
    agent.learn(2)
    assert [row["env_steps"] for row in agent.history] == [400, 800]
    for row in agent.history:
        assert row["episodes"] == 2  # 400 steps of 200-step episodes
        assert np.isfinite(row["mean_robustness"]) and 0.0 <= row["success_rate"] <= 1.0

    path = agent.save(tmp_path / "ppo.zip")
    loaded = Agent.load(path)
    assert type(loaded) is SB3Agent and isinstance(loaded.model, PPO)
    obs = loaded.observation_space.sample()[None].repeat(3, axis=0)
    np.testing.assert_array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])
    assert loaded.evaluate(4, seed=3)["robustness"].tolist() == agent.evaluate(4, seed=3)["robustness"].tolist()
    loaded.learn(1)
    assert loaded.history[-1]["iteration"] == 3 and loaded.history[-1]["env_steps"] == 1200


def test_learning_leaves_no_sb3_log_folders(tmp_path, monkeypatch):
    """SB3's default logger makes an empty SB3-<time> folder in the temp directory per learn() call."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, **TINY)
    agent.learn(2)
    Agent.load(agent.save(tmp_path / "a.zip")).learn(1)
    assert not list(tmp_path.glob("SB3-*"))
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",  # as if tensorboard were installed: SB3's own logger is kept
                        lambda name, *args: object() if name == "tensorboard" else real_find_spec(name, *args))
    logged = SB3Agent("TLCarNav-v0", "ppo", seed=0, tensorboard_log=str(tmp_path / "tb"), **TINY)
    assert logged.model.tensorboard_log == str(tmp_path / "tb") and not logged.model._custom_logger


def test_tensorboard_log_without_tensorboard_is_refused_before_any_env_is_built(monkeypatch):
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *args: None if name == "tensorboard" else real_find_spec(name, *args))
    with pytest.raises(ImportError, match=r"tensorboard_log='tb' needs the tensorboard package.*pip install"):
        SB3Agent("TLCarNav-v0", "ppo", seed=0, tensorboard_log="tb", **TINY)


def test_an_agent_saved_with_tensorboard_logs_loads_and_acts_without_tensorboard(tmp_path, monkeypatch):
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",  # trained where tensorboard is installed
                        lambda name, *args: object() if name == "tensorboard" else real_find_spec(name, *args))
    path = SB3Agent("TLCarNav-v0", "ppo", seed=0, tensorboard_log=str(tmp_path / "tb"), **TINY).save(tmp_path / "a")
    monkeypatch.setattr(importlib.util, "find_spec",  # loaded where it is not
                        lambda name, *args: None if name == "tensorboard" else real_find_spec(name, *args))
    loaded = Agent.load(path)
    assert loaded.config.algo_kwargs["tensorboard_log"] == str(tmp_path / "tb")
    assert loaded.evaluate(1, seed=0)["robustness"].shape == (1,)
    with pytest.raises(ImportError, match="needs the tensorboard package"):  # learning would fail inside SB3
        loaded.learn(1)


def test_off_policy_algorithm_by_class():
    agent = SB3Agent("TLCarNav-v0", SAC, seed=0, steps_per_iteration=200, n_envs=1, learning_starts=150,
                     batch_size=32, policy_kwargs={"net_arch": [32, 32]})
    agent.learn(1)
    assert agent.history[0]["env_steps"] == 200 and agent.history[0]["episodes"] == 1


def test_algorithm_names_and_budget_checks():
    assert resolve_algorithm("sac") is SAC and resolve_algorithm(PPO) is PPO
    with pytest.raises(ValueError, match="unknown algorithm 'nope'.*PPO"):
        SB3Agent("TLCarNav-v0", "nope")
    with pytest.raises(ValueError, match="5%"):
        SB3Agent("TLCarNav-v0", "PPO", n_envs=8, n_steps=3000)
    with pytest.raises(ValueError, match="n_envs"):
        SB3Agent("TLCarNav-v0", "PPO", n_envs=0)


def test_the_registry_names_every_installed_algorithm():
    sb3_contrib = pytest.importorskip("sb3_contrib")
    import stable_baselines3
    from tl_gym.agents.registry import SB3_ALGORITHMS, SB3_CONTRIB_ALGORITHMS

    def names(module):
        return {name.lower() for name in module.__all__ if isinstance(getattr(module, name), type)
                and issubclass(getattr(module, name), stable_baselines3.common.base_class.BaseAlgorithm)}

    assert set(SB3_ALGORITHMS) == names(stable_baselines3)
    assert set(SB3_CONTRIB_ALGORITHMS) == names(sb3_contrib)
    assert resolve_algorithm("tqc") is sb3_contrib.TQC


def test_an_sb3_contrib_name_without_sb3_contrib_names_the_package(monkeypatch):
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)  # what an env without sb3-contrib imports
    with pytest.raises(ValueError, match="'TQC' is sb3-contrib's.*pip install sb3-contrib"):
        resolve_algorithm("TQC")
    with pytest.raises(ValueError, match="unknown algorithm 'nope'"):
        resolve_algorithm("nope")
    assert resolve_algorithm("ppo") is PPO


@pytest.mark.parametrize("algo", ["PPO", PPO])
def test_the_algorithm_first_is_named_as_the_old_argument_order(algo):
    with pytest.raises(TypeError, match="env first"):
        SB3Agent(algo, "TLCarNav-v0")


# Fair baselines: VecNormalize, the Markov view, per-task hyperparameters -------------------------------------


def test_markov_view_is_the_default_and_terminal_the_ablation():
    markov = SB3Agent("TLCarNav-v0", "ppo", seed=0, **TINY)
    assert markov.config.tl_reward == "markov"
    assert markov.env_kwargs == TL_REWARD_ENV_KWARGS["markov"] == {"observe_monitor": True, "reward_mode": "dense"}
    assert markov.observation_space.shape[0] > 6  # the car's 6 numbers, then the monitor's state
    # evaluation runs on the very envs the model trained on: same observation layout
    assert markov.env.single_observation_space == markov.model.observation_space == markov.sb3_env.observation_space
    assert markov.env.get_attr("reward_mode") == ("dense", "dense")

    ablation = SB3Agent("TLCarNav-v0", "ppo", seed=0, tl_reward="terminal", **TINY)
    assert ablation.env_kwargs == {"observe_monitor": False, "reward_mode": "terminal"}
    assert ablation.observation_space.shape == (6,) and ablation.model.observation_space.shape == (6,)

    mixed = SB3Agent("TLCarNav-v0", "ppo", seed=0, env_kwargs={"reward_mode": "terminal", "task": 2}, **TINY)
    assert mixed.env_kwargs == {"observe_monitor": True, "reward_mode": "terminal", "task": 2}  # the user's win


def test_on_an_env_id_the_label_follows_the_view_the_env_kwargs_leave(tmp_path, monkeypatch):
    """The user's env_kwargs win over the preset's: the label says what the env does (it said "markov" of an env
    without the view, so the agent refused to load onto a matching env object), and an explicit tl_reward they
    contradict is refused before any env is built."""
    unviewed = SB3Agent("TLCarNav-v0", "ppo", seed=0, env_kwargs={"observe_monitor": False}, **TINY)
    assert unviewed.config.tl_reward == "terminal"
    assert unviewed.env_kwargs == {"observe_monitor": False, "reward_mode": "dense"}  # the user's win, as before
    unviewed.save(tmp_path / "agent.zip")
    env = gym.make("TLCarNav-v0", observe_monitor=False, reward_mode="dense")
    assert Agent.load(tmp_path / "agent.zip", env=env).config.tl_reward == "terminal"

    import tl_gym.agents.sb3 as sb3_module

    monkeypatch.setattr(sb3_module, "_make_sync_vec", lambda *a, **k: pytest.fail("an env was built"))
    for asked, view in (("markov", False), ("terminal", True)):
        with pytest.raises(ValueError, match=rf"tl_reward='{asked}' sets observe_monitor={not view}, but env_kwargs "
                                             rf"set observe_monitor={view}: drop one"):
            SB3Agent("TLCarNav-v0", "ppo", tl_reward=asked, env_kwargs={"observe_monitor": view}, **TINY)


def test_unknown_tl_reward_is_refused_at_construction():
    with pytest.raises(ValueError, match=r"tl_reward must be one of \['markov', 'terminal'\], got 'dense'"):
        SB3Agent("TLCarNav-v0", "ppo", tl_reward="dense")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"learning_rat": 3e-4}, r"unknown hyperparameter 'learning_rat' \(did you mean 'learning_rate'\?\): "
                                 r"neither one of \['steps_per_iteration', .*\] nor an argument of SAC"),
        ({"steps_per_iteraton": 64}, r"'steps_per_iteraton' \(did you mean 'steps_per_iteration'\?\)"),
        ({"n_epochs": 3}, r"unknown hyperparameter 'n_epochs'.*nor an argument of SAC"),
        ({"verbose": 1}, r"hyperparameter 'verbose': SB3Agent sets SAC's 'verbose' itself"),
        ({"observe_monitor": False}, r"unknown hyperparameter 'observe_monitor'.*; 'observe_monitor' is a keyword of "
                                     r"the env TLCarNav-v0, not of the agent: pass env_kwargs=\{'observe_monitor': "
                                     r"False\}"),
    ],
)
def test_a_misspelt_or_reserved_hyperparameter_is_refused_before_any_env_is_built(kwargs, message, monkeypatch):
    import tl_gym.agents.sb3 as sb3_module

    monkeypatch.setattr(sb3_module, "_make_sync_vec", lambda *a, **k: pytest.fail("an env was built"))
    with pytest.raises(ValueError, match=message):
        SB3Agent("TLCarNav-v0", "sac", seed=0, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"steps_per_iteration": 0}, "steps_per_iteration must be an int >= 1, got 0"),
        ({"n_envs": 0}, "n_envs must be an int >= 1, got 0"),
        ({"normalize": "yes"}, "normalize must be true, false or a dict of VecNormalize keywords, got 'yes'"),
        ({"normalize": 3}, "normalize must be true, false or a dict of VecNormalize keywords, got 3"),
        ({"hyperparams": 3}, "hyperparams must be true, false or a file path, got 3"),
        ({"n_timesteps": 0}, "n_timesteps must be a whole number >= 1, got 0"),
        ({"noise_type": "pink"}, r"noise_type must be None or one of \('normal', 'ornstein-uhlenbeck'\), got 'pink'"),
        ({"noise_std": -1.0}, "noise_std must be a finite number >= 0, got -1.0"),
        ({"her_goals": -1}, "her_goals must be an int >= 0, got -1"),
        ({"her_strategy": "any"}, r"her_strategy must be one of \('future', 'satisfied'\), got 'any'"),
        ({"end_is_terminal": "no"}, "end_is_terminal must be true or false, got 'no'"),
        # the common algorithm arguments SB3 itself takes as they come
        ({"gamma": 2.0}, r"gamma must lie in \(0, 1\], got 2.0"),
        ({"gamma": True}, r"gamma must lie in \(0, 1\], got True"),
        ({"tau": 0.0}, r"tau must lie in \(0, 1\], got 0.0"),
        ({"learning_rate": "fast"}, "learning_rate must be a finite number > 0, got 'fast'"),
        ({"batch_size": 0}, "batch_size must be an int >= 1, got 0"),
        ({"buffer_size": 1.5}, "buffer_size must be an int >= 1, got 1.5"),
    ],
)
def test_a_bad_setting_is_refused_naming_it_before_any_env_is_built(kwargs, message, monkeypatch):
    import tl_gym.agents.sb3 as sb3_module

    monkeypatch.setattr(sb3_module, "_make_sync_vec", lambda *a, **k: pytest.fail("an env was built"))
    with pytest.raises(ValueError, match=message):
        SB3Agent("TLCarNav-v0", "sac", seed=0, **kwargs)


def test_an_algorithm_that_is_neither_a_class_nor_a_name_is_refused_naming_it():
    with pytest.raises(TypeError, match="algo must be an SB3 algorithm class or its name, got 3"):
        SB3Agent("TLCarNav-v0", 3)


def test_a_hyperparameter_file_given_as_a_path_object_is_read_and_saved_as_text(tmp_path):
    path = tmp_path / "mine.yml"
    path.write_text("TLCarNav-v0:\n  ppo:\n    gamma: 0.9\n")
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, hyperparams=path, **TINY)
    assert agent.model.gamma == 0.9
    assert agent.config.hyperparams == str(path)
    with pytest.raises(ValueError, match="hyperparams must be true, false or a file path as text"):
        SB3Config(algo="PPO", hyperparams=path)  # the config itself is JSON: the agent writes the path as text


def test_predict_on_an_observation_without_the_view_says_the_agent_observes_its_monitor():
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, **TINY)
    raw, _ = gym.make("TLCarNav-v0").reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(6,\); the agent's observation space has shape \(12,\)\. "
                                         r"The agent observes its env's monitor"):
        agent.predict(raw)
    viewed, _ = gym.make("TLCarNav-v0", **agent.env_kwargs).reset(seed=0)
    assert agent.predict(viewed)[0].shape == (2,) and agent.predict(np.stack([viewed] * 3))[0].shape == (3, 2)
    plain = SB3Agent("TLCarNav-v0", "ppo", seed=0, tl_reward="terminal", **TINY)
    with pytest.raises(ValueError, match=r"observation space has shape \(6,\)\.$"):  # no view: no hint
        plain.predict(np.zeros(12))


def test_an_id_in_module_form_finds_the_ids_hyperparameters():
    module_form = SB3Agent("tl_gym:TLPendulum-v0", "sac", seed=0)  # Gymnasium's "module:EnvId"
    plain = SB3Agent("TLPendulum-v0", "sac", seed=0)
    assert module_form.n_timesteps == plain.n_timesteps is not None
    assert module_form.config.algo_kwargs == plain.config.algo_kwargs and module_form.env_kwargs == plain.env_kwargs


def test_action_noise_on_an_on_policy_algorithm_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"noise_type='normal': PPO takes no action noise"):
        SB3Agent("TLCarNav-v0", "ppo", seed=0, noise_type="normal", **TINY)


def test_an_env_object_is_taken_as_it_is():
    plain = gym.make("TLCarNav-v0")
    with pytest.raises(ValueError, match=r"tl_reward='markov' needs the env keywords observe_monitor=True"):
        SB3Agent(plain, "ppo", tl_reward="markov", **TINY)
    assert SB3Agent(plain, "ppo", **TINY).config.tl_reward == "terminal"
    viewed = gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="dense")
    agent = SB3Agent(viewed, "ppo", **TINY)
    assert agent.config.tl_reward == "markov"
    assert agent.env.single_observation_space == agent.model.observation_space == viewed.observation_space


@pytest.mark.parametrize(("kwargs", "label"), [
    ({"observe_monitor": True, "reward_mode": "potential", "satisfaction_bonus": 5.0, "gamma": 0.999}, "markov"),
    ({"reward_mode": "dense"}, "terminal"),  # no view: the raw observation
])
def test_an_env_object_with_other_reward_settings_saves_and_loads(tmp_path, kwargs, label):
    """Read from the env by its view; loading checks the view alone (it was an error for any reward mode but the
    two presets: the saved label was checked against every keyword)."""
    env = gym.make("TLCarNav-v0", **kwargs)
    agent = SB3Agent(env, "ppo", seed=0, **TINY)
    assert agent.config.tl_reward == label
    if label == "markov":  # asked for: the potential mode is a shaped reward with the view
        assert SB3Agent(env, "ppo", seed=0, tl_reward=label, **TINY).config.tl_reward == label
    else:  # asked for, the ablation contradicts the dense reward
        with pytest.raises(ValueError, match=r"tl_reward='terminal' needs the env keywords reward_mode='terminal'"):
            SB3Agent(env, "ppo", seed=0, tl_reward=label, **TINY)
    agent.save(tmp_path / "agent.zip")
    loaded = Agent.load(tmp_path / "agent.zip", env=env)
    obs = np.stack([env.observation_space.sample() for _ in range(3)])
    np.testing.assert_array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])
    other = gym.make("TLCarNav-v0", observe_monitor=label != "markov")
    with pytest.raises(ValueError, match=rf"trained with tl_reward='{label}'.*observations are not the agent's"):
        Agent.load(tmp_path / "agent.zip", env=other)



class HidesRewardSettings(gym.Wrapper):
    """An env that does not expose its reward settings (a TL env of the user's own, say)."""

    def get_wrapper_attr(self, name):
        if name in TL_REWARD_ENV_KWARGS["markov"]:
            raise AttributeError(name)
        return super().get_wrapper_attr(name)


def test_an_env_object_that_does_not_expose_its_view_loads_with_the_label_it_was_trained_with(tmp_path):
    """A setting the env does not expose is not checked: not when training, and not when loading either."""
    env = HidesRewardSettings(gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="dense"))
    agent = SB3Agent(env, "ppo", seed=0, tl_reward="markov", **TINY)
    assert agent.config.tl_reward == "markov"
    agent.save(tmp_path / "agent.zip")
    loaded = Agent.load(tmp_path / "agent.zip", env=env)
    assert loaded.config.tl_reward == "markov"
    obs = np.stack([env.observation_space.sample() for _ in range(3)])
    np.testing.assert_array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])

def _stats(agent):
    vec = agent.vec_normalize
    return [vec.obs_rms.mean.copy(), vec.obs_rms.var.copy(), vec.obs_rms.count, vec.ret_rms.mean.copy(),
            vec.ret_rms.var.copy(), vec.ret_rms.count]


def test_vecnormalize_is_applied_saved_and_loaded(tmp_path):
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, **TINY)
    assert agent.config.normalize is True and agent.vec_normalize.norm_reward  # the car's entry: normalize: true
    assert agent.vec_normalize.gamma == agent.model.gamma == 0.999  # returns discounted as the algorithm does
    assert agent.model.get_env() is agent.vec_normalize and agent.vec_normalize.venv is agent.sb3_env
    agent.learn(1)
    stats = _stats(agent)
    assert stats[2] > 1 and np.all(stats[1] != 1.0)  # it did learn statistics

    rng = np.random.default_rng(0)
    obs = np.stack([agent.observation_space.sample() for _ in range(5)]) * rng.uniform(0.5, 2.0, (5, 1))
    normalised = agent.vec_normalize.normalize_obs(obs)
    with one_torch_thread():  # as predict runs it, so that the float sums match bit for bit
        expected = agent.model.predict(normalised, deterministic=True)[0]
        raw = agent.model.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(agent.predict(obs)[0], expected)
    assert not np.allclose(raw, expected)  # the normalisation matters

    result = agent.evaluate(2, seed=1)
    after = _stats(agent)
    for a, b in zip(stats, after):
        np.testing.assert_array_equal(a, b)  # evaluation does not update the running statistics

    path = agent.save(tmp_path / "ppo.zip")
    with zipfile.ZipFile(path) as archive:
        raw = archive.read(VECNORMALIZE_MEMBER)
    (tmp_path / "vecnormalize.pkl").write_bytes(raw)  # SB3's own loader reads the member
    sb3_loaded = VecNormalize.load(str(tmp_path / "vecnormalize.pkl"), agent.sb3_env)
    np.testing.assert_array_equal(sb3_loaded.obs_rms.mean, stats[0])

    loaded = Agent.load(path)
    for a, b in zip(stats, _stats(loaded)):
        np.testing.assert_array_equal(a, b)
    assert loaded.model.get_env() is loaded.vec_normalize and loaded.vec_normalize.venv is loaded.sb3_env
    np.testing.assert_array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])
    assert loaded.evaluate(2, seed=1)["robustness"].tolist() == result["robustness"].tolist()
    loaded.learn(1)
    assert loaded.vec_normalize.obs_rms.count > stats[2]  # training goes on updating them


def test_normalize_off_and_on_observations_only(tmp_path):
    off = SB3Agent("TLCarNav-v0", "ppo", seed=0, normalize=False, **TINY)
    assert off.vec_normalize is None and off.model.get_env() is off.sb3_env
    with zipfile.ZipFile(off.save(tmp_path / "off.zip")) as archive:
        assert VECNORMALIZE_MEMBER not in archive.namelist()
    assert Agent.load(tmp_path / "off.zip").vec_normalize is None
    obs_only = SB3Agent("TLCarNav-v0", "ppo", seed=0, normalize="{'norm_obs': True, 'norm_reward': False}", **TINY)
    assert obs_only.vec_normalize.norm_obs and not obs_only.vec_normalize.norm_reward
    with pytest.raises(ValueError, match="norm_everything"):
        SB3Agent("TLCarNav-v0", "ppo", normalize={"norm_everything": True}, **TINY)


def test_the_replay_buffer_saves_and_loads_so_that_training_resumes(tmp_path):
    """`save` leaves the buffer out; `save_replay_buffer` keeps it for a run that goes on in another process."""
    agent = SB3Agent("TLCarNav-v0", "sac", seed=0, steps_per_iteration=64, learning_starts=32, batch_size=16,
                     buffer_size=1000, policy_kwargs={"net_arch": [16, 16]})
    agent.learn(1)
    assert agent.off_policy and agent.save_replay_buffer(tmp_path / "buffer.pkl") == tmp_path / "buffer.pkl"
    loaded = Agent.load(agent.save(tmp_path / "sac.zip"))
    assert loaded.model.replay_buffer.size() == 0  # not in the agent's file
    loaded.load_replay_buffer(tmp_path / "buffer.pkl")
    assert loaded.model.replay_buffer.size() == 64
    np.testing.assert_array_equal(loaded.model.replay_buffer.observations, agent.model.replay_buffer.observations)
    loaded.learn(1)
    assert loaded.model.num_timesteps == 128 and loaded.model.replay_buffer.size() == 128
    assert [row["env_steps"] for row in loaded.history] == [64, 128]
    assert not list(tmp_path.glob(".*.tmp"))  # the temporary file was moved over buffer.pkl


def test_an_on_policy_agent_has_no_replay_buffer_to_save(tmp_path):
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, **TINY)
    assert not agent.off_policy
    with pytest.raises(ValueError, match="PPO is on-policy and keeps none"):
        agent.save_replay_buffer(tmp_path / "buffer.pkl")
    assert not (tmp_path / "buffer.pkl").exists()


def test_off_policy_entry_with_action_noise_saves_and_loads(tmp_path):
    agent = SB3Agent("TLCarNav-v0", "td3", seed=0, steps_per_iteration=64, n_envs=2, learning_starts=32,
                     batch_size=16, buffer_size=1000)
    assert isinstance(agent.model.action_noise, NormalActionNoise)  # the entry's noise_type: normal
    assert agent.config.noise_type == "normal" and agent.model.policy.net_arch == [400, 300]
    np.testing.assert_array_equal(agent.model.action_noise._sigma, [0.1, 0.1])  # noise_std's default, per action
    agent.learn(1)
    loaded = Agent.load(agent.save(tmp_path / "td3.zip"))
    obs = np.stack([agent.observation_space.sample() for _ in range(3)])
    np.testing.assert_array_equal(loaded.predict(obs)[0], agent.predict(obs)[0])
    # the loaded model explores as the saved one did: the same noise, not none (predict never draws it); SB3
    # draws it per env once training starts, from copies of the one it was given
    noise = getattr(loaded.model.action_noise, "base_noise", None)
    assert loaded.config.noise_type == "normal" and isinstance(noise, NormalActionNoise)
    np.testing.assert_array_equal(noise._sigma, [0.1, 0.1])
    np.testing.assert_array_equal(noise._mu, [0.0, 0.0])


def test_the_task_entry_is_read_and_explicit_kwargs_win(tmp_path):
    task2 = SB3Agent("TLCarNav-v0", "ppo", env_kwargs={"task": 2}, **TINY)
    assert task2.model.gamma == 0.999 and task2.n_timesteps == 1_500_000  # TLCarNav-v0:task=2
    assert task2.model.n_steps == 32  # the user's iteration size, not the entry's n_steps=1000
    assert SB3Agent("TLCarNav-v0", "ppo", **TINY).n_timesteps == 300_000  # TLCarNav-v0
    assert SB3Agent("TLCarNav-v0", "ppo", gamma=0.9, **TINY).model.gamma == 0.9
    none = SB3Agent("TLCarNav-v0", "ppo", hyperparams=False, **TINY)
    assert none.model.gamma == 0.99 and none.n_timesteps is None  # SB3's own default
    assert parse_normalize(none.config.normalize) == {"norm_obs": True, "norm_reward": False}

    own = tmp_path / "mine.yml"
    own.write_text("TLCarNav-v0:\n  ppo:\n    gamma: 0.5\n    normalize: false\n"
                   "    policy_kwargs: \"dict(net_arch=[8], activation_fn=nn.Tanh)\"\n")
    agent = SB3Agent("TLCarNav-v0", "ppo", hyperparams=str(own), **TINY)
    assert agent.model.gamma == 0.5 and agent.vec_normalize is None
    assert agent.model.policy.activation_fn is torch.nn.Tanh and agent.model.policy.net_arch == [8]
    loaded = Agent.load(agent.save(tmp_path / "mine.zip"))
    assert loaded.config == agent.config and loaded.config.algo_kwargs["policy_kwargs"]["activation_fn"] == "Tanh"
    relu = SB3Agent("TLCarNav-v0", "ppo", hyperparams=str(own), policy_kwargs={"activation_fn": torch.nn.ReLU}, **TINY)
    assert relu.model.policy.activation_fn is torch.nn.ReLU and relu.model.policy.net_arch != [8]  # whole-name win


def test_a_task_entry_adds_its_shaping_to_the_markov_view_only(tmp_path):
    """An entry's markov_env_kwargs sit between the markov preset and the user's env_kwargs; the terminal ablation
    never gets them; a saved agent keeps the keywords it trained with."""
    own = tmp_path / "shaped.yml"
    entry = "TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: {satisfaction_bonus: 4.0, reward_mode: potential}\n"
    own.write_text(entry)
    shaped = SB3Agent("TLCarNav-v0", "ppo", seed=0, hyperparams=str(own), **TINY)
    assert shaped.env_kwargs == {"observe_monitor": True, "reward_mode": "potential", "satisfaction_bonus": 4.0,
                                 "gamma": 0.99}  # potential shaping takes the agent's discount, as always
    assert shaped.env.get_attr("satisfaction_bonus") == (4.0, 4.0)
    assert "markov_env_kwargs" not in shaped.config.algo_kwargs
    saved = shaped.save(tmp_path / "shaped.zip")
    own.unlink()  # the keywords come from the save, not from the file read again
    loaded = Agent.load(saved)
    assert loaded.env_kwargs == shaped.env_kwargs and loaded.env.get_attr("satisfaction_bonus") == (4.0, 4.0)
    by_id = Agent.load(saved, env="TLCarNav-v0")  # the saved id is the saved env, shaping and all
    assert by_id.env_kwargs == shaped.env_kwargs and by_id.env.get_attr("satisfaction_bonus") == (4.0, 4.0)
    unshaped = Agent.load(saved, env="TLCarNav-v0", env_kwargs={"reward_mode": "potential"})
    assert "satisfaction_bonus" not in unshaped.env_kwargs  # given keywords: those, as for a new agent
    assert unshaped.env.get_attr("satisfaction_bonus") == (0.0, 0.0)
    with pytest.raises(ValueError, match=r"env_kwargs \{'task': 2\} are the keywords of an env id"):
        Agent.load(saved, env=shaped.env, env_kwargs={"task": 2})
    own.write_text(entry)

    users = SB3Agent("TLCarNav-v0", "ppo", hyperparams=str(own), env_kwargs={"satisfaction_bonus": 0.0}, **TINY)
    assert users.env_kwargs["satisfaction_bonus"] == 0.0 and users.env_kwargs["reward_mode"] == "potential"
    ablation = SB3Agent("TLCarNav-v0", "ppo", hyperparams=str(own), tl_reward="terminal", **TINY)
    assert ablation.env_kwargs == TL_REWARD_ENV_KWARGS["terminal"]
    assert ablation.env.get_attr("satisfaction_bonus") == (0.0, 0.0)


def test_an_env_object_without_the_tasks_shaping_is_warned_about(tmp_path):
    own = tmp_path / "shaped.yml"
    own.write_text("TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: {satisfaction_bonus: 4.0}\n")
    plain = gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="dense")
    with pytest.warns(UserWarning, match=r"does not have the markov_env_kwargs of ppo on TLCarNav-v0 in .*shaped.yml: "
                                         r"\{'satisfaction_bonus': 4.0\}"):
        SB3Agent(plain, "ppo", hyperparams=str(own), **TINY)
    shaped = gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="dense", satisfaction_bonus=4.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SB3Agent(shaped, "ppo", hyperparams=str(own), **TINY)


def test_an_env_objects_potential_shaping_with_another_discount_than_the_agents_is_warned_about():
    # an env id gets the agent's gamma; an object cannot be rebuilt, so its user is told
    undiscounted = gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="potential")  # the wrapper's gamma=1
    with pytest.warns(UserWarning, match=r"potential shaping uses gamma=1.0 but PPO discounts by 0.99: .*gamma=0.99"):
        SB3Agent(undiscounted, "ppo", hyperparams=False, **TINY)
    matched = gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="potential", gamma=0.99)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SB3Agent(matched, "ppo", hyperparams=False, **TINY)
        SB3Agent(gym.make("TLCarNav-v0", observe_monitor=True, reward_mode="dense"), "ppo", hyperparams=False, **TINY)


def test_an_env_keyword_the_env_refuses_is_named_with_its_source(tmp_path):
    own = tmp_path / "typo.yml"
    own.write_text("TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: {satisfaction_bonsu: 4.0}\n")
    with pytest.raises(TypeError, match=r"does not take the env keyword satisfaction_bonsu=4.0 \(from the "
                                        r"markov_env_kwargs of ppo on TLCarNav-v0 in .*typo.yml\)"):
        SB3Agent("TLCarNav-v0", "ppo", hyperparams=str(own), **TINY)
    with pytest.raises(TypeError) as raised:  # the user's own keyword: the env's own error, no source invented
        SB3Agent("TLCarNav-v0", "ppo", env_kwargs={"colour": 1}, **TINY)
    assert "colour" in str(raised.value) and "(from " not in str(raised.value)


def test_the_packaged_hyperparameters_validate():
    table = load_hyperparams()
    for suite_id in ("TLCarNav-v0", "TLCarNav-v0:task=2", "TLPendulum-v0", "TLMountainCar-v0", "TLParking-v0"):
        assert {"ppo", "sac", "td3"} <= set(table[suite_id]), suite_id
    for env_key, algos in table.items():
        for algo, entry in algos.items():
            assert entry["n_timesteps"] >= 1, (env_key, algo)
            if algo == "ppo":  # one iteration of the default 8000 steps is a whole number of rollouts
                rollout = entry["n_steps"] * entry["n_envs"]
                assert abs(-(-8000 // rollout) * rollout - 8000) <= 400, (env_key, rollout)
                assert rollout % entry["batch_size"] == 0, (env_key, "batch_size")
    assert find_hyperparams(table, "TLCarNav-v0", {"task": 2}, "PPO")["n_timesteps"] == 1_500_000


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("TLCarNav-v0:\n  ppo:\n    gama: 0.9\n",
         r"TLCarNav-v0 / ppo: unknown hyperparameter 'gama' \(did you mean 'gamma'\?\)"),
        ("TLCarNav-v0:\n  sac:\n    n_epochs: 3\n", "unknown hyperparameter 'n_epochs'.*SAC"),
        ("TLCarNav-v0:\n  nope:\n    gamma: 0.9\n", "unknown algorithm 'nope'"),
        ("TLCarNav-v0:\n  ppo:\n    learning_rate: lin_fast\n", "expected 'lin_<number>'"),
        ("TLCarNav-v0:\n  ppo:\n    gamma: lin_0.9\n", "gamma='lin_0.9': a 'lin_' schedule is only for"),
        ("TLCarNav-v0:\n  ppo:\n    clip_range: lin_-0.2\n", "must be a finite number > 0"),
        ("TLCarNav-v0:\n  ppo:\n    policy_kwargs: \"dict(net_arch=__import__('os'))\"\n", "cannot read"),
        ("TLCarNav-v0:\n  ppo:\n    policy_kwargs: {activation_fn: nn.Sigmoidal}\n", "unknown activation_fn"),
        # a class name other than activation_fn's would reach SB3 as the text 'RMSprop'
        ("TLCarNav-v0:\n  ppo:\n    policy_kwargs: \"dict(optimizer_class=th.optim.RMSprop)\"\n",
         "cannot read 'th.optim.RMSprop'"),
        ("TLCarNav-v0:\n  ppo:\n    normalize: \"{'norm_obs': True, 'gamma2': 1}\"\n", "gamma2"),
        ("TLCarNav-v0:task:\n  ppo: {}\n", "bad env key"),
        ("TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: {observe_monitor: false}\n",
         "markov_env_kwargs may not set observe_monitor"),
        ("TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: {reward_mode: potential, gamma: 0.9}\n",
         "markov_env_kwargs may not set gamma"),
        ("TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: 10\n",
         "markov_env_kwargs must be a mapping of env keyword names to values, got 10"),
        ("- TLCarNav-v0\n- ppo\n", "expected a mapping of env keys to algorithms"),
        ("TLCarNav-v0: 3\n", "TLCarNav-v0: expected a mapping of algorithm names to settings"),
        ("TLCarNav-v0:\n  ppo: 3\n", "TLCarNav-v0 / ppo: expected a mapping of settings"),
        ("TLCarNav-v0:\n  ppo:\n    normalize: \"{'norm_obs'\"\n", "normalize must be true, false or a dict"),
        ("TLCarNav-v0:\n  ppo:\n    normalize: 3\n", "normalize must be true, false or a dict"),
        ("TLCarNav-v0:\n  ppo:\n    policy_kwargs: \"dict(\"\n", r"policy_kwargs text does not parse: 'dict\('"),
        ("TLCarNav-v0:\n  ppo:\n    policy_kwargs: [64, 64]\n", "policy_kwargs must be a dict or its text"),
        ("TLCarNav-v0:\n  ppo:\n    n_timesteps: 1.5\n", "n_timesteps must be a whole number >= 1, got 1.5"),
    ],
)
def test_a_bad_hyperparameter_file_is_refused_naming_the_culprit(tmp_path, text, message):
    path = tmp_path / "bad.yml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_hyperparams(path)
    with pytest.raises(ValueError, match=message):
        SB3Agent("TLCarNav-v0", "ppo", hyperparams=str(path), **TINY)


def test_zoo_linear_schedules_decay_over_the_budget_and_survive_save_load(tmp_path):
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, n_timesteps=256, learning_rate="lin_1e-3", clip_range="lin_0.2",
                     **TINY)

    def rates(agent):
        model = agent.model
        return model.policy.optimizer.param_groups[0]["lr"], model.clip_range(model._current_progress_remaining)

    seen = []
    for _ in range(3):
        agent.learn(1)
        seen.append(rates(agent))
    # PPO trains after each 64-step rollout, at 64, 128, 192 of the 256 steps
    np.testing.assert_allclose(seen, [(1e-3 * (1 - k / 4), 0.2 * (1 - k / 4)) for k in (1, 2, 3)])
    loaded = Agent.load(agent.save(tmp_path / "lin.zip"))
    assert loaded.config.algo_kwargs["learning_rate"] == "lin_1e-3"
    loaded.learn(1)  # the budget's last rollout
    assert rates(loaded) == (0.0, 0.0)
    with pytest.warns(UserWarning, match="past it they stay at their end values"):
        loaded.learn(1)


def _halving(start: float):
    """An SB3-style schedule that is not linear: ``start`` at the beginning, half of it at the end."""
    return lambda progress_remaining: start * (0.5 + 0.5 * progress_remaining)


def test_callable_schedules_run_over_the_budget_not_each_iteration_and_survive_save_load(tmp_path):
    """SB3 counts a schedule's progress against one learn call; each iteration is one, so a callable learning rate
    restarted every iteration and fell to its end value in each (a learning rate of 0 with SB3's linear example)."""
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, n_timesteps=256, learning_rate=_halving(1e-3),
                     clip_range=_halving(0.2), **TINY)

    def rates(agent):
        model = agent.model
        return model.policy.optimizer.param_groups[0]["lr"], model.clip_range(model._current_progress_remaining)

    agent.learn(1)
    agent.learn(1)
    # the second rollout trains at 128 of the 256 steps: half the budget's progress left
    np.testing.assert_allclose(rates(agent), (1e-3 * 0.75, 0.2 * 0.75))
    loaded = Agent.load(agent.save(tmp_path / "callable.zip"))
    loaded.learn(1)  # at 192 of 256: a quarter left
    np.testing.assert_allclose(rates(loaded), (1e-3 * 0.625, 0.2 * 0.625))


@pytest.mark.parametrize("value", ["lin_1e-3", _halving(1e-3)])
def test_a_schedule_needs_a_budget(value):
    with pytest.raises(ValueError, match=r"learning_rate=.* is a schedule of the training's progress, which runs "
                                         r"over n_timesteps here .* give n_timesteps"):
        SB3Agent("TLCarNav-v0", "ppo", hyperparams=False, learning_rate=value, **TINY)


def test_dqn_exploration_decays_over_the_budget():
    """DQN's ε falls over exploration_fraction × n_timesteps, as the zoo has it; without a budget it fell within
    each iteration's learn call, so after the first iteration the agent barely explored."""
    import tl_gym

    env = tl_gym.TLTLRewardWrapper(gym.make("CartPole-v1", max_episode_steps=20), "G(x < 2)", {"x": 0})
    with pytest.raises(ValueError, match=r"DQN decays its exploration over exploration_fraction × n_timesteps"):
        SB3Agent(env, "dqn", seed=0, steps_per_iteration=32, n_envs=1)
    agent = SB3Agent(env, "dqn", seed=0, steps_per_iteration=32, n_envs=1, n_timesteps=128, exploration_fraction=0.5,
                     exploration_initial_eps=1.0, exploration_final_eps=0.1, learning_starts=16, batch_size=8)
    epsilons = []
    for _ in range(3):
        agent.learn(1)
        epsilons.append(agent.model.exploration_rate)
    # ε falls from 1 to 0.1 over the first 64 steps: 0.55 at 32, 0.1 from 64 on
    np.testing.assert_allclose(epsilons, [0.55, 0.1, 0.1])


def test_dqn_exploration_keeps_its_budget_through_save_load_and_old_files_still_load(tmp_path):
    import json
    import zipfile

    import tl_gym

    env = tl_gym.TLTLRewardWrapper(gym.make("CartPole-v1", max_episode_steps=20), "G(x < 2)", {"x": 0})
    agent = SB3Agent(env, "dqn", seed=0, steps_per_iteration=16, n_envs=1, n_timesteps=128, exploration_fraction=0.5,
                     exploration_initial_eps=1.0, exploration_final_eps=0.1, learning_starts=8, batch_size=8)
    agent.learn(1)
    path = agent.save(tmp_path / "dqn.zip")
    loaded = Agent.load(path, env=env)
    loaded.learn(1)  # at 32 of the 64 steps ε falls over
    assert loaded.model.exploration_rate == pytest.approx(0.55)
    # a file saved before DQN needed a budget holds n_timesteps null: it loads, acts and learns as it was made
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    meta = json.loads(members["meta.json"])
    meta["config"]["n_timesteps"] = None
    members["meta.json"] = json.dumps(meta).encode()
    old = tmp_path / "old_dqn.zip"
    with zipfile.ZipFile(old, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    old_agent = Agent.load(old, env=env)
    assert old_agent.config.n_timesteps is None and "exploration_schedule" not in old_agent._schedules
    old_agent.learn(1)


@pytest.mark.parametrize("end_is_terminal", [True, False])
def test_the_end_of_the_trace_is_a_termination_for_sb3(end_is_terminal):
    agent = SB3Agent("TLCarNav-v0", "PPO", seed=0, env_kwargs={"horizon": 3}, steps_per_iteration=6, n_envs=2,
                     n_steps=3, batch_size=6, end_is_terminal=end_is_terminal)
    venv = agent.sb3_env
    venv.reset()
    for _ in range(3):
        _, _, dones, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
    assert dones.all()
    # SB3 bootstraps a value past an episode end only when it was a truncation
    assert [info["TimeLimit.truncated"] for info in infos] == [not end_is_terminal] * 2
    with pytest.raises(ValueError, match="end_is_terminal must be true or false"):
        SB3Agent("TLCarNav-v0", "PPO", end_is_terminal="yes")


def test_potential_shaping_gets_the_agents_discount():
    agent = SB3Agent("TLCarNav-v0", "PPO", seed=0, env_kwargs={"reward_mode": "potential", "horizon": 4},
                     steps_per_iteration=8, n_envs=2, n_steps=4, batch_size=8, gamma=0.97)
    assert agent.env_kwargs["gamma"] == 0.97 == agent.model.gamma
    assert agent.sb3_env.get_attr("gamma") == [0.97, 0.97]
    mine = SB3Agent("TLCarNav-v0", "PPO", seed=0, env_kwargs={"reward_mode": "potential", "gamma": 1.0, "horizon": 4},
                    steps_per_iteration=8, n_envs=2, n_steps=4, batch_size=8, gamma=0.97)
    assert mine.env_kwargs["gamma"] == 1.0  # the user's own wins


def test_agents_saved_before_the_settings_split_still_find_their_schedule_class():
    """SB3 model zips saved before agents/sb3_settings.py existed pickle ``tl_gym.agents.sb3.LinearSchedule``."""
    from tl_gym.agents.sb3_settings import LinearSchedule

    assert pickle.loads(b"ctl_gym.agents.sb3\nLinearSchedule\n.") is LinearSchedule


def test_stochastic_actions_are_seeded_by_evaluate_and_leave_training_alone():
    """SB3 samples actions with torch's global generator, the one its training draws from too."""
    def policy_after_two_iterations(sample_between: bool) -> list[np.ndarray]:
        agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, env_kwargs={"horizon": 16}, **TINY)
        agent.learn(1)
        if sample_between:  # as `tl-gym train` samples trajectories to plot, or an evaluation of the stochastic policy
            first = agent.evaluate(2, seed=5, deterministic=False)["robustness"]
            assert agent.evaluate(2, seed=5, deterministic=False)["robustness"].tolist() == first.tolist()
            assert first.tolist() != agent.evaluate(2, seed=5)["robustness"].tolist()  # and still stochastic
        agent.learn(1)
        return [p.detach().numpy().copy() for p in agent.model.policy.parameters()]

    for a, b in zip(policy_after_two_iterations(False), policy_after_two_iterations(True)):
        np.testing.assert_array_equal(a, b)


def test_load_takes_the_saved_settings_without_reading_the_hyperparameter_file_again(tmp_path, monkeypatch):
    """The saved config holds the file's settings: a relative path from elsewhere, or an edited file, is moot."""
    (tmp_path / "train").mkdir()
    monkeypatch.chdir(tmp_path / "train")
    Path("mine.yml").write_text("TLCarNav-v0:\n  ppo:\n    gamma: 0.5\n")
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, hyperparams="mine.yml", **TINY)
    path = agent.save(tmp_path / "mine.zip")
    Path("mine.yml").write_text("TLCarNav-v0:\n  ppo:\n    gamma: 0.7\n    ent_coef: 0.5\n")  # edited since
    loaded = Agent.load(path)
    assert loaded.config == agent.config and loaded.config.hyperparams == "mine.yml"
    assert loaded.model.gamma == 0.5 and loaded.model.ent_coef == agent.model.ent_coef == 0.0
    monkeypatch.chdir(tmp_path)  # where mine.yml is not
    assert Agent.load(path).config == agent.config


def test_a_float_written_without_a_dot_is_a_number(tmp_path):
    """PyYAML (YAML 1.1) reads 3e-4 as text, which SB3 refused only when it built or trained the model."""
    path = tmp_path / "floats.yml"
    path.write_text("TLCarNav-v0:\n  ppo:\n    learning_rate: 3e-4\n    ent_coef: 1E-2\n    n_timesteps: 1e5\n"
                    "    clip_range: !!float 2e-1\n")
    entry = load_hyperparams(path)["TLCarNav-v0"]["ppo"]
    assert entry == {"learning_rate": 3e-4, "ent_coef": 0.01, "n_timesteps": 100_000, "clip_range": 0.2}
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, hyperparams=str(path), **TINY)
    assert agent.model.learning_rate == 3e-4 and agent.model.ent_coef == 0.01


def test_close_closes_the_training_envs_too():
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, **TINY)
    closed = []
    for env in [*agent.sb3_env.envs, agent.env]:
        env.close = lambda env=env, close=env.close: (closed.append(env), close())
    agent.close()
    assert len(closed) == 3  # the two envs SB3 trains on, and the evaluation env


def test_epsilon_greedy_sampling_leaves_numpy_and_torch_global_generators_alone():
    """DQN explores with numpy's global generator and its action space's; its training draws from them too."""
    import tl_gym

    env = tl_gym.TLTLRewardWrapper(gym.make("CartPole-v1", max_episode_steps=20), "G(x < 2)", {"x": 0})
    agent = SB3Agent(env, "dqn", seed=0, steps_per_iteration=32, n_envs=1, learning_starts=16, batch_size=8,
                     buffer_size=100, n_timesteps=1000)
    agent.model.exploration_rate = 1.0  # every stochastic action a random one
    numpy_state, torch_state = np.random.get_state()[1].copy(), torch.get_rng_state().clone()
    space_state = agent.model.action_space.np_random.bit_generator.state
    actions = [agent.predict(np.zeros((1, 4)), deterministic=False)[0].item() for _ in range(20)]
    assert len(set(actions)) == 2  # random
    agent.evaluate(2, seed=0, deterministic=False)
    np.testing.assert_array_equal(np.random.get_state()[1], numpy_state)
    assert torch.equal(torch.get_rng_state(), torch_state)
    assert agent.model.action_space.np_random.bit_generator.state == space_state


def test_sb3_records_each_episode_as_with_the_zoos_monitor():
    """SB3 logs rollout/ep_rew_mean and ep_len_mean from Monitor's info["episode"]; without it, nothing."""
    agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, env_kwargs={"horizon": 16}, **TINY)
    agent.learn(1)
    episodes = list(agent.model.ep_info_buffer)
    assert len(episodes) == agent.history[-1]["episodes"] == 4  # 64 steps of 16-step episodes
    assert all(episode["l"] == 16 and np.isfinite(episode["r"]) for episode in episodes)


def test_an_algorithm_that_cannot_take_the_env_says_so_and_recurrent_ppo_gets_its_own_policy():
    """SB3's AssertionError (DQN on Box actions) is a ValueError naming the algorithm; RecurrentPPO has no
    MlpPolicy, so its own MlpLstmPolicy is the default (it failed with "Policy MlpPolicy unknown")."""
    with pytest.raises(ValueError, match=r"DQN refused this env or these settings: The algorithm only supports"):
        SB3Agent("TLCarNav-v0", "dqn", n_timesteps=1000)
    pytest.importorskip("sb3_contrib")
    agent = SB3Agent("TLPendulum-v0", "recurrentppo", n_envs=1, n_steps=64, batch_size=32, steps_per_iteration=64)
    assert type(agent.model.policy).__name__ == "RecurrentActorCriticPolicy"


class WithMode(gym.Env):
    """A Dict observation with a Discrete entry beside the Box: VecNormalize cannot scale the whole Dict."""

    observation_space = gym.spaces.Dict({"pos": gym.spaces.Box(-10.0, 10.0, (2,), np.float32),
                                         "mode": gym.spaces.Discrete(3)})
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = np.zeros(2, np.float32)
        return {"pos": self.pos.copy(), "mode": 0}, {}

    def step(self, action):
        self.pos = np.clip(self.pos + action, -10, 10).astype(np.float32)
        return {"pos": self.pos.copy(), "mode": int(self.pos[0] > 0)}, 0.0, False, False, {}


def test_the_default_normalisation_scales_the_box_entries_of_a_dict_with_other_entries():
    """VecNormalize raised "only supports gym.spaces.Box" at the default settings; the Box keys are scaled now."""
    env = tl_gym.TLTLRewardWrapper(gym.wrappers.TimeLimit(WithMode(), 20), "F(x > 2)", signals={"x": ("pos", 0)},
                                   observe_monitor=True, reward_mode="dense")
    agent = SB3Agent(env, "ppo", seed=0, hyperparams=False, **TINY).learn(1)
    assert set(agent.vec_normalize.norm_obs_keys) == {"pos", "monitor"}  # not "mode"
    assert agent.vec_normalize.obs_rms.keys() == {"pos", "monitor"}
    obs, _ = env.reset(seed=0)
    action, _ = agent.predict(obs)
    assert agent.action_space.contains(action)


@pytest.mark.parametrize("algo, reason", [("ars", "whole evaluation episodes of perturbed policies"),
                                          ("maskableppo", "needs the env's action masks")])
def test_algorithms_that_do_not_fit_the_agent_are_refused_at_construction_with_the_reason(algo, reason):
    """ARS crashed at its first learn (its callback steps carry no dones); MaskablePPO acted without its masks."""
    pytest.importorskip("sb3_contrib")
    with pytest.raises(ValueError, match=reason):
        SB3Agent("TLPendulum-v0", algo)


def test_a_dict_observation_with_an_algorithm_without_a_multi_input_policy_names_the_fix():
    pytest.importorskip("sb3_contrib")
    pytest.importorskip("highway_env")
    with pytest.raises(ValueError, match=r"CrossQ has no policy for Dict observations \(its policies: MlpPolicy\): "
                                         r"flatten the observation, env_wrapper='gymnasium.wrappers.Flatten"):
        SB3Agent("TLParking-v0", "crossq", n_timesteps=100, hyperparams=False)  # the task's entry flattens


def test_the_zoos_env_wrapper_wraps_every_env_the_agent_trains_and_evaluates_on_and_is_saved(tmp_path):
    """CrossQ takes no Dict observation: the zoo's env_wrapper flattens parking's for it, in training, evaluation
    and after loading (the config keeps the key)."""
    pytest.importorskip("sb3_contrib")
    pytest.importorskip("highway_env")
    agent = SB3Agent("TLParking-v0", "crossq", seed=0, n_timesteps=200, steps_per_iteration=64, learning_starts=32,
                     batch_size=16, hyperparams=False, env_wrapper="gymnasium.wrappers.FlattenObservation",
                     policy_kwargs={"net_arch": {"pi": [16, 16], "qf": [16, 16]}})
    flat = agent.observation_space
    assert isinstance(flat, gym.spaces.Box) and agent.sb3_env.observation_space == flat
    assert all(find_wrapper(env, gym.wrappers.FlattenObservation) is not None for env in agent.sb3_env.envs)
    agent.learn(1)
    loaded = Agent.load(agent.save(tmp_path / "flat.zip"))
    assert loaded.config.env_wrapper == "gymnasium.wrappers.FlattenObservation" and loaded.observation_space == flat
    assert loaded.evaluate(2, seed=3)["robustness"].tolist() == agent.evaluate(2, seed=3)["robustness"].tolist()


def test_an_env_object_gets_the_env_wrapper_too_with_its_keywords_and_a_vector_env_is_refused():
    import tl_gym

    env = tl_gym.TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=20), "G(abs(th) < 3)", {"th": 2})
    wrapper = [{"gymnasium.wrappers.NormalizeObservation": {"epsilon": 0.125}}]
    agent = SB3Agent(env, "ppo", seed=0, steps_per_iteration=40, n_envs=2, batch_size=40, hyperparams=False,
                     env_wrapper=wrapper)
    assert find_wrapper(env, gym.wrappers.NormalizeObservation) is None  # the user's env object is left as it was
    for wrapped in (*agent.sb3_env.envs, *agent.env.envs):  # SB3's training envs and the agent's own
        assert find_wrapper(wrapped, gym.wrappers.NormalizeObservation).epsilon == 0.125
    vector = gym.make_vec("TLPendulum-v0", num_envs=2, vectorization_mode="sync")
    with pytest.raises(TypeError, match="env_wrapper=.* wraps single envs: pass an env id or an Env"):
        SB3Agent(vector, "ppo", env_wrapper=wrapper)
    with pytest.raises(ValueError, match="env_wrapper 'gymnasium.Env' is not a gymnasium.Wrapper class"):
        SB3Agent("TLPendulum-v0", "ppo", env_wrapper="gymnasium.Env")
    with pytest.raises(ValueError, match="env_wrapper 'nope.Wrapper' does not import"):
        SB3Agent("TLPendulum-v0", "ppo", env_wrapper="nope.Wrapper")


def test_an_env_object_that_flattens_a_dict_task_gets_a_policy_for_its_own_observation():
    """The task's entry (found by the env's spec id) names MultiInputPolicy for parking's Dict; a flattened env
    object gets the default policy for its Box (it crashed in SB3's CombinedExtractor), the rest of the entry kept."""
    pytest.importorskip("highway_env")
    env = gym.wrappers.FlattenObservation(gym.make("TLParking-v0", observe_monitor=True, reward_mode="dense"))
    with pytest.warns(UserWarning, match="markov_env_kwargs"):  # the entry's env keywords cannot reach an object
        agent = SB3Agent(env, "sac", seed=0, steps_per_iteration=100, learning_starts=50, batch_size=16)
    assert type(agent.model.policy).__name__ == "SACPolicy" and agent.config.policy is None
    assert (agent.model.tau, agent.model.learning_rate) == (0.05, 1e-3)  # the parking entry's (SB3's: 0.005, 3e-4)


@pytest.mark.parametrize("algo, n_envs", [("ppo", 8), ("a2c", 8), ("sac", 1), ("td3", 1), ("ddpg", 1)])
def test_default_n_envs_is_one_for_off_policy_algorithms(algo, n_envs):
    """With 8 envs an off-policy algorithm took one gradient step per 8 env steps; the zoo's default is 1."""
    agent = SB3Agent("TLPendulum-v0", algo, hyperparams=False, steps_per_iteration=1024)
    assert agent.config.n_envs == agent.model.n_envs == n_envs


def test_env_wrapper_edges_entry_policy_her_goals_json_and_loading_an_env_object(tmp_path):
    """The parking entries' MultiInputPolicy is for the Dict observation a FlattenObservation changes; relabelling
    reads the Dict goals; keywords must be JSON to be saved; an env object is saved unwrapped (it loaded wrapped
    twice)."""
    pytest.importorskip("highway_env")
    import tl_gym

    flat = "gymnasium.wrappers.FlattenObservation"
    agent = SB3Agent("TLParking-v0", "ppo", seed=0, env_wrapper=flat, steps_per_iteration=64, n_envs=1, batch_size=32)
    assert type(agent.model.policy).__name__ == "ActorCriticPolicy" and agent.config.policy is None
    with pytest.raises(ValueError, match="her_goals=1 relabels the goals .* env_wrapper=.* changes"):
        SB3Agent("TLParking-v0", "sac", env_wrapper=flat, her_goals=1)
    with pytest.raises(ValueError, match="keywords must be JSON values"):
        SB3Agent("TLPendulum-v0", "ppo", env_wrapper=[{"gymnasium.wrappers.TransformReward": {"func": np.tanh}}])
    env = tl_gym.TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=20), "G(abs(th) < 3)", {"th": 2})
    timed = SB3Agent(env, "ppo", seed=0, steps_per_iteration=40, n_envs=2, batch_size=40, hyperparams=False,
                     env_wrapper="gymnasium.wrappers.TimeAwareObservation")
    loaded = Agent.load(timed.save(tmp_path / "timed.zip"))
    assert loaded.observation_space == timed.observation_space and loaded.observation_space.shape == (4,)
    for agent_ in (timed, loaded):
        chain = agent_.env.envs[0]
        count = 0
        while chain is not None:
            count += isinstance(chain, gym.wrappers.TimeAwareObservation)
            chain = getattr(chain, "env", None)
        assert count == 1
