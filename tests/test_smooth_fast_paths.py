"""Shortcuts of the smoother give the general path's answers: chunks of trajectories, the
per-trajectory Jacobian at position 0, and predicates between signals and numbers."""

import math

import numpy as np
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tests import reference as ref
from tests import strategies as S
from tl_gym import TraceError, parse
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import smooth
from tl_gym.tltl import trace as trace_module
from tl_gym.tltl.expressions import margin_bound

FORMULAS = [
    "F(x > 1 & x < 3 & y > -1 & y < 1) & G(sqrt((x - 2)^2 + y^2) > 0.5)",  # φ1's shape
    "(x > 0) U (y > 1)",
    "(x > 0) T (y > 1) T (x < -1)",
    "G(x > 1 -> X F(y < 0)) | !(x * y > 2)",
    "sqrt(x^2 + y^2) > 1 & F(x > y) & (2 > 1)",  # a generic predicate at position 0 only
    "X(x <= 0) & F(y >= x)",
]
BETA = 3.0


def _trace(n: int = 37, length: int = 9, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"x": rng.normal(1.0, 1.5, (n, length)), "y": rng.normal(0.0, 1.5, (n, length))}


def _value_and_grads(formula, trace, weights):
    tensors = {k: torch.tensor(v, requires_grad=True) for k, v in trace.items()}
    value = formula.smooth_robustness(tensors, BETA)
    grads = torch.autograd.grad(value, list(tensors.values()), grad_outputs=torch.tensor(weights))
    return value.detach().numpy(), [g.numpy() for g in grads]


