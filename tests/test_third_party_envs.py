"""TLTLRewardWrapper on envs tl_gym does not own: classic control and highway-env's parking (Dict observations)."""

import gymnasium as gym
import numpy as np
import pytest

from tl_gym import TLTLRewardWrapper, parse


def random_episode(env, seed):
    """Run one random episode to its end; return (rewards, last info)."""
    env.reset(seed=seed)
    env.action_space.seed(seed)
    rewards = []
    while True:
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        rewards.append(reward)
        if terminated or truncated:
            return rewards, info


def check_terminal_reward(env, spec, seed=0):
    rewards, info = random_episode(env, seed)
    expected = parse(spec).robustness(info["trace"])
    assert rewards[-1] == expected == info["robustness"]
    assert all(r == 0.0 for r in rewards[:-1])
    assert all(type(r) is float for r in rewards)
    return rewards, info


def test_pendulum_swing_up_and_stay_up():
    spec = "F(G(cos_th > 0.95)) & G(abs(th_dot) < 8)"
    env = TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=60), spec, signals={"cos_th": 0, "th_dot": 2})
    rewards, info = check_terminal_reward(env, spec)
    assert len(rewards) == 60 and len(info["trace"]["cos_th"]) == 61


def test_mountain_car_reaches_the_flag():
    spec = "F(position >= 0.45)"
    base = gym.make("MountainCarContinuous-v0", max_episode_steps=80)
    env = TLTLRewardWrapper(base, spec, signals={"position": 0, "velocity": 1})
    rewards, info = check_terminal_reward(env, spec)
    assert not info["satisfied"]  # a random car does not climb the hill in 80 steps
    np.testing.assert_array_less(info["trace"]["position"], 0.45)


def test_mountain_car_dense_rewards_sum_to_the_robustness():
    spec = "F(position >= 0.45) & G(velocity < 0.07)"
    base = gym.make("MountainCarContinuous-v0", max_episode_steps=80)
    env = TLTLRewardWrapper(base, spec, signals={"position": 0, "velocity": 1}, reward_mode="dense")
    rewards, info = random_episode(env, seed=1)
    assert sum(rewards) == pytest.approx(parse(spec).robustness(info["trace"]), abs=1e-12)


def test_highway_parking_with_dict_observations():
    pytest.importorskip("highway_env")
    spec = "F(distance < 0.05) & G(speed < 10)"
    signals = {
        "distance": lambda obs: float(np.linalg.norm(obs["achieved_goal"][:2] - obs["desired_goal"][:2])),
        "speed": lambda obs, info: info["speed"],
        "x": ("observation", 0),  # extra names are allowed
    }
    env = TLTLRewardWrapper(gym.make("parking-v0", max_episode_steps=15), spec, signals=signals)
    rewards, info = check_terminal_reward(env, spec)
    assert len(info["trace"]["distance"]) == len(rewards) + 1
    assert set(info["trace"]) == {"distance", "speed"}
