"""The engine against the naive reference (`tests/reference.py`) and hand-worked tables.

Hypothesis draws formulas with every operator (nesting depth ≥ 4, ``U``/``T`` with
temporal left operands included) and short traces (T = 1 … 7), batched and not; the
exact, Boolean and smoothed values must match the reference to 1e-9 (relative for
large values), with ±∞ matching exactly. The tables below follow rtamt's tests: one
per operator on a 3–5-step trace, each value worked out by hand from the paper.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import tests.reference as ref
from tests import strategies as S
from tl_gym import TraceError, parse

INF = math.inf


def assert_matches(got, expected, tol: float = 1e-9, what: str = "") -> None:
    """Equal to ``tol`` (relative above 1), infinities exactly, never NaN."""
    got = np.asarray(got, dtype=np.float64)
    expected = np.asarray(expected, dtype=np.float64)
    assert got.shape == expected.shape, f"{what}: shape {got.shape} != {expected.shape}"
    assert not np.isnan(got).any(), f"{what}: NaN in {got}"
    infinite = np.isinf(expected)
    assert np.array_equal(got[infinite], expected[infinite]), f"{what}: got {got}, expected {expected}"
    assert np.array_equal(np.isinf(got), infinite), f"{what}: got {got}, expected {expected}"
    err = np.abs(got[~infinite] - expected[~infinite])
    scale = np.maximum(1.0, np.abs(expected[~infinite]))
    assert (err <= tol * scale).all(), f"{what}: got {got}, expected {expected}"


def _row(trace: dict, i: int) -> dict:
    return {k: v[i] for k, v in trace.items()}


# --------------------------------------------------------------------------- exact and Boolean


@given(S.formulas(min_depth=4), S.batched_traces(), S.rho_maxes())
def test_exact_matches_reference(formula, trace, rho_max):
    assume(ref.is_defined(formula, trace))
    expected = ref.robustness_over_time(formula, trace, rho_max)
    assert_matches(formula.robustness_over_time(trace, rho_max), expected, what="over time, batched")
    assert_matches(formula.robustness(trace, rho_max), expected[:, 0], what="batched")
    for i in range(expected.shape[0]):
        row = _row(trace, i)
        assert_matches(formula.robustness_over_time(row, rho_max), expected[i], what=f"over time, row {i}")
        value = formula.robustness(row, rho_max)
        assert isinstance(value, float)
        assert_matches(value, expected[i, 0], what=f"row {i}")


@given(S.formulas(min_depth=4), S.batched_traces())
def test_satisfied_matches_reference(formula, trace):
    assume(ref.is_defined(formula, trace))
    expected = ref.satisfied(formula, trace)
    got = formula.satisfied(trace)
    assert got.dtype == np.bool_ and np.array_equal(got, expected)
    for i in range(len(expected)):
        value = formula.satisfied(_row(trace, i))
        assert isinstance(value, bool) and value == expected[i]


@given(S.formulas(max_depth=3, leaves=S.predicates(exprs=S.expressions(depth=2, numbers=S.small_numbers()))),
       S.traces())
def test_unsafe_arithmetic_is_refused_or_matches(formula, trace):
    """Any arithmetic (division, log, sqrt, ^ of anything): a TraceError, or the reference's value.

    The engine may refuse a trace on which some predicate is undefined at some
    position (whether or not the formula reads it there); when it answers, the
    answer must be the reference's, which reads only the positions it needs. The
    smoother also refuses predicate values beyond its range (|β·ρ| ≥ 5e299).
    """
    smooth = (
        lambda tr: formula.smooth_robustness(tr, 1.0),
        lambda f, tr, eager: ref.smooth_robustness(f, tr, 1.0, eager=eager),
    )
    for method, reference in (
        (formula.robustness, ref.robustness),
        (formula.robustness_over_time, ref.robustness_over_time),
        smooth,
    ):
        try:
            got = method(trace)
        except TraceError as error:
            if method is smooth[0] and "too large to smooth" in str(error):  # |β·ρ| beyond 5e299 at β = 1
                assert ref.largest_margin(formula, trace) >= 5e299
                continue
            assert not ref.is_defined(formula, trace)
            continue
        assert_matches(got, reference(formula, trace, eager=False))
    try:
        got = formula.satisfied(trace)
    except TraceError:
        assert not ref.is_defined(formula, trace)
    else:
        assert got == ref.satisfied(formula, trace, eager=False)


# --------------------------------------------------------------------------- smoothed


@given(S.formulas(min_depth=4), S.batched_traces(max_length=6), S.betas(), S.rho_maxes())
def test_smooth_matches_reference(formula, trace, beta, rho_max):
    assume(ref.is_defined(formula, trace))
    expected = ref.smooth_over_time(formula, trace, beta, rho_max)
    assert_matches(formula.smooth_robustness(trace, beta, rho_max), expected[:, 0], what="numpy batched")
    tensors = {k: torch.tensor(v) for k, v in trace.items()}
    got = formula.smooth_robustness(tensors, beta, rho_max)
    assert isinstance(got, torch.Tensor) and got.dtype == torch.float64
    assert_matches(np.asarray(got), expected[:, 0], what="torch batched")
    assert_matches(np.asarray(formula.smooth_robustness_over_time(trace, beta, rho_max)), expected, what="over time")
    over_time = formula.smooth_robustness_over_time(tensors, beta, rho_max)
    assert isinstance(over_time, torch.Tensor)
    assert_matches(over_time.numpy(), expected, what="torch over time")
    row = _row(trace, 0)
    value = formula.smooth_robustness(row, beta, rho_max)
    assert isinstance(value, float)
    assert_matches(value, expected[0, 0], what="numpy row 0")
    assert_matches(np.asarray(formula.smooth_robustness(_row(tensors, 0), beta, rho_max)), expected[0, 0], what="torch")


@pytest.mark.parametrize(("text", "expected"), [("true | false", INF), ("!!false", -INF), ("X true", INF),
                                              ("true U false", -INF)])
def test_signal_free_formula_keeps_torch(text, expected):
    """Torch in, torch out, even when the formula reads no signal of the trace (engine bug 1)."""
    value = parse(text).smooth_robustness({"x": torch.tensor([1.0, 2.0])}, 1.0)
    assert isinstance(value, torch.Tensor) and value.dtype == torch.float64 and value.shape == ()
    assert value.item() == expected  # (X true at position 0 reads `true` at position 1)


@settings(max_examples=min(settings().max_examples, 30))
@given(S.formulas(min_depth=2, max_depth=4, leaves=S.predicates(exprs=S.smooth_expressions())),
       S.traces(max_length=6), st.sampled_from(S.BETAS))
def test_smooth_values_and_gradients_are_never_nan(formula, trace, beta):
    """β from 0.1 to 1e6 on traces with large values: finite or ±∞ values, finite gradients.

    (Predicates use differentiable arithmetic: a kink such as sqrt(abs(x)) at 0 has an
    undefined derivative whatever the smoothing.)
    """
    assume(ref.is_defined(formula, trace))
    tensors = {k: torch.tensor(v * 100.0, requires_grad=True) for k, v in trace.items()}
    assume(ref.is_defined(formula, {k: v * 100.0 for k, v in trace.items()}))
    value = formula.smooth_robustness(tensors, beta)
    assert not torch.isnan(value)
    if value.requires_grad:
        value.backward()
        for name, tensor in tensors.items():
            if tensor.grad is not None:
                assert torch.isfinite(tensor.grad).all(), (name, tensor.grad)


# --------------------------------------------------------------------------- hand-worked tables

# One trajectory of five steps, the values chosen so that every operator's answer
# is distinct at each position. p: x > 0 (robustness x), q: y > 0 (robustness y).
X5 = [1.0, -2.0, 3.0, 0.5, -1.0]
Y5 = [-1.0, -3.0, 2.0, 4.0, -0.5]
TRACE5 = {"x": X5, "y": Y5}

TABLES = [
    # formula, robustness at positions 0..4 (worked by hand from section II-A)
    ("x > 0", [1.0, -2.0, 3.0, 0.5, -1.0]),
    ("x >= 0", [1.0, -2.0, 3.0, 0.5, -1.0]),
    ("x < 0", [-1.0, 2.0, -3.0, -0.5, 1.0]),
    ("0 <= x", [1.0, -2.0, 3.0, 0.5, -1.0]),
    ("2 * x - 1 > y", [2.0, -2.0, 3.0, -4.0, -2.5]),
    ("!(x > 0)", [-1.0, 2.0, -3.0, -0.5, 1.0]),
    ("x > 0 & y > 0", [-1.0, -3.0, 2.0, 0.5, -1.0]),
    ("x > 0 | y > 0", [1.0, -2.0, 3.0, 4.0, -0.5]),
    ("x > 0 -> y > 0", [-1.0, 2.0, 2.0, 4.0, 1.0]),
    ("X x > 0", [-2.0, 3.0, 0.5, -1.0, -INF]),
    ("X X x > 0", [3.0, 0.5, -1.0, -INF, -INF]),
    ("F x > 0", [3.0, 3.0, 3.0, 0.5, -1.0]),
    ("G x > 0", [-2.0, -2.0, -1.0, -1.0, -1.0]),
    ("F G y > -1", [0.5, 0.5, 0.5, 0.5, 0.5]),  # y + 1 = [0, -2, 3, 5, 0.5]
    ("G F x > 0", [-1.0, -1.0, -1.0, -1.0, -1.0]),
    # U(t) = max over t' >= t of min(y(t'), min of x over [t, t')), non-strict:
    # t=4: y4=-0.5. t=3: max(4, min(0.5, -0.5)) = 4. t=2: max(2, min(3, 4), ...) = 3.
    # t=1: max(-3, min(-2, ...)) = -2. t=0: max(-1, min(1, -3), min(1, -2, 2), ...) = -1.
    ("x > 0 U y > 0", [-1.0, -2.0, 3.0, 4.0, -0.5]),
    # T(t) = max over t' > t'' >= t of min(y(t'), x(t'')); none at the last position.
    # t=3: min(y4, x3) = -0.5. t=2: max(min(4, 3), ...) = 3. t=1, t=0: 3 (x2 then y3).
    ("x > 0 T y > 0", [3.0, 3.0, 3.0, -0.5, -INF]),
    # Temporal left operand, judged on the truncated segment s_{t''..t'-1}:
    # (F x > 0) U y > 0 at t=0: t'=3 needs F x>0 on s_0..s_2 at t''=0,1,2 = 3,3,3 and y3=4 -> 3;
    # t'=2: F on s_0..s_1 at 0,1 = 1,-2 -> min(2, -2) = -2; t'=0: -1; t'=1: min(-3, 1) = -3.
    ("(F x > 0) U y > 0", [3.0, 3.0, 3.0, 4.0, -0.5]),
    # (X x > 0) T y > 0 at t=3: t'=4 needs X x > 0 on s_0..s_3 at 3: no next state, -inf.
    # t=2: t'=3: X on s_0..s_2 at 2 is -inf; t'=4: X on s_0..s_3 at 2,3 = 0.5, -inf -> max 0.5,
    # min(-0.5, 0.5) = -0.5. t=0: t'=3 with X on s_0..s_2 at 0,1,2 = -2, 3, -inf -> min(4, 3) = 3.
    ("(X x > 0) T y > 0", [3.0, 3.0, -0.5, -INF, -INF]),
    ("true", [INF] * 5),
    ("false", [-INF] * 5),
    ("F (x > 0 & y > 0) & G (x > -3)", [1.0, 1.0, 2.0, 0.5, -1.0]),
]


@pytest.mark.parametrize(("text", "expected"), TABLES, ids=[t for t, _ in TABLES])
def test_operator_table(text, expected):
    formula = parse(text)
    assert_matches(formula.robustness_over_time(TRACE5), expected, what=text)
    assert_matches(ref.robustness_over_time(formula, TRACE5), expected, what=f"reference {text}")


def test_paper_example():
    """Section II-A: F(s > 5 & s < 10) on [11, 6, 7] is max(-1, 1, 2) = 2."""
    formula = parse("F(s > 5 & s < 10)")
    assert formula.robustness({"s": [11.0, 6.0, 7.0]}) == 2.0
    assert formula.satisfied({"s": [11.0, 6.0, 7.0]})
    assert formula.robustness({"s": np.array([[11.0, 6.0, 7.0], [11.0, 12.0, 4.0]])}).tolist() == [2.0, -1.0]


def test_next_at_the_last_state_is_minus_rho_max():
    formula = parse("X s > 0")
    assert formula.robustness({"s": [5.0]}) == -INF
    assert formula.robustness({"s": [5.0]}, rho_max=7.0) == -7.0
    assert formula.robustness({"s": [5.0, 2.0]}, rho_max=7.0) == 2.0
    assert formula.robustness_over_time({"s": [5.0, 2.0]}, rho_max=7.0).tolist() == [2.0, -7.0]
    assert not formula.satisfied({"s": [5.0]})
    assert formula.smooth_robustness({"s": [5.0]}, 2.0, rho_max=7.0) == -7.0
    assert formula.smooth_robustness({"s": [5.0]}, 2.0) == -INF


@pytest.mark.parametrize("rho_max", [INF, 3.0])
def test_true_and_false_are_plus_minus_rho_max(rho_max):
    trace = {"s": [1.0, -1.0]}
    assert parse("true").robustness(trace, rho_max) == rho_max
    assert parse("false").robustness(trace, rho_max) == -rho_max
    assert parse("true").satisfied(trace) and not parse("false").satisfied(trace)
    assert parse("true").smooth_robustness(trace, 1.0, rho_max) == rho_max
    assert parse("s > 0 | false").robustness(trace, rho_max) == 1.0
    # a finite rho_max is a term of the smooth max like any other: log(e^3 + e^1) at β = 1
    expected = math.log(math.exp(3.0) + math.exp(1.0)) if math.isfinite(rho_max) else INF
    assert parse("s > 0 | true").smooth_robustness(trace, 1.0, rho_max) == pytest.approx(expected, rel=1e-12)


def test_strict_and_non_strict_comparisons():
    trace = {"s": [2.0]}
    assert not parse("s < 2").satisfied(trace) and parse("s <= 2").satisfied(trace)
    assert not parse("s > 2").satisfied(trace) and parse("s >= 2").satisfied(trace)
    for text in ("s < 2", "s <= 2", "s > 2", "s >= 2"):
        assert parse(text).robustness(trace) == 0.0


@pytest.mark.parametrize("beta", [0.5, 4.0])
def test_smoothed_until_hand_worked(beta):
    """x > 0 U y > 0 on 3 steps, smoothed in the prescribed nesting, written out term by term."""
    x, y = [1.0, -2.0, 3.0], [-1.0, 0.5, 2.0]

    def smax(*v):
        return math.log(sum(math.exp(beta * a) for a in v)) / beta

    def smin(*v):
        return -smax(*(-a for a in v))

    # t' = 0: y0 alone (empty inner min); t' = 1: smin(y1, x0); t' = 2: smin(y2, smin(x0, x1))
    expected = smax(y[0], smin(y[1], x[0]), smin(y[2], smin(x[0], x[1])))
    got = parse("x > 0 U y > 0").smooth_robustness({"x": x, "y": y}, beta)
    assert got == pytest.approx(expected, rel=1e-12)
    # and Then: the inner max over t'' (empty at t' = 0, dropped)
    expected_then = smax(smin(y[1], x[0]), smin(y[2], smax(x[0], x[1])))
    assert parse("x > 0 T y > 0").smooth_robustness({"x": x, "y": y}, beta) == pytest.approx(expected_then, rel=1e-12)
