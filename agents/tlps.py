"""Temporal Logic Policy Search (TLPS), the paper's Algorithm 1.

Li, Ma and Belta, "A Policy Search Method For Temporal Logic Specified
Reinforcement Learning Tasks", ACC 2018, section IV. The policy is the
time-varying linear-Gaussian ``π(a_t | s_t) = N(K_t s_t + k_t, C_t)`` of
`LinearGaussianPolicy`, with learned ``k_t``, ``C_t``; each episode draws its own
feed-forward sequence ``k_t^i``. The paper keeps ``K_t`` fixed; by default
``K_t`` is refit too, acting on the deviation from the weighted mean state
(``feedback="fitted"``, `tl_gym.agents.feedback`); ``feedback="open"`` is the paper's.

A trajectory τ is what the formula reads: the recorded values of its signals,
shape ``(T+1, S)`` (``x`` and ``y`` on the car), so TLPS runs on any env wrapped
by `tl_gym.TLTLRewardWrapper`. One update (Algorithm 1, lines 4–18):

1. sample N episodes in one batch (l.4–7);
2. move every τ^i to the τ̄^i that maximises the smoothed robustness ρ̂ within
   ``‖τ̄^i − τ^i‖² ≤ ε`` (l.8, `tl_gym.agents.trust_region`);
3. fit a Gaussian to the *updated* trajectories (Eq. 12; line 9's "τ" is a typo:
   a fit to the sampled ones carries no robustness information and does not learn). With the
   default weights (``"hybrid"``, ``hybrid_mix=1.0``, the measured best) the fit does not enter
   them and is skipped: samples are ranked by ρ̂(τ̄^i) alone, and ``regularization`` has no effect;
   it matters for ``"importance"``, ``"paper"`` and a mix below 1 (docs/tlps.md);
4. weight the samples from log-space logits (l.10–13, `tl_gym.agents.weights`) with a
   temperature α fixed or adapted to a KL bound;
5. refit ``k_t`` and ``C_t`` by weighted maximum likelihood (l.14–17), with a
   standard-deviation floor that can decay over iterations (the paper's "covariance
   damping schedule", section VI), and with fitted feedback ``K_t`` and its centre by
   weighted ridge regression on the drawn noise.

With ``action_repair="model"`` and an env that exposes a differentiable ``dynamics_model``
(the car), step 2 moves each episode's feed-forward instead, through the model, and step 5
refits to the repaired episodes (`tl_gym.agents.model_repair`; docs/tlps.md, H19).

Where this departs from the paper, and why, is in `docs/tlps.md`: the weights are
not the literal softmax of densities, which does not learn (see `TLPSConfig.weights`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from tl_gym.checks import check_fraction, check_positive

from .episodic import AbstractEpisodicSearch, EpisodicSearchConfig
from .model_repair import find_model, repair_feedforward
from .sampling import rollout
from .trust_radius import AdaptiveRadius
from .trust_region import check_trust_region, improve_trajectories, smooth_by_length
from .weights import (
    WEIGHTINGS,
    adapt_alpha,
    check_kl_bound,
    kl_bound_for,
    kl_to_uniform,
    sample_logits,
    softmax_weights,
)

SMOOTHING_FORMS = ("nested", "linear")
ACTION_REPAIRS = ("none", "model")


@dataclass(frozen=True, kw_only=True)
class TLPSConfig(EpisodicSearchConfig):
    """Hyperparameters of `TLPS`; the defaults and the measurements behind them are in ``docs/tlps.md``.

    The batch, policy, feedback and exploration fields (``n_episodes`` … ``exploration_halflife``)
    are shared with REPS: see `EpisodicSearchConfig`.
    """

    epsilon: float = 4.5
    """Trust region ``‖τ̄ − τ‖² ≤ ε`` in squared signal units, summed over steps and signals (> 0).
    On the 300-unit car arena 4.5 lets a trajectory move ~2 units in total, a fraction of the
    30-unit goals: ε = 0.005 in goal widths, scaled by 30² (docs/tlps.md)."""
    beta: float = 9.0
    """Sharpness of the log-sum-exp smoothing (> 0; the paper's 9)."""
    smoothing: str = "linear"
    """The engine's smoothing form: ``"nested"`` (the paper's, O(T²) for a ``T`` nested under a
    temporal operator) or ``"linear"`` (same limit and error bracket, O(T))."""
    weights: str = "hybrid"
    """Sample logits: ``"hybrid"``, ``"importance"`` or ``"paper"`` (see `tl_gym.agents.weights`)."""
    hybrid_mix: float = 1.0
    """Share of the standardised ρ̂(τ̄^i) in the hybrid logits, in [0, 1]; the rest is the
    standardised importance logit. 1.0 (the measured best) ranks samples by the smoothed
    robustness of their updated trajectories alone."""
    kl_bound: float | None = None
    """α is adapted so that KL(w ‖ uniform) equals this bound, unless ``alpha`` is set. ``None``: 2.0, at most
    log(n_episodes / 2), so that two episodes or more share the weight (`weights.kl_bound_for`); a bound given
    must be > 0 and below log(n_episodes), where it could not bind."""
    alpha: float | None = None
    """A fixed temperature α (> 0) instead of the adapted one."""
    regularization: float = 900.0
    """Ridge added to every per-step covariance of both trajectory fits, squared signal units (> 0); unused
    by the default weights (``"hybrid"`` with ``hybrid_mix=1.0`` fit no Gaussian)."""
    solver: str = "projected"
    """Trust-region solver: ``"projected"`` (batched) or ``"slsqp"`` (scipy, per trajectory, as the paper)."""
    solver_steps: int = 20
    """Iterations of the projected solver (>= 1); SLSQP gets five times as many at most."""
    solver_decay: float = 0.5
    """Step-length factor of the projected solver after a step that did not improve, in (0, 1)."""
    solver_warm_start: bool = False
    """Start the projected solver's steps at the median distance the last update moved its points
    instead of at the trust region's radius, which later updates overshoot several times over
    (docs/tlps.md, H22)."""
    threads: int | None = 1
    """Torch threads during the trust-region solve, when it ran through torch's autograd. Since the
    solve takes the engine's gradient without torch (`Formula.smooth_robustness_and_gradient`), it
    has no effect; kept (and checked) so that saved agents and scripts that set it still load."""
    action_repair: str = "none"
    """``"none"``: the paper's update in signal space (line 8). ``"model"``: repair each episode's
    feed-forward through the env's differentiable ``dynamics_model`` and refit to the repaired
    episodes (`tl_gym.agents.model_repair`); needs such an env (TLCarNav-v0) and the projected solver."""
    action_epsilon: float = 1.0
    """With ``action_repair="model"``: trust region ``‖k̄^i − k^i‖² ≤ action_epsilon`` in squared
    normalised action units, summed over steps and action components (> 0); 1.0 moves a 200-step
    car episode's actions by 0.05 per component on average (docs/tlps.md, H19)."""
    trust_adapt: bool = False
    """Adapt the trust region's size (``epsilon``, or ``action_epsilon`` with the repair) from the
    ratio of the next batch's realised gain in mean ρ̂ to the gain the update promised: halve it
    below 0.25, double it above 0.75 (`tl_gym.agents.trust_radius`; docs/tlps.md, H21)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check_trust_region(self.epsilon, self.beta, self.solver, self.solver_steps, self.solver_decay, prefix="solver_")
        if self.smoothing not in SMOOTHING_FORMS:
            raise ValueError(f"smoothing must be one of {SMOOTHING_FORMS}, got {self.smoothing!r}")
        if self.weights not in WEIGHTINGS:
            raise ValueError(f"weights must be one of {WEIGHTINGS}, got {self.weights!r}")
        check_fraction("hybrid_mix", self.hybrid_mix, allow_zero=True)
        if self.alpha is None:  # a fixed α leaves the bound unused
            check_kl_bound("kl_bound", self.kl_bound, self.n_episodes)
        if self.action_repair not in ACTION_REPAIRS:
            raise ValueError(f"action_repair must be one of {ACTION_REPAIRS}, got {self.action_repair!r}")
        check_positive("action_epsilon", self.action_epsilon)
        if self.action_repair == "model" and self.solver != "projected":
            raise ValueError(f"action_repair='model' runs the projected solver; got solver={self.solver!r}")
        if self.action_repair == "model" and (self.weights, self.hybrid_mix) != ("hybrid", 1.0):
            raise ValueError("action_repair='model' ranks the repaired episodes by their ρ̂ (weights='hybrid', "
                             f"hybrid_mix=1.0); got weights={self.weights!r}, hybrid_mix={self.hybrid_mix!r}")
        if self.alpha is not None:
            check_positive("alpha", self.alpha)
        check_positive("regularization", self.regularization)
        for name in ("trust_adapt", "solver_warm_start"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.threads is not None and (not isinstance(self.threads, int) or self.threads < 1):
            raise ValueError(f"threads must be a positive int or None, got {self.threads!r}")


class TLPS(AbstractEpisodicSearch):
    """Temporal Logic Policy Search (the paper's Algorithm 1) on any TLTL-wrapped env.

    See the module docstring for the algorithm and `TLPSConfig` for the hyperparameters.
    History rows add ``smooth_robustness`` (mean ρ̂ of the samples), ``smooth_updated``
    (mean ρ̂ of the updated trajectories), ``alpha``, ``kl`` (KL(w ‖ uniform)),
    ``weight_rank_corr`` (Spearman correlation of the logits with the exact robustness),
    ``policy_std``, ``std_floor``, with ``feedback="fitted"`` (the default) ``feedback_gain``, and the
    seconds spent sampling and in the trust region.

    Example:
        >>> from tl_gym.agents import TLPS
        >>> agent = TLPS("TLCarNav-v0", seed=0, n_episodes=8, solver_steps=2).learn(2)
        >>> [row["iteration"] for row in agent.history]
        [1, 2]
    """

    config: TLPSConfig
    config_class = TLPSConfig

    def _setup(self) -> None:
        super()._setup()
        self._model = find_model(self.env) if self.config.action_repair == "model" else None
        if self.config.action_repair == "model" and self._model is None:
            raise ValueError(f"action_repair='model' needs an env with a differentiable `dynamics_model` "
                             f"(TLCarNav-v0 has one); {self._env_source['id'] or type(self.env).__name__!r} has none")
        self._radius = AdaptiveRadius()
        self._moved = math.nan  # median distance the last update moved its points (solver_warm_start)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        arrays = super()._state_arrays()
        if self.config.trust_adapt:
            arrays["trust_radius"] = self._radius.to_array()
        if self.config.solver_warm_start:
            arrays["solver_moved"] = np.array([self._moved])
        return arrays

    def _load_state(self, arrays: dict[str, np.ndarray], files: dict[str, bytes]) -> None:
        super()._load_state(arrays, files)
        if "trust_radius" in arrays:
            self._radius = AdaptiveRadius.from_array(arrays["trust_radius"])
        if "solver_moved" in arrays:
            self._moved = float(arrays["solver_moved"][0])

    @property
    def signal_names(self) -> tuple[str, ...]:
        """The signals that make up a trajectory τ, in the order of its last axis."""
        return self.formula.signals

    def _update(self, iteration: int) -> dict[str, Any]:
        cfg = self.config
        # ALGO LOGIC: one pass of Algorithm 1's lines 5-18 (the buffer holds exactly N episodes).
        start = time.perf_counter()
        seed = int(self.rng.integers(2**31 - 1))
        feedforward = self.policy.sample_feedforward(cfg.n_episodes, self.rng)  # k_t^i ~ N(k_t, C_t)
        batch = rollout(self.env, feedforward, self.policy.feedback, seed=seed)  # l.4-7: N episodes, batched
        tau = np.stack([batch.traces[name] for name in self.signal_names], axis=-1)  # τ^i: (N, T+1, S)
        sampled_at = time.perf_counter()
        scale = 1.0
        if cfg.trust_adapt:  # the last update's promise against this batch, sampled from its refit
            sampled = smooth_by_length(self.formula, self.signal_names, tau, cfg.beta, batch.lengths,
                                       form=cfg.smoothing)
            scale = self._radius.adapt(float(np.mean(sampled)))
        first_step = self._moved if cfg.solver_warm_start and self._moved > 0 else None

        if self._model is None:
            result = improve_trajectories(  # l.8: τ̄^i = argmax ρ̂ s.t. ‖τ̄^i − τ^i‖² ≤ ε
                self.formula, self.signal_names, tau, cfg.beta, cfg.epsilon * scale, solver=cfg.solver,
                steps=cfg.solver_steps, decay=cfg.solver_decay, form=cfg.smoothing, first_step=first_step,
                lengths=batch.lengths,  # episodes that ended early: judged and moved on their own states
            )
            updated, smooth_before, smooth_after = result.updated, result.smooth_before, result.smooth_after
            alive = np.arange(tau.shape[1]) <= batch.lengths[:, None]  # not the copies padding an early end
            moved = np.sqrt(np.sum((updated - tau) ** 2 * alive[:, :, None], axis=(1, 2)))
        else:  # l.8 through the model: k̄^i = argmax ρ̂(τ(k)) s.t. ‖k − k^i‖² ≤ ε_a; refit to the repaired episodes
            repair = repair_feedforward(self._model, self.policy, batch, feedforward, self.formula,
                                        cfg.action_epsilon * scale, cfg.beta, cfg.solver_steps, cfg.solver_decay,
                                        cfg.smoothing, first_step)
            moved = np.sqrt(np.sum((repair.feedforward - feedforward) ** 2, axis=(1, 2)))
            updated = np.stack([repair.traces[name] for name in self.signal_names], axis=-1)
            smooth_before, smooth_after = repair.smooth_before, repair.smooth_after
            sent = np.clip(repair.actions, self.action_space.low, self.action_space.high)  # as the env clips them
            batch = dataclasses.replace(batch, observations=repair.observations, traces=repair.traces,
                                        actions=sent)  # robustness and success stay the sampled ones
            feedforward = repair.feedforward
        solved_at = time.perf_counter()
        self._moved = float(np.median(moved))
        if cfg.trust_adapt:
            self._radius.record(float(np.mean(smooth_before)), float(np.mean(smooth_after)))

        # l.9: fit (μ̄, Σ̄) to the updated τ̄ (Eq. 12); l.10-11: log N(τ^i | μ̄, Σ̄), and the
        # importance / hybrid corrections (see weights.py); l.12: w^i ∝ exp(α logit^i)
        logits = sample_logits(cfg.weights, tau, updated, cfg.regularization,
                               updated_smooth=smooth_after, mix=cfg.hybrid_mix)
        if cfg.alpha is not None:
            alpha = cfg.alpha
        else:
            bound = kl_bound_for(cfg.kl_bound, len(logits))
            alpha = adapt_alpha(logits, bound) if bound > 0 else 0.0  # 0: two episodes, uniform weights
        weights = softmax_weights(logits, alpha)

        floor = cfg.std_floor(iteration)  # exploration schedule (paper, section VI: covariance damping)
        refit = self._refit(batch, feedforward, weights, floor)  # l.14-17: k_t', C_t' (and K_t) by weighted ML
        # l.18: the buffer is cleared: nothing is carried to the next update.

        # TRY NOT TO MODIFY: diagnostics for the history
        varied = np.ptp(batch.robustness) > 0 and np.ptp(logits) > 0  # spearmanr warns on constants
        corr = spearmanr(logits, batch.robustness).statistic if varied else 0.0
        return {
            "env_steps": batch.env_steps,
            "mean_robustness": batch.mean_robustness,
            "success_rate": batch.success_rate,
            "smooth_robustness": float(np.mean(smooth_before)),
            "smooth_updated": float(np.mean(smooth_after)),
            "alpha": float(alpha),
            "kl": kl_to_uniform(weights),
            "weight_rank_corr": float(np.nan_to_num(corr)),
            "policy_std": float(self.policy.std.mean()),
            "std_floor": floor,
            "time_sampling": sampled_at - start,
            "time_trust_region": solved_at - sampled_at,
            **({"trust_scale": scale} if cfg.trust_adapt else {}),
            **refit,
        }
