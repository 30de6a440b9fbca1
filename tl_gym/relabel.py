"""Hindsight goal relabelling (HER) for TLTL rewards on goal-conditioned envs.

A goal-conditioned env (Gymnasium-Robotics' ``GoalEnv`` layout, as highway-env's parking-v0)
observes a Dict with ``"achieved_goal"`` and ``"desired_goal"``. Hindsight experience replay
(Andrychowicz et al., 2017) stores each episode a second time with the desired goal replaced
by one the episode achieved later, so that a policy that missed its goal still learns how to
reach the place it did reach. SB3's ``HerReplayBuffer`` recomputes each relabelled
transition's reward alone, from ``compute_reward(achieved_goal, desired_goal, info)``; a TLTL
reward cannot be relabelled that way: the reward of a step depends on the whole prefix of
the episode, and with ``observe_monitor=True`` so do the monitor features of the observation.

`GoalRelabeller` therefore replays a recorded episode, with the goal replaced in every
observation, through a copy of the episode's `TLTLRewardWrapper`: the rewards, the monitor
features and the end of the relabelled episode are exactly what the wrapper would have produced
had the env drawn that goal. The relabelled episode ends at the first step that the env's
``compute_terminated(achieved_goal, desired_goal, info)`` (Gymnasium-Robotics' name) calls
terminal for the new goal (in parking: parked there, or crashed), else where the recorded one ended.

Example (a one-dimensional "reach the goal" env; its reward is F(error < 0.5)):
    >>> import gymnasium as gym
    >>> import numpy as np
    >>> from gymnasium import spaces
    >>> from tl_gym import TLTLRewardWrapper
    >>> class Reach(gym.Env):
    ...     observation_space = spaces.Dict({k: spaces.Box(-10, 10, (1,)) for k in
    ...                                      ("observation", "achieved_goal", "desired_goal")})
    ...     action_space = spaces.Box(-1, 1, (1,))
    ...     def reset(self, *, seed=None, options=None):
    ...         self.x, self.goal = np.zeros(1, np.float32), np.full(1, 5.0, np.float32)
    ...         return self._obs(), {}
    ...     def step(self, action):
    ...         self.x = self.x + np.asarray(action, np.float32)
    ...         obs = self._obs()
    ...         return obs, 0.0, self.compute_terminated(obs["achieved_goal"], self.goal, {}), False, {}
    ...     def compute_terminated(self, achieved_goal, desired_goal, info):
    ...         return bool(abs(achieved_goal[0] - desired_goal[0]) < 0.5)
    ...     def _obs(self):
    ...         return {"observation": self.x, "achieved_goal": self.x, "desired_goal": self.goal}
    >>> error = lambda obs: abs(float(obs["achieved_goal"][0] - obs["desired_goal"][0]))
    >>> env = TLTLRewardWrapper(gym.wrappers.TimeLimit(Reach(), 3), "F(error < 0.5)", {"error": error},
    ...                         reward_mode="dense", observe_monitor=True)
    >>> recorder = EpisodeRecorder(env)
    >>> _ = recorder.reset()
    >>> for _ in range(3):
    ...     _, reward, *_, info = recorder.step(np.ones(1, np.float32))
    >>> info["satisfied"], recorder.episodes[0].length  # the goal at 5 was not reached
    (False, 3)
    >>> relabelled = GoalRelabeller(env).relabel(recorder.episodes[0], goal_step=2)
    >>> relabelled.rewards, relabelled.dones  # x = 2 at step 2 reaches the new goal: rho = 0.5, satisfied
    ([-0.5, 1.0], [False, True])
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from tl_gym.wrapper import MONITOR_KEY, TLTLRewardWrapper, env_info, find_wrapper

ACHIEVED, DESIRED = "achieved_goal", "desired_goal"
#: How `GoalRelabeller.sample` picks the goals of an episode's relabellings.
RELABEL_STRATEGIES = ("future", "satisfied")


@dataclasses.dataclass
class Episode:
    """One recorded episode of a `TLTLRewardWrapper`-wrapped goal env, as the env below the wrapper saw it.

    ``observations`` (the reset observation first) and ``infos`` are one longer than
    ``actions``; the observations are the wrapped env's, without the monitor features.
    """

    observations: list[dict[str, Any]]
    infos: list[dict[str, Any]]
    actions: list[Any]
    terminated: bool
    truncated: bool

    @property
    def length(self) -> int:
        """Steps in the episode."""
        return len(self.actions)


@dataclasses.dataclass
class RelabelledEpisode:
    """The transitions of a relabelled episode, as the agent would have seen them (monitor features included)."""

    observations: list[Any]
    actions: list[Any]
    rewards: list[float]
    dones: list[bool]
    """``terminated`` of each step; with ``end_is_terminal`` in `GoalRelabeller`, every episode end."""
    robustness: float = float("nan")
    """The exact robustness of the relabelled episode (the wrapper's terminal ``info["robustness"]``)."""

    @property
    def length(self) -> int:
        """Steps in the relabelled episode."""
        return len(self.actions)


class EpisodeRecorder(gym.Wrapper):
    """Records the episodes of a `TLTLRewardWrapper`-wrapped env for `GoalRelabeller`; changes nothing.

    Put it outside the wrapper; finished episodes collect in ``episodes`` (`pop_episodes` takes them).
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.episodes: list[Episode] = []
        self._current: Episode | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._current = Episode([_base(obs)], [env_info(info)], [], False, False)
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        episode = self._current
        if episode is not None:
            episode.observations.append(_base(obs))
            episode.infos.append(env_info(info))
            episode.actions.append(np.array(action, copy=True))
            if terminated or truncated:
                episode.terminated, episode.truncated = bool(terminated), bool(truncated)
                self.episodes.append(episode)
                self._current = None
        return obs, reward, terminated, truncated, info

    def pop_episodes(self) -> list[Episode]:
        """The episodes finished since the last call."""
        episodes, self.episodes = self.episodes, []
        return episodes


class _ReplayEnv(gym.Env):
    """Plays back one episode's observations, with the goal replaced, and decides its end afresh."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space,
                 compute_terminated: Callable[[Any, Any, dict], Any]):
        self.observation_space = observation_space
        self.action_space = action_space
        self._compute_terminated = compute_terminated
        self._episode: Episode | None = None
        self._goal: Any = None
        self._t = 0

    def load(self, episode: Episode, goal: Any) -> None:
        self._episode, self._goal, self._t = episode, np.array(goal, copy=True), 0

    def _observation(self, t: int) -> dict[str, Any]:
        return {**self._episode.observations[t], DESIRED: self._goal.copy()}  # type: ignore[union-attr]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        self._t = 0
        return self._observation(0), dict(self._episode.infos[0])  # type: ignore[union-attr]

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        episode = self._episode
        assert episode is not None
        self._t += 1
        t = self._t
        obs, info = self._observation(t), dict(episode.infos[t])
        terminated = bool(self._compute_terminated(obs[ACHIEVED], self._goal, info))
        truncated = False
        if t == episode.length and not terminated:  # the recorded episode ends here whatever the goal
            terminated, truncated = episode.terminated, episode.truncated
        return obs, 0.0, terminated, truncated, info  # the wrapper adds no env reward (checked)


