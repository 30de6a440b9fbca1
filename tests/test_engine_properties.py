"""Properties the engine must have whatever the formula: soundness, Lemma 1, limits, gradients.

* ρ > 0 implies satisfied and ρ < 0 implies not satisfied (section II-A);
* the Lemma 1 bracket holds, ρ − below ≤ ρ̂ ≤ ρ + above, and the bracket is the
  recursive Lemma 1 of `tests.reference.bracket`;
* the smoothing error is at most C/β, so it vanishes as β grows (monotonically for a
  formula made of maxima only);
* regrouping a conjunction (disjunction) never changes a smoothed value;
* autograd equals finite differences (float64 `torch.autograd.gradcheck`);
* evaluating twice gives the same answer (rtamt's issue 85);
* every node class is handled by every evaluator, and an unknown one is refused;
* the paper's Eq. 18 is not the smoothing of φ1 (Eq. 17).
"""

from __future__ import annotations

import dataclasses
import inspect
import math

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import tests.reference as ref
from tests import strategies as S
from tl_gym import parse
from tl_gym.logic import F, G, all_of, any_of, signal, sqrt
from tl_gym.tltl import ast

INF = math.inf


# --------------------------------------------------------------------------- soundness


@given(S.formulas(min_depth=2), S.batched_traces())
def test_robustness_sign_decides_satisfaction(formula, trace):
    assume(ref.is_defined(formula, trace))
    rho = formula.robustness_over_time(trace)
    ok = ref.satisfied_over_time(formula, trace)  # (the engine's own is checked against it)
    assert np.array_equal(formula.satisfied(trace), ok[:, 0])
    assert ok[rho > 0].all(), "ρ > 0 but not satisfied"
    assert not ok[rho < 0].any(), "ρ < 0 but satisfied"


# --------------------------------------------------------------------------- Lemma 1


@given(S.formulas(min_depth=2), S.batched_traces(max_length=6), S.betas(), st.sampled_from(["nested", "linear"]))
def test_lemma1_bracket_holds(formula, trace, beta, form):
    assume(ref.is_defined(formula, trace))
    length = next(iter(trace.values())).shape[-1]
    below, above = formula.smoothing_bracket(length, beta)
    rho = formula.robustness_over_time(trace)
    smooth = np.asarray(formula.smooth_robustness_over_time(trace, beta, form=form))
    assert np.array_equal(np.isinf(rho), np.isinf(smooth)) and (rho[np.isinf(rho)] == smooth[np.isinf(rho)]).all()
    finite = np.isfinite(rho)
    slack = 1e-9 * np.maximum(1.0, np.abs(rho[finite]))
    assert (rho[finite] - below - slack <= smooth[finite]).all(), (rho, smooth, below)
    assert (smooth[finite] <= rho[finite] + above + slack).all(), (rho, smooth, above)


def _then_under_temporal(formula, under: bool = False) -> bool:
    """Whether a ``T`` occurs inside the operand of a temporal operator."""
    if isinstance(formula, ast.Then) and under:
        return True
    temporal = isinstance(formula, (ast.Next, ast.Eventually, ast.Always, ast.Until, ast.Then))
    return any(_then_under_temporal(c, under or temporal) for c in formula.children)


@given(S.formulas(min_depth=2), S.batched_traces(max_length=6), S.betas())
def test_linear_form_changes_only_a_nested_then(formula, trace, beta):
    """``form="linear"`` only re-smooths a ``T`` nested under a temporal operator; elsewhere it is the same."""
    assume(ref.is_defined(formula, trace) and not _then_under_temporal(formula))
    linear = formula.smooth_robustness(trace, beta, form="linear")
    nested = formula.smooth_robustness(trace, beta)
    np.testing.assert_allclose(linear, nested, rtol=1e-9, atol=1e-9)


@given(S.formulas(max_depth=5), st.integers(1, 50), S.betas())
def test_bracket_is_the_recursive_lemma1(formula, horizon, beta):
    below, above = formula.smoothing_bracket(horizon, beta)
    exp_below, exp_above = ref.bracket(formula, horizon, beta)
    assert below == pytest.approx(exp_below, rel=1e-12, abs=1e-300)
    assert above == pytest.approx(exp_above, rel=1e-12, abs=1e-300)


