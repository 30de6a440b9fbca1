"""The one agent registry: names, classes, construction and the saved-class lookup."""

import pytest
from tl_gym.agents import REPS, TLPS
from tl_gym.agents.registry import agent_class, check_agent_name, is_episodic, make_agent, saved_class
from tl_gym.agents.sb3 import SB3Agent


def test_names_map_to_classes():
    assert agent_class("tlps") is TLPS and agent_class("REPS") is REPS
    assert agent_class("ppo") is SB3Agent and agent_class("TD3") is SB3Agent
    assert agent_class("tl_gym.agents.reps:REPS") is REPS
    assert is_episodic("TLPS") and not is_episodic("sac")


@pytest.mark.parametrize("name", ["", "sb3", "sb3:PPO", 3])
def test_malformed_names_are_refused(name):
    with pytest.raises(ValueError, match="agent name|name the stable-baselines3 algorithm"):
        check_agent_name(name)


def test_a_missing_attribute_is_an_import_error():
    with pytest.raises(ImportError, match="has no 'Nope'"):
        agent_class("tl_gym.agents.reps:Nope")


def test_make_agent_puts_the_env_first_for_every_agent():
    episodic = make_agent("reps", "TLCarNav-v0", seed=3, n_episodes=4)
    assert isinstance(episodic, REPS) and episodic.seed == 3 and episodic.config.n_episodes == 4
    ppo = make_agent("ppo", "TLCarNav-v0", seed=1, steps_per_iteration=64, n_envs=2, batch_size=32)
    assert isinstance(ppo, SB3Agent) and ppo.algo_class.__name__ == "PPO"
    with pytest.raises(ValueError, match="unknown agent 'nope': tlps, reps, a stable-baselines3 algorithm"):
        make_agent("nope", "TLCarNav-v0")
    with pytest.raises(ValueError, match=r"unknown agent 'td4' \(did you mean 'td3'\?\)"):
        make_agent("td4", "TLCarNav-v0")
    episodic.close()
    ppo.close()


def test_saved_class_knows_the_librarys_agents_only():
    assert saved_class("TLPS") is TLPS and saved_class("SB3Agent") is SB3Agent
    with pytest.raises(LookupError, match="unknown agent class 'Mine'"):
        saved_class("Mine")
