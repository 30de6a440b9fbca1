"""The TL task suite: third-party Gymnasium envs, each with a TLTL formula, its signals and a horizon.

Every task is a factory that builds the base env with its horizon, wraps it in
`StepClock` (the step index in ``info["t"]`` and a ``horizon`` attribute agents read)
and in `tl_gym.TLTLRewardWrapper` with the task's formula. Success is the exact
robustness ρ > 0, reported by the wrapper as ``info["robustness"]`` and
``info["satisfied"]`` on the step that ends the episode. ``import tl_gym`` registers:

| id | base env | formula |
|----|----------|---------|
| ``TLPendulum-v0`` | Pendulum-v1 | `pendulum_formula` |
| ``TLMountainCar-v0`` | MountainCarContinuous-v0 | `mountain_car_formula` |
| ``TLParking-v0`` | highway-env's parking-v0 (``pip install "tl_gym[highway]"``) | `parking_formula` |

Signals are read by small picklable callables (`InfoValue`, `PendulumAngle`,
`ParkingGoalError`, `ParkingSpeed`), so the envs deep-copy and run in
`gymnasium.vector.AsyncVectorEnv`. Every factory forwards any further keyword to
`TLTLRewardWrapper` (``reward``, ``beta``, ``reward_mode``, ``clip``, ``rho_max``,
``observe_monitor`` …). See ``docs/tasks.md``.

Example:
    >>> import gymnasium as gym
    >>> import tl_gym
    >>> env = gym.make("TLPendulum-v0")
    >>> print(env.get_wrapper_attr("formula"))
    G (t >= 100 -> abs(th) < 0.3) & G abs(th_dot) < 8
    >>> env.get_wrapper_attr("horizon")
    200
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.error import DependencyNotInstalled

from tl_gym.checks import check_count, check_finite, check_floats, check_positive, did_you_mean
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.parser import parse
from tl_gym.wrapper import TLTLRewardWrapper

HIGHWAY_HINT = 'pip install "tl_gym[highway]"'

#: Parking-v0's observation features, in the order the parking signals read them.
PARKING_FEATURES = ("x", "y", "vx", "vy", "cos_h", "sin_h")


# --------------------------------------------------------------------------- building blocks


class StepClock(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Writes the step index into ``info["t"]`` and states the episode's horizon.

    ``info["t"]`` is 0 after ``reset`` and ``t`` after the ``t``-th ``step``, the index of the
    observation in the trace s_0 … s_T that `TLTLRewardWrapper` records, so a formula can
    read time as a signal (``{"t": InfoValue("t")}``). The attribute ``horizon`` is the
    number of actions per episode, read by the agents (``tl_gym.agents``) and by the
    wrapper's ``observe_monitor`` view. The clock does not truncate: the base env's
    ``TimeLimit`` does.

    Example:
        >>> import gymnasium as gym
        >>> env = StepClock(gym.make("Pendulum-v1", max_episode_steps=3), horizon=3)
        >>> _, info = env.reset(seed=0)
        >>> info["t"], env.step(env.action_space.sample())[-1]["t"]
        (0, 1)
    """

    def __init__(self, env: gym.Env, horizon: int):
        """Wrap ``env``, whose episodes last at most ``horizon`` steps."""
        check_count("horizon", horizon)
        gym.utils.RecordConstructorArgs.__init__(self, horizon=horizon)
        gym.Wrapper.__init__(self, env)
        self.horizon = int(horizon)
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._t = 0
        return obs, {**info, "t": 0}

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._t += 1
        return obs, reward, terminated, truncated, {**info, "t": self._t}


@dataclass(frozen=True)
class InfoValue:
    """Signal read from ``info[key]``: a picklable value object (unlike a lambda) that compares by its key.

    Example:
        >>> InfoValue("t")(None, {"t": 3})
        3.0
    """

    key: str

    def __call__(self, obs: Any, info: Mapping[str, Any]) -> float:
        if self.key not in info:
            raise KeyError(f"signal from info[{self.key!r}]: the env's info has no such key (keys: {list(info)})")
        return float(info[self.key])


