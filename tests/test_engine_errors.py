"""Bad input gets a clear error naming the culprit, raised before any evaluation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tl_gym import TraceError, UnknownSignalError, parse
from tl_gym.logic import F, G, U, X, implies, not_, signal

PHI = parse("F(x > 1) & G(y < 2)")


def _evaluators(formula):
    """Every public evaluation of a formula, as callables of a trace."""
    return {
        "robustness": lambda tr: formula.robustness(tr),
        "robustness_over_time": lambda tr: formula.robustness_over_time(tr),
        "satisfied": lambda tr: formula.satisfied(tr),
        "smooth_robustness": lambda tr: formula.smooth_robustness(tr, 2.0),
        "smooth_robustness_over_time": lambda tr: formula.smooth_robustness_over_time(tr, 2.0),
    }


EVALUATORS = list(_evaluators(PHI))


@pytest.mark.parametrize("method", EVALUATORS)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_trace_names_signal_and_first_position(method, bad):
    y = [0.0, 1.0, bad, 0.5, bad]
    with pytest.raises(TraceError, match=r"'y'.*position 2") as info:
        _evaluators(PHI)[method]({"x": [0.0, 1.0, 2.0, 3.0, 4.0], "y": y})
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("method", EVALUATORS)
def test_non_finite_batched_trace_names_trajectory_and_position(method):
    y = np.zeros((3, 4))
    y[2, 3] = math.nan
    y[1, 1] = math.inf  # the first bad entry in row-major order
    with pytest.raises(TraceError, match=r"'y'.*trajectory 1, position 1"):
        _evaluators(PHI)[method]({"x": np.ones((3, 4)), "y": y})


def test_non_finite_torch_trace_is_refused():
    y = torch.tensor([0.0, float("nan"), 1.0], requires_grad=True)
    with pytest.raises(TraceError, match=r"'y'.*position 1"):
        PHI.smooth_robustness({"x": torch.zeros(3), "y": y}, 1.0)


def test_a_second_derivative_of_the_smooth_robustness_is_refused():
    """Its gradient comes from numpy: with create_graph=True it would be a constant whose own gradient reads 0."""
    x = torch.tensor([0.0, 0.5, 2.0], dtype=torch.float64, requires_grad=True)
    value = parse("F(x > 1)").smooth_robustness({"x": x}, 5.0)
    with pytest.raises(RuntimeError, match="differentiable once"):
        torch.autograd.grad(value, x, create_graph=True)
    value = parse("F(x > 1)").smooth_robustness({"x": x}, 5.0)
    (gradient,) = torch.autograd.grad(value, x)  # once is fine
    assert gradient[2] > gradient[1] > gradient[0] > 0


def test_nan_in_an_unread_signal_is_ignored():
    trace = {"x": [2.0, 0.0], "y": [0.0, 0.0], "unused": [math.nan, 1.0]}
    assert PHI.robustness(trace) == 1.0


@pytest.mark.parametrize("method", EVALUATORS)
def test_missing_signal_is_named(method):
    with pytest.raises(UnknownSignalError, match="'y'") as info:
        _evaluators(PHI)[method]({"x": [1.0, 2.0], "speed": [0.0, 0.0]})
    assert isinstance(info.value, KeyError)
    assert "speed" in str(info.value)  # and the names it has, to spot a typo


@pytest.mark.parametrize("method", EVALUATORS)
@pytest.mark.parametrize(
    "trace",
    [
        {"x": [1.0, 2.0, 3.0], "y": [1.0, 2.0]},  # lengths differ
        {"x": np.ones((2, 3)), "y": np.ones((3, 3))},  # batch sizes differ
        {"x": np.ones((2, 3)), "y": np.ones(3)},  # batched and not
        {"x": np.ones((2, 2, 2)), "y": np.ones((2, 2, 2))},  # 3-D
        {"x": [], "y": []},  # empty
        {"x": 1.0, "y": 2.0},  # scalars
    ],
    ids=["lengths", "batch", "mixed", "3d", "empty", "scalar"],
)
def test_inconsistent_shapes(method, trace):
    with pytest.raises(TraceError, match="shape"):
        _evaluators(PHI)[method](trace)


def test_non_numeric_signal():
    with pytest.raises(TraceError, match="'x'"):
        PHI.robustness({"x": ["a", "b"], "y": [0.0, 0.0]})


def test_trace_must_be_a_mapping():
    with pytest.raises(TypeError, match="maps signal names"):
        PHI.robustness([[1.0, 2.0]])  # type: ignore[arg-type]


@pytest.mark.parametrize("beta", [0.0, -1.0, math.nan, math.inf, -math.inf])
def test_bad_beta(beta):
    trace = {"x": [1.0], "y": [1.0]}
    with pytest.raises(ValueError, match="beta"):
        PHI.smooth_robustness(trace, beta)
    with pytest.raises(ValueError, match="beta"):
        PHI.smooth_robustness_over_time(trace, beta)
    with pytest.raises(ValueError, match="beta"):
        PHI.smoothing_bracket(5, beta)


@pytest.mark.parametrize("horizon", [0, -3, 2.5])
def test_bad_horizon(horizon):
    with pytest.raises(ValueError, match="horizon"):
        PHI.smoothing_bracket(horizon, 1.0)


BAD_RHO_MAX = [0.0, -1.0, math.nan]


@pytest.mark.parametrize("rho_max", BAD_RHO_MAX)
def test_bad_rho_max_smooth(rho_max):
    with pytest.raises(ValueError, match="rho_max"):
        PHI.smooth_robustness({"x": [1.0], "y": [1.0]}, 1.0, rho_max)


@pytest.mark.parametrize("rho_max", BAD_RHO_MAX)
def test_bad_rho_max_exact(rho_max):
    with pytest.raises(ValueError, match="rho_max"):
        PHI.robustness({"x": [1.0], "y": [1.0]}, rho_max)


def test_bad_form():
    with pytest.raises(ValueError, match="form"):
        PHI.smooth_robustness({"x": [1.0], "y": [1.0]}, 1.0, form="fast")


def test_signal_free_formula_needs_a_length():
    with pytest.raises(TraceError, match="reads no signal, so the trace must hold an array that gives its length"):
        parse("F true").robustness({})
    assert parse("F true").robustness({"anything": [0.0, 0.0]}) == math.inf


# --------------------------------------------------------------------------- predicate arithmetic


@pytest.mark.parametrize("method", EVALUATORS)
@pytest.mark.parametrize(
    ("text", "values"),
    [("sqrt(x) > 0", [1.0, -1.0]), ("log(x) > 0", [1.0, 0.0]), ("1 / x > 0", [1.0, 0.0]), ("x ^ 0.5 > 0", [4.0, -4.0])],
)
def test_undefined_arithmetic_raises_trace_error(method, text, values):
    """NaN/inf from a predicate's arithmetic where it is read: TraceError naming it and the position."""
    with pytest.raises(TraceError, match=r"(?s)" + text.split()[0][:3] + r".*position 1"):
        _evaluators(parse(f"G({text})"))[method]({"x": values})


