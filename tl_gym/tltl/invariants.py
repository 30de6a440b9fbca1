"""Safety invariants: the top-level conjuncts ``G ψ`` that settle a formula's verdict early.

A conjunct ``G ψ`` of the formula, with ψ temporal-free, bounds the robustness of the whole
trace by every state's ψ: ``ρ(φ1 & … & G ψ & …) ≤ ρ(G ψ) = min_t ψ(s_t) ≤ ψ(s_k)`` for any
position k. So as soon as one state has ``ψ(s_k) ≤ 0``, no continuation of the trace can
satisfy the formula (ρ > 0): its verdict is settled, whatever comes next. `InvariantMonitor`
watches the states one at a time and names the first invariant a state breaks; the wrapper's
``end_on_violation`` ends the episode there (`tl_gym.TLTLRewardWrapper`).

The check is sound but not complete: it sees only the invariants at the top of the formula
(the operands of its n-ary ``&``, or the formula itself), not every way a prefix can settle a
verdict (``G`` under ``|``, over a temporal ψ, or written ``!F`` is not looked into; a reach part
``F φ`` never settles one, as the future may still meet it).

Example:
    >>> from tl_gym import parse
    >>> monitor = InvariantMonitor(parse("F(x > 2) & G(x < 5)"))
    >>> [str(i) for i in monitor.invariants]
    ['G x < 5']
    >>> [monitor.broken({"x": v}) for v in (0.0, 3.0)]
    [None, None]
    >>> str(monitor.broken({"x": 6.0}))
    'G x < 5'
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from tl_gym.errors import UnknownSignalError
from tl_gym.tltl import ast as nodes
from tl_gym.tltl.ast import Formula, conjuncts
from tl_gym.tltl.trace import check_rho_max
from tl_gym.tltl.windowed import compile_state_formula


def safety_invariants(formula: Formula) -> tuple[Formula, ...]:
    """The top-level conjuncts of ``formula`` of the form ``G ψ`` with ψ temporal-free.

    Example:
        >>> from tl_gym import parse
        >>> [str(f) for f in safety_invariants(parse("F(x > 2) & G(x < 5) & G(y > 0 | x > 1)"))]
        ['G x < 5', 'G (y > 0 | x > 1)']
        >>> safety_invariants(parse("F(x > 2) | G(x < 5)"))
        ()
    """
    return tuple(c for c in conjuncts(formula) if isinstance(c, nodes.Always) and not c.child.is_temporal)


class InvariantMonitor:
    """Which safety invariant of a formula (`safety_invariants`) a state breaks, if any.

    Args:
        formula: the formula; it must have at least one safety invariant.
        rho_max: the robustness of ``true`` in the invariants.

    Raises:
        ValueError: the formula has no top-level conjunct ``G ψ`` with ψ temporal-free (the
            message names the formula): nothing could ever settle its verdict early here.
    """

    def __init__(self, formula: Formula, rho_max: float = math.inf):
        self.formula = formula
        self.rho_max = check_rho_max(rho_max)
        self.invariants = safety_invariants(formula)
        if not self.invariants:
            raise ValueError(f"{formula} has no safety invariant (a top-level conjunct G ψ with ψ temporal-free), "
                             f"so no state can settle its verdict early")
        self._checks = [(invariant, compile_state_formula(invariant.child, self.rho_max))
                        for invariant in self.invariants]

    def broken(self, state: Mapping[str, float]) -> Formula | None:
        """The first invariant ``G ψ`` with ``ψ(state) ≤ 0`` (the formula cannot hold any more), else None.

        Raises:
            UnknownSignalError: ``state`` lacks a signal an invariant reads.
        """
        for invariant, check in self._checks:
            try:
                value = check(state)
            except KeyError as exc:
                raise UnknownSignalError(f"the state has no signal {exc.args[0]!r}, which {invariant} reads") from None
            if not value > 0:
                return invariant
        return None

    def __reduce__(self) -> tuple[type, tuple[Formula, float]]:
        """Pickled and copied as its formula: the checks are compiled functions."""
        return InvariantMonitor, (self.formula, self.rho_max)