@dataclass(frozen=True)
class PendulumAngle:
    """Pendulum's angle from upright in (-π, π] (rad), from the observation ``[cos θ, sin θ, θ̇]``.

    Example:
        >>> round(PendulumAngle()(np.array([0.0, 1.0, 0.0])), 4)
        1.5708
    """

    def __call__(self, obs: np.ndarray) -> float:
        return math.atan2(float(obs[1]), float(obs[0]))


def check_goal_weighting(name: str, values: Any) -> tuple[float, ...]:
    """parking-v0's ``reward_weights`` or observation ``scales`` as floats, checked.

    One per feature of `PARKING_FEATURES`, the x one > 0 (the goal error is expressed along x); a
    ``ValueError`` naming ``name`` otherwise.
    """
    what = f"{len(PARKING_FEATURES)} finite numbers ({', '.join(PARKING_FEATURES)}), the x one > 0"
    floats = check_floats(f"parking's {name}", values, len(PARKING_FEATURES), what)
    if not (all(math.isfinite(v) for v in floats) and floats[0] > 0):
        raise ValueError(f"parking's {name} must be {what}, got {values!r}")
    return floats


@dataclass(frozen=True)
class ParkingGoalError:
    """Parking-v0's own distance to the slot, in metres: ``Σ_i w_i |achieved_i - desired_i| · s_x / w_x``.

    ``weights`` are the env's ``reward_weights`` and ``scales`` its observation ``scales``, so the
    value is the env's weighted L1 goal distance expressed as an offset along x in metres. With
    the default config it is ``|Δx| + 0.3 |Δy| + 2 |Δcos h| + 2 |Δsin h|``, and the env's success
    (``-sqrt(Σ w_i |Δ_i|) > -success_goal_reward``) is ``goal_error < success_goal_reward² · s_x / w_x``
    = 1.44 m (`parking_success_threshold`).

    Example:
        >>> error = ParkingGoalError((1, 0.3, 0, 0, 0.02, 0.02), (100, 100, 5, 5, 1, 1))
        >>> obs = {"achieved_goal": np.array([0.01, 0.1, 0, 0, 0, 1]), "desired_goal": np.array([0, 0.14, 0, 0, 0, 1])}
        >>> round(error(obs), 6)  # 1 m off in x, 4 m in y
        2.2
    """

    weights: tuple[float, ...]
    scales: tuple[float, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "weights", check_goal_weighting("reward_weights", self.weights))
        object.__setattr__(self, "scales", check_goal_weighting("observation scales", self.scales))

    def __call__(self, obs: Mapping[str, np.ndarray]) -> float:
        diff = np.abs(np.asarray(obs["achieved_goal"], dtype=np.float64) - np.asarray(obs["desired_goal"]))
        return float(diff @ np.asarray(self.weights)) * self.scales[0] / self.weights[0]


@dataclass(frozen=True)
class ParkingSpeed:
    """Parking-v0's speed in m/s: ``hypot(vx, vy)`` of the observation times the velocity scale."""

    velocity_scale: float

    def __call__(self, obs: Mapping[str, np.ndarray]) -> float:
        observation = obs["observation"]
        return math.hypot(float(observation[2]), float(observation[3])) * float(self.velocity_scale)


# --------------------------------------------------------------------------- formulas


def pendulum_formula(up_by: int = 100, max_angle: float = 0.3, max_speed: float = 8.0) -> Formula:
    """Swing up by step ``up_by`` and stay within ``max_angle`` of upright; never reach ``max_speed``.

    Example:
        >>> print(pendulum_formula())
        G (t >= 100 -> abs(th) < 0.3) & G abs(th_dot) < 8
    """
    check_count("up_by", up_by)
    check_positive("max_angle", max_angle)
    check_positive("max_speed", max_speed)
    return parse(f"G(t >= {int(up_by)} -> abs(th) < {_num(max_angle)}) & G(abs(th_dot) < {_num(max_speed)})")


def mountain_car_formula(flag: float = 0.45, speed_limit: float = 0.045) -> Formula:
    """Reach the flag and never drive faster than ``speed_limit``.

    Example:
        >>> print(mountain_car_formula())
        F position >= 0.45 & G abs(velocity) < 0.045
    """
    check_finite("flag", flag)
    check_positive("speed_limit", speed_limit)
    return parse(f"F(position >= {_num(flag)}) & G(abs(velocity) < {_num(speed_limit)})")