class GoalRelabeller:
    """Relabels recorded episodes of a goal-conditioned, `TLTLRewardWrapper`-wrapped env with achieved goals.

    Args:
        env: the env the episodes were recorded on (any wrapper chain holding one
            `TLTLRewardWrapper` over a goal-conditioned env); it is only read.
        end_is_terminal: report every end of a relabelled episode as done (as `SB3Agent`'s
            ``end_is_terminal`` does for the real ones); else only terminations.

    Raises:
        ValueError: no `TLTLRewardWrapper` in ``env``, an observation below it that is not a
            Dict with ``"achieved_goal"`` and ``"desired_goal"`` of one shape, an env without
            ``compute_terminated``, or a wrapper that adds the env's own reward
            (``env_reward_weight``), which a relabelling would have to recompute too.
    """

    def __init__(self, env: gym.Env, end_is_terminal: bool = True):
        wrapper = find_wrapper(env, TLTLRewardWrapper)
        if wrapper is None:
            raise ValueError(f"goal relabelling needs an env wrapped in TLTLRewardWrapper, got {env}")
        space = wrapper.env.observation_space
        if not (isinstance(space, spaces.Dict) and ACHIEVED in space.spaces and DESIRED in space.spaces):
            raise ValueError(
                "goal relabelling needs a goal-conditioned env: a Dict observation with 'achieved_goal' and "
                f"'desired_goal' below the TLTLRewardWrapper, got {space}"
            )
        if space[ACHIEVED].shape != space[DESIRED].shape:
            raise ValueError(f"'achieved_goal' {space[ACHIEVED].shape} and 'desired_goal' {space[DESIRED].shape} "
                             "must have one shape to relabel one with the other")
        compute_terminated = getattr(env.unwrapped, "compute_terminated", None)
        if not callable(compute_terminated):
            raise ValueError(
                f"goal relabelling needs {type(env.unwrapped).__name__}.compute_terminated(achieved_goal, "
                "desired_goal, info) (Gymnasium-Robotics' GoalEnv method) to end a relabelled episode where "
                "the env would have"
            )
        if wrapper.env_reward_weight:
            raise ValueError(f"goal relabelling recomputes the TL reward only: env_reward_weight must be 0, "
                             f"got {wrapper.env_reward_weight}")
        self.end_is_terminal = bool(end_is_terminal)
        self._replay = _ReplayEnv(space, wrapper.env.action_space, compute_terminated)
        kwargs = {k: v for k, v in wrapper._saved_kwargs.items() if k != "env"}
        self._wrapper = TLTLRewardWrapper(self._replay, **kwargs)

    def relabel(self, episode: Episode, goal_step: int) -> RelabelledEpisode:
        """``episode`` with its desired goal replaced by the goal it achieved at step ``goal_step``.

        Raises:
            ValueError: ``goal_step`` is not in ``1 … episode.length``.
        """
        if not 1 <= goal_step <= episode.length:
            raise ValueError(f"goal_step must be in 1 … {episode.length} (the episode's steps), got {goal_step}")
        self._replay.load(episode, episode.observations[goal_step][ACHIEVED])
        obs, _ = self._wrapper.reset()
        out = RelabelledEpisode([obs], [], [], [])
        for action in episode.actions:
            obs, reward, terminated, truncated, info = self._wrapper.step(action)
            out.observations.append(obs)
            out.actions.append(action)
            out.rewards.append(float(reward))
            out.dones.append(bool(terminated or (truncated and self.end_is_terminal)))
            if terminated or truncated:
                out.robustness = float(info["robustness"])
                break
        return out

    def sample(self, episode: Episode, n_goals: int, rng: np.random.Generator,
               strategy: str = "future") -> list[RelabelledEpisode]:
        """``n_goals`` relabellings of ``episode``.

        ``strategy="future"`` (HER's): each with the goal of a step drawn uniformly.
        ``"satisfied"``: relabels with the goal of every step, then draws the ``n_goals`` among
        those under which the episode satisfies the formula (ρ > 0), without replacement, and
        fills up with uniform draws when there are fewer. With a TL task, reaching a goal is
        not enough (parking: also slower than 1 m/s there), so most "future" goals give failed
        episodes; this keeps the hindsight successes that teach the task, at ``length``
        relabellings per episode (about 1 ms each on parking).

        Raises:
            ValueError: an unknown strategy.
        """
        if strategy not in RELABEL_STRATEGIES:
            raise ValueError(f"strategy must be one of {RELABEL_STRATEGIES}, got {strategy!r}")
        if episode.length == 0:
            return []
        if strategy == "future":
            steps = rng.integers(1, episode.length + 1, size=n_goals)
            return [self.relabel(episode, int(step)) for step in steps]
        every = [self.relabel(episode, step) for step in range(1, episode.length + 1)]
        satisfied = [e for e in every if e.robustness > 0]
        picked = [satisfied[i] for i in rng.permutation(len(satisfied))[:n_goals]]
        picked += [every[i] for i in rng.integers(0, len(every), size=n_goals - len(picked))]
        return picked


def _base(obs: Any) -> dict[str, Any]:
    """The wrapped env's observation: the Dict without the monitor features."""
    return {k: np.array(v, copy=True) for k, v in obs.items() if k != MONITOR_KEY}