@pytest.mark.parametrize("method", EVALUATORS)
def test_arithmetic_overflow_raises_trace_error(method):
    """Finite signals whose product overflows: TraceError, not an infinite robustness (engine bug 3)."""
    with pytest.raises(TraceError, match="position 0"):
        _evaluators(parse("F(x * x > 0)"))[method]({"x": [1e200, 1.0]})


# --------------------------------------------------------------------------- builders


@pytest.mark.parametrize("name", ["F", "until", "true", "sqrt", "1x", "x-y", ""])
def test_reserved_or_invalid_signal_names(name):
    with pytest.raises(ValueError, match="signal"):
        signal(name)


def test_formulas_have_no_truth_value():
    with pytest.raises(TypeError, match="&"):
        bool(signal("x") > 1)
    with pytest.raises(TypeError, match="&"):
        (signal("x") > 1) and (signal("y") > 1)  # noqa: B015 - the point is that `and` refuses


def test_builders_reject_non_formulas_and_non_numbers():
    with pytest.raises(TypeError, match="expected a Formula, got str"):
        F(signal("x") > 1) & "y > 1"  # type: ignore[operator]  # noqa: B015
    with pytest.raises(TypeError, match="expected an expression or a number, got str"):
        signal("x") < "3"  # type: ignore[operator]  # noqa: B015
    with pytest.raises(ValueError, match="finite"):
        signal("x") < math.inf  # noqa: B015


