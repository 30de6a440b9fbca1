"""benchmarks/parking_nstep.py: the flattened parking id and its hyperparameter lookup."""

import gymnasium as gym
import numpy as np
import pytest
from tl_gym.agents import sb3

from benchmarks import parking_nstep


@pytest.fixture
def flat_parking(monkeypatch):
    """Register the trial's id for one test; restore the lookup and the registry after it."""
    pytest.importorskip("highway_env")
    monkeypatch.setattr(sb3, "find_hyperparams", sb3.find_hyperparams)
    parking_nstep._register_flat_parking()
    yield parking_nstep.FLAT_ID
    gym.registry.pop(parking_nstep.FLAT_ID, None)


def test_flat_id_reads_parking_sac_entry(flat_parking):
    table = sb3.load_hyperparams()
    entry = sb3.find_hyperparams(table, "TLParking-v0", {}, "sac")
    assert entry  # the parking entry exists, so the comparison below can fail
    assert sb3.find_hyperparams(table, flat_parking, {}, "sac") == entry


def test_flat_id_flattens_the_dict_observation(flat_parking):
    env = gym.make(flat_parking)
    nested = gym.make("TLParking-v0")
    obs, _ = env.reset(seed=3)
    nested_obs, _ = nested.reset(seed=3)
    assert isinstance(env.observation_space, gym.spaces.Box)
    np.testing.assert_array_equal(obs, gym.spaces.flatten(nested.observation_space, nested_obs))
    env.close()
    nested.close()
