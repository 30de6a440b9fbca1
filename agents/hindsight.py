"""Hindsight relabelling for SB3's off-policy agents on goal-conditioned TL tasks (``her_goals``).

`HindsightFeeder` is an SB3 callback: after every env step it takes the episodes that the
training envs' `tl_gym.relabel.EpisodeRecorder` finished, relabels each ``n_goals`` times with
goals it achieved (``strategy``: "future" HER, or "satisfied"), through the TL reward
(`tl_gym.relabel.GoalRelabeller`), and adds the relabelled transitions to the algorithm's
replay buffer as SB3 itself stores a transition: unnormalised observations (VecNormalize
normalises them when it samples), actions scaled to the policy's ``[-1, 1]``. A buffer that
holds one transition per env per row gets the relabelled ones in rows of ``n_envs``; a
remainder waits for the next episode.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tl_gym.relabel import EpisodeRecorder, GoalRelabeller, RelabelledEpisode


def make_hindsight_feeder(recorders: Sequence[EpisodeRecorder], relabeller: GoalRelabeller, n_goals: int,
                          rng: np.random.Generator, strategy: str = "future") -> Any:
    """The SB3 callback that feeds relabelled episodes of ``recorders`` into the model's replay buffer."""
    from stable_baselines3.common.callbacks import BaseCallback

    class HindsightFeeder(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.added = 0
            self._pending: list[tuple[Any, Any, np.ndarray, float, bool]] = []

        def _on_step(self) -> bool:
            for recorder in recorders:
                for episode in recorder.pop_episodes():
                    for relabelled in relabeller.sample(episode, n_goals, rng, strategy):
                        self._pending.extend(_transitions(relabelled))
            self._flush()
            return True

        def _flush(self) -> None:
            buffer = self.model.replay_buffer
            n_envs = buffer.n_envs
            while len(self._pending) >= n_envs:
                rows, self._pending = self._pending[:n_envs], self._pending[n_envs:]
                obs, next_obs, actions, rewards, dones = zip(*rows)
                actions = self.model.policy.scale_action(np.stack(actions))
                buffer.add(_stack(obs), _stack(next_obs), actions, np.array(rewards), np.array(dones),
                           [{} for _ in rows])
                self.added += n_envs

    return HindsightFeeder()


def _transitions(episode: RelabelledEpisode) -> list[tuple[Any, Any, np.ndarray, float, bool]]:
    obs = episode.observations
    return [(obs[t], obs[t + 1], np.asarray(episode.actions[t]), episode.rewards[t], episode.dones[t])
            for t in range(episode.length)]


def _stack(observations: Sequence[Any]) -> Any:
    """Observations of one row, stacked along a new first axis (a Dict: key by key)."""
    if isinstance(observations[0], dict):
        return {key: np.stack([o[key] for o in observations]) for key in observations[0]}
    return np.stack(observations)
