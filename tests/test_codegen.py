"""Formulas written out as Python source (tl_gym.tltl.codegen): the same floats as the closures they replace."""

import math
from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tl_gym import TraceError, parse
from tl_gym.logic import X, signal
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import operators
from tl_gym.tltl import windowed as windowed_module
from tl_gym.tltl.codegen import CodeWriter, state_formula_source, writable
from tl_gym.tltl.windowed import _state_closure, _window_closure, compile_state_formula, compile_window_formula

from .test_online import rho_maxes, state_formulas, windowed

floats = st.floats(-3, 3, allow_nan=False, width=32)
states = st.fixed_dictionaries({"a": floats, "b": floats})
extended = st.floats(allow_nan=False)  # ±inf included: the monitor's values


def same(x: float, y: float) -> bool:
    return x == y and math.copysign(1.0, x) == math.copysign(1.0, y)  # -0.0 told apart from 0.0


@given(st.sampled_from([nodes.Not, nodes.And, nodes.Or, nodes.Implies]), st.lists(extended, min_size=1, max_size=4))
def test_connective_source_computes_the_connective(kind, values):
    if kind in (nodes.Not,):
        values = values[:1]
    if kind is nodes.Implies:
        values = (values * 2)[:2]
    code = CodeWriter()
    parts = [code.bind(v) for v in values]
    written = code.scalar_function("f", "", operators.connective_source(kind, parts))()
    assert same(written, operators.CONNECTIVES[kind](values))


def _fallback_used(*args):
    raise AssertionError("the written expression fell back to the closures")


def _written(compile_formula, formula, rho_max):
    """``compile_formula(formula, rho_max)``, its closures (the fallback) replaced by a failure: the code alone."""
    def no_closures(*args):
        return _fallback_used

    with mock.patch.object(windowed_module, "_state_closure", no_closures), \
            mock.patch.object(windowed_module, "_window_closure", no_closures):
        written = compile_formula(formula, rho_max)
    assert written.__code__.co_filename.startswith("<tl_gym ")  # source written by CodeWriter, not a closure
    return written


@settings(max_examples=300, deadline=None)
@given(state_formulas, st.lists(states, min_size=1, max_size=5), rho_maxes)
def test_written_state_formulas_equal_their_closures(formula, trace, rho_max):
    assert writable(formula)
    written, closure = _written(compile_state_formula, formula, rho_max), _state_closure(formula, rho_max)
    for state in trace:
        assert same(written(state), closure(state)), str(formula)


@settings(max_examples=300, deadline=None)
@given(windowed, st.lists(states, min_size=1, max_size=5), rho_maxes)
def test_written_window_formulas_equal_their_closures(formula, window, rho_max):
    assert writable(formula)
    written, closure = _written(compile_window_formula, formula, rho_max), _window_closure(formula, rho_max)
    for i in range(len(window)):
        assert same(written(window, i), closure(window, i)), (str(formula), i)


def test_the_car_formula_is_one_expression():
    code = CodeWriter()
    source = state_formula_source(parse("x > 210 & x < 240 & !(y >= 45)"), math.inf, "s", code, checked=None)
    assert source == "min((s['x'] - 210.0), (240.0 - s['x']), (-(s['y'] - 45.0)))"


def test_undefined_arithmetic_still_names_its_predicate():
    a = signal("a")
    state_formula = compile_state_formula((a > 0) & parse("log(b) > 1"), math.inf)
    with pytest.raises(TraceError, match=r"predicate 'log\(b\) > 1' is NaN or infinite"):
        state_formula({"a": 1.0, "b": -1.0})
    window_formula = compile_window_formula(X(parse("1 / b > 0")) | (a > 0), math.inf)
    with pytest.raises(TraceError, match=r"predicate '1 / b > 0' is NaN or infinite"):
        window_formula([{"a": 1.0, "b": 1.0}, {"a": 1.0, "b": 0.0}], 0)


def test_formulas_too_deep_for_one_expression_keep_their_closures():
    a = signal("a")
    deep = a > 0
    for k in range(50):
        deep = ~deep if k % 2 else deep & (a < k)
    assert not writable(deep)
    assert compile_state_formula(deep, math.inf)({"a": 0.5}) == _state_closure(deep, math.inf)({"a": 0.5})


def test_an_arithmetic_error_in_plain_arithmetic_still_names_its_predicate():
    """Python ints overflow a float: the written expression falls back to the closure, which names the predicate."""
    state_formula = compile_state_formula(parse("a * a * 1.0 > 1 & b > 0"), math.inf)
    with pytest.raises(TraceError, match=r"predicate 'a \* a \* 1 > 1' is NaN or infinite"):
        state_formula({"a": 10**200, "b": 1.0})


@given(st.sampled_from(["<", "<=", ">", ">="]), floats, floats)
def test_margin_source_computes_the_margin(op, lhs, rhs):
    code = CodeWriter()
    written = code.scalar_function("f", "", operators.margin_source(op, code.bind(lhs), code.bind(rhs)))()
    assert same(written, operators.margin(op, lhs, rhs))


def test_numpy_scalars_under_floating_point_errors_still_name_the_predicate():
    """Under np.errstate(all="raise") numpy scalars raise FloatingPointError; the written code falls back to the
    closure as for Python's own errors."""
    state_formula = compile_state_formula(parse("x * y > 0 & z > 0"), math.inf)
    with np.errstate(all="raise"), pytest.raises(TraceError, match=r"predicate 'x \* y > 0' is NaN or infinite"):
        state_formula({"x": np.float64(1e200), "y": np.float64(1e200), "z": 1.0})