@pytest.mark.parametrize(
    "build",
    [lambda: F(signal("x")), lambda: G("x > 1"), lambda: U(signal("x") > 1, signal("y")),
     lambda: implies(signal("x"), signal("y") > 1), lambda: not_(signal("x")), lambda: X(3.0)],
)
def test_temporal_and_binary_builders_reject_non_formulas(build):
    """`F(x)` of a bare signal built a tree that printed `F x` and failed only when evaluated (AttributeError)."""
    with pytest.raises(TypeError, match="expected a Formula"):
        build()


def test_builders_take_python_bools_and_numpy_numbers():
    """A bool operand becomes a constant, as with `&`; numpy scalars are numbers (`x > goal[0]` of a float32 array)."""
    x = signal("x")
    assert U(x > 1, True) == parse("x > 1 U true")
    goal = np.array([3.0, 4.0], dtype=np.float32)
    assert (x > goal[0]) == parse("x > 3")
    assert (x + np.int64(2) < goal[1]) == parse("x + 2 < 4")


def test_numpy_scalars_are_accepted_for_beta_rho_max_and_horizon():
    """`beta=np.float32(9)`, `rho_max=np.int64(100)` were refused as "not positive" (a sweep's values)."""
    trace = {"x": [1.0, 3.0], "y": [1.0, 1.0]}
    expected = PHI.smooth_robustness(trace, 9.0, 100.0)
    assert PHI.smooth_robustness(trace, np.float32(9.0), np.int64(100)) == expected
    assert PHI.robustness(trace, np.float32(100.0)) == PHI.robustness(trace, 100.0)
    below, above = PHI.smoothing_bracket(np.int64(200), np.float32(9.0))
    assert (below, above) == PHI.smoothing_bracket(200, 9.0)
    assert type(below) is float


def test_exact_evaluators_take_tensors_that_require_grad():
    """numpy refuses such a tensor: `robustness` raised torch's RuntimeError instead of answering."""
    s = torch.tensor([11.0, 6.0, 7.0], requires_grad=True)
    phi = parse("F(s > 5 & s < 10)")
    assert phi.robustness({"s": s}) == 2.0
    assert phi.satisfied({"s": s})
    np.testing.assert_array_equal(phi.robustness_over_time({"s": s}), [2.0, 2.0, 2.0])
    value, grad = phi.smooth_robustness_and_gradient({"s": s}, 9.0)
    assert value == pytest.approx(2.0)


def test_smoothing_integer_tensors_gives_floats():
    """An integer tensor gave an integer result: 2.000000002 truncated to 2, and -inf to a garbage integer."""
    phi = parse("F(s > 5 & s < 10)")
    value = phi.smooth_robustness({"s": torch.tensor([11, 6, 7])}, 9.0)
    assert value.dtype == torch.float64
    assert value.item() == phi.smooth_robustness({"s": [11.0, 6.0, 7.0]}, 9.0)
    assert parse("X(s > 0)").smooth_robustness({"s": torch.tensor([1])}, 9.0).item() == -math.inf
    over_time = phi.smooth_robustness_over_time({"s": torch.tensor([[11, 6, 7]])}, 9.0)
    assert over_time.dtype == torch.float64 and over_time[0, 2].item() == pytest.approx(1.99998629)
    assert phi.smooth_robustness({"s": torch.tensor([11.0, 6.0, 7.0])}, 9.0).dtype == torch.float32  # floats kept