def parking_formula(success_error: float = 1.44, arrival_speed: float = 1.0, speed_limit: float = 5.0) -> Formula:
    """Enter the slot (the env's own success region) slower than ``arrival_speed``; never reach ``speed_limit``.

    Example:
        >>> print(parking_formula())
        F (goal_error < 1.44 & speed < 1) & G speed < 5
    """
    check_positive("success_error", success_error)
    check_positive("arrival_speed", arrival_speed)
    check_positive("speed_limit", speed_limit)
    return parse(
        f"F(goal_error < {_num(success_error)} & speed < {_num(arrival_speed)}) & G(speed < {_num(speed_limit)})"
    )


def parking_success_threshold(config: Mapping[str, Any]) -> float:
    """The ``goal_error`` (m) below which parking-v0 reports success: ``success_goal_reward² · s_x / w_x``."""
    weights, scales = config["reward_weights"], config["observation"]["scales"]
    return float(config["success_goal_reward"]) ** 2 * float(scales[0]) / float(weights[0])


# --------------------------------------------------------------------------- entry points


def make_pendulum(
    horizon: int = 200,
    up_by: int = 100,
    max_angle: float = 0.3,
    max_speed: float = 8.0,
    render_mode: str | None = None,
    **wrapper_kwargs: Any,
) -> TLTLRewardWrapper:
    """The entry point of ``TLPendulum-v0``: swing Pendulum-v1 up, keep it up, never at its speed clip.

    Formula `pendulum_formula`: ``G(t >= up_by -> abs(th) < max_angle) & G(abs(th_dot) < max_speed)``
    over s_0 … s_horizon, with ``th`` the angle from upright (rad), ``th_dot`` the angular
    velocity (rad/s, which Pendulum clips to ±8) and ``t`` the step index. The start is
    Pendulum's own: θ uniform in [-π, π], θ̇ uniform in [-1, 1].

    Args:
        horizon: actions per episode (the trace has ``horizon + 1`` states).
        up_by: the step from which the pendulum must stay within ``max_angle`` of upright (< horizon).
        max_angle: allowed angle from upright from step ``up_by`` on (rad).
        max_speed: bound on ``|θ̇|`` at every step (rad/s); 8 means "never at Pendulum's speed clip".
        render_mode: passed to Pendulum-v1.
        **wrapper_kwargs: `TLTLRewardWrapper` keywords (``reward``, ``beta``, ``reward_mode``, ``clip`` …).

    Raises:
        ValueError: a bad horizon, ``up_by`` not below it, or a bound that is not > 0.
    """
    horizon = check_count("horizon", horizon)  # a plain int: Gymnasium's TimeLimit refuses numpy integers
    formula = pendulum_formula(up_by, max_angle, max_speed)
    if up_by >= horizon:
        raise ValueError(f"up_by must be below horizon ({horizon}), got {up_by!r}")
    base = gym.make("Pendulum-v1", max_episode_steps=horizon, render_mode=render_mode)
    signals = {"th": PendulumAngle(), "th_dot": 2, "t": InfoValue("t")}
    return _wrap(base, horizon, formula, signals, wrapper_kwargs, monitor_scale=1.0, task=make_pendulum)


def make_mountain_car(
    horizon: int = 250,
    speed_limit: float = 0.045,
    render_mode: str | None = None,
    **wrapper_kwargs: Any,
) -> TLTLRewardWrapper:
    """The entry point of ``TLMountainCar-v0``: reach the flag without ever driving faster than ``speed_limit``.

    Formula `mountain_car_formula`: ``F(position >= 0.45) & G(abs(velocity) < speed_limit)``.
    MountainCarContinuous-v0 terminates at the flag (position ≥ 0.45 with velocity ≥ 0) and
    clips the velocity to ±0.07; pushing along the velocity (bang-bang) reaches 0.069.

    Args:
        horizon: actions per episode, unless the car reaches the flag first.
        speed_limit: bound on ``|velocity|`` at every step.
        render_mode: passed to MountainCarContinuous-v0.
        **wrapper_kwargs: `TLTLRewardWrapper` keywords.

    Raises:
        ValueError: a bad horizon or a speed limit that is not > 0.
    """
    formula = mountain_car_formula(0.45, speed_limit)
    horizon = check_count("horizon", horizon)
    base = gym.make("MountainCarContinuous-v0", max_episode_steps=horizon, render_mode=render_mode)
    signals = {"position": 0, "velocity": 1}
    return _wrap(base, horizon, formula, signals, wrapper_kwargs, monitor_scale=0.5, task=make_mountain_car)


