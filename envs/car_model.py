"""The car's dynamics as a model with Jacobians, for agents that use a known model.

`CarModel` wraps `tl_gym.envs.dynamics.car_step` (the env's own step) with its Jacobians,
the inverse that recovers each step's additive noise from a recorded episode, and, with numba
installed (``tl_gym[fast]``), a compiled closed loop under a time-varying linear feedback. With that
noise held fixed, an episode's states are a differentiable function of its actions: TLPS's
``action_repair="model"`` (docs/tlps.md, H19) climbs the smoothed robustness along that
function. `CarNavEnv` and `CarNavVectorEnv` expose one as ``dynamics_model``.

Example:
    >>> import numpy as np
    >>> model = CarModel(CarParams())
    >>> state, action = np.array([[10.0, 20.0, 0.3, 0, 0, 0]]), np.array([[0.5, -0.2]])
    >>> A, B = model.jacobians(state, action)
    >>> eps, quiet = 1e-6, np.zeros((1, 3))
    >>> numeric = (model.step(state, action + [eps, 0], quiet) - model.step(state, action, quiet)) / eps
    >>> bool(np.allclose(B[0, :, 0], numeric[0], atol=1e-4))
    True
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from tl_gym.envs.dynamics import NOISE_SIZE, STATE_SIZE, CarParams, car_step, wrap_angle

from tl_gym.tltl import fused


class CarModel:
    """``s_{t+1} = f(s_t, a_t) + n_t`` of the paper's car; actions normalised to ``[-1, 1]`` (clipped, as the env does).

    Args:
        params: the car's constants (`CarParams`); only ``dt``, ``wheelbase``, ``max_speed`` and
            ``max_steer`` are read.
    """

    noise_size = NOISE_SIZE

    def __init__(self, params: CarParams):
        self.params = params

    def step(self, state: np.ndarray, action: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The next states ``(n, 6)`` from states ``(n, 6)``, normalised actions ``(n, 2)`` and noise ``(n, 3)``."""
        p = self.params
        return car_step(state, p.physical_action(np.asarray(action, dtype=np.float64)), p.dt, p.wheelbase, noise)

    def jacobians(self, state: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(∂f/∂s (n, 6, 6), ∂f/∂a (n, 6, 2))`` at ``(state, action)``; zero along a clipped action component.

        The new pose is ``pose + dt · rates`` and the new state stores the rates, which depend on
        the heading θ and the actions only (the heading's wrap has slope 1).
        """
        p = self.params
        n = state.shape[0]
        kernel = _jacobians_kernel()
        if kernel is not None:  # the same entries, written row by row without temporaries
            A, B = np.empty((n, STATE_SIZE, STATE_SIZE)), np.empty((n, STATE_SIZE, 2))
            kernel(np.asarray(state, dtype=np.float64), np.asarray(action, dtype=np.float64),
                   p.dt, p.wheelbase, p.max_speed, p.max_steer, A, B)
            return A, B
        clipped = np.clip(action, -1.0, 1.0)
        inside = (np.abs(action) <= 1.0).astype(np.float64)
        speed = (clipped[:, 0] + 1.0) * (0.5 * p.max_speed)
        steer = clipped[:, 1] * p.max_steer
        cos, sin, tan = np.cos(state[:, 2]), np.sin(state[:, 2]), np.tan(steer)
        d_rates_d_theta = np.stack([-speed * sin, speed * cos, np.zeros(n)], axis=1)
        d_rates_d_speed = np.stack([cos, sin, tan / p.wheelbase], axis=1)
        d_turn_d_steer = speed / p.wheelbase / np.cos(steer) ** 2
        A = np.zeros((n, STATE_SIZE, STATE_SIZE))
        A[:, [0, 1, 2], [0, 1, 2]] = 1.0
        A[:, :3, 2] += p.dt * d_rates_d_theta
        A[:, 3:, 2] = d_rates_d_theta
        B = np.zeros((n, STATE_SIZE, 2))
        B[:, 3:, 0] = d_rates_d_speed * (0.5 * p.max_speed * inside[:, :1])
        B[:, 5, 1] = d_turn_d_steer * p.max_steer * inside[:, 1]
        B[:, :3] = p.dt * B[:, 3:]
        return A, B

    def noise(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Each step's additive noise of recorded episodes: ``s_{t+1} − f(s_t, a_t)`` on ``(x, y, θ)``, θ wrapped.

        Args:
            observations: ``(N, T+1, 6)`` states.
            actions: ``(N, T, 2)`` the actions that were sent.

        Returns:
            ``(N, T, 3)``; `step` with it reproduces ``observations``.
        """
        states = observations[:, :-1]
        noiseless = self.step(states, actions, np.zeros(states.shape[:-1] + (NOISE_SIZE,)))
        noise = observations[:, 1:, :3] - noiseless[..., :3]
        noise[..., 2] = wrap_angle(noise[..., 2])
        return noise

    def closed_loop(self, start: np.ndarray, noise: np.ndarray, feedforward: np.ndarray, gains: np.ndarray,
                    centre: np.ndarray, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """States ``(N, T+1, 6)`` and actions ``(N, T, 2)`` of ``a_t = k_t + K_t (s_t ⊖ s̄_t)``, noise fixed.

        The loop `tl_gym.agents.model_repair.closed_loop` runs step by step in Python, compiled
        into one numba loop (the same numbers to rounding, tested): 200 steps of 40 cars cost
        well under a millisecond instead of tens of numpy calls per step. None without numba.

        Args:
            start: ``(N, 6)`` start states.
            noise: ``(N, T, 3)`` each step's additive noise (`noise`).
            feedforward: ``(N, T, 2)`` the feed-forwards k_t.
            gains: ``(T, 2, 6)`` the feedback gains K_t.
            centre: ``(T, 6)`` the states s̄_t the feedback is centred on.
            angles: ``(6,)`` bool, the components whose deviation is wrapped to ``[-π, π)``.
        """
        kernel = _closed_loop_kernel()
        if kernel is None:
            return None
        n, horizon, act_dim = feedforward.shape
        states, actions = np.empty((n, horizon + 1, STATE_SIZE)), np.empty((n, horizon, act_dim))
        p = self.params
        kernel(np.asarray(start, dtype=np.float64), np.asarray(noise, dtype=np.float64),
               np.asarray(feedforward, dtype=np.float64), np.asarray(gains, dtype=np.float64),
               np.asarray(centre, dtype=np.float64), np.asarray(angles, dtype=np.bool_),
               p.dt, p.wheelbase, p.max_speed, p.max_steer, states, actions)
        return states, actions


def _closed_loop(start, noise, feedforward, gains, centre, angles, dt, wheelbase, max_speed, max_steer,
                 states, actions):  # pragma: no cover - compiled by numba
    """`CarModel.closed_loop`'s loop, operation for operation as `car_step` and `CarParams.physical_action`."""
    n, horizon, act_dim = feedforward.shape
    obs_dim = start.shape[1]
    two_pi = 2.0 * math.pi
    for i in range(n):
        for j in range(obs_dim):
            states[i, 0, j] = start[i, j]
        for t in range(horizon):
            for a in range(act_dim):
                feedback = 0.0
                for j in range(obs_dim):
                    deviation = states[i, t, j] - centre[t, j]
                    if angles[j]:
                        deviation = (deviation + math.pi) % two_pi - math.pi
                    feedback += gains[t, a, j] * deviation
                actions[i, t, a] = feedforward[i, t, a] + feedback
            speed = (min(max(actions[i, t, 0], -1.0), 1.0) + 1.0) * (0.5 * max_speed)
            steer = min(max(actions[i, t, 1], -1.0), 1.0) * max_steer
            theta = states[i, t, 2]
            rates = (speed * math.cos(theta), speed * math.sin(theta), speed / wheelbase * math.tan(steer))
            for j in range(3):
                states[i, t + 1, 3 + j] = rates[j]
                states[i, t + 1, j] = rates[j] * dt + states[i, t, j] + noise[i, t, j]
            states[i, t + 1, 2] = (states[i, t + 1, 2] + math.pi) % two_pi - math.pi


@functools.cache
def _closed_loop_kernel() -> Callable[..., None] | None:
    """`_closed_loop` compiled by numba (cached on disk), or None when numba is not installed."""
    if not fused.available():
        return None
    import numba

    return numba.njit(cache=True)(_closed_loop)


def _jacobians(state, action, dt, wheelbase, max_speed, max_steer, A, B):  # pragma: no cover - compiled by numba
    """`CarModel.jacobians`' entries, row by row (every entry of ``A`` and ``B`` written)."""
    for r in range(state.shape[0]):
        A[r] = 0.0
        B[r] = 0.0
        u0, u1 = action[r, 0], action[r, 1]
        speed = (min(max(u0, -1.0), 1.0) + 1.0) * (0.5 * max_speed)
        steer = min(max(u1, -1.0), 1.0) * max_steer
        cos, sin, tan = math.cos(state[r, 2]), math.sin(state[r, 2]), math.tan(steer)
        d_theta = (-speed * sin, speed * cos, 0.0)  # the rates' slopes in θ
        d_speed = (cos, sin, tan / wheelbase)  # ... and in the physical speed
        for j in range(3):
            A[r, j, j] = 1.0
            A[r, j, 2] += dt * d_theta[j]
            A[r, 3 + j, 2] = d_theta[j]
            if abs(u0) <= 1.0:
                B[r, 3 + j, 0] = d_speed[j] * (0.5 * max_speed)
        if abs(u1) <= 1.0:
            B[r, 5, 1] = speed / wheelbase / math.cos(steer) ** 2 * max_steer
        for j in range(3):
            B[r, j, 0] = dt * B[r, 3 + j, 0]
            B[r, j, 1] = dt * B[r, 3 + j, 1]


@functools.cache
def _jacobians_kernel() -> Callable[..., None] | None:
    """`_jacobians` compiled by numba (cached on disk), or None when numba is not installed."""
    if not fused.available():
        return None
    import numba

    return numba.njit(cache=True)(_jacobians)