@pytest.mark.parametrize(
    ("text", "horizon", "beta", "expected"),
    [
        ("x > 0", 5, 1.0, (0.0, 0.0)),
        ("F x > 0", 5, 2.0, (0.0, math.log(5) / 2)),
        ("G x > 0", 4, 1.0, (math.log(4), 0.0)),
        ("!G x > 0", 4, 1.0, (0.0, math.log(4))),
        ("G x > 0 & F y > 0", 4, 1.0, (math.log(4) + math.log(2), math.log(4))),
        ("x > 0 & y > 0 & z > 0", 3, 1.0, (math.log(3), 0.0)),
        ("x > 0 -> F y > 0", 3, 1.0, (0.0, math.log(3) + math.log(2))),
        # U: inner smin over ≤ T-1 = 2 terms, 2-term smin with ψ, smax over T = 3 positions
        ("x > 0 U y > 0", 3, 1.0, (math.log(2) + math.log(2), math.log(3))),
        ("x > 0 T y > 0", 3, 1.0, (math.log(2), math.log(2) + math.log(3))),
    ],
)
def test_bracket_hand_worked(text, horizon, beta, expected):
    assert parse(text).smoothing_bracket(horizon, beta) == pytest.approx(expected, rel=1e-12)


# --------------------------------------------------------------------------- β → ∞


@settings(max_examples=min(settings().max_examples, 40))
@given(S.formulas(min_depth=2, max_depth=4), S.traces(max_length=6))
def test_smoothing_error_shrinks_as_beta_grows(formula, trace):
    assume(ref.is_defined(formula, trace))
    rho = formula.robustness(trace)
    assume(math.isfinite(rho))
    length = len(trace["x"])
    for beta in (1.0, 10.0, 1e2, 1e3, 1e4, 1e5, 1e6):
        err = abs(formula.smooth_robustness(trace, beta) - rho)
        assert err <= max(formula.smoothing_bracket(length, beta)) + 1e-9 * max(1.0, abs(rho))
    assert abs(formula.smooth_robustness(trace, 1e6) - rho) <= 1e-4 * max(1.0, S.depth(formula)) + 1e-9 * abs(rho)


maxima_only = S.formulas(max_depth=4, operators=(ast.Or, ast.Eventually), constants=False)


@given(maxima_only, S.traces())
def test_error_of_a_max_only_formula_decreases_monotonically(formula, trace):
    rho = formula.robustness(trace)
    errors = [formula.smooth_robustness(trace, beta) - rho for beta in (0.1, 0.3, 1, 3, 10, 30, 100, 1e3)]
    rounding = 1e-9 * max(1.0, abs(rho))
    assert all(e >= -rounding for e in errors)  # log-sum-exp never underestimates a max
    assert all(b <= a + rounding for a, b in zip(errors, errors[1:])), errors


# --------------------------------------------------------------------------- regrouping


@st.composite
def _grouped(draw, operands, combine):
    """Combine ``operands`` (in order) with a binary ``combine`` along a random tree."""
    items = list(operands)
    while len(items) > 1:
        i = draw(st.integers(0, len(items) - 2))
        items[i : i + 2] = [combine(items[i], items[i + 1])]
    return items[0]


@settings(max_examples=min(settings().max_examples, 30))
@given(st.data(), st.lists(S.formulas(max_depth=2), min_size=3, max_size=5), S.traces(max_length=5), S.betas())
def test_regrouping_never_changes_a_smoothed_value(data, operands, trace, beta):
    assume(ref.is_defined(all_of(*operands), trace))
    for nary, combine in ((all_of, lambda a, b: a & b), (any_of, lambda a, b: a | b)):
        flat = nary(*operands)
        for _ in range(2):
            grouped = data.draw(_grouped(operands, combine))
            assert grouped == flat
            for wrap in (lambda f: f, F, lambda f: G(f) | (signal("x") > 0)):
                assert wrap(grouped).smooth_robustness(trace, beta) == wrap(flat).smooth_robustness(trace, beta)
                assert wrap(grouped).smoothing_bracket(5, beta) == wrap(flat).smoothing_bracket(5, beta)
        # and the flat value is the n-ary smooth reduction of the operands (not a nested pairwise one)
        values = [ref.smooth_robustness(op, trace, beta) for op in flat.operands]
        reduce = ref.smooth_min if nary is all_of else ref.smooth_max
        expected = reduce(values, beta)
        got = flat.smooth_robustness(trace, beta)
        assert got == expected or abs(got - expected) <= 1e-9 * max(1.0, abs(expected))