def make_parking(
    horizon: int = 100,
    arrival_speed: float = 1.0,
    speed_limit: float = 5.0,
    terminate_on_success: bool = False,
    config: Mapping[str, Any] | None = None,
    render_mode: str | None = None,
    **wrapper_kwargs: Any,
) -> TLTLRewardWrapper:
    """The entry point of ``TLParking-v0``: park in highway-env's slot slowly, under a speed limit.

    Formula `parking_formula`: ``F(goal_error < 1.44 & speed < arrival_speed) & G(speed < speed_limit)``,
    with ``goal_error`` the env's own weighted distance to the slot in metres (`ParkingGoalError`;
    below 1.44 m is the env's success) and ``speed`` in m/s (`ParkingSpeed`). The slot is drawn
    by parking-v0 at reset, as is the start heading. Only a crash or the horizon ends the episode:
    a car that reaches the slot may drive on into it and stop, so a satisfying episode's robustness
    measures how well it parked (up to 1). With ``terminate_on_success=True`` (parking-v0's own
    rule) the episode ends as the car crosses into the success region, which caps that robustness
    at about one step of travel (docs/tasks.md).

    Args:
        horizon: actions per episode (5 per simulated second), unless the car crashes first.
        arrival_speed: the car must be slower than this (m/s) in the slot.
        speed_limit: bound on the speed at every step (m/s).
        terminate_on_success: end the episode when the car reaches the slot, as parking-v0 does
            (the task as measured before 2026-12-03).
        config: parking-v0 config overrides (``duration`` is raised to outlast ``horizon``).
        render_mode: passed to parking-v0.
        **wrapper_kwargs: `TLTLRewardWrapper` keywords.

    Raises:
        DependencyNotInstalled: highway-env is missing (``pip install "tl_gym[highway]"``).
        ValueError: a bad horizon or bound, or a config whose observation is not parking's
            ``KinematicsGoal`` with features ``x, y, vx, vy, cos_h, sin_h``.
    """
    try:
        import highway_env  # noqa: F401  (registers parking-v0)
    except ImportError as error:
        raise DependencyNotInstalled(
            f"TLParking-v0 needs highway-env, an optional extra of tl_gym: {HIGHWAY_HINT}"
        ) from error
    from tl_gym.envs.fast_parking import NumpyParkingEnv

    horizon = check_count("horizon", horizon)  # a plain int: Gymnasium's TimeLimit refuses numpy integers
    if not isinstance(terminate_on_success, (bool, np.bool_)):  # bool("no") would be True
        raise ValueError(f"terminate_on_success must be True or False, got {terminate_on_success!r}")
    # parking-v0's own wrappers and checks, on its subclass that reads the goal observation without pandas
    spec = dataclasses.replace(gym.spec("parking-v0"), entry_point=NumpyParkingEnv)
    if config is not None and "terminate_on_success" in config:
        raise ValueError("pass terminate_on_success as TLParking-v0's own keyword, not in config")
    _check_goal_weighting_of(config or {})
    config = {**(config or {}), "terminate_on_success": bool(terminate_on_success)}
    base = gym.make(spec, config=config, render_mode=render_mode)
    cfg = base.unwrapped.config
    observation = cfg["observation"]
    if observation.get("type") != "KinematicsGoal" or tuple(observation.get("features", ())) != PARKING_FEATURES:
        raise ValueError(
            f"TLParking-v0 reads parking's KinematicsGoal observation with features {list(PARKING_FEATURES)}; "
            f"the config asks for {observation.get('type')!r} with {observation.get('features')!r}"
        )
    if observation.get("normalize", False):
        raise ValueError("TLParking-v0 reads unnormalised observations: set config['observation']['normalize'] False")
    # the env truncates at `duration` seconds; let the TimeLimit below own the horizon
    frequency = float(cfg["policy_frequency"])
    cfg["duration"] = max(float(cfg["duration"]), horizon / frequency + 1.0)
    base = gym.wrappers.TimeLimit(base, max_episode_steps=horizon)
    formula = parking_formula(parking_success_threshold(cfg), arrival_speed, speed_limit)
    signals = {
        "goal_error": ParkingGoalError(tuple(cfg["reward_weights"]), tuple(observation["scales"])),
        "speed": ParkingSpeed(float(observation["scales"][2])),
    }
    return _wrap(base, horizon, formula, signals, wrapper_kwargs, monitor_scale=10.0, task=make_parking)


