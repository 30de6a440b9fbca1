"""`CarNavVectorEnv`: many TLCarNav-v0 cars stepped in one numpy call.

The agents sample 40 episodes at a time; stepping 40 wrapped single envs through
`SyncVectorEnv` spends its time in Python, while this class calls the same
`car_step` once on a ``(num_envs, 6)`` array and scores all finished episodes with
one batched call of the engine.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from tl_gym.envs.car import (
    ACTION_SPACE,
    RENDER_SIZE,
    CarProperties,
    car_reward_settings,
    car_setup,
    observation_space,
)
from tl_gym.envs.dynamics import car_step, sample_episode_noise
from tl_gym.envs.tasks import task_formula

from tl_gym.checks import check_count
from tl_gym.monitor_view import MonitorView, augment_space
from tl_gym.shaping import HierarchicalPotential, discounted_increment
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.online_batch import BatchPrefixMonitor
from tl_gym.wrapper import MONITOR_KEY, RewardSettingsAttributes, terminal_info


class CarNavVectorEnv(RewardSettingsAttributes, CarProperties, VectorEnv):
    """``num_envs`` TLCarNav-v0 cars with one batched simulator and one batched reward.

    It behaves as ``SyncVectorEnv`` over ``gym.make("TLCarNav-v0", ...)`` with the same
    arguments: ``reset(seed=s)`` seeds car ``i`` with ``s + i`` and each car draws its
    noise exactly as the single env does, so both give the same trajectories and
    rewards for the same actions. Autoreset is Gymnasium's default (``NEXT_STEP``:
    the step after an episode ends resets that car, ignores its action and pays 0),
    and ``info`` uses the vector layout, arrays with ``_key`` masks: on the step that
    ends episodes, ``"robustness"``, ``"satisfied"``, ``"is_success"``, ``"trace"`` (an object array of
    one `tl_gym.wrapper.Trace` per car, ``info["trace"][i]["x"]`` of shape ``(T+1,)``, as
    ``SyncVectorEnv`` batches the wrapper's) and, with ``reward="smooth"``,
    ``"smooth_robustness"``. ``reward_mode="dense"`` and ``observe_monitor=True`` run the
    online monitor of every car at once (`tl_gym.tltl.online_batch.BatchPrefixMonitor`, a few
    numpy calls per operator and step for all cars), with the single env's features and rewards.

    Example:
        >>> import gymnasium as gym
        >>> import tl_gym
        >>> envs = gym.make_vec("TLCarNav-v0", num_envs=40, vectorization_mode="vector_entry_point")
        >>> obs, info = envs.reset(seed=0)
        >>> obs.shape
        (40, 6)
        >>> for _ in range(200):
        ...     obs, reward, terminated, truncated, info = envs.step(np.zeros((40, 2), dtype=np.float32))
        >>> bool(truncated.all()), info["trace"][0]["x"].shape, bool(np.all(reward == info["robustness"]))
        (True, (201,), True)

    Change logs:
        * v0.1.0 - Initially added.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 40, task: int = 1, no_revisit: str = "leave",
                 render_mode: str | None = None, autoreset_mode: AutoresetMode | str | None = None, **kwargs: Any):
        """Check the arguments (as `make_car_env` does) and allocate the batch; see `CarNavEnv` for each one.

        ``kwargs`` are the reward settings (`tl_gym.wrapper.RewardSettings`) and the car's keywords.
        ``autoreset_mode`` (what ``gym.make_vec`` passes on): the batched car resets on the next step only.
        """
        check_count("num_envs", num_envs)
        settings, car_kwargs = car_reward_settings(kwargs)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']} for the batched car, "
                             f"got {render_mode!r}; vectorization_mode='sync' gives each car its own window")
        try:
            mode = AutoresetMode.NEXT_STEP if autoreset_mode is None else AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode must be an AutoresetMode, got {autoreset_mode!r}") from None
        if mode is not AutoresetMode.NEXT_STEP:
            raise ValueError(f"autoreset_mode={autoreset_mode!r}: the batched car resets a finished car on the next "
                             "step (AutoresetMode.NEXT_STEP) only; vectorization_mode='sync' offers the other modes")
        self.num_envs = int(num_envs)
        self.task = task
        self.layout, self.params, overrides = car_setup(task, car_kwargs)
        self.formula = task_formula(task, no_revisit, **overrides)
        self.settings = settings
        if settings.reward == "smooth":  # as the single car's wrapper, when built
            settings.check_smoothable(self.formula)
        self.render_mode = render_mode

        self.single_observation_space = observation_space(self.params, self.layout)
        # every car's monitor at once, for dense rewards and the Markov view; the view encodes its state
        self._monitor: BatchPrefixMonitor | None = None
        self._view: MonitorView | None = None
        self._value = np.zeros(self.num_envs)  # the monitors' values after the last update
        monitor_scale = settings.monitor_scale
        self._potentials = (
            [HierarchicalPotential(self.formula, self.rho_max, monitor_scale) for _ in range(self.num_envs)]
            if self.reward_mode == "potential" else []
        )
        self._phi = np.zeros(self.num_envs)
        if self.reward_mode != "terminal" or self.observe_monitor:
            bounds = dict(zip(("x", "y"), zip(self.single_observation_space.low[:2],
                                               self.single_observation_space.high[:2])))
            self._view = MonitorView(PrefixMonitor(self.formula, self.rho_max), monitor_scale, self.clip,
                                     self.params.horizon, bounds)
            self._monitor = BatchPrefixMonitor(self.formula, self.num_envs, self.rho_max)
        if self.observe_monitor:
            self.single_observation_space = augment_space(self.single_observation_space, self._view, MONITOR_KEY)
        self.single_action_space = ACTION_SPACE
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

        n, horizon = self.num_envs, self.params.horizon
        self._rngs: list[np.random.Generator] = [seeding.np_random()[0] for _ in range(n)]
        self._state = np.zeros((n, 6))
        self._noise = np.zeros((horizon, n, 3))  # time-major, so that one step reads one block
        self._path = np.zeros((horizon + 1, n, 2))
        # Every car has the same horizon and restarts on the same step, so one clock serves all.
        self._t = -1  # -1: never reset
        self._autoreset = False
        self._paid = np.zeros(n)  # each car's clipped prefix robustness after the last step (0 at the reset)

    # episodes ---------------------------------------------------------------------------------
    def _start_episodes(self) -> None:
        for i, rng in enumerate(self._rngs):
            self._state[i], self._noise[:, i] = sample_episode_noise(rng, self.params, self.layout.start)
        self._t = 0
        self._path[0] = self._state[:, :2]
        self._autoreset = False
        self._paid[:] = 0.0

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        mask = (options or {}).get("reset_mask")  # SyncVectorEnv's partial reset: the other cars keep their episode
        if mask is not None and not np.all(mask):
            raise ValueError("CarNavVectorEnv restarts every car together (one clock for all): options['reset_mask'] "
                             "must be all True; gym.make_vec(..., vectorization_mode='sync') resets some cars only")
        super().reset(seed=int(seed) if isinstance(seed, (int, np.integer)) else None)
        if seed is None:
            seeds: Sequence[int | None] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or {self.num_envs} seeds, got {len(seeds)}")
        # as Env.reset: a seed re-creates a car's generator, None continues it
        self._rngs = [rng if s is None else seeding.np_random(s)[0] for rng, s in zip(self._rngs, seeds)]
        self._start_episodes()
        return self._observe(), {}

    def _observe(self) -> np.ndarray:
        """The cars' observations; with ``observe_monitor``, each monitor updated with its car's position."""
        if self._monitor is None:
            return self._state.copy()
        t = self._t
        if t == 0:
            self._monitor.reset()
        self._value = self._monitor.update({"x": self._state[:, 0], "y": self._state[:, 1]})
        if self._potentials:  # γ Φ(s') − Φ(s) of the step that led here, with Φ(s_T) = 0 at the last state
            states = [{"x": x, "y": y} for x, y in self._state[:, :2].tolist()]
            if t == 0:
                for potential in self._potentials:
                    potential.reset()
                self._phi = np.array([p.update(s) for p, s in zip(self._potentials, states)])
                self._shaping = np.zeros(self.num_envs)
            else:
                phi = np.zeros(self.num_envs)
                if t < self.params.horizon:
                    phi = np.array([p.update(s) for p, s in zip(self._potentials, states)])
                self._shaping, self._phi = discounted_increment(phi, self._phi, self.gamma)
        if not self.observe_monitor:
            return self._state.copy()
        return np.concatenate([self._state, self._view.encode_rows(self._monitor.rows, t)], axis=1)  # type: ignore[union-attr]

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self._t < 0:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, 2):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {actions.shape}")
        n = self.num_envs
        rewards = np.zeros(n)
        done = np.zeros(n, dtype=bool)
        if self._autoreset:  # NEXT_STEP autoreset: every car restarts and ignores its action (a NaN one too)
            self._start_episodes()
            return self._observe(), rewards, done, done.copy(), {}
        if not math.isfinite(actions.sum()) and not np.isfinite(actions).all():  # one sum clears almost every call
            cars = np.flatnonzero(~np.isfinite(actions).all(axis=1)).tolist()
            raise ValueError(f"the actions of car(s) {cars} are not finite ({actions[cars[0]].tolist()} for car "
                             f"{cars[0]}): they would move to NaN, and every car's episode fail at its end")
        p = self.params
        t = self._t
        self._state = car_step(
            self._state, p.physical_action(actions), p.dt, p.wheelbase, self._noise[t]
        )
        self._t = t = t + 1
        self._path[t] = self._state[:, :2]
        infos: dict[str, Any] = {}
        obs = self._observe()
        if t >= p.horizon:
            self._autoreset = True
            rewards = self._score(infos) - self._paid
            if self._potentials:
                rewards = rewards + self._shaping
            return obs, rewards, done, ~done, infos
        if self.reward_mode != "terminal":
            rewards, self._paid = discounted_increment(self.settings.prefix_paid(self._value), self._paid, self.gamma)
        if self._potentials:
            rewards = rewards + self._shaping
        return obs, rewards, done, done.copy(), infos

    def _score(self, infos: dict[str, Any]) -> np.ndarray:
        """Rewards of the episodes that just ended (all of them), filling ``infos`` in the vector layout."""
        path = self._path[: self._t + 1]
        trace = {"x": np.ascontiguousarray(path[:, :, 0].T), "y": np.ascontiguousarray(path[:, :, 1].T)}
        ended = terminal_info(self.formula, trace, self.rho_max, self.settings.smooth_beta)
        for key, values in ended.items():  # every car ended: the vector layout's masks are all true
            infos[key], infos[f"_{key}"] = values, np.ones(self.num_envs, dtype=bool)
        return self.settings.terminal_paid(ended)

    def render(self) -> np.ndarray | None:
        """One frame with every car and its path so far (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            gym.logger.warn('call render() on a vector env made with render_mode="rgb_array"')
            return None
        from tl_gym.envs.rendering import render_frame

        t = max(self._t, 0)
        paths = [self._path[: t + 1, i] for i in range(self.num_envs)]
        return render_frame(self.layout, paths, self._state[:, :3], RENDER_SIZE)
