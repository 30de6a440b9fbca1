"""Shortcuts of the exact evaluator give the general path's answers, errors included."""

import math

import numpy as np
import pytest
from hypothesis import given

from tests import strategies as S
from tl_gym import TraceError, parse
from tl_gym.tltl import exact, operators
from tl_gym.tltl import trace as trace_module

# F/G of a predicate over sqrt/exp/log take the extreme before the function (position 0 only);
# robustness_over_time never takes the shortcut, so its entry 0 is the general path's value.
MONOTONE = [
    "G(sqrt((x - 1)^2 + y^2) > 1)",
    "F(sqrt(x^2 + y^2) >= 2)",
    "G(2 < exp(x / 3))",
    "F(3 > log(x^2 + 1))",
    "G(log(x^2 + 1) <= 1.5)",
    "F(1 <= sqrt(abs(y)))",
]


@pytest.mark.parametrize("text", MONOTONE)
def test_monotone_shortcut_equals_the_general_path(text, monkeypatch):
    rng = np.random.default_rng(0)
    trace = {"x": rng.normal(0, 2, (64, 25)), "y": rng.normal(0, 2, (64, 25))}
    taken = []  # the shortcut's runs: without any, both sides below would be the general path
    shortcut = exact._monotone_extreme
    monkeypatch.setattr(exact, "_monotone_extreme", lambda *a: taken.append(1) or shortcut(*a))
    formula = parse(text)
    np.testing.assert_array_equal(formula.robustness(trace, backend="numpy"), formula.robustness_over_time(trace)[:, 0])
    row = {k: v[0] for k, v in trace.items()}
    assert formula.robustness(row, backend="numpy") == formula.robustness_over_time(trace)[0, 0]
    assert len(taken) == 2


@pytest.mark.parametrize("text", ["G(sqrt(x) > 1)", "F(log(x) < 0)", "G(exp(x) > 0)"])
def test_monotone_shortcut_refuses_what_the_general_path_refuses(text):
    trace = {"x": np.array([[1.0, 4.0, -1.0, 800.0]])}
    with pytest.raises(TraceError, match=r"position (2|3)"):
        parse(text).robustness(trace)


def test_signal_versus_number_skips_no_real_overflow():
    # x - (-1e308) overflows although x is finite: the magnitude bound must send it to the check
    with pytest.raises(TraceError, match="position 0"):
        parse("x > -1e308").robustness({"x": [1e308, 0.0]})
    assert parse("x > 240").robustness({"x": [250.0, 0.0]}) == 10.0


@pytest.mark.parametrize(
    "text", ["F(x > 1 & y < 0) & G(sqrt(x^2 + y^2) > 0.1)", "(x > 0) T (y > 1) T (x < -1)", "G(x > 0 -> X F(y < 0))",
             "(F x > 2) U (y > 1)"])
def test_groups_of_trajectories_change_nothing(text, monkeypatch):
    rng = np.random.default_rng(3)
    trace = {"x": rng.normal(1, 1.5, (37, 9)), "y": rng.normal(0, 1.5, (37, 9))}
    formula = parse(text)
    whole = [formula.robustness(trace), formula.robustness_over_time(trace), formula.satisfied(trace)]
    monkeypatch.setattr(trace_module, "CHUNK_ELEMENTS", 1)  # groups of 16 trajectories: 16 + 16 + 5
    assert len(trace_module.chunks(37, 9)) == 3
    grouped = [formula.robustness(trace), formula.robustness_over_time(trace), formula.satisfied(trace)]
    for got, expected in zip(grouped, whole):
        np.testing.assert_array_equal(got, expected)


def test_errors_name_the_trajectory_of_the_whole_batch_not_of_its_group(monkeypatch):
    monkeypatch.setattr(trace_module, "CHUNK_ELEMENTS", 1)
    x = np.ones((37, 9))
    x[20, 3] = -200.0
    with pytest.raises(TraceError, match="trajectory 20, position 3"):
        parse("F(sqrt(x + 100) > 1)").robustness({"x": x})


@given(S.formulas(min_depth=3, leaves=S.predicates(exprs=S.safe_expressions())), S.batched_traces())
def test_rewritten_plan_equals_the_plain_plan(formula, trace):
    """The rewrites of the exact plan, all and each alone, against the plain plan, bit for bit."""
    for alg in (operators.numeric(math.inf), operators.BOOLEAN):
        plain, _ = exact._evaluate(formula, trace, alg, first=True, rewrite=False)
        for rewrite in (True, *(frozenset({name}) for name in exact.REWRITES)):
            rewritten, _ = exact._evaluate(formula, trace, alg, first=True, rewrite=rewrite)
            np.testing.assert_array_equal(rewritten, plain)