# --------------------------------------------------------------------------- helpers


def _wrapper_keywords() -> tuple[str, ...]:
    """The `TLTLRewardWrapper` keywords every suite id takes besides its own (its ``**wrapper_kwargs``)."""
    return tuple(name for name in inspect.signature(TLTLRewardWrapper).parameters if name not in ("env", "spec",
                                                                                                    "signals"))


for _maker in (make_pendulum, make_mountain_car, make_parking):  # their **wrapper_kwargs, for agents' messages
    _maker.env_keywords = _wrapper_keywords  # type: ignore[attr-defined]


def _wrap(
    base: gym.Env,
    horizon: int,
    formula: Formula,
    signals: Mapping[str, Any],
    wrapper_kwargs: dict[str, Any],
    monitor_scale: float,
    task: Callable[..., Any],
) -> TLTLRewardWrapper:
    """`StepClock` and `TLTLRewardWrapper` around ``base``; ``task`` is the entry point (its keywords name errors).

    ``monitor_scale`` is the task's default for the wrapper keyword of that name (when the wrapper
    has it): the size of the robustness of an early, failing policy, so monitor features are of order one.
    """
    params = inspect.signature(TLTLRewardWrapper).parameters
    kwargs = dict(wrapper_kwargs)
    if "monitor_scale" in params:
        kwargs.setdefault("monitor_scale", monitor_scale)
    if "horizon" in params:
        kwargs.setdefault("horizon", horizon)
    unknown = sorted(set(kwargs) - set(params) - {"env", "spec", "signals"})
    if unknown or {"env", "spec", "signals"} & set(kwargs):
        culprit = unknown[0] if unknown else sorted({"env", "spec", "signals"} & set(kwargs))[0]
        own = [name for name in inspect.signature(task).parameters if name != "wrapper_kwargs"]
        wrapper = [name for name in params if name not in ("env", "spec", "signals", "horizon")]  # horizon: own
        raise TypeError(
            f"unexpected keyword {culprit!r}{did_you_mean(culprit, own + wrapper)}: the task takes its "
            f"own ({', '.join(own)}) and TLTLRewardWrapper's ({', '.join(wrapper)})"
        )
    return TLTLRewardWrapper(StepClock(base, horizon), formula, signals, **kwargs)


def _check_goal_weighting_of(config: Mapping[str, Any]) -> None:
    """The goal weighting a parking config gives, checked before parking-v0 is built.

    parking-v0's constructor fails on a bad one in numpy's words. Checked: ``reward_weights``, and the
    ``scales`` of an observation that is the task's own (another observation is refused after the
    build, naming its type and features).
    """
    if config.get("reward_weights") is not None:
        check_goal_weighting("reward_weights", config["reward_weights"])
    observation = config.get("observation")
    if (isinstance(observation, Mapping) and observation.get("scales") is not None
            and observation.get("type", "KinematicsGoal") == "KinematicsGoal"
            and tuple(observation.get("features", PARKING_FEATURES)) == PARKING_FEATURES):
        check_goal_weighting("observation scales", observation["scales"])


def _num(value: float) -> str:
    """A number as formula text, without a trailing ``.0``."""
    return repr(int(value)) if float(value).is_integer() else repr(float(value))
