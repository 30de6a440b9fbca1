"""benchmarks/parking_demos.py: the hand controller's episodes in SAC's replay buffer, and the runner's hook."""

import dataclasses

import numpy as np
import pytest
from tl_gym.agents.registry import make_agent

from benchmarks import parking_demos
from benchmarks.parking_starts import ParkingController
from benchmarks.run_one import execute_run
from benchmarks.suite import suite_run
from benchmarks.sweep_config import RunSpec

SMALL = {"steps_per_iteration": 16, "learning_starts": 8, "batch_size": 8, "buffer_size": 1000,
         "policy_kwargs": "dict(net_arch=[8])"}


class RecordingController(ParkingController):
    """The hand controller, keeping every observation it saw and action it took."""

    seen: list = []

    def __call__(self, obs):
        action = super().__call__(obs)
        RecordingController.seen.append((obs["observation"].copy(), action))
        return action


def test_trial_is_the_suite_sac_run_as_it_ran_under_its_own_label():
    spec = parking_demos.trial_spec(100, 5, seed=100)
    suite_sac = suite_run("parking", "SAC")
    assert spec.seed == 100 and "100 controller steps" in spec.label
    assert spec.env_kwargs == {"satisfaction_bonus": 0.0, "end_on_violation": False}  # it ran before the SAC entry's
    # bonus and end at the violation
    assert dataclasses.replace(spec, label=suite_sac.label, seed=suite_sac.seed, note=suite_sac.note,
                               env_kwargs=suite_sac.env_kwargs) == suite_sac
    assert spec.run_id != suite_sac.run_id


@pytest.fixture
def agent():
    pytest.importorskip("highway_env")
    spec = parking_demos.trial_spec(0, 0, seed=0)
    made = make_agent(spec.agent, spec.env, seed=0, env_kwargs=dict(spec.env_kwargs), **SMALL)
    yield made
    made.close()


def test_demonstrations_are_stored_raw_as_sb3_stores_its_own(agent):
    RecordingController.seen = []
    result = parking_demos.add_demonstrations(agent, 120, make_controller=RecordingController)
    buffer = agent.model.replay_buffer
    assert buffer.size() == 120 and result["episodes"] == 1  # 100-step episodes: one ends within 120 steps
    seen = np.stack([obs for obs, _ in RecordingController.seen])
    # the controller saw the unnormalised observation, and the buffer holds exactly that (VecNormalize is on)
    assert agent.vec_normalize is not None and agent.vec_normalize.norm_obs
    np.testing.assert_allclose(buffer.observations["observation"][:120, 0], seen, atol=1e-6)
    np.testing.assert_allclose(buffer.actions[:120, 0], np.stack([a for _, a in RecordingController.seen]))
    # the next observation of step t is the observation of step t + 1, but at the episode's end
    np.testing.assert_allclose(buffer.next_observations["observation"][:98, 0], seen[1:99], atol=1e-6)
    assert buffer.dones[:120, 0].tolist() == [0.0] * 99 + [1.0] + [0.0] * 20
    assert agent.vec_normalize.obs_rms["observation"].count > 100  # the statistics saw the demonstrations


def test_pretraining_moves_the_policy_and_learning_goes_on(agent):
    parking_demos.add_demonstrations(agent, 40)
    before = [p.detach().clone() for p in agent.model.actor.parameters()]
    parking_demos.pretrain(agent, 3)
    assert any(not np.allclose(b, a.detach()) for b, a in zip(before, agent.model.actor.parameters()))
    agent.learn(1)
    assert agent.model.replay_buffer.size() == 40 + 16 and agent.model.num_timesteps == 16


def test_runner_prepares_a_new_run_once(tmp_path):
    spec = RunSpec(env="TLCarNav-v0", env_kwargs={}, agent="reps", label="REPS",
                   hyperparameters={"n_episodes": 2}, seed=0, iterations=1)
    prepared = []
    execute_run(spec, tmp_path / "run", prepare=prepared.append)
    execute_run(spec, tmp_path / "run", prepare=prepared.append)  # done already: not prepared again
    assert len(prepared) == 1 and prepared[0].__class__.__name__ == "REPS"
