"""The compiled smoothing kernel (`tl_gym.tltl.fused_smooth`) gives the numpy smoother's values and gradients.

``smooth_robustness`` uses the kernel by default when numba is installed (``backend="auto"``), so the
reference, hypothesis and gradcheck tests run it too; here it is compared with the numpy plan
(``backend="numpy"``) directly, value and per-trajectory gradient, on random and deep formulas and on
the car's task 2, and the fallback without numba is checked.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from tl_gym.envs.tasks import task_formula

from tests import strategies as S
from tl_gym import TraceError, parse
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import fused, fused_smooth, smooth, smooth_opcodes
from tl_gym.tltl.trace import prepare

pytest.importorskip("numba")


def _both(formula, trace, beta, rho_max=math.inf, form="nested"):
    """(value, Jacobian) at position 0 from the numpy plan and from the kernel (None: not covered)."""
    prepared = prepare(formula.signals, trace)
    args = (formula, prepared.signals, prepared.n, prepared.length, beta, rho_max, form, prepared.magnitudes)
    expected = smooth._at_position_zero(*args, jacobian=True, backend="numpy")
    top = min(beta * rho_max, smooth._INF) if math.isfinite(rho_max) else smooth._INF
    return expected, fused_smooth.at_position_zero(formula, prepared.signals, beta, top, form, True)


def _assert_equal(expected, got):
    (z, jac), (z_fused, jac_fused) = expected, got
    scale = np.maximum(1.0, np.abs(z))
    np.testing.assert_allclose(z_fused / scale, z / scale, rtol=0, atol=1e-10)
    for name, grad in jac.items():
        np.testing.assert_allclose(jac_fused[name], grad, rtol=1e-8, atol=1e-10, err_msg=name)


@settings(max_examples=300, deadline=None)
@given(S.formulas(max_depth=4), S.batched_traces(max_length=8), st.sampled_from([0.5, 1.0, 9.0, 1e3]),
       S.rho_maxes(), st.sampled_from(["nested", "linear"]))
def test_kernel_equals_the_numpy_smoother(formula, trace, beta, rho_max, form):
    try:
        expected, got = _both(formula, trace, beta, rho_max, form)
    except TraceError:  # the numpy plan refuses the trace: the kernel must not answer it either
        prepared = prepare(formula.signals, trace)
        top = min(beta * rho_max, smooth._INF) if math.isfinite(rho_max) else smooth._INF
        assert fused_smooth.at_position_zero(formula, prepared.signals, beta, top, form, True) is None
        return
    if got is not None:
        _assert_equal(expected, got)


@settings(max_examples=100, deadline=None)
@given(S.formulas(max_depth=4, operators=S.UNARY + S.NARY + (nodes.Implies,)), st.sampled_from(["nested", "linear"]))
def test_every_formula_without_until_or_then_is_covered(formula, form):
    """Only U / T at every position in the nested form, or with a temporal left operand, stay on numpy."""
    assert (fused_smooth.program_for(formula, form) is None) == (not formula.signals)


@pytest.mark.parametrize("form", ["nested", "linear"])
def test_task_formulas_on_random_paths(form):
    rng = np.random.default_rng(0)
    walk = np.cumsum(np.cumsum(rng.standard_normal((2, 6, 60)), axis=2), axis=2)
    trace = {"x": 150 + 3 * walk[0], "y": 150 + 3 * walk[1]}
    for task in (1, 2):
        formula = task_formula(task, "leave")
        expected, got = _both(formula, trace, 9.0, form=form)
        if task == 2 and form == "nested":  # T nested under T: the O(T²) smoothing stays on numpy
            assert got is None
            continue
        _assert_equal(expected, got)


def test_goal_boxes_are_smoothed_once():
    """``g & X !g`` with g a four-predicate box reads g's value (log-sum-exp is associative)."""
    program = fused_smooth.program_for(task_formula(2, "leave"), "linear")
    counts = program.steps[:, 4][program.steps[:, 0] == smooth_opcodes.NARY]
    assert sorted(counts.tolist()) == [2, 2, 2, 2, 4, 4, 4, 7]


@pytest.mark.parametrize("text", [
    "F " * 300 + "x > 1",
    " & ".join(f"x > {i / 10}" for i in range(200)),
    "(" + " + ".join(["x"] * 150) + " < 400) U F(y > 0)",
    "(" * 100 + "x > 0 -> X(y < 1)" + ")" * 100,
    "F(max(x, y, 0.5) - min(x, -y) > abs(x) / (2 + y * y)) & G(exp(x / 20) < 3 | log(2 + y * y) > sqrt(x * x))",
    "F(x ^ 3 > 2 ^ y) | (x > 0 T y > 0 T x < 1)",
])
def test_deep_and_odd_formulas(text):
    rng = np.random.default_rng(1)
    trace = {"x": rng.uniform(-3, 3, (3, 40)), "y": rng.uniform(-3, 3, (3, 40))}
    expected, got = _both(parse(text), trace, 2.0, form="linear")
    assert got is not None
    _assert_equal(expected, got)


@pytest.mark.parametrize(("text", "trace"), [
    ("F(log(x) > 0)", {"x": [1.0, -1.0]}),
    ("G(x / y > 0)", {"x": [1.0, 1.0], "y": [1.0, 0.0]}),
    ("F(x < 1e300)", {"x": [3.0, 2.0]}),
    ("0 < min(0, sqrt(x))", {"x": [-1.0]}),  # NaN as min's second operand (it once came out as 0)
    ("0 < max(0, sqrt(x))", {"x": [-1.0]}),
    ("F(max(x, log(x), 2) > 0)", {"x": [1.0, -1.0]}),
])
def test_undefined_or_too_large_predicates_are_refused_as_by_numpy(text, trace):
    formula = parse(text)
    with pytest.raises(TraceError) as numpy_error:
        formula.smooth_robustness(trace, 1.0, backend="numpy")
    with pytest.raises(TraceError) as error:
        formula.smooth_robustness(trace, 1.0, backend="numba")
    assert str(error.value) == str(numpy_error.value)


