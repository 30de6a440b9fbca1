"""`CarNavEnv`, the paper's car (section VI), and `make_car_env`, the entry point of TLCarNav-v0."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from tl_gym.envs.car_model import CarModel
from tl_gym.envs.dynamics import CarParams, car_step, sample_episode_noise
from tl_gym.envs.tasks import Layout, make_layout, task_formula

from tl_gym.checks import did_you_mean
from tl_gym.wrapper import RewardSettings, TLTLRewardWrapper

RENDER_SIZE = (480, 480)
#: Divisor of the monitor features (``observe_monitor=True``): a third of the 300-unit arena.
CAR_MONITOR_SCALE = 100.0


def observation_space(params: CarParams, layout: Layout) -> spaces.Box:
    """The Box of ``[x, y, θ, ẋ, ẏ, θ̇]``: positions within ±`CarParams.position_bound`, rates by the actions."""
    bound = params.position_bound(layout.start, layout.arena)
    high = np.array(
        [bound, bound, math.pi, params.max_speed, params.max_speed, params.max_turn_rate], dtype=np.float64
    )
    return spaces.Box(-high, high, dtype=np.float64)


ACTION_SPACE = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

#: Keywords that replace a part of the task's layout (`tl_gym.envs.tasks.make_layout`).
LAYOUT_KEYS = ("start", "goals", "obstacle", "arena")


#: Keywords TLCarNav-v0 does not take that a user may try, and why (its error says so).
CAR_REFUSED_KEYWORDS = {
    "end_on_violation": "a TLTLRewardWrapper keyword the car does not take: the car's tasks keep the episode going "
                        "after an obstacle is touched, as the paper's do",
    "env_reward_weight": "a TLTLRewardWrapper keyword the car does not take: the car pays no reward of its own",
    "max_episode_steps": "the car owns its episode length (a TimeLimit would sit outside the reward wrapper): pass "
                         "horizon=",
}


def _unknown_keyword_message(culprit: str, fields: list[str]) -> str:
    """Why ``culprit`` is refused, and every keyword the car (and TLCarNav-v0 around it) takes."""
    car = [*fields, *LAYOUT_KEYS, "render_mode"]
    reward = [f.name for f in dataclasses.fields(RewardSettings)]
    why = CAR_REFUSED_KEYWORDS.get(culprit)
    hint = f" ({why})" if why else did_you_mean(culprit, list(car_keywords()))
    # one name quoted, the culprit's: SB3Agent finds the keyword it added in the message by its quotes
    return (f"the car has no keyword {culprit!r}{hint}; the car takes ({', '.join(car)}); TLCarNav-v0 also "
            f"takes task, no_revisit and the reward's ({', '.join(reward)})")


def car_setup(task: int, car_kwargs: Mapping[str, Any]) -> tuple[Layout, CarParams, dict[str, Any]]:
    """A car's layout, physical parameters and layout overrides, from its keywords.

    The one place that reads the car's keywords: its defaults live in `CarParams` and the task's
    layout in `make_layout`; `CarNavEnv`, `CarNavVectorEnv` and `make_car_env` all come here.

    Raises:
        TypeError: a keyword that is neither a `CarParams` field nor a layout override (the message lists every
            keyword the car and TLCarNav-v0 take, the closest name, and why a wrapper keyword is not the car's).
    """
    fields = [f.name for f in dataclasses.fields(CarParams)]
    unknown = sorted(set(car_kwargs) - set(fields) - set(LAYOUT_KEYS))
    if unknown:
        raise TypeError(_unknown_keyword_message(unknown[0], fields))
    overrides = {key: car_kwargs[key] for key in LAYOUT_KEYS if car_kwargs.get(key) is not None}
    params = CarParams(**{key: value for key, value in car_kwargs.items() if key in fields})
    return make_layout(task, **overrides), params, overrides


class CarProperties:
    """What the single and the batched car derive from their `CarParams` (``self.params``)."""

    params: CarParams

    @property
    def horizon(self) -> int:
        """Actions per episode; the trace has ``horizon + 1`` states."""
        return self.params.horizon

    @property
    def dynamics_model(self) -> CarModel:
        """The car's dynamics as a differentiable model (`tl_gym.envs.car_model.CarModel`)."""
        return CarModel(self.params)


class CarNavEnv(CarProperties, gym.Env):
    """The car of "A Policy Search Method For Temporal Logic Specified RL Tasks" (Li, Ma, Belta), section VI.

    ## Description
    A car drives in a 300 × 300 arena (units: read centimetres of a 3 m × 3 m arena)
    past a circular obstacle towards one goal (task 1) or three goals in order
    (task 2), as in the paper's Figure 1. This class is the bare simulator: its own
    reward is 0. `gym.make("TLCarNav-v0")` wraps it in `tl_gym.TLTLRewardWrapper`
    with the task's formula (`tl_gym.envs.tasks.task_formula`), which pays the
    robustness; see ``docs/envs.md``.

    ## Observation Space
    ``Box(6,)`` float64, the full state (the agent is not told the model):

    | Num | Observation | Min | Max | Unit |
    |-----|-------------|-----|-----|------|
    | 0 | x, position | -6400 | 6400 | unit |
    | 1 | y, position | -6400 | 6400 | unit |
    | 2 | θ, heading from the x axis | -π | π | rad |
    | 3 | ẋ, x rate of the last step | -60 | 60 | unit/s |
    | 4 | ẏ, y rate of the last step | -60 | 60 | unit/s |
    | 5 | θ̇, turn rate of the last step | -2.74 | 2.74 | rad/s |

    The arena has no walls: the position bound B = (farthest start coordinate or arena
    side) + horizon · max_speed · dt + 100 is out of reach (a full-speed horizon covers
    6000; the noise sum would need about 47 standard deviations more). Rate bounds follow
    ``max_speed``, ``wheelbase`` and ``max_steer`` (θ̇ ≤ max_speed / L · tan(max_steer)).

    ## Action Space
    ``Box(-1, 1, (2,))`` float32, normalised and clipped, mapped to the physical action:

    | Num | Action | Min | Max | Physical value | Unit |
    |-----|--------|-----|-----|----------------|------|
    | 0 | forward speed | -1 | 1 | a_v = 30 (u0 + 1) in [0, 60] | unit/s |
    | 1 | steering angle | -1 | 1 | a_Φ = 0.6 u1 in [-0.6, 0.6] | rad |

    ## Transition Dynamics
    Euler steps of ``dt = 0.5`` s: ``ẋ = a_v cos θ``, ``ẏ = a_v sin θ``,
    ``θ̇ = a_v / L tan a_Φ`` with ``L = 15``; ``x += dt ẋ + n_x``, ``y += dt ẏ + n_y``,
    ``θ += dt θ̇ + n_θ`` with Gaussian noise of std (0.15, 0.15, 0.002). One full-speed
    step moves 30 units (a goal's width). The obstacle is penetrable: the car drives
    through it and the robustness pays for the depth.

    ## Reward
    0 on every step (the temporal-logic reward is `TLTLRewardWrapper`'s).

    ## Starting State
    ``(x, y, θ) = start + N(0, diag(1.5, 1.5, 0.01)²)`` with rates 0; ``start`` is
    (30, 30, π/4) for task 1 and (30, 30, 0) for task 2.

    ## Episode End
    1. *Truncation*: after ``horizon`` actions (200 by default), so the trace is s_0 … s_200.
    2. *Termination*: never (the obstacle is penetrable).

    ## Arguments
    >>> import gymnasium as gym
    >>> import tl_gym
    >>> env = gym.make("TLCarNav-v0", task=2)
    >>> print(env.unwrapped)
    <CarNavEnv<TLCarNav-v0>>
    >>> env.unwrapped.params.horizon
    200

    | Parameter | Type | Default | Description |
    |-----------|------|---------|-------------|
    | task | int | 1 | 1 (Eq. 16) or 2 (Eq. 19) |
    | horizon | int | 200 | actions per episode |
    | dt | float | 0.5 | time step (s) |
    | wheelbase | float | 15 | axle distance L (unit) |
    | max_speed | float | 60 | upper bound of a_v (unit/s) |
    | max_steer | float | 0.6 | bound of the steering angle a_Φ (rad) |
    | noise_std | 3 floats | (0.15, 0.15, 0.002) | per-step noise on x, y, θ |
    | start_std | 3 floats | (1.5, 1.5, 0.01) | start noise on x, y, θ |
    | start | 3 floats | task's | mean start (x, y, θ) |
    | goals | list of 4-tuples | task's | (x_low, x_high, y_low, y_high) per goal |
    | obstacle | 3 floats | (150, 150, 40) | (x, y, radius) |
    | arena | 2 floats | (300, 300) | drawn size (no walls) |
    | render_mode | str | None | "rgb_array" or "human" |

    ## Vectorized environment
    `tl_gym.envs.vector.CarNavVectorEnv` steps many cars in one numpy call with the
    same `car_step` (``gym.make_vec("TLCarNav-v0", num_envs=40, vectorization_mode="vector_entry_point")``).

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(self, task: int = 1, render_mode: str | None = None, **car_kwargs: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.task = task
        self.layout, self.params, self.layout_overrides = car_setup(task, car_kwargs)
        self.observation_space = observation_space(self.params, self.layout)
        self.action_space = ACTION_SPACE
        self.render_mode = render_mode
        self.state = np.zeros(6, dtype=np.float64)
        self._noise = np.zeros((self.params.horizon, 3))
        self._path = np.zeros((self.params.horizon + 1, 2))
        self._t = -1  # -1: never reset
        self._viewer: Any = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.state, self._noise = sample_episode_noise(self.np_random, self.params, self.layout.start)
        self._t = 0
        self._path[0] = self.state[:2]
        if self.render_mode == "human":
            self.render()
        return self.state.copy(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._t < 0 or self._t >= self.params.horizon:
            raise RuntimeError("the episode is over (or never started): call reset() before step()")
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (2,):
            raise ValueError(f"action must have shape (2,) (speed, steering in [-1, 1]), got {action.shape}")
        if not (math.isfinite(action[0]) and math.isfinite(action[1])):  # two scalar tests: 0.1 µs, a numpy call 1.7
            raise ValueError(f"action {action.tolist()} is not finite: the car would move to NaN, and the episode's "
                             "robustness fail at its end")
        physical = self.params.physical_action(action)
        p = self.params
        self.state = car_step(self.state, physical, p.dt, p.wheelbase, self._noise[self._t])
        self._t += 1
        self._path[self._t] = self.state[:2]
        truncated = self._t >= p.horizon  # the env owns its horizon: no TimeLimit is registered
        if self.render_mode == "human":
            self.render()
        return self.state.copy(), 0.0, False, truncated, {}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn('call render() on an env made with render_mode="rgb_array" or "human"')
            return None
        from tl_gym.envs.rendering import HumanViewer, render_frame

        t = max(self._t, 0)
        frame = render_frame(self.layout, [self._path[: t + 1]], self.state[None, :3], RENDER_SIZE)
        if self.render_mode == "rgb_array":
            return frame
        if self._viewer is None:
            self._viewer = HumanViewer(RENDER_SIZE, self.metadata["render_fps"])
        self._viewer.show(frame)
        return None

    def close(self) -> None:
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


def make_car_env(task: int = 1, no_revisit: str = "leave", **kwargs: Any) -> TLTLRewardWrapper:
    """The entry point of TLCarNav-v0: a `CarNavEnv` wrapped in `TLTLRewardWrapper` with its task's formula.

    Args:
        task: 1 or 2.
        no_revisit: task 2's no-revisit conjunct, ``"leave"`` (default) or ``"strict"`` (Eq. 19).
        **kwargs: the reward settings (`tl_gym.wrapper.RewardSettings`, defaults as the wrapper's but
            ``monitor_scale``) and the car's keywords:

        reward: ``"exact"`` or ``"smooth"`` robustness (`TLTLRewardWrapper`).
        beta: smoothing sharpness for ``reward="smooth"``; 9 as in the paper.
        reward_mode: ``"terminal"``, ``"dense"`` or ``"potential"`` (`TLTLRewardWrapper`).
        rho_max: robustness of ``true`` (and minus that of ``X φ`` at the last state).
        clip: bound of the rewards (`TLTLRewardWrapper`).
        observe_monitor: append the task monitor's state to the observation (the Markov view,
            `TLTLRewardWrapper`): 6 + 6 features for task 1, 6 + 45 for task 2.
        monitor_scale: divisor of the monitor's robustness values and positions; 100 units,
            a third of the arena, keeps them of order one (and the unit of the potential).
        gamma: the agent's discount, for the dense and potential modes (`TLTLRewardWrapper`).
        satisfaction_bonus: ``B`` ≥ 0 added to the robustness paid once the (prefix) formula is satisfied
            (`TLTLRewardWrapper`).
        car keywords: `CarNavEnv` arguments (`CarParams` fields such as ``horizon`` and ``start_std``,
            layout overrides, ``render_mode``).
    """
    settings, car_kwargs = car_reward_settings(kwargs)
    car = CarNavEnv(task=task, **car_kwargs)
    formula = task_formula(task, no_revisit, **car.layout_overrides)
    return TLTLRewardWrapper(car, formula, signals={"x": 0, "y": 1}, **dataclasses.asdict(settings))


def car_keywords() -> tuple[str, ...]:
    """Every keyword ``gym.make("TLCarNav-v0", ...)`` takes: the task's, the car's and the reward's."""
    return ("task", "no_revisit", *(f.name for f in dataclasses.fields(CarParams)), *LAYOUT_KEYS, "render_mode",
            *(f.name for f in dataclasses.fields(RewardSettings)))


make_car_env.env_keywords = car_keywords  # type: ignore[attr-defined]  # its **kwargs, for agents' messages


def car_reward_settings(kwargs: Mapping[str, Any]) -> tuple[RewardSettings, dict[str, Any]]:
    """The car's reward settings (``monitor_scale`` defaults to `CAR_MONITOR_SCALE`) and its other keywords."""
    return RewardSettings.split(kwargs, monitor_scale=CAR_MONITOR_SCALE)