@pytest.mark.parametrize("method", EVALUATORS)
def test_mixed_infinite_margin_raises_trace_error(method):
    """A margin of [-inf, +inf] (x · log 0 with x of both signs): TraceError, no numpy warning (engine bug 6)."""
    with pytest.raises(TraceError, match="position 0"):
        _evaluators(parse("F(x < x * log(0))"))[method]({"x": [1.0, -1.0]})


@pytest.mark.parametrize("text", ["x < 1e300", "x / 1e-300 > 0"])
def test_smoothing_refuses_values_beyond_its_range(text):
    """Finite predicate values with |β·ρ| ≥ 5e299 cannot be told from ±∞ in β units: refused, named.

    The exact robustness still answers them (found by hypothesis: a value of 9e307 came back as inf).
    """
    formula = parse(f"F({text})")
    trace = {"x": [3.0, 2.0, 1.0]}
    assert math.isfinite(formula.robustness(trace))
    with pytest.raises(TraceError, match=r"at trajectory 0, position 0: too large to smooth"):
        formula.smooth_robustness(trace, 1.0)


@pytest.mark.parametrize(("text", "rho_max", "beta"), [("true", 6e299, 1.0), ("G true", 1e296, 1e6),
                                                     ("X(x > 0)", 1e299, 9.0)])
def test_smoothing_refuses_a_finite_rho_max_beyond_its_range(text, rho_max, beta):
    """It smoothed ⊤ (and X at the last state) as ±inf, where the exact robustness is ±rho_max."""
    formula, trace = parse(text), {"x": [3.0]}
    assert abs(formula.robustness(trace, rho_max)) == rho_max
    with pytest.raises(ValueError, match=r"rho_max=.* is too large to smooth with β = .*pass rho_max=inf"):
        formula.smooth_robustness(trace, beta, rho_max)
    assert formula.smooth_robustness(trace, beta, 1e4) == pytest.approx(formula.robustness(trace, 1e4))
    # a formula that never takes the value ±rho_max smooths with any (a large sentinel rho_max worked, and works)
    assert parse("F(x > 0.5)").smooth_robustness(trace, beta, rho_max) == pytest.approx(2.5)


def test_the_wrapper_refuses_a_smooth_reward_with_an_unsmoothable_rho_max_when_built():
    import gymnasium as gym

    from tl_gym import TLTLRewardWrapper

    with pytest.raises(ValueError, match=r"rho_max=1e\+300 is too large to smooth"):
        TLTLRewardWrapper(gym.make("Pendulum-v1"), "F(c > 0.5) | X(c > 0)", signals={"c": 0}, reward="smooth",
                          rho_max=1e300)
    TLTLRewardWrapper(gym.make("Pendulum-v1"), "F(c > 0.5)", signals={"c": 0}, reward="smooth", rho_max=1e300)


def test_value_range_skips_checks_only_where_values_are_known_finite():
    from tl_gym.tltl.expressions import value_range

    sides = parse("sqrt((x - 150)^2 + (y - 150)^2) > 40 & log(x) > 0 & 1 / y > 0 & abs(x) * 2 > min(x, -y)")
    predicates = [p for p in sides.walk() if type(p).__name__ == "Predicate"]
    magnitudes = {"x": 300.0, "y": 300.0}
    low, high = value_range(predicates[0].lhs, magnitudes)
    assert low == 0.0 and high == pytest.approx(math.sqrt(2) * 450)
    assert value_range(predicates[1].lhs, magnitudes) is None  # log of a value that may be <= 0
    assert value_range(predicates[2].lhs, magnitudes) is None  # division by a value that may be 0
    assert value_range(predicates[3].lhs, magnitudes) == (0.0, 600.0)
    assert value_range(predicates[3].rhs, magnitudes) == (-300.0, 300.0)