@given(S.formulas(max_depth=3, leaves=S.predicates(exprs=S.expressions(depth=2, numbers=S.small_numbers()))),
       S.traces())
def test_unsafe_arithmetic_is_refused_or_smoothed_as_by_numpy(formula, trace):
    """Division, log, sqrt and powers of anything: the kernel refuses what numpy refuses, and agrees elsewhere."""
    try:
        expected = formula.smooth_robustness(trace, 1.0, backend="numpy")
    except TraceError as numpy_error:
        with pytest.raises(TraceError) as error:
            formula.smooth_robustness(trace, 1.0, backend="numba")
        assert str(error.value) == str(numpy_error)
        return
    got = formula.smooth_robustness(trace, 1.0, backend="numba")
    scale = max(1.0, abs(expected))
    assert abs(got - expected) / scale <= 1e-10 or got == expected


def test_auto_loads_the_kernel_once_numpy_smoothing_has_cost_the_process_enough(monkeypatch):
    calls = []
    kernel = fused_smooth.at_position_zero
    monkeypatch.setattr(fused_smooth, "at_position_zero", lambda *a: calls.append(1) or kernel(*a))
    monkeypatch.setattr(fused_smooth, "_KERNEL_MODULE", "not loaded")  # as in a process that has not loaded it
    monkeypatch.setattr(fused_smooth, "_SPENT", [0.0])
    monkeypatch.setattr(fused_smooth, "AUTO_SECONDS", math.inf)
    formula, trace = parse("F(x > 1) & G(y < 3)"), {"x": np.array([[0.0, 2.0, 1.5]]), "y": np.array([[1.0, 2.0, 0.0]])}
    expected = formula.smooth_robustness(trace, 2.0, backend="numpy")
    assert formula.smooth_robustness(trace, 2.0) == expected and not calls  # numpy, and its time counted
    assert fused_smooth._SPENT[0] > 0
    monkeypatch.setattr(fused_smooth, "AUTO_SECONDS", fused_smooth._SPENT[0])
    np.testing.assert_allclose(formula.smooth_robustness(trace, 2.0), expected, rtol=1e-12)
    assert calls == [1]
    formula.smooth_robustness(trace, 2.0, backend="numpy")
    assert calls == [1]


def test_the_default_backend_runs_the_kernel_and_torch_gets_its_gradient(monkeypatch):
    monkeypatch.setattr(fused_smooth, "AUTO_SECONDS", 0.0)
    answers = []  # what each call of the kernel returned (None: it declined, and numpy answered)
    kernel = fused_smooth.at_position_zero
    monkeypatch.setattr(fused_smooth, "at_position_zero", lambda *a: answers.append(kernel(*a)) or answers[-1])
    formula = task_formula(2, "leave")
    rng = np.random.default_rng(2)
    x, y = rng.uniform(0, 300, (2, 4, 30))
    tensors = {k: torch.tensor(v, requires_grad=True) for k, v in (("x", x), ("y", y))}
    value = formula.smooth_robustness(tensors, 9.0, form="linear")
    value.sum().backward()
    plain = {k: torch.tensor(v, requires_grad=True) for k, v in (("x", x), ("y", y))}
    expected = formula.smooth_robustness(plain, 9.0, form="linear", backend="numpy")
    expected.sum().backward()
    assert fused_smooth.program_for(formula, "linear") is not None
    # the default call ran the kernel, which answered it with a Jacobian; the numpy call did not run it
    assert len(answers) == 1 and answers[0] is not None and set(answers[0][1]) == {"x", "y"}
    np.testing.assert_allclose(value.detach().numpy(), expected.detach().numpy(), rtol=1e-10)
    for name in ("x", "y"):
        np.testing.assert_allclose(tensors[name].grad.numpy(), plain[name].grad.numpy(), rtol=1e-8, atol=1e-12)


def test_without_numba_the_numpy_smoother_answers(monkeypatch):
    monkeypatch.setattr(fused, "available", lambda: False)
    monkeypatch.setattr(fused, "_WARNED", [])
    formula = parse("F(x > 1) & G(y < 3)")
    trace = {"x": np.array([[0.0, 2.0, 1.5]]), "y": np.array([[1.0, 2.0, 0.0]])}
    monkeypatch.setattr(fused_smooth, "at_position_zero", lambda *a, **k: pytest.fail("the kernel ran"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "auto" falls back silently
        value = formula.smooth_robustness(trace, 2.0)
    with pytest.warns(UserWarning, match="numba is not installed"):
        assert formula.smooth_robustness(trace, 2.0, backend="numba") == value
    assert value == formula.smooth_robustness(trace, 2.0, backend="numpy")
    with pytest.raises(ValueError, match="backend"):
        formula.smooth_robustness(trace, 2.0, backend="jax")


def test_terms_under_steep_predicates_are_not_cut():
    """A term 45 below the smooth min, under sqrt(|x|) at x = 5.6e-135: its weight (3e-20) times its slope
    (7e66) is most of the gradient, so below non-linear predicates the kernel exponentiates every term."""
    formula = parse("x < 0 & X(0 < sqrt(abs(x)))")
    expected, got = _both(formula, {"x": np.array([[5.0, 5.55771789e-135]])}, 9.0)
    assert abs(expected[1]["x"][0, 1]) > 1e40
    _assert_equal(expected, got)
    assert fused_smooth.program_for(formula, "nested").cuts.tolist() == [-37.0, -700.0, -700.0, -700.0]
