"""benchmarks/parking_nstep.py: the flattened parking id and the trial's run."""

import gymnasium as gym
import numpy as np
import pytest
from tl_gym.agents import sb3_settings
from tl_gym.agents.registry import make_agent

from benchmarks import parking_nstep
from benchmarks.suite import suite_run


def test_trial_is_the_suite_sac_run_with_the_parking_entry():
    spec = parking_nstep.trial_spec(3, seed=100)
    suite_sac = suite_run("parking", "SAC")
    entry = sb3_settings.find_hyperparams(sb3_settings.load_hyperparams(), "TLParking-v0", {}, "sac")
    assert entry  # the parking entry exists, so the comparison below can fail
    assert (spec.env, spec.seed) == (parking_nstep.FLAT_ID, 100)
    assert (spec.iterations, spec.evaluate_episodes, spec.evaluate_every) == (
        suite_sac.iterations, suite_sac.evaluate_episodes, suite_sac.evaluate_every)
    hyper = dict(spec.hyperparameters)
    assert (hyper.pop("hyperparams"), hyper.pop("policy"), hyper.pop("n_steps")) == (False, "MlpPolicy", 3)
    assert entry.pop(sb3_settings.MARKOV_ENV_KWARGS) == {"satisfaction_bonus": 10.0, "end_on_violation": True}  # env
    # keywords, not passed on
    assert hyper == {**{k: v for k, v in entry.items() if k != "policy"}, **suite_sac.hyperparameters}
    assert spec.env_kwargs == {"satisfaction_bonus": 0.0, "end_on_violation": False}  # as the trial ran, before both


@pytest.fixture
def flat_parking():
    """Register the trial's id for one test; take it out of the registry after it."""
    pytest.importorskip("highway_env")
    parking_nstep.register_flat_parking()
    parking_nstep.register_flat_parking()  # a second call is a no-op
    yield parking_nstep.FLAT_ID
    gym.registry.pop(parking_nstep.FLAT_ID, None)


def test_flat_id_flattens_the_dict_observation(flat_parking):
    env = gym.make(flat_parking)
    nested = gym.make("TLParking-v0")
    obs, _ = env.reset(seed=3)
    nested_obs, _ = nested.reset(seed=3)
    assert isinstance(env.observation_space, gym.spaces.Box)
    np.testing.assert_array_equal(obs, gym.spaces.flatten(nested.observation_space, nested_obs))
    env.close()
    nested.close()


def test_agent_builds_on_the_flat_id_with_n_step_returns(flat_parking):
    spec = parking_nstep.trial_spec(3, seed=0)
    hyper = {**spec.hyperparameters, "learning_starts": 8, "batch_size": 8, "buffer_size": 64}
    agent = make_agent("sac", spec.env, seed=0, env_kwargs=spec.env_kwargs, **hyper)
    assert agent.model.n_steps == 3
    assert agent.model.gamma == 0.99 and agent.model.batch_size == 8
