"""The car's dynamics as a model with Jacobians, for agents that use a known model.

`CarModel` wraps `tl_gym.envs.dynamics.car_step` (the env's own step) with its Jacobians
and the inverse that recovers each step's additive noise from a recorded episode. With that
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

import numpy as np
from tl_gym.envs.dynamics import NOISE_SIZE, STATE_SIZE, CarParams, car_step, wrap_angle


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
