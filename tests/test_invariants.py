"""Safety invariants settle a verdict early: tested against the reference semantics."""

from __future__ import annotations

import math
import pickle

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tests import reference
from tests.strategies import SIGNALS, formulas, traces
from tl_gym import UnknownSignalError, parse
from tl_gym.tltl import ast as nodes
from tl_gym.tltl.invariants import InvariantMonitor, safety_invariants

TEMPORAL_FREE = (nodes.Not, nodes.And, nodes.Or, nodes.Implies)


@st.composite
def formulas_with_invariants(draw: st.DrawFn) -> nodes.Formula:
    """``φ1 & … & G ψ1 & …``: any conjuncts (deep ones too) beside one to three invariants."""
    invariants = [nodes.Always(draw(formulas(max_depth=4, operators=TEMPORAL_FREE)))
                  for _ in range(draw(st.integers(1, 3)))]
    others = draw(st.lists(formulas(max_depth=draw(st.sampled_from((3, 8)))), max_size=2))
    operands = draw(st.permutations(invariants + others))
    return operands[0] if len(operands) == 1 else nodes.And(tuple(operands))


def _state(trace, t):
    return {name: float(values[t]) for name, values in trace.items()}


@settings(max_examples=300, deadline=None)
@given(formulas_with_invariants(), traces(max_length=8), st.sampled_from((math.inf, 2.0)))
def test_a_broken_invariant_settles_every_longer_prefix(formula, trace, rho_max):
    assume(reference.is_defined(formula, trace))
    monitor = InvariantMonitor(formula, rho_max)
    length = len(trace[SIGNALS[0]])
    for k in range(length):
        state = _state(trace, k)
        broken = monitor.broken(state)
        # it names the first invariant whose ψ is not positive at s_k, by the reference's margin
        expected = next((g for g in safety_invariants(formula)
                         if not reference.robustness(g.child, {n: v[k:k + 1] for n, v in trace.items()}, rho_max) > 0),
                        None)
        assert broken == expected
        if broken is not None:  # no prefix through s_k satisfies the formula: ρ ≤ 0 for each
            for end in range(k + 1, length + 1):
                prefix = {n: v[:end] for n, v in trace.items()}
                assert not reference.robustness(formula, prefix, rho_max) > 0


def test_only_top_level_always_of_a_temporal_free_formula_counts():
    assert [str(f) for f in safety_invariants(parse("G(x < 1)"))] == ["G x < 1"]
    for text in ("F(x > 1)", "G(x < 1) | F(y > 0)", "G(F(x > 1))", "G(x < 1 -> X y > 0)", "!F(x > 1)"):
        assert safety_invariants(parse(text)) == (), text
    with pytest.raises(ValueError, match=r"F x > 1 has no safety invariant"):
        InvariantMonitor(parse("F(x > 1)"))


def test_bad_input_is_named_and_the_monitor_pickles():
    monitor = InvariantMonitor(parse("F(x > 2) & G(y < 5)"))
    with pytest.raises(UnknownSignalError, match="'y'.*G y < 5"):
        monitor.broken({"x": 0.0})
    with pytest.raises(ValueError, match="rho_max"):
        InvariantMonitor(parse("G(y < 5)"), rho_max=-1.0)
    copy = pickle.loads(pickle.dumps(InvariantMonitor(parse("G(y < 5) & G(x > 0)"), rho_max=2.0)))
    assert copy.rho_max == 2.0 and str(copy.broken({"x": -1.0, "y": 0.0})) == "G x > 0"
