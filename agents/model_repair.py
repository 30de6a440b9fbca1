"""TLPS's update through a known model: repair each episode's actions (``action_repair="model"``).

The paper's line 8 moves each sampled trajectory τ^i in signal space, and the policy can only
follow through the weights: a weighted average of samples never leaves their cloud
(docs/tlps.md, issue 16). When the env exposes a differentiable model of its dynamics
(``dynamics_model``; the car's is `tl_gym.envs.car_model.CarModel`), TLPS moves the actions
instead:

1. recover every step's additive noise ``n_t^i = s_{t+1}^i − f(s_t^i, a_t^i)`` from the episode;
2. with that noise fixed, the episode's states are a function of its feed-forward ``k^i``
   through the closed loop ``a_t = k_t + K_t (s_t ⊖ s̄_t)``; climb ρ̂ of that function,
   ``k̄^i = argmax ρ̂(τ(k))`` subject to ``‖k − k^i‖² ≤ action_epsilon``, with the projected
   solver of `tl_gym.agents.trust_region` and torch's gradient through model and engine;
3. re-simulate: the repaired states and feed-forwards are a consistent pair, which the
   policy is refit to with the weights, so its mean can move past the best sample.

This is deliverable 2 of issue 16 with the known model in place of one fitted to the batch
(H15 measured the fitted one's error at 51–100 %; the known one reproduces the episode to
1e-6). Research record: docs/tlps.md, H19.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from tl_gym.tltl.ast import Formula

from .feedback import matching_components
from .policy import LinearGaussianPolicy
from .sampling import Rollouts
from .trust_region import TrustRegionResult, projected_ascent, torch_threads


class DynamicsModel(Protocol):
    """What ``action_repair="model"`` needs from an env's ``dynamics_model``."""

    def step(self, state: torch.Tensor, action: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """Next states ``(n, obs_dim)`` from states, actions as sent to the env and additive noise."""

    def noise(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The additive noise ``(N, T, k)`` that reproduces recorded episodes through `step`."""


@dataclass(frozen=True)
class Repair:
    """Output of `repair_feedforward`.

    Attributes:
        feedforward: the repaired feed-forwards k̄^i, ``(N, T, act_dim)``.
        observations: the re-simulated states under k̄^i, ``(N, T+1, obs_dim)``.
        traces: the formula's signals read from them, name -> ``(N, T+1)``.
        smooth_before: ρ̂ of the sampled episodes, ``(N,)``.
        smooth_after: ρ̂ of the repaired ones, ``(N,)``.
    """

    feedforward: np.ndarray
    observations: np.ndarray
    traces: dict[str, np.ndarray]
    smooth_before: np.ndarray
    smooth_after: np.ndarray


def signal_columns(batch: Rollouts, names: tuple[str, ...]) -> dict[str, int]:
    """The observation component each signal is read from.

    Raises:
        ValueError: a signal is not an observation component (the model's states would not give it).
    """
    columns = {}
    for name in names:
        found = matching_components(batch.observations, batch.traces[name])
        if not found:
            raise ValueError(f"action_repair='model' needs every signal to be an observation component; "
                             f"signal {name!r} is not one")
        columns[name] = found[0]
    return columns


def closed_loop(model: DynamicsModel, policy: LinearGaussianPolicy, start: torch.Tensor, noise: torch.Tensor,
                feedforward: torch.Tensor) -> torch.Tensor:
    """States ``(N, T+1, obs_dim)`` of the closed loop ``a_t = k_t + K_t (s_t ⊖ s̄_t)`` under fixed noise."""
    gains, centre, angles = (torch.as_tensor(np.ascontiguousarray(a)) for a in
                             (policy.gains, policy.centre, policy.angles))
    states, s = [start], start
    for t in range(feedforward.shape[1]):
        deviation = s - centre[t]
        wrapped = torch.remainder(deviation + math.pi, 2.0 * math.pi) - math.pi
        action = feedforward[:, t] + torch.einsum("ij,nj->ni", gains[t], torch.where(angles, wrapped, deviation))
        s = model.step(s, action, noise[:, t])
        states.append(s)
    return torch.stack(states, dim=1)


def repair_feedforward(model: DynamicsModel, policy: LinearGaussianPolicy, batch: Rollouts, feedforward: np.ndarray,
                       formula: Formula, epsilon: float, beta: float, steps: int = 20, decay: float = 0.5,
                       form: str = "linear", threads: int | None = 1) -> Repair:
    """Repair every episode's feed-forward through the model (module docstring, steps 1–3).

    Args:
        model: the env's ``dynamics_model``.
        policy: the policy that drew the batch (its ``K_t``, ``s̄_t`` close the loop).
        batch: the sampled episodes; all must last the policy's horizon.
        feedforward: their drawn feed-forwards k^i, ``(N, T, act_dim)``.
        formula: the task formula; its signals must be observation components.
        epsilon: trust region ``‖k̄^i − k^i‖² ≤ epsilon``, in squared normalised action units
            summed over steps and components (> 0).
        beta: smoothing sharpness, as `tl_gym.agents.trust_region.improve_trajectories`.
        steps: iterations of the projected solver.
        decay: its step-length factor after a step that did not improve.
        form: the engine's smoothing form, ``"nested"`` or ``"linear"``.
        threads: torch threads (None keeps the process setting).

    Raises:
        RuntimeError: an episode ended before the horizon (its later states are not simulated).
        ValueError: a signal is not an observation component.
    """
    if np.any(batch.lengths != feedforward.shape[1]):
        raise RuntimeError("action_repair='model' needs episodes of the full horizon; one ended early")
    columns = signal_columns(batch, formula.signals)
    start = torch.from_numpy(np.ascontiguousarray(batch.observations[:, 0], dtype=np.float64))
    noise = torch.from_numpy(model.noise(batch.observations, batch.actions))

    def smooth(states: torch.Tensor) -> torch.Tensor:
        return formula.smooth_robustness({n: states[..., j] for n, j in columns.items()}, beta, math.inf, form)

    def evaluate(k: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = torch.tensor(k, dtype=torch.float64, requires_grad=True)
        index = torch.from_numpy(rows)
        values = smooth(closed_loop(model, policy, start[index], noise[index], x))
        values.sum().backward()
        return values.detach().numpy(), x.grad.numpy()

    with torch_threads(threads):
        result: TrustRegionResult = projected_ascent(evaluate, np.asarray(feedforward, dtype=np.float64),
                                                     epsilon, steps, decay)
        with torch.no_grad():
            observations = closed_loop(model, policy, start, noise, torch.from_numpy(result.updated)).numpy()
    traces = {n: observations[..., j] for n, j in columns.items()}
    return Repair(result.updated, observations, traces, result.smooth_before, result.smooth_after)


def find_model(env: Any) -> DynamicsModel | None:
    """The env's ``dynamics_model`` (on the vector env or its first sub-env), or None."""
    from .sampling import env_attribute

    return env_attribute(env, "dynamics_model")
