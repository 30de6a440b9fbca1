"""Episodic Relative Entropy Policy Search (REPS), the paper's baseline.

Peters, Mülling and Altün, "Relative Entropy Policy Search", AAAI 2010; the
episodic form follows Deisenroth, Neumann and Peters, "A Survey on Policy Search
for Robotics", 2013, section 2.4.2. The search runs over the same parameters as
TLPS: the feed-forward terms ``k_t`` of the time-varying linear-Gaussian policy
(`LinearGaussianPolicy`), each episode drawing its own ``k_t^i ~ N(k_t, C_t)``.
Its return is the exact robustness of the episode (the paper's "original
robustness as terminal reward").

Each iteration:

1. sample ``N`` episodes (batched) and their robustness ``R^i``;
2. minimise the dual ``g(η) = η ε + η log(1/N Σ_i exp(R^i / η))`` over ``η > 0``
   (L-BFGS-B, log-sum-exp form, returns standardised, ``η`` bounded below);
3. weight episode ``i`` by ``w^i ∝ exp(R^i / η)``: the reweighted sample
   distribution stays within ``KL(w ‖ uniform) ≤ ε`` of the current one (episodes at a robustness of
   ±inf excepted: those at +inf take all the weight, those at −inf none, whatever ε);
4. refit ``k_t`` and ``C_t`` by weighted maximum likelihood.

The default ``ε = 2`` (at most log(N/2), `weights.kl_bound_for`) was tuned on the car's task 1, where the
sampled episodes' mean robustness first rose above 0 at update 5–8 (seeds 0–2; ``ε = 1``: 9–16), docs/agents.md;
docs/tlps.md compares the agents.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from .episodic import AbstractEpisodicSearch, EpisodicSearchConfig
from .sampling import rollout
from .weights import check_kl_bound, is_flat, kl_bound_for

#: Lower bound on the temperature ``η`` of standardised returns: below it the
#: weights are one-hot to machine precision and the dual's gradient is noise.
ETA_MIN = 1e-6


@dataclass(frozen=True, kw_only=True)
class REPSConfig(EpisodicSearchConfig):
    """Hyperparameters of `REPS`: the KL bound, and the fields shared with TLPS (`EpisodicSearchConfig`)."""

    epsilon: float | None = None
    """KL bound between the reweighted and the current sample distribution. ``None``: 2.0, at most
    log(n_episodes / 2), so that two episodes or more share the weight (`weights.kl_bound_for`; episodes at a
    robustness of +inf take all the weight whatever the bound); a bound given must be > 0 and below
    log(n_episodes), where it could not bind."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check_kl_bound("epsilon", self.epsilon, self.n_episodes)


def reps_weights(returns: np.ndarray, epsilon: float) -> tuple[np.ndarray, float, float]:
    """Solve episodic REPS's dual and return the episode weights.

    Minimises ``g(η) = η ε + η log(1/N Σ exp(R^i/η))`` with L-BFGS-B on returns
    standardised to unit spread (the weights are invariant to that affine change,
    and ``η`` is then of order one), written with log-sum-exp so that no exponential
    overflows.

    Args:
        returns: the episodes' returns ``R^i``, shape ``(N,)``.
        epsilon: KL bound ``ε ≥ 0`` (0: uniform weights; REPS passes `kl_bound_for` of its ``epsilon``).

    Returns:
        ``(weights, eta, kl)``: normalised weights ``(N,)``, the temperature in the units of
        ``returns``, and ``KL(w ‖ uniform) ≤ ε`` (a bisection on ``η`` repairs a solver stop on the wrong side).

    Infinite returns (a robustness of ``±inf``: ``X φ`` at an episode's last state, or ``true``, with the
    wrapper's ``rho_max=inf``) get what ``exp(R/η)`` gives them at every ``η``: the episodes at ``+inf``
    share all the weight; those at ``-inf`` get none, and the dual is solved on the finite ones with the
    bound that remains, ``ε − log(N / #finite)`` (uniform over them when nothing remains). ``η`` is then
    reported as ``nan`` or as the finite ones' temperature.

    Raises:
        ValueError: a return is NaN.

    Example:
        >>> w, eta, kl = reps_weights(np.array([0.0, 1.0, 2.0, 3.0]), epsilon=0.5)
        >>> bool(np.all(np.diff(w) > 0)), bool(kl <= 0.5 + 1e-6)
        (True, True)
    """
    returns = np.asarray(returns, dtype=float)
    n = returns.shape[0]
    missing = np.flatnonzero(np.isnan(returns))
    if missing.size:
        raise ValueError(f"REPS got a NaN return (robustness) for episode(s) {missing.tolist()}")
    if not np.isfinite(returns).all():
        return _weights_with_infinite_returns(returns, epsilon)
    if n < 2 or epsilon <= 0 or is_flat(returns):  # equal returns, up to rounding, carry no preference
        return np.full(n, 1.0 / n), float("inf"), 0.0
    spread = float(np.std(returns))
    r = (returns - returns.max()) / spread  # <= 0, unit spread

    def dual(x: np.ndarray) -> tuple[float, np.ndarray]:
        eta = float(x[0])
        z = r / eta
        lse = logsumexp(z)
        value = eta * epsilon + eta * (lse - np.log(n))
        p = np.exp(z - lse)
        grad = epsilon + lse - np.log(n) - float(p @ z)
        return value, np.array([grad])

    result = minimize(dual, x0=np.array([1.0]), jac=True, method="L-BFGS-B", bounds=[(ETA_MIN, None)],
                      options={"ftol": 1e-12, "gtol": 1e-10, "maxiter": 500})
    eta = float(result.x[0])
    log_w, kl = _log_weights(r, eta)
    if kl > epsilon:
        # the solver stopped a hair inside the infeasible side: KL falls as eta grows, so
        # bisect (geometrically) to the smallest eta that keeps the bound exactly
        low, high = eta, 2.0 * eta
        while _log_weights(r, high)[1] > epsilon:
            low, high = high, 2.0 * high
        for _ in range(60):
            mid = np.sqrt(low * high)
            low, high = (mid, high) if _log_weights(r, mid)[1] > epsilon else (low, mid)
        eta = high
        log_w, kl = _log_weights(r, eta)
    weights = np.exp(log_w)
    return weights, float(eta * spread), kl


