"""Hindsight goal relabelling (tl_gym.relabel, agents.hindsight): a relabelled episode is the episode
the wrapper would have produced had the env drawn that goal; SB3's replay buffer receives it."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from hypothesis import given
from hypothesis import strategies as st

from tl_gym import TLTLRewardWrapper
from tl_gym.relabel import EpisodeRecorder, GoalRelabeller

FORMULA = "F(dist < 0.5 & speed < 0.6) & G(speed < 1.2)"
HORIZON = 12


class PointGoal(gym.Env):
    """A point in the plane that moves by its action; reach the goal (drawn at reset, or ``options["goal"]``)."""

    observation_space = spaces.Dict({key: spaces.Box(-50.0, 50.0, (2,), np.float64)
                                     for key in ("observation", "achieved_goal", "desired_goal")})
    action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = np.zeros(2)
        self.goal = np.array(options["goal"], float) if options else self.np_random.uniform(-4, 4, 2)
        return self._obs(), {}

    def step(self, action):
        self.speed = float(np.hypot(*action))
        self.pos = self.pos + np.asarray(action, float)
        obs = self._obs()
        info = {"speed": self.speed}
        return obs, 0.0, self.compute_terminated(obs["achieved_goal"], obs["desired_goal"], info), False, info

    def compute_terminated(self, achieved_goal, desired_goal, info):
        return bool(np.hypot(*(achieved_goal - desired_goal)) < 0.5)

    def _obs(self):
        return {"observation": self.pos.copy(), "achieved_goal": self.pos.copy(), "desired_goal": self.goal.copy()}


@dataclasses.dataclass(frozen=True)
class Dist:
    def __call__(self, obs):
        return float(np.hypot(*(obs["achieved_goal"] - obs["desired_goal"])))


@dataclasses.dataclass(frozen=True)
class Speed:
    def __call__(self, obs, info):
        return float(info.get("speed", 0.0))


def make_point(reward_mode: str = "dense", observe_monitor: bool = True, **kwargs) -> TLTLRewardWrapper:
    return TLTLRewardWrapper(gym.wrappers.TimeLimit(PointGoal(), HORIZON), FORMULA, {"dist": Dist(), "speed": Speed()},
                             reward_mode=reward_mode, observe_monitor=observe_monitor, **kwargs)


def run(env, actions, options=None):
    """Observations, rewards and ends of one episode played with ``actions`` (stops at its end)."""
    obs, _ = env.reset(seed=0, options=options)
    observations, rewards, ends = [obs], [], []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        observations.append(obs)
        rewards.append(reward)
        ends.append((terminated, truncated))
        if terminated or truncated:
            break
    return observations, rewards, ends


MODES = [("dense", True), ("potential", True), ("terminal", False), ("dense", False)]


@pytest.mark.parametrize(("reward_mode", "observe_monitor"), MODES)
@given(actions=st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1)), min_size=HORIZON, max_size=HORIZON),
       pick=st.floats(0, 1))
def test_relabelled_episode_is_the_episode_with_that_goal(reward_mode, observe_monitor, actions, pick):
    actions = [np.array(a, np.float32) for a in actions]
    env = EpisodeRecorder(make_point(reward_mode, observe_monitor))
    run(env, actions)
    episode = env.pop_episodes()[0]
    step = 1 + min(int(pick * episode.length), episode.length - 1)
    goal = episode.observations[step]["achieved_goal"]
    relabelled = GoalRelabeller(env, end_is_terminal=False).relabel(episode, step)

    observations, rewards, ends = run(make_point(reward_mode, observe_monitor), actions, options={"goal": goal})
    assert relabelled.length == len(rewards) <= step
    assert relabelled.rewards == pytest.approx(rewards, abs=1e-12)
    assert relabelled.dones == [terminated for terminated, _ in ends]
    for mine, theirs in zip(relabelled.observations, observations):
        assert mine.keys() == theirs.keys()
        for key in mine:
            np.testing.assert_array_equal(mine[key], theirs[key])


def test_a_relabelled_episode_ends_where_it_reaches_its_goal():
    env = EpisodeRecorder(make_point())
    far = [np.array([1.0, 0.0], np.float32)] * HORIZON  # full speed away from the start
    run(env, far)
    episode = env.pop_episodes()[0]
    assert (episode.length, episode.truncated) == (HORIZON, True)
    for end_is_terminal in (True, False):
        relabelled = GoalRelabeller(env, end_is_terminal=end_is_terminal).relabel(episode, 5)
        assert relabelled.length == 5 and relabelled.dones == [False] * 4 + [True]
        assert sum(relabelled.rewards) == pytest.approx(0.6 - 1.0)  # reached at speed 1: "slower than 0.6" fails


def test_parking_replay_with_its_own_goal_reproduces_the_episode():
    pytest.importorskip("highway_env")
    for mode, monitor in (("dense", True), ("potential", True), ("terminal", False)):
        env = EpisodeRecorder(gym.make("TLParking-v0", reward_mode=mode, observe_monitor=monitor, horizon=30))
        env.action_space.seed(1)
        rng = np.random.default_rng(1)
        actions = [rng.uniform(-1, 1, 2).astype(np.float32) for _ in range(30)]
        observations, rewards, _ = run(env, actions)
        episode = env.pop_episodes()[0]
        relabeller = GoalRelabeller(env)
        relabeller._replay.load(episode, episode.observations[0]["desired_goal"])  # the episode's own goal
        replayed, replayed_rewards, _ = run(relabeller._wrapper, episode.actions)
        assert replayed_rewards == rewards
        for mine, theirs in zip(replayed, observations):
            for key in theirs:
                np.testing.assert_array_equal(mine[key], theirs[key])


def test_sample_draws_goals_from_the_episode():
    env = EpisodeRecorder(make_point())
    run(env, [np.array([0.3, 0.1], np.float32)] * HORIZON)
    episode = env.pop_episodes()[0]
    out = GoalRelabeller(env).sample(episode, 5, np.random.default_rng(0))
    assert len(out) == 5
    assert all(1 <= e.length <= episode.length and e.dones[-1] for e in out)
    assert any(e.rewards and sum(e.rewards) > 0 for e in out)  # slow moves: the reached goals are satisfied


def test_satisfied_strategy_prefers_goals_under_which_the_formula_holds():
    env = EpisodeRecorder(make_point())
    # slow for 6 steps, then full speed: the goals of steps 1-6 are reached slowly (satisfied), later ones are not
    run(env, [np.array([0.3, 0.0], np.float32)] * 6 + [np.array([1.0, 0.0], np.float32)] * 6)
    episode = env.pop_episodes()[0]
    relabeller = GoalRelabeller(env)
    every = [relabeller.relabel(episode, k) for k in range(1, episode.length + 1)]
    assert [e.robustness > 0 for e in every] == [True] * 6 + [False] * 6
    picked = relabeller.sample(episode, 4, np.random.default_rng(0), strategy="satisfied")
    assert len(picked) == 4 and all(e.robustness > 0 for e in picked)
    assert len({e.length for e in picked}) == 4  # drawn without replacement
    more = relabeller.sample(episode, 9, np.random.default_rng(0), strategy="satisfied")
    assert sum(e.robustness > 0 for e in more) >= 6  # all 6 satisfied ones, then uniform draws
    with pytest.raises(ValueError, match="strategy must be one of"):
        relabeller.sample(episode, 1, np.random.default_rng(0), strategy="final")


def test_bad_envs_are_named():
    with pytest.raises(ValueError, match="TLTLRewardWrapper"):
        GoalRelabeller(PointGoal())
    box = TLTLRewardWrapper(gym.make("Pendulum-v1"), "F(x > 0)", {"x": 0}, reward_mode="dense")
    with pytest.raises(ValueError, match="achieved_goal"):
        GoalRelabeller(box)

    class NoTerminated(PointGoal):
        compute_terminated = None

    plain = TLTLRewardWrapper(gym.wrappers.TimeLimit(NoTerminated(), HORIZON), FORMULA,
                              {"dist": Dist(), "speed": Speed()}, reward_mode="dense")
    with pytest.raises(ValueError, match="NoTerminated.compute_terminated"):
        GoalRelabeller(plain)
    with pytest.raises(ValueError, match="env_reward_weight"):
        GoalRelabeller(make_point(env_reward_weight=1.0))
    env = EpisodeRecorder(make_point())
    run(env, [np.ones(2, np.float32)] * HORIZON)
    with pytest.raises(ValueError, match="goal_step must be in 1"):
        GoalRelabeller(env).relabel(env.pop_episodes()[0], 0)


def test_sac_gets_the_relabelled_transitions():
    pytest.importorskip("stable_baselines3")
    from tl_gym.agents import SB3Agent

    agent = SB3Agent(make_point(), "sac", seed=0, her_goals=3, steps_per_iteration=120, learning_starts=60,
                     batch_size=16, policy_kwargs={"net_arch": [16]}, hyperparams=False)
    agent.learn(1)
    feeder = agent._hindsight
    buffer = agent.model.replay_buffer
    assert 0 < feeder.added <= 3 * 120
    assert buffer.pos * buffer.n_envs == 120 + feeder.added  # rows of n_envs transitions
    assert feeder.added % buffer.n_envs == 0
    # every stored action is in the policy's [-1, 1] scale, real and relabelled
    assert np.abs(buffer.actions[: buffer.pos]).max() <= 1.0


def test_her_goals_is_checked():
    pytest.importorskip("stable_baselines3")
    from tl_gym.agents import SB3Agent

    with pytest.raises(ValueError, match="off-policy"):
        SB3Agent(make_point(), "ppo", her_goals=2, hyperparams=False)
    with pytest.raises(ValueError, match="her_goals must be an int >= 0"):
        SB3Agent(make_point(), "sac", her_goals=-1, hyperparams=False)
    with pytest.raises(ValueError, match="her_strategy must be one of"):
        SB3Agent(make_point(), "sac", her_goals=1, her_strategy="best", hyperparams=False)
