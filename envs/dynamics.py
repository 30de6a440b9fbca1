"""The paper's car (section VI) as one pure, batched function, plus its parameters.

Both the single environment (`tl_gym.envs.car`) and the batched one
(`tl_gym.envs.vector`) call `car_step` and draw their noise with
`sample_episode_noise`, so that the two cannot drift apart: car ``i`` of the
vector env seeded with ``seed + i`` follows the single env seeded with ``seed + i``
exactly.

Units: the arena is 300 × 300 units (read them as centimetres of a 3 m × 3 m
arena), time is in seconds, angles in radians.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from tl_gym.checks import check_count, check_floats, check_positive

STATE_SIZE = 6  # x, y, θ, ẋ, ẏ, θ̇
NOISE_SIZE = 3  # additive noise on x, y, θ


@dataclass(frozen=True)
class CarParams:
    """Physical constants of the car and its noise.

    Attributes:
        dt: time step (s).
        wheelbase: distance L between the axles (units).
        max_speed: the forward speed a_v lies in ``[0, max_speed]`` (units/s).
        max_steer: the steering angle a_Φ lies in ``[-max_steer, max_steer]`` (rad), below π/2.
        noise_std: standard deviation of the Gaussian noise added to (x, y, θ) at every step.
        start_std: standard deviation of the Gaussian noise added to the start (x, y, θ).
        horizon: number of actions per episode; the trace holds ``horizon + 1`` states.
    """

    dt: float = 0.5
    wheelbase: float = 15.0
    max_speed: float = 60.0
    max_steer: float = 0.6
    noise_std: tuple[float, float, float] = (0.15, 0.15, 0.002)
    start_std: tuple[float, float, float] = (1.5, 1.5, 0.01)
    horizon: int = 200

    def __post_init__(self) -> None:
        for name in ("dt", "wheelbase", "max_speed"):
            check_positive(name, getattr(self, name))
        steer = self.max_steer  # any real number (a numpy float from a config too), not a bool
        if not (isinstance(steer, numbers.Real) and not isinstance(steer, bool) and 0 < steer < math.pi / 2):
            raise ValueError(f"max_steer must lie in (0, π/2) rad (tan diverges at π/2), got {steer!r}")
        object.__setattr__(self, "max_steer", float(steer))
        what = "three finite numbers >= 0 (x, y, θ)"
        for name in ("noise_std", "start_std"):
            given = getattr(self, name)
            value = check_floats(name, given, NOISE_SIZE, what)  # a scalar, None or text is no triple
            if not all(math.isfinite(v) and v >= 0 for v in value):
                raise ValueError(f"{name} must be {what}, got {given!r}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "horizon", check_count("horizon", self.horizon))

    @property
    def max_turn_rate(self) -> float:
        """Largest |θ̇| the car can reach (rad/s): ``max_speed / L · tan(max_steer)``."""
        return self.max_speed / self.wheelbase * math.tan(self.max_steer)

    def position_bound(self, start: tuple[float, ...], arena: tuple[float, ...]) -> float:
        """Bound B of |x| and |y|: farthest start coordinate or arena side, plus a full-speed horizon, plus 100.

        6400 with the defaults. Driving at full speed for the whole horizon covers
        ``horizon · max_speed · dt`` (6000); the noise would have to add another 100
        (about 47 standard deviations of its 200-step sum) to cross B, and a car that drives
        full speed one way for the whole episode is itself the worst case. A much noisier car
        (``noise_std`` of tens of units a step) can leave the space: B does not widen with the
        noise, because a saved agent (and SB3's own check) compares the space exactly, bounds
        included, and agents of the wide-start studies would no longer load.
        """
        far = max(abs(float(start[0])), abs(float(start[1])), *map(float, arena))
        return far + self.horizon * self.max_speed * self.dt + 100.0

    def physical_action(self, action: np.ndarray) -> np.ndarray:
        """Map normalised actions in [-1, 1] (clipped first) to ``[a_v, a_Φ]``; shape ``(..., 2)``."""
        out = np.minimum(action, 1.0, dtype=np.float64)
        np.maximum(out, -1.0, out=out)
        speed = out[..., 0]
        speed += 1.0
        speed *= 0.5 * self.max_speed
        out[..., 1] *= self.max_steer
        return out


def wrap_angle(theta: np.ndarray) -> np.ndarray:
    """Angles wrapped into ``[-π, π)``."""
    return np.mod(theta + math.pi, 2.0 * math.pi) - math.pi


def car_step(state: np.ndarray, action: np.ndarray, dt: float, wheelbase: float, noise: np.ndarray) -> np.ndarray:
    """One Euler step of the paper's car, for any batch shape.

    ``ẋ = a_v cos θ``, ``ẏ = a_v sin θ``, ``θ̇ = a_v / L · tan a_Φ``, evaluated at the
    current state; the new position and heading add ``dt`` times these rates and the
    noise, and the new state stores the rates that moved it. Written with few, in-place
    numpy operations: at 40 cars their per-call overhead is the cost.

    Args:
        state: ``(..., 6)`` states ``[x, y, θ, ẋ, ẏ, θ̇]``.
        action: ``(..., 2)`` physical actions ``[a_v, a_Φ]`` (units/s, rad).
        dt: time step (s).
        wheelbase: axle distance L (units).
        noise: ``(..., 3)`` additive noise on ``(x, y, θ)``, already scaled.

    Returns:
        The next states, a new ``(..., 6)`` float64 array (θ wrapped into ``[-π, π)``).
    """
    out = np.empty(np.broadcast_shapes(state.shape, noise.shape[:-1] + (STATE_SIZE,)), dtype=np.float64)
    theta, speed = state[..., 2], action[..., 0]
    rates = out[..., 3:]
    np.multiply(speed, np.cos(theta), out=rates[..., 0])
    np.multiply(speed, np.sin(theta), out=rates[..., 1])
    np.divide(speed, wheelbase, out=rates[..., 2])  # (a_v / L) · tan a_Φ: the order max_turn_rate uses
    rates[..., 2] *= np.tan(action[..., 1])
    pose = out[..., :3]
    np.multiply(rates, dt, out=pose)
    pose += state[..., :3]
    pose += noise
    heading = pose[..., 2]  # wrap into [-π, π)
    heading += math.pi
    np.mod(heading, 2.0 * math.pi, out=heading)
    heading -= math.pi
    return out


def sample_episode_noise(
    rng: np.random.Generator, params: CarParams, start: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Draw one episode's randomness: the start state and every step's noise.

    Drawn in one call from ``rng`` (3 start values, then ``horizon × 3`` step values),
    which is what makes the single and the batched env agree.

    Returns:
        ``(state0, step_noise)``: the start state ``(6,)`` (rates zero) and the scaled
        per-step noise ``(horizon, 3)``.
    """
    draws = rng.standard_normal((params.horizon + 1, NOISE_SIZE))  # row 0: start, rows 1…: steps
    state0 = np.zeros(STATE_SIZE, dtype=np.float64)
    state0[:3] = draws[0]
    state0[:3] *= params.start_std
    state0[:3] += start
    state0[2] = wrap_angle(state0[2])
    step_noise = draws[1:]
    step_noise *= params.noise_std
    return state0, step_noise