def _weights_with_infinite_returns(returns: np.ndarray, epsilon: float) -> tuple[np.ndarray, float, float]:
    """`reps_weights` when some return is ``±inf`` (its docstring): the limit of ``exp(R/η)`` weights."""
    n = returns.shape[0]
    top = returns == np.inf
    finite = np.isfinite(returns)
    if top.any() or not finite.any():  # all weight on +inf; or every episode at -inf: nothing to rank
        support = top if top.any() else np.ones(n, dtype=bool)
        weights = support / support.sum()
        return weights, float("nan"), float(np.log(n / support.sum()))
    left = epsilon - np.log(n / finite.sum())  # KL(w ‖ uniform) = KL over the finite ones + log(N / #finite)
    weights = np.zeros(n)
    if left > 0:
        weights[finite], eta, _ = reps_weights(returns[finite], left)
    else:
        weights[finite], eta = 1.0 / finite.sum(), float("inf")
    positive = weights[weights > 0]
    return weights, eta, float(positive @ np.log(n * positive))


def _log_weights(r: np.ndarray, eta: float) -> tuple[np.ndarray, float]:
    """Normalised log weights ``r / η - logsumexp(r / η)`` and their ``KL(w ‖ uniform)``."""
    log_w = r / eta
    log_w = log_w - logsumexp(log_w)
    return log_w, float(np.exp(log_w) @ (log_w + np.log(r.shape[0])))


class REPS(AbstractEpisodicSearch):
    """Episodic REPS over the feed-forward terms of a time-varying linear-Gaussian policy.

    See the module docstring for the algorithm and `REPSConfig` for the hyperparameters.
    History rows add ``eta`` (the dual's temperature), ``kl`` (``KL(w ‖ uniform)``),
    ``policy_std`` (mean standard deviation of the policy after the update), ``std_floor`` (the
    exploration floor) and, with ``feedback="fitted"`` (the default), ``feedback_gain`` (docs/agents.md).

    Example:
        >>> from tl_gym.agents import REPS
        >>> agent = REPS("TLCarNav-v0", seed=0, n_episodes=8).learn(2)
        >>> [row["iteration"] for row in agent.history]
        [1, 2]
    """

    config: REPSConfig
    config_class = REPSConfig
    kl_field = "epsilon"


    def _update(self, iteration: int) -> dict[str, Any]:
        seed = int(self.rng.integers(2**31 - 1))
        feedforward = self.policy.sample_feedforward(self.config.n_episodes, self.rng)
        batch = rollout(self.env, feedforward, self.policy.feedback, seed=seed)
        weights, eta, kl = reps_weights(batch.robustness, kl_bound_for(self.config.epsilon, self.config.n_episodes))
        floor = self.config.std_floor(iteration)
        refit = self._refit(batch, feedforward, weights, floor)
        return {
            "env_steps": batch.env_steps,
            "mean_robustness": batch.mean_robustness,
            "success_rate": batch.success_rate,
            "eta": eta,
            "kl": kl,
            "policy_std": float(self.policy.std.mean()),
            "std_floor": floor,
            **refit,
        }