@pytest.mark.parametrize("text", FORMULAS)
def test_chunks_of_trajectories_change_nothing(text, monkeypatch):
    formula, trace = parse(text), _trace()
    weights = np.random.default_rng(1).normal(size=37)  # negative upstream gradients too
    whole_value, whole_grads = _value_and_grads(formula, trace, weights)
    whole_numpy = formula.smooth_robustness(trace, BETA)
    monkeypatch.setattr(trace_module, "CHUNK_ELEMENTS", 1)  # 16 trajectories per chunk: 16 + 16 + 5
    assert [s.stop - s.start for s in trace_module.chunks(37, 9)] == [16, 16, 5]
    value, grads = _value_and_grads(formula, trace, weights)
    np.testing.assert_allclose(value, whole_value, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(formula.smooth_robustness(trace, BETA), whole_numpy, rtol=1e-12, atol=1e-12)
    for got, expected in zip(grads, whole_grads):
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("text", FORMULAS)
def test_position_zero_jacobian_equals_the_tape_of_every_position(text):
    """The eager per-trajectory Jacobian (position 0) against the recorded tape (every position)."""
    formula, trace = parse(text), _trace(n=5)
    weights = np.array([1.0, -2.0, 0.5, 0.0, 3.0])
    value, grads = _value_and_grads(formula, trace, weights)
    tensors = {k: torch.tensor(v, requires_grad=True) for k, v in trace.items()}
    over_time = formula.smooth_robustness_over_time(tensors, BETA)
    tape = torch.autograd.grad(over_time[:, 0], list(tensors.values()), grad_outputs=torch.tensor(weights))
    np.testing.assert_allclose(value, over_time[:, 0].detach().numpy(), rtol=1e-9, atol=1e-12)
    for got, expected in zip(grads, tape):
        np.testing.assert_allclose(got, expected.numpy(), rtol=1e-9, atol=1e-12)


def test_no_jacobian_without_grad_and_backward_can_repeat():
    formula, trace = parse(FORMULAS[0]), _trace(n=4)
    plain = formula.smooth_robustness({k: torch.tensor(v) for k, v in trace.items()}, BETA)
    assert not plain.requires_grad
    np.testing.assert_allclose(plain.numpy(), formula.smooth_robustness(trace, BETA), rtol=1e-12)
    x = torch.tensor(trace["x"], requires_grad=True)
    value = formula.smooth_robustness({"x": x, "y": torch.tensor(trace["y"])}, BETA).sum()
    first = torch.autograd.grad(value, x, retain_graph=True)[0]
    second = torch.autograd.grad(value, x)[0]
    assert torch.equal(first, second) and first.abs().sum() > 0


def test_signal_against_itself_and_number_against_number():
    x = torch.tensor([[1.0, 2.0, 3.0]], requires_grad=True)
    value = parse("F(x < x + 0)").smooth_robustness({"x": x}, BETA)  # generic path: x + 0 is arithmetic
    assert value.item() == pytest.approx(0.0 + np.log(3) / BETA)
    same = parse("G(x <= x)").smooth_robustness({"x": x}, BETA)  # linear path: the slopes cancel
    assert same.item() == pytest.approx(-np.log(3) / BETA)
    (grad,) = torch.autograd.grad(same, x, allow_unused=True)
    assert grad is None or not grad.any()
    assert parse("1 < 2").smooth_robustness({"x": [0.0, 5.0]}, BETA) == pytest.approx(1.0)


def test_signal_versus_number_overflow_is_refused():
    # x - (-1e308) overflows although x is finite: the magnitude bound must send it to the check
    with pytest.raises(TraceError, match="position 0"):
        parse("x > -1e308").smooth_robustness({"x": [1e308, 0.0]}, BETA)
    with pytest.raises(TraceError, match="position 1"):
        parse("G(x < 1e308)").smooth_robustness_over_time({"x": [0.0, -1e308]}, BETA)


def test_errors_name_the_trajectory_of_the_whole_batch_not_of_its_chunk(monkeypatch):
    monkeypatch.setattr(trace_module, "CHUNK_ELEMENTS", 1)  # chunks of 16 trajectories
    trace = _trace()
    trace["x"][20, 3] = -200.0
    for formula in (parse("F(sqrt(x + 100) > 1)"), parse("sqrt(x + 100) > 1")):
        position = 3 if formula.is_temporal else 0
        trace["x"][20, 0] = -200.0 if position == 0 else 1.0
        with pytest.raises(TraceError, match=rf"trajectory 20, position {position}"):
            formula.smooth_robustness(trace, BETA)


def test_gradient_only_when_autograd_will_ask_for_it(monkeypatch):
    formula, trace = parse(FORMULAS[0]), _trace(n=3)
    asked = []
    original = smooth._at_position_zero

    def recorded(*args, **kwargs):
        if "backend" in kwargs:  # the callers' calls, not the numpy fallback's inner one (whether "auto" falls
            asked.append(kwargs["jacobian"])  # back depends on whether an earlier test loaded the kernel)
        return original(*args, **kwargs)

    monkeypatch.setattr(smooth, "_at_position_zero", recorded)
    x = torch.tensor(trace["x"], requires_grad=True)
    with torch.no_grad():
        formula.smooth_robustness({"x": x, "y": torch.tensor(trace["y"])}, BETA)
    formula.smooth_robustness({"x": x.detach(), "y": torch.tensor(trace["y"])}, BETA)
    formula.smooth_robustness({"x": x, "y": torch.tensor(trace["y"])}, BETA)
    assert asked == [False, False, True]


def test_numpy_signal_beside_torch_signals():
    formula, trace = parse(FORMULAS[0]), _trace(n=3)
    x = torch.tensor(trace["x"], requires_grad=True)
    value = formula.smooth_robustness({"x": x, "y": trace["y"]}, BETA)
    np.testing.assert_allclose(value.detach().numpy(), formula.smooth_robustness(trace, BETA), rtol=1e-12)
    value.sum().backward()
    assert x.grad is not None and x.grad.shape == x.shape


def test_gradient_of_a_single_state_through_a_reversed_scan():
    """A suffix scan's gradient on one trajectory of one state is a reversed view; torch refuses
    negative strides, and numpy calls such an array contiguous (found by hypothesis)."""
    x = torch.zeros((1, 1), dtype=torch.float64, requires_grad=True)
    values = parse("X((0 < 0) T (x < 0))").smooth_robustness_over_time({"x": x}, 0.5, 5.0, form="linear")
    values.sum().backward()
    assert x.grad is not None and x.grad.shape == (1, 1) and torch.isfinite(x.grad).all()


def test_column_major_groups_only_where_time_is_only_reduced():
    """φ1 (F and G of temporal-free formulas) is smoothed on column-major views; scans get row-major copies."""
    from tl_gym.envs.tasks import task_formula

    from tl_gym.tltl.smooth import _reductions_only

    assert _reductions_only(task_formula(1))
    assert not _reductions_only(task_formula(2))
    assert not _reductions_only(parse("F(x > 0 & X(x > 1))")) and not _reductions_only(parse("F G(x > 0)"))
    x = np.random.default_rng(0).normal(size=(5, 7))
    for text in ("F(x > 0) & G(x < 2)", "F(x > 0 U x > 1)"):  # one of each layout, same values as unbatched
        formula = parse(text)
        batched = formula.smooth_robustness({"x": x}, BETA)
        np.testing.assert_allclose(batched, [formula.smooth_robustness({"x": row}, BETA) for row in x], rtol=1e-12)


def test_eventually_of_a_conjunction_skips_its_logarithm_and_keeps_its_values():
    """F over & (and G over |) at position 0 reduces the operands' extreme, dividing by their softmax
    total instead of taking its log: the values and gradients stay the nested smoothing's."""
    rng = np.random.default_rng(4)
    trace = {"x": rng.normal(size=(6, 9)), "y": rng.normal(size=(6, 9))}
    for text, shared in (("F(x > 0 & y < 1)", "G(x > 0 | y < 1)"), ("G(x > 0 | y > x)", "F(x > 0 & y > x)")):
        formula = parse(text)
        reused = parse(f"{text} & {shared} & ({shared[2:-1]})")  # the inner formula read twice: no shortcut
        for beta in (0.5, 9.0, 1e4):
            tensors = {k: torch.tensor(v, requires_grad=True) for k, v in trace.items()}
            value = formula.smooth_robustness(tensors, beta)
            value.sum().backward()
            expected = ref.smooth_robustness(formula, {k: v.tolist() for k, v in trace.items()}, beta)
            np.testing.assert_allclose(value.detach().numpy(), expected, rtol=1e-9, atol=1e-12)
            assert all(torch.isfinite(t.grad).all() for t in tensors.values())
            np.testing.assert_allclose(reused.smooth_robustness(trace, beta), ref.smooth_robustness(
                reused, {k: v.tolist() for k, v in trace.items()}, beta), rtol=1e-9, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(S.formulas(min_depth=2, max_depth=4, leaves=S.predicates(exprs=S.smooth_expressions())),
       S.batched_traces(max_length=5), st.sampled_from(smooth.FORMS), st.booleans(),
       st.sampled_from([True, *(frozenset({name}) for name in sorted(smooth.REWRITES))]))
def test_rewritten_plan_equals_the_plain_plan(formula, trace, form, first, rewrites):
    """The rewrites of the smoothing plan, all and each alone (position 0, linear predicates, F over &;
    gradient factors always), give the plain plan's values and gradients."""
    if form == "linear":  # a T needed at position 0 only is smoothed nested (linear time there) in both forms,
        # while the plain plan smooths every T in the linear form: another smoothing, not a rewrite of it
        steps = smooth.plan_for(formula, first, form, rewrites).steps
        assume(not any(step.first and isinstance(step.node, nodes.Then) for step in steps))
    n, length = trace["x"].shape
    signals = {k: np.ascontiguousarray(np.asarray(v, dtype=float).T) for k, v in trace.items()}
    magnitudes = {k: float(np.abs(v).max()) for k, v in trace.items()}
    results, refused = [], []
    for rewrite in (False, rewrites):
        try:
            group, z = smooth._evaluate(formula, {k: v.copy() for k, v in signals.items()}, n, length, BETA, 50.0,
                                        form, first, magnitudes, rewrite=rewrite)
        except TraceError:  # too large to smooth, or undefined: both plans must refuse it
            refused.append(rewrite)
            continue
        weights = np.linspace(-1.0, 2.0, z.size).reshape(z.shape)
        grads = group.backward(weights.copy())
        results.append((z, {k: grads.get(k, np.zeros((length, n))) for k in signals}))
    assert refused in ([], [False], [False, rewrites])  # at position 0 the rewritten plan reads fewer positions
    assume(not refused)
    (plain, plain_grads), (rewritten, grads) = results
    np.testing.assert_allclose(rewritten, plain, rtol=1e-9, atol=1e-9)
    # the smoothing weights come from differences of β-scaled values, exact to their last bit: with margins of 1e9
    # (x·z at x = 8e4, z = −2e4) one ulp of β·ρ is about 1e-6 of a weight, which the two plans round their own way
    bound = max((margin_bound(p.lhs, p.rhs, tuple(magnitudes.items())) for p in formula.walk()
                 if isinstance(p, nodes.Predicate)), default=0.0)
    rtol = max(1e-7, 4 * float(np.spacing(BETA * bound))) if math.isfinite(bound) else 1e-7
    for name in signals:
        np.testing.assert_allclose(grads[name], plain_grads[name], rtol=rtol, atol=1e-7)


@pytest.mark.parametrize("text", ["(X(0 < x)) U (0 < 0)", "!((!X(0 < x)) U (y < 0))", "(F(x > y)) U (x < 1)"])
def test_gradient_of_a_temporal_left_operand_judged_on_segments(text):
    """The segments' rule sends gradients to the signals itself: no operand's factor may scale them
    (found by hypothesis's gradcheck)."""
    formula = parse(text)
    tensors = tuple(torch.zeros((1, 3), dtype=torch.float64, requires_grad=True) for _ in range(2))
    assert torch.autograd.gradcheck(lambda x, y: formula.smooth_robustness({"x": x, "y": y}, 0.5, 5.0), tensors,
                                    eps=1e-6, atol=1e-6, rtol=1e-4)
    assert torch.autograd.gradcheck(lambda x, y: formula.smooth_robustness_over_time({"x": x, "y": y}, 0.5, 5.0),
                                    tensors, eps=1e-6, atol=1e-6, rtol=1e-4)