def test_regrouping_in_text():
    trace = {"x": [1.0, 2.0, -1.0], "y": [0.5, 0.2, 3.0], "z": [2.0, 2.0, 2.0]}
    texts = ["F(x > 0 & y > 0 & z > 0)", "F((x > 0 & y > 0) & z > 0)", "F(x > 0 & (y > 0 & z > 0))"]
    assert len({parse(t) for t in texts}) == 1
    assert len({parse(t).smooth_robustness(trace, 2.0) for t in texts}) == 1
    # one 3-term min (log 3 below), not two nested 2-term ones (2·log 2): the bracket sees the grouping
    assert {parse(t).smoothing_bracket(3, 1.0) for t in texts} == {(math.log(3), math.log(3))}


# --------------------------------------------------------------------------- gradients

smooth_formulas = S.formulas(
    min_depth=1, max_depth=4, leaves=S.predicates(exprs=S.smooth_expressions()),
)


@settings(max_examples=min(settings().max_examples, 25))
@given(smooth_formulas, S.batched_traces(max_length=5, max_batch=2, rescale=False),
       st.sampled_from([0.5, 1.0, 3.0]), st.sampled_from(["nested", "linear"]))
def test_autograd_equals_finite_differences(formula, trace, beta, form):
    """float64 gradcheck of the value at position 0 and of the values at every position."""
    assume(ref.is_defined(formula, trace))
    rho_max = 5.0  # keeps `true` and `X φ` at the end finite
    tensors = tuple(torch.tensor(trace[name], requires_grad=True) for name in S.SIGNALS)

    def at_zero(*signals):
        return formula.smooth_robustness(dict(zip(S.SIGNALS, signals)), beta, rho_max, form=form)

    value = at_zero(*tensors)
    assume(bool(torch.isfinite(value).all()) and value.requires_grad)
    # finite differences of a value v carry a rounding error of about ulp(v) / eps: beyond 1e4 it
    # exceeds gradcheck's tolerance whatever the gradient (e.g. exp(z^2/4) at z = 8 is 8.9e6)
    assume(float(value.detach().abs().max()) < 1e4)
    assert torch.autograd.gradcheck(at_zero, tensors, eps=1e-6, atol=1e-6, rtol=1e-4)

    over_time = formula.smooth_robustness_over_time(dict(zip(S.SIGNALS, tensors)), beta, rho_max, form=form)
    finite = torch.isfinite(over_time.detach())  # (`T` at the last position is −∞, with no gradient)
    finite &= over_time.detach().abs() < 1e4

    def every_position(*signals):
        values = formula.smooth_robustness_over_time(dict(zip(S.SIGNALS, signals)), beta, rho_max, form=form)
        return values[finite]

    assert torch.autograd.gradcheck(every_position, tensors, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_gradient_of_the_paper_example_by_hand():
    """d/ds of smax_t(smin(s_t - 5, 10 - s_t)): softmax weights times the inner smin's weights."""
    beta = 2.0
    s = torch.tensor([11.0, 6.0, 7.0], dtype=torch.float64, requires_grad=True)
    parse("F(s > 5 & s < 10)").smooth_robustness({"s": s}, beta).backward()
    a, b = s.detach() - 5, 10 - s.detach()
    inner = -torch.logaddexp(-beta * a, -beta * b) / beta
    outer_w = torch.softmax(beta * inner, 0)
    inner_grad = torch.softmax(-beta * torch.stack([a, b]), 0)  # weights of a (d/ds = 1) and b (d/ds = -1)
    expected = outer_w * (inner_grad[0] - inner_grad[1])
    assert torch.allclose(s.grad, expected, rtol=1e-12, atol=1e-15)


# --------------------------------------------------------------------------- determinism


@settings(max_examples=min(settings().max_examples, 30))
@given(S.formulas(min_depth=2, max_depth=4), S.batched_traces(), S.batched_traces(), S.betas())
def test_evaluating_twice_gives_the_same_answer(formula, trace, other, beta):
    assume(ref.is_defined(formula, trace) and ref.is_defined(formula, other))

    def everything(tr):
        return (
            formula.robustness(tr), formula.robustness_over_time(tr), formula.satisfied(tr),
            formula.smooth_robustness(tr, beta), np.asarray(formula.smooth_robustness_over_time(tr, beta)),
            formula.smoothing_bracket(next(iter(tr.values())).shape[-1], beta),
        )

    first = everything(trace)
    everything(other)  # an evaluation in between must leave nothing behind
    for a, b in zip(first, everything(trace)):
        np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------- every node, every evaluator

SAMPLES = {
    ast.Constant: ast.Constant(True),
    ast.Predicate: signal("x") > 1,
    ast.Not: ast.Not(signal("x") > 1),
    ast.And: ast.And((signal("x") > 1, signal("y") < 2, signal("x") < 3)),
    ast.Or: ast.Or((signal("x") > 1, signal("y") < 2)),
    ast.Implies: ast.Implies(signal("x") > 1, signal("y") < 2),
    ast.Next: ast.Next(signal("x") > 1),
    ast.Eventually: ast.Eventually(signal("x") > 1),
    ast.Always: ast.Always(signal("x") > 1),
    ast.Until: ast.Until(signal("x") > 1, signal("y") < 2),
    ast.Then: ast.Then(signal("x") > 1, signal("y") < 2),
}
NODE_TRACE = {
    "x": np.array([[0.5, 2.0, 1.5, 3.5], [2.5, 0.0, 1.0, 1.2]]),
    "y": np.array([[3.0, 1.0, 2.5, 0.5], [1.0, 2.2, 1.9, 4.0]]),
}


def test_node_list_is_complete():
    concrete = {
        cls for _, cls in inspect.getmembers(ast, inspect.isclass)
        if issubclass(cls, ast.Formula) and dataclasses.is_dataclass(cls) and cls.__module__ == ast.__name__
    }
    assert concrete == set(ast.FORMULA_NODES) == set(SAMPLES)


@pytest.mark.parametrize("node_class", ast.FORMULA_NODES, ids=lambda c: c.__name__)
@pytest.mark.parametrize("rho_max", [INF, 4.0])
def test_every_node_is_handled_by_every_evaluator(node_class, rho_max):
    formula = SAMPLES[node_class]
    assert type(formula) is node_class
    # a node under F and under G, so that over-time values of the node are used too
    for f in (formula, F(formula), G(formula)):
        expected = ref.robustness_over_time(f, NODE_TRACE, rho_max)
        np.testing.assert_array_equal(f.robustness_over_time(NODE_TRACE, rho_max), expected)
        np.testing.assert_array_equal(f.satisfied(NODE_TRACE), ref.satisfied(f, NODE_TRACE))
        for beta in (0.7, 5.0):
            got = np.asarray(f.smooth_robustness_over_time(NODE_TRACE, beta, rho_max))
            np.testing.assert_allclose(got, ref.smooth_over_time(f, NODE_TRACE, beta, rho_max), rtol=1e-12, atol=1e-12)
            assert f.smoothing_bracket(4, beta) == pytest.approx(ref.bracket(f, 4, beta), rel=1e-12)


@dataclasses.dataclass(frozen=True)
class _Unknown(ast.Formula):
    """A node no evaluator knows: each must refuse it, never fall back to a child's value."""

    child: ast.Formula

    @property
    def children(self):
        return (self.child,)


@pytest.mark.parametrize(
    "evaluate",
    [
        lambda f: f.robustness(NODE_TRACE),
        lambda f: f.robustness_over_time(NODE_TRACE),
        lambda f: f.satisfied(NODE_TRACE),
        lambda f: f.smooth_robustness(NODE_TRACE, 1.0),
        lambda f: f.smooth_robustness_over_time(NODE_TRACE, 1.0),
        lambda f: f.smoothing_bracket(4, 1.0),
    ],
    ids=["exact", "exact_over_time", "boolean", "smooth", "smooth_over_time", "bracket"],
)
def test_unknown_node_is_refused(evaluate):
    for formula in (_Unknown(signal("x") > 1), F(_Unknown(signal("x") > 1))):
        with pytest.raises(TypeError, match="_Unknown"):
            evaluate(formula)


# --------------------------------------------------------------------------- Eq. 18


def _phi1_parts(x, y):
    """The five terms of φ1 at each step: four goal-box margins, then obstacle clearance."""
    box = np.stack([x - 1, 2 - x, y - 1, 2 - y])
    clearance = np.sqrt((x - 0.5) ** 2 + (y - 0.5) ** 2) - 0.2
    return box, clearance


def test_eq18_is_not_the_smoothing_of_phi1():
    """Eq. 18 (one smooth min over all steps and all five terms) tends to the min over time.

    Only the nested smoothing of φ1 = F(goal box) & G(obstacle) tends to the exact
    robustness (Eq. 17) as β grows.
    """
    x1, y1 = signal("x"), signal("y")
    phi1 = F((x1 > 1) & (x1 < 2) & (y1 > 1) & (y1 < 2)) & G(sqrt((x1 - 0.5) ** 2 + (y1 - 0.5) ** 2) > 0.2)
    assert phi1 == parse("F(x > 1 & x < 2 & y > 1 & y < 2) & G(sqrt((x - 0.5)^2 + (y - 0.5)^2) > 0.2)")
    # from (0, 1.5) past the obstacle into the box, ending at its centre
    x = np.array([0.0, 0.4, 0.9, 1.3, 1.5])
    y = np.array([1.5, 1.5, 1.5, 1.5, 1.5])
    trace = {"x": x, "y": y}
    box, clearance = _phi1_parts(x, y)
    eq17 = min(box.min(axis=0).max(), clearance.min())
    assert phi1.robustness(trace) == pytest.approx(eq17, abs=1e-12) and eq17 == pytest.approx(0.5)
    min_over_time = min(box.min(), clearance.min())  # = x_0 - 1 = -1
    assert min_over_time == pytest.approx(-1.0)

    def eq18(beta):
        terms = np.concatenate([box.ravel(), clearance])
        low = terms.min()  # shifted, so that large β does not overflow
        return low - np.log(np.exp(-beta * (terms - low)).sum()) / beta

    for beta in (1.0, 9.0, 100.0):
        assert abs(eq18(beta) - phi1.smooth_robustness(trace, beta)) > 0.5
    for beta in (100.0, 1e3, 1e6):
        assert phi1.smooth_robustness(trace, beta) == pytest.approx(eq17, abs=10 / beta)
        assert eq18(beta) == pytest.approx(min_over_time, abs=10 / beta)
    assert phi1.satisfied(trace) and eq18(1e3) < 0  # Eq. 18 would call a satisfying run a failure


@settings(max_examples=min(settings().max_examples, 40))
@given(smooth_formulas, S.batched_traces(max_length=6, max_batch=3, rescale=False),
       st.sampled_from([0.5, 1.0, 9.0]), st.sampled_from(["nested", "linear"]), st.sampled_from([5.0, math.inf]))
def test_the_numpy_gradient_is_autograd_s(formula, trace, beta, form, rho_max):
    """`smooth_robustness_and_gradient` gives autograd's values and gradients, without tensors."""
    assume(ref.is_defined(formula, trace))
    values, grads = formula.smooth_robustness_and_gradient(trace, beta, rho_max, form)
    tensors = {name: torch.tensor(trace[name], requires_grad=True) for name in S.SIGNALS}
    expected = formula.smooth_robustness(tensors, beta, rho_max, form=form)
    np.testing.assert_array_equal(values, expected.detach().numpy())
    if not expected.requires_grad:  # no signal read
        assert grads == {}
        return
    expected.sum().backward()
    assert set(grads) == set(formula.signals)
    for name in formula.signals:
        grad = tensors[name].grad  # None: the values do not depend on this signal
        autograd = np.zeros(grads[name].shape) if grad is None else np.nan_to_num(grad.numpy(), nan=0.0,
                                                                                   posinf=0.0, neginf=0.0)
        np.testing.assert_array_equal(np.nan_to_num(grads[name], nan=0.0, posinf=0.0, neginf=0.0), autograd)
    single = {name: np.asarray(trace[name])[0] for name in S.SIGNALS}  # one trajectory: a float and (T,) arrays
    value, grad = formula.smooth_robustness_and_gradient(single, beta, rho_max, form)
    assert value == values[0] or (math.isnan(value) and math.isnan(values[0]))
    for name in formula.signals:
        np.testing.assert_array_equal(grad[name], grads[name][0])
