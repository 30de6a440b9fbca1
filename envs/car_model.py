"""The car's dynamics as a differentiable model, for agents that use a known model.

`CarModel` is `tl_gym.envs.dynamics.car_step` written in torch, plus the inverse that
recovers each step's additive noise from a recorded episode. With that noise held fixed, an
episode's states are a differentiable function of its actions: TLPS's
``action_repair="model"`` (docs/tlps.md, H19) climbs the smoothed robustness along that
function. `CarNavEnv` and `CarNavVectorEnv` expose one as ``dynamics_model``.

Example:
    >>> import numpy as np, torch
    >>> from tl_gym.envs.dynamics import CarParams, car_step
    >>> model, params = CarModel(CarParams()), CarParams()
    >>> state, action = np.array([[10.0, 20.0, 0.3, 0, 0, 0]]), np.array([[0.5, -0.2]])
    >>> expected = car_step(state, params.physical_action(action), params.dt, params.wheelbase, np.zeros((1, 3)))
    >>> got = model.step(torch.tensor(state), torch.tensor(action), torch.zeros(1, 3))
    >>> bool(np.allclose(got.numpy(), expected))
    True
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from tl_gym.envs.dynamics import NOISE_SIZE, CarParams, wrap_angle


class CarModel:
    """``s_{t+1} = f(s_t, a_t) + n_t`` of the paper's car, in torch; actions normalised to ``[-1, 1]``.

    Args:
        params: the car's constants (`CarParams`); only ``dt``, ``wheelbase``, ``max_speed`` and
            ``max_steer`` are read.
    """

    noise_size = NOISE_SIZE

    def __init__(self, params: CarParams):
        self.params = params

    def _rates(self, state: Any, action: Any, lib: Any) -> list[Any]:
        """``[ẋ, ẏ, θ̇]`` at ``state`` under the normalised ``action`` (clipped to [-1, 1]), in numpy or torch."""
        p = self.params
        clipped = lib.clip(action, -1.0, 1.0)
        speed = (clipped[..., 0] + 1.0) * (0.5 * p.max_speed)
        heading = state[..., 2]
        turn = speed / p.wheelbase * lib.tan(clipped[..., 1] * p.max_steer)
        return [speed * lib.cos(heading), speed * lib.sin(heading), turn]

    def step(self, state: Any, action: Any, noise: Any) -> Any:
        """The next states (torch), differentiable in ``state`` and ``action``.

        Args:
            state: ``(n, 6)`` states ``[x, y, θ, ẋ, ẏ, θ̇]``.
            action: ``(n, 2)`` normalised actions (clipped here, as the env clips them).
            noise: ``(n, 3)`` additive noise on ``(x, y, θ)``.
        """
        import torch

        rates = torch.stack(self._rates(state, action, torch), dim=-1)
        pose = state[..., :3] + self.params.dt * rates + noise
        heading = torch.remainder(pose[..., 2:] + math.pi, 2.0 * math.pi) - math.pi
        return torch.cat([pose[..., :2], heading, rates], dim=-1)

    def noise(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Each step's additive noise of recorded episodes: ``s_{t+1} − f(s_t, a_t)`` on ``(x, y, θ)``, θ wrapped.

        Args:
            observations: ``(N, T+1, 6)`` states.
            actions: ``(N, T, 2)`` the actions that were sent.

        Returns:
            ``(N, T, 3)``; `step` with it reproduces ``observations``.
        """
        states = observations[:, :-1]
        rates = np.stack(self._rates(states, np.asarray(actions, dtype=np.float64), np), axis=-1)
        noise = observations[:, 1:, :3] - states[..., :3] - self.params.dt * rates
        noise[..., 2] = wrap_angle(noise[..., 2])
        return noise
