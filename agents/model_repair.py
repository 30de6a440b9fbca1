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
   solver of `tl_gym.agents.trust_region`, the engine's gradient carried back to the actions
   by the adjoint of the closed loop (the model's Jacobians);
3. re-simulate: the repaired states and feed-forwards are a consistent pair, which the
   policy is refit to with the weights, so its mean can move past the best sample.

This is deliverable 2 of issue 16 with the known model in place of one fitted to the batch
(H15 measured the fitted one's error at 51–100 %; the known one reproduces the episode to
1e-6). Research record: docs/tlps.md, H19.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from tl_gym.errors import EpisodeError
from tl_gym.tltl import fused
from tl_gym.tltl.ast import Formula

from .feedback import matching_components
from .horizon import env_attribute
from .policy import LinearGaussianPolicy
from .sampling import Rollouts
from .trust_region import Gradient, projected_ascent, smooth_value_and_grad


class DynamicsModel(Protocol):
    """What ``action_repair="model"`` needs from an env's ``dynamics_model`` (the car's: `CarModel`).

    A model may also offer ``closed_loop(start, noise, feedforward, gains, centre, angles)``, the
    whole loop of `closed_loop` in one call (the car's is compiled by numba), returning None
    where it cannot; `closed_loop` then steps the model itself.
    """

    def step(self, state: np.ndarray, action: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """Next states ``(n, obs_dim)`` from states, actions as sent to the env and additive noise."""

    def jacobians(self, state: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(∂step/∂state (n, obs_dim, obs_dim), ∂step/∂action (n, obs_dim, act_dim))``."""

    def noise(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The additive noise ``(N, T, k)`` that reproduces recorded episodes through `step`."""


@dataclass(frozen=True)
class Repair:
    """Output of `repair_feedforward`.

    Attributes:
        feedforward: the repaired feed-forwards k̄^i, ``(N, T, act_dim)``.
        observations: the re-simulated states under k̄^i, ``(N, T+1, obs_dim)``.
        actions: the re-simulated actions (before the env's clipping), ``(N, T, act_dim)``.
        traces: the formula's signals read from them, name -> ``(N, T+1)``.
        smooth_before: ρ̂ of the sampled episodes, ``(N,)``.
        smooth_after: ρ̂ of the repaired ones, ``(N,)``.
    """

    feedforward: np.ndarray
    observations: np.ndarray
    actions: np.ndarray
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


def closed_loop(model: DynamicsModel, policy: LinearGaussianPolicy, start: np.ndarray, noise: np.ndarray,
                feedforward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States ``(N, T+1, obs_dim)``, actions ``(N, T, act_dim)`` of ``a_t = k_t + K_t (s_t ⊖ s̄_t)``, noise fixed.

    A model with a compiled ``closed_loop`` (the car's, with numba) runs the whole loop; else it is
    stepped here.
    """
    compiled = getattr(model, "closed_loop", None)
    simulated = None if compiled is None else compiled(start, noise, feedforward, policy.gains, policy.centre,
                                                        policy.angles)
    if simulated is not None:
        return simulated
    n, horizon, act_dim = feedforward.shape
    states = np.empty((n, horizon + 1, start.shape[-1]))
    actions = np.empty((n, horizon, act_dim))
    states[:, 0] = start
    for t in range(horizon):
        actions[:, t] = feedforward[:, t] + policy.feedback_term(t, states[:, t])
        states[:, t + 1] = model.step(states[:, t], actions[:, t], noise[:, t])
    return states, actions


def feedforward_gradient(model: DynamicsModel, policy: LinearGaussianPolicy, states: np.ndarray, actions: np.ndarray,
                         state_gradient: np.ndarray) -> np.ndarray:
    """The gradient of a function of the states with respect to the feed-forward, by the adjoint of `closed_loop`.

    ``state_gradient`` ``(N, T+1, obs_dim)`` is the function's gradient with respect to each
    state; the adjoint carries it back through ``s_{t+1} = f(s_t, a_t)`` and the feedback
    ``∂a_t/∂s_t = K_t`` (the heading's wrap has slope 1). Returns ``(N, T, act_dim)``.
    """
    n, horizon, act_dim = actions.shape
    obs_dim = states.shape[-1]
    d_state, d_action = model.jacobians(states[:, :-1].reshape(-1, obs_dim), actions.reshape(-1, act_dim))  # all steps
    d_state, d_action = d_state.reshape(n, horizon, obs_dim, obs_dim), d_action.reshape(n, horizon, obs_dim, act_dim)
    grad = np.empty_like(actions)
    kernel = _adjoint_kernel()
    if kernel is not None:
        kernel(d_state, d_action, np.ascontiguousarray(state_gradient, dtype=np.float64),
               np.ascontiguousarray(policy.gains, dtype=np.float64), grad)
        return grad
    adjoint = state_gradient[:, horizon].copy()
    for t in range(horizon - 1, -1, -1):
        grad[:, t] = np.einsum("nij,ni->nj", d_action[:, t], adjoint)
        adjoint = state_gradient[:, t] + np.einsum("nij,ni->nj", d_state[:, t], adjoint) + grad[:, t] @ policy.gains[t]
    return grad


def _adjoint(d_state, d_action, state_gradient, gains, grad):  # pragma: no cover - compiled by numba
    """`feedforward_gradient`'s backward loop, one episode at a time."""
    n, horizon, obs_dim, act_dim = d_action.shape
    adjoint = np.empty(obs_dim)
    carried = np.empty(obs_dim)
    for e in range(n):
        for i in range(obs_dim):
            adjoint[i] = state_gradient[e, horizon, i]
        for t in range(horizon - 1, -1, -1):
            for a in range(act_dim):
                total = 0.0
                for i in range(obs_dim):
                    total += d_action[e, t, i, a] * adjoint[i]
                grad[e, t, a] = total
            for j in range(obs_dim):
                total = 0.0
                for i in range(obs_dim):
                    total += d_state[e, t, i, j] * adjoint[i]
                for a in range(act_dim):
                    total += grad[e, t, a] * gains[t, a, j]
                carried[j] = state_gradient[e, t, j] + total
            for j in range(obs_dim):
                adjoint[j] = carried[j]


@functools.cache
def _adjoint_kernel() -> Callable[..., None] | None:
    """`_adjoint` compiled by numba (cached on disk), or None when numba is not installed (``tl_gym[fast]``)."""
    if not fused.available():
        return None
    import numba

    return numba.njit(cache=True)(_adjoint)


def repair_feedforward(model: DynamicsModel, policy: LinearGaussianPolicy, batch: Rollouts, feedforward: np.ndarray,
                       formula: Formula, epsilon: float, beta: float, steps: int = 20, decay: float = 0.5,
                       form: str = "linear", first_step: float | None = None) -> Repair:
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
        first_step: the solver's first step length (at most √epsilon, the default).

    Raises:
        EpisodeError: (a RuntimeError) an episode ended before the horizon (its later states are not simulated).
        ValueError: a signal is not an observation component (known after the first batch), or the
            model does not replay the batch's episodes (a wrapper changed observations or actions).
    """
    if np.any(batch.lengths != feedforward.shape[1]):
        raise EpisodeError("action_repair='model' needs episodes of the full horizon; one ended early")
    columns = signal_columns(batch, formula.signals)
    names, index = tuple(columns), list(columns.values())
    start, noise = batch.observations[:, 0], model.noise(batch.observations, batch.actions)
    feedforward = np.asarray(feedforward, dtype=np.float64)
    replay, _ = closed_loop(model, policy, start, noise, feedforward)
    if not np.allclose(replay, batch.observations, rtol=1e-6, atol=1e-6):
        raise ValueError("action_repair='model': the env's dynamics_model does not reproduce its episodes (a wrapper "
                         "that changes observations or actions?); the repair would follow a wrong model")

    def evaluate(k: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, Gradient]:
        states, actions = closed_loop(model, policy, start[rows], noise[rows], k)
        values, signal_grad = smooth_value_and_grad(formula, names, states[..., index], beta, math.inf, form)

        def gradient(chosen: np.ndarray) -> np.ndarray:  # the adjoint of the chosen episodes only
            picked = states[chosen]
            state_grad = np.zeros_like(picked)
            state_grad[..., index] = signal_grad[chosen]
            return feedforward_gradient(model, policy, picked, actions[chosen], state_grad)

        return values, gradient

    result = projected_ascent(evaluate, feedforward, epsilon, steps, decay, first_step)
    observations, actions = closed_loop(model, policy, start, noise, result.updated)
    traces = {n: observations[..., j] for n, j in columns.items()}
    return Repair(result.updated, observations, actions, traces, result.smooth_before, result.smooth_after)


def find_model(env: Any) -> DynamicsModel | None:
    """The env's ``dynamics_model`` (on the vector env or its first sub-env), or None."""
    return env_attribute(env, "dynamics_model")
