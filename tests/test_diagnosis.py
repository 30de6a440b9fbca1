"""tl_gym.diagnosis: which top-level conjunct broke, episode by episode."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import tests.reference as ref
from tests import strategies as S
from tl_gym import parse
from tl_gym.diagnosis import conjunct_breakdown, format_breakdown
from tl_gym.errors import UnknownSignalError
from tl_gym.tltl.ast import And, conjuncts


@st.composite
def episodes(draw: st.DrawFn) -> dict[str, list[np.ndarray]]:
    """1 … 4 episodes of different lengths over the strategies' signals."""
    runs = draw(st.lists(S.traces(max_length=6, rescale=False), min_size=1, max_size=4))
    return {name: [run[name] for run in runs] for name in S.SIGNALS}


@given(S.formulas(min_depth=1, max_depth=4), episodes(), S.rho_maxes())
def test_breakdown_agrees_with_the_reference_per_conjunct_and_in_its_min(formula, traces, rho_max):
    rows = conjunct_breakdown(formula, traces, rho_max)
    parts = conjuncts(formula)
    n = len(traces["x"])
    assert [r.conjunct for r in rows] == [str(p) for p in parts]
    for part, row in zip(parts, rows):
        expected = [ref.robustness(part, {k: v[i] for k, v in traces.items()}, rho_max) for i in range(n)]
        np.testing.assert_allclose(row.robustness, expected, rtol=1e-9, atol=1e-9)
        assert row.violated == int(np.sum(row.robustness <= 0))
        assert row.median == float(np.quantile(expected, 0.5, method="lower"))
    whole = np.array([ref.robustness(formula, {k: v[i] for k, v in traces.items()}, rho_max) for i in range(n)])
    lowest = np.min([r.robustness for r in rows], axis=0)
    np.testing.assert_allclose(lowest, whole, rtol=1e-9, atol=1e-9)  # & is the min of its conjuncts
    failures = int(np.sum(lowest <= 0))
    assert all(r.failures == failures for r in rows)
    # every failed episode has at least one lowest conjunct, and none counts more often than the failures
    assert failures <= sum(r.lowest for r in rows) <= failures * len(rows)


def test_a_formula_that_is_no_conjunction_is_its_own_one_conjunct():
    phi = parse("F(x > 1) | G(x < 0)")
    assert not isinstance(phi, And)
    (row,) = conjunct_breakdown(phi, {"x": [np.array([0.0, 2.0]), np.array([0.5])]})
    assert row.conjunct == str(phi) and list(row.robustness) == [1.0, -0.5]
    assert (row.violated, row.lowest, row.failures) == (1, 1, 1)


def test_ties_count_for_each_lowest_conjunct():
    phi = parse("F(x > 1) & G(y < 1)")
    rows = conjunct_breakdown(phi, {"x": [np.array([0.0])], "y": [np.array([2.0])]})  # both at -1
    assert [r.lowest for r in rows] == [1, 1] and rows[0].failures == 1


def test_format_breakdown_aligns_the_columns():
    phi = parse("F(x > 2) & G(v < 1)")
    text = format_breakdown(conjunct_breakdown(phi, {"x": [np.array([0.0])], "v": [np.array([0.0])]}))
    header, first, second = text.splitlines()
    assert header.index("violated in") == first.index("1 of 1") == second.index("0 of 1")
    assert "lowest in the 1 failures" in header and format_breakdown([]) == ""


@pytest.mark.parametrize("traces, match", [
    ({"x": []}, "same number"),
    ({"x": [np.zeros(2)], "v": [np.zeros(2), np.zeros(2)]}, "same number"),
])
def test_bad_traces_are_named(traces, match):
    with pytest.raises(ValueError, match=match):
        conjunct_breakdown(parse("F(x > 0) & G(v < 1)"), traces)


def test_a_missing_signal_is_named():
    with pytest.raises(UnknownSignalError, match="no signal .v."):
        conjunct_breakdown(parse("F(x > 0) & G(v < 1)"), {"x": [np.zeros(2)]})


def test_the_median_is_defined_when_robustness_is_infinite():
    (row,) = conjunct_breakdown(parse("X true"), {"x": [np.zeros(1), np.zeros(2)]})  # -inf, then +inf
    assert list(row.robustness) == [-math.inf, math.inf] and row.median == -math.inf


def test_rho_max_bounds_true():
    (row,) = conjunct_breakdown(parse("true"), {"x": [np.zeros(1)]}, rho_max=3.0)
    assert row.robustness[0] == 3.0 and row.median == 3.0
