"""The fused numba kernel (``backend="numba"``) gives the numpy plan's robustness, bit for bit.

Three kernels are compiled (into a temporary cache directory), so the module stays fast; it is
skipped when numba is not installed.
"""

from __future__ import annotations

import math
import re
import warnings
from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests import strategies as S
from tl_gym import TraceError, parse
from tl_gym.tltl import exact, fused

pytest.importorskip("numba")

# every operator, and the predicate arithmetic the kernel writes out (exp/log may differ in the last bit)
EVERY_OPERATOR = parse(
    "F(x > 1 & y < 2) & G(sqrt((x - 1)^2 + y^2) > 0.5) | X(x <= y) -> ((x > 0) U (y > 1)) & ((x > 0) T (y > 1))"
    " & !(abs(x) * 2 > 3 + y / 4) & (true | false) & F G(max(x, y) - min(x, -y, 1) >= -(x))"
)
DIVISION = parse("G(x / y > -50 | y > 0) -> X X F(x > 0)")
# F / G of monotone predicates: f applied to the extremes after the loop (outside f's domain: the numpy plan)
MONOTONE = parse("G(log(x + 2) > -1) | F(sqrt(y) < 1) | G(2 < exp(x / 3)) & F(sqrt(x) >= 0.5)")


@pytest.fixture(scope="module", autouse=True)
def cache_directory(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("TL_GYM_CACHE", str(tmp_path_factory.mktemp("fused")))
        yield


def _kernel_answers(formula, trace, rho_max):
    """``formula.robustness(trace, rho_max, backend="numba")``, failing if the numpy plan answered it instead."""
    with mock.patch.object(exact, "robustness", side_effect=AssertionError("the kernel declined: numpy answered")):
        return formula.robustness(trace, rho_max, backend="numba")


@settings(max_examples=60, deadline=None)
@given(S.batched_traces(names=("x", "y"), max_length=9), st.sampled_from([math.inf, 2.5]))
def test_fused_kernel_equals_the_numpy_plan(trace, rho_max):
    for formula in (EVERY_OPERATOR, DIVISION):
        try:
            expected = formula.robustness(trace, rho_max)
        except TraceError as error:  # an undefined predicate: the same error, naming the same place
            with pytest.raises(TraceError, match=re.escape(str(error).split(" (")[0])):
                formula.robustness(trace, rho_max, backend="numba")
            continue
        # where the numpy plan answers, the kernel does (a kernel that always declined passed before)
        np.testing.assert_array_equal(_kernel_answers(formula, trace, rho_max), expected)
        row = {k: v[0] for k, v in trace.items()}
        assert _kernel_answers(formula, row, rho_max) == formula.robustness(row, rho_max)
    try:
        expected = MONOTONE.robustness(trace, rho_max)
    except TraceError:
        with pytest.raises(TraceError):
            MONOTONE.robustness(trace, rho_max, backend="numba")
    else:  # exp and log of numba and of numpy may differ in the last bit
        np.testing.assert_allclose(MONOTONE.robustness(trace, rho_max, backend="numba"), expected, rtol=1e-14)


def test_kernel_is_compiled_once_and_timed():
    kernel = fused.kernel_for(EVERY_OPERATOR)
    assert kernel is not None and kernel.names == ("x", "y") and kernel.seconds > 0
    assert fused.kernel_for(EVERY_OPERATOR) is kernel  # kept on the formula
    assert "for t in range(length - 1, -1, -1):" in kernel.source


@pytest.mark.parametrize("text", ["(F x > 1) U (y > 0)", "true & F false", " & ".join(f"x > {i}" for i in range(500))])
def test_formulas_outside_the_kernel_use_the_numpy_plan(text):
    formula = parse(text)
    assert fused.kernel_for(formula) is None
    trace = {"x": np.linspace(-1, 3, 12).reshape(2, 6), "y": np.ones((2, 6))}
    np.testing.assert_array_equal(formula.robustness(trace, backend="numba"), formula.robustness(trace))


def test_without_numba_the_numpy_plan_answers(monkeypatch):
    monkeypatch.setattr(fused, "available", lambda: False)
    monkeypatch.setattr(fused, "_WARNED", [])
    formula = parse("F(x > 1)")
    with pytest.warns(UserWarning, match="numba is not installed"):
        assert formula.robustness({"x": [0.0, 2.0]}, backend="numba") == 1.0
    with pytest.raises(ValueError, match="backend"):
        formula.robustness({"x": [0.0]}, backend="torch")


def test_auto_runs_the_numpy_plan_until_the_kernel_pays(monkeypatch):
    trace = {"x": np.linspace(-1, 3, 40).reshape(4, 10), "y": np.linspace(2, -2, 40).reshape(4, 10)}
    formula = parse("F(x > 2.5 & y < 0) & G(x + y < 4)")
    expected = formula.robustness(trace, backend="numpy")
    np.testing.assert_array_equal(formula.robustness(trace), expected)  # auto, numpy so far: nothing compiled
    assert formula.__dict__["_plans"].get(("fused",)) is None
    monkeypatch.setattr(fused, "AUTO_SECONDS", 0.0)  # as if the formula had cost half a second already
    np.testing.assert_array_equal(formula.robustness(trace), expected)
    assert fused.kernel_for(formula) is not None and formula.__dict__["_plans"][("fused",)]
    same = parse(str(formula))  # a new formula object: its kernel is in numba's cache, so auto loads it at once
    monkeypatch.setattr(fused, "AUTO_SECONDS", math.inf)
    np.testing.assert_array_equal(same.robustness(trace), expected)
    assert same.__dict__["_plans"].get(("fused",))


def test_auto_without_numba_is_the_numpy_plan(monkeypatch):
    monkeypatch.setattr(fused, "available", lambda: False)
    monkeypatch.setattr(fused, "AUTO_SECONDS", 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse("F(x > 1)").robustness({"x": [0.0, 2.0]}) == 1.0


@pytest.mark.parametrize("text, a", [("(-2) ^ 4 + a > 0", [0.0, 1.0]), ("G((-0.5) ^ a < 1)", [2.0, 3.0]),
                                     ("F((0 - 3) ^ 3 < a)", [-30.0, -20.0]), ("F(-(2 ^ 2) < a)", [-5.0, 0.0])])
def test_a_negative_literal_base_is_powered_as_numpy_powers_it(text, a):
    """The kernel wrote ``-2.0 ** 4.0``, which Python reads as ``-(2.0 ** 4.0)``: numba gave -16 where numpy 16."""
    formula, trace = parse(text), {"a": np.array(a)}
    assert formula.robustness(trace, backend="numba") == formula.robustness(trace, backend="numpy")


def test_a_negative_base_to_a_fractional_power_is_nan_in_both_backends():
    formula, trace = parse("G((-0.5) ^ a < 1)"), {"a": np.array([0.5])}
    for backend in ("numpy", "numba"):
        with pytest.raises(TraceError):
            formula.robustness(trace, backend=backend)
