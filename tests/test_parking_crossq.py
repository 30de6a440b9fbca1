"""benchmarks/parking_crossq.py: the CrossQ trial's run on the flattened parking id."""

import gymnasium as gym
import pytest
import torch
from tl_gym.agents import sb3_settings
from tl_gym.agents.registry import make_agent

from benchmarks import parking_crossq, parking_nstep
from benchmarks.suite import suite_run


def test_trial_is_the_suite_sac_run_moved_to_crossq():
    spec = parking_crossq.trial_spec(512, seed=100)
    suite_sac = suite_run("parking", "SAC")
    entry = sb3_settings.find_hyperparams(sb3_settings.load_hyperparams(), "TLParking-v0", {}, "sac")
    assert entry  # the parking entry exists, so the comparisons below can fail
    assert (spec.env, spec.agent, spec.seed) == (parking_nstep.FLAT_ID, "crossq", 100)
    assert (spec.iterations, spec.evaluate_episodes, spec.evaluate_every) == (
        suite_sac.iterations, suite_sac.evaluate_episodes, suite_sac.evaluate_every)
    # the entry's env keywords written out: the flattened id has no entry of its own
    assert spec.env_kwargs == entry.pop(sb3_settings.MARKOV_ENV_KWARGS) == {"satisfaction_bonus": 10.0,
                                                                           "end_on_violation": True}
    hyper = dict(spec.hyperparameters)
    assert (hyper.pop("hyperparams"), hyper.pop("policy")) == (False, "MlpPolicy")
    assert hyper.pop("policy_kwargs") == {"net_arch": {"pi": [256, 256], "qf": [512, 512]}}
    assert "tau" in entry  # SAC's, dropped: CrossQ has no target network
    kept = {k: v for k, v in entry.items() if k not in ("policy", "policy_kwargs", "tau")}
    assert hyper == {**kept, **suite_sac.hyperparameters}


@pytest.fixture
def flat_parking():
    """Register the trial's id for one test; take it out of the registry after it."""
    pytest.importorskip("highway_env")
    pytest.importorskip("sb3_contrib")
    parking_nstep.register_flat_parking()
    yield parking_nstep.FLAT_ID
    gym.registry.pop(parking_nstep.FLAT_ID, None)


def test_crossq_builds_on_the_flat_id_and_trains(flat_parking):
    spec = parking_crossq.trial_spec(32, seed=0)
    hyper = {**spec.hyperparameters, "learning_starts": 8, "batch_size": 8, "buffer_size": 64,
             "steps_per_iteration": 16}
    agent = make_agent("crossq", spec.env, seed=0, env_kwargs=spec.env_kwargs, **hyper)
    assert type(agent.model).__name__ == "CrossQ"
    assert agent.model.gamma == 0.99 and agent.model.batch_size == 8
    linear = [m for m in agent.model.policy.critic.q_networks[0].modules() if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linear] == [32, 32, 1]  # the critic's width as asked
    agent.learn(iterations=1)
    assert agent.history[-1]["env_steps"] >= 16
