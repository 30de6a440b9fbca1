"""Hierarchical potential-based shaping from a TLTL formula (``reward_mode="potential"``).

The dense prefix increments of `tl_gym.TLTLRewardWrapper` follow the minimum over the
formula's conjuncts: while the worst conjunct does not move, progress on the others pays
nothing (task 2 of the car: driving to the first goal does not change the margin of the
third). Following Berducci et al., "Hierarchical potential-based reward shaping from task
specifications" (HPRS, 2021), `HierarchicalPotential` scores the top-level conjuncts by
kind and orders them:

* **safety** (``G``, "never again", Boolean and bounded-lookahead conjuncts): 1 while the
  conjunct's prefix robustness is > 0, else 0 (once broken, a ``G`` stays broken);
* **targets**: ``F φ`` scores 1 once satisfied, else ``exp(φ(s_t) / scale)`` (closeness of the
  current state, 1 at the boundary); a chain ``φ1 T … T φm`` (or ``F`` of one) scores
  ``(k + closeness of φ_{k+1}(s_t)) / m`` after its first ``k`` operands were met in order;
  ``φ U ψ`` scores like ``F ψ`` while φ has held up to s_t, 0 once φ failed before ψ was met;
  ``F`` of any other temporal operand scores 1 once met, else 0.

``Φ = scale · (Σ safety + Π safety · mean target)``: targets count only while every safety
conjunct holds, as in HPRS. The wrapper pays ``γ Φ(s_{t+1}) − Φ(s_t)`` on top of the dense
increments, with ``Φ(s_T) = 0`` at the last state, so an episode's rewards add up to
``clip(ρ) − Φ(s_0)`` for ``γ = 1``: the terminal robustness shifted by a constant of the start
state, which changes no optimal policy (Ng, Harada and Russell, 1999). Φ is a function of the
monitor's state and of the current signals, so it is Markov in the ``observe_monitor`` view
when the signals are read from the observation.

Example:
    >>> from tl_gym import parse
    >>> phi = HierarchicalPotential(parse("F(x > 2) & G(x < 5)"), scale=1.0)
    >>> round(phi.update({"x": 0.0}), 4)  # safe (1) + exp(-2) of the way to the target
    1.1353
    >>> phi.update({"x": 3.0}), phi.update({"x": 6.0})  # target met; then the safety broken
    (2.0, 0.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from tl_gym.checks import check_positive
from tl_gym.tltl.ast import Eventually, Formula, Then, Until, conjuncts
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.windowed import compile_state_formula

State = Mapping[str, float]


def satisfaction_value(value: Any, bonus: float, satisfied: Any = None) -> Any:
    """``value + bonus · [satisfied]``, ``satisfied`` defaulting to ``value > 0``: the robustness as paid.

    The one rule of ``satisfaction_bonus`` (`tl_gym.TLTLRewardWrapper`): the wrapper pays this
    monotone transform of the (clipped) robustness instead of the robustness itself, at the end in
    terminal mode and as the potential Φ of the dense increments, so an episode's rewards add up to
    ``clip(ρ) + bonus · [ρ > 0]``. Episodes keep their order by ρ, but every satisfied one now earns
    ``bonus`` more than every violated one, near misses included: success, which the suite counts,
    outweighs a higher mean ρ. Scalars or numpy arrays.

    Example:
        >>> satisfaction_value(0.25, 10.0), satisfaction_value(-0.25, 10.0), satisfaction_value(0.0, 10.0)
        (10.25, -0.25, 0.0)
        >>> import numpy as np
        >>> satisfaction_value(np.array([-1.0, 2.0]), 5.0).tolist()
        [-1.0, 7.0]
    """
    return value + bonus * ((value > 0) if satisfied is None else satisfied)


def discounted_increment(value: Any, previous: Any, gamma: float) -> tuple[Any, Any]:
    """The shaping reward of a step, ``γ Φ(s') − Φ(s)``, and the new potential: ``(γ·value − previous, value)``.

    The one rule of both shapings the wrapper pays (Ng, Harada and Russell, 1999). The hierarchical
    potential of `HierarchicalPotential` (``reward_mode="potential"``) is 0 at the last state.
    ``reward_mode="dense"`` is the same shaping of the terminal robustness, with Φ the clipped prefix
    robustness of the state reached (``value``; 0 at the reset state): a step pays ``γ Φ(s') − Φ(s)``
    and the last one ``ρ − Φ(s)``. An episode of T steps then
    discounts to ``γ^(T-1) ρ``, its terminal robustness (``ρ`` itself at γ = 1), so the agent's optimal
    policies are those of the terminal reward. Plain increments ``Φ(s') − Φ(s)`` under γ < 1 would
    pay for raising the prefix robustness early, i.e. for hurrying. Scalars or numpy arrays.

    Example:
        >>> discounted_increment(2.0, 0.5, gamma=0.9)
        (1.3, 2.0)
    """
    return gamma * value - previous, value


def _closeness(value: float, scale: float) -> float:
    """How near a state is to meeting a predicate of robustness ``value``: 1 at or past the boundary."""
    return 1.0 if value >= 0 else math.exp(value / scale)


class _Safety:
    """1 while the conjunct's prefix robustness is > 0."""

    def __init__(self, formula: Formula, rho_max: float):
        self.monitor = PrefixMonitor(formula, rho_max)

    def reset(self) -> None:
        self.monitor.reset()

    def update(self, s: State) -> float:
        return 1.0 if self.monitor.update(s) > 0 else 0.0


class _Chain:
    """``φ1 T … T φm`` (``m = 1``: ``F φ1``): completed stages plus the closeness of the next one."""

    def __init__(self, operands: list[Formula], rho_max: float, scale: float):
        stages: list[Formula] = []
        for k in range(1, len(operands) + 1):
            chain = operands[k - 1]
            for operand in reversed(operands[: k - 1]):
                chain = Then(operand, chain)
            stages.append(Eventually(chain) if k == 1 else chain)
        self.monitors = [PrefixMonitor(f, rho_max) for f in stages]
        self.formulas, self.rho_max = operands, rho_max
        self.operands = self._compiled()
        self.scale = scale

    def _compiled(self) -> list[Callable[[State], float]]:
        return [compile_state_formula(f, self.rho_max) for f in self.formulas]

    def __getstate__(self) -> dict[str, Any]:  # compiled functions do not pickle: a copy compiles its own
        return {**self.__dict__, "operands": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.operands = self._compiled()

    def reset(self) -> None:
        for monitor in self.monitors:
            monitor.reset()

    def update(self, s: State) -> float:
        done = 0  # leading stages met (a longer chain is only met after the shorter ones)
        for k, monitor in enumerate(self.monitors):
            if monitor.update(s) > 0 and done == k:
                done += 1
        if done == len(self.operands):
            return 1.0
        return (done + _closeness(self.operands[done](s), self.scale)) / len(self.operands)


class _Until:
    """``φ U ψ``: 1 once met, the closeness of ψ while φ has held so far, 0 once φ failed before ψ was met."""

    def __init__(self, formula: Until, rho_max: float, scale: float):
        self.monitor = PrefixMonitor(formula, rho_max)
        self.formula, self.rho_max = formula, rho_max
        self.left, self.right = self._compiled()
        self.scale = scale
        self.reset()

    def _compiled(self) -> tuple[Callable[[State], float], Callable[[State], float]]:
        return compile_state_formula(self.formula.left, self.rho_max), compile_state_formula(self.formula.right,
                                                                                            self.rho_max)

    def __getstate__(self) -> dict[str, Any]:  # compiled functions do not pickle: a copy compiles its own
        return {**self.__dict__, "left": None, "right": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.left, self.right = self._compiled()

    def reset(self) -> None:
        self.monitor.reset()
        self.held = math.inf  # min of φ over the states so far

    def update(self, s: State) -> float:
        met = self.monitor.update(s) > 0
        self.held = min(self.held, self.left(s))  # φ up to s_t: the monitor's own running min
        if met:
            return 1.0
        # once φ failed with ψ still unmet, every later ψ comes after a failure of φ
        return _closeness(self.right(s), self.scale) if self.held > 0 else 0.0


class _Met(_Safety):
    """A target with no measure of closeness (``F`` of a temporal operand): 1 once met, else 0."""


def _chain_operands(formula: Formula) -> list[Formula] | None:
    """The operands of a chain target, or None.

    ``[φ1, …, φm]`` of ``φ1 T (… T φm)`` and of ``F(φ1 T …)``, ``[φ]`` of ``F φ``; all temporal-free.
    """
    if isinstance(formula, Eventually):
        if isinstance(formula.child, Then):  # F(φ1 T …) is the chain itself
            return _chain_operands(formula.child)
        return None if formula.child.is_temporal else [formula.child]
    operands: list[Formula] = []
    node = formula
    while isinstance(node, Then):
        operands.append(node.left)
        node = node.right
    operands.append(node)
    return None if len(operands) < 2 or any(f.is_temporal for f in operands) else operands


class HierarchicalPotential:
    """The HPRS-style potential Φ of a formula's prefix and current state (see the module docstring).

    Args:
        formula: the task formula; its top-level conjuncts are scored by kind.
        rho_max: the robustness of ``true``.
        scale: the robustness units of "close" for targets, and the unit of Φ (> 0).

    Attributes:
        safety: the conjuncts scored as safety requirements (their text).
        targets: the conjuncts scored as targets.
    """

    def __init__(self, formula: Formula, rho_max: float = math.inf, scale: float = 1.0):
        check_positive("scale", scale)
        self.scale = float(scale)
        self._safety: list[_Safety] = []
        self._targets: list[_Chain | _Until] = []
        self.safety: list[str] = []
        self.targets: list[str] = []
        for conjunct in conjuncts(formula):
            operands = _chain_operands(conjunct)
            if operands is not None:
                self._targets.append(_Chain(operands, rho_max, self.scale))
                self.targets.append(str(conjunct))
            elif isinstance(conjunct, Until) and not (conjunct.left.is_temporal or conjunct.right.is_temporal):
                self._targets.append(_Until(conjunct, rho_max, self.scale))
                self.targets.append(str(conjunct))
            elif isinstance(conjunct, Eventually):  # F of a temporal operand: a target, met or not yet
                self._targets.append(_Met(conjunct, rho_max))
                self.targets.append(str(conjunct))
            else:  # G, "never again", state and bounded-lookahead conjuncts, anything else: hold it
                self._safety.append(_Safety(conjunct, rho_max))
                self.safety.append(str(conjunct))

    def reset(self) -> None:
        """Forget the trace; the next `update` is s_0."""
        for part in (*self._safety, *self._targets):
            part.reset()

    def update(self, state: State) -> float:
        """Append one state; return Φ of the prefix so far."""
        safe = [part.update(state) for part in self._safety]
        reached = [part.update(state) for part in self._targets]
        value = sum(safe)
        if reached and all(safe):
            value += sum(reached) / len(reached)
        return self.scale * value
