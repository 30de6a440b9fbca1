"""Deep and wide formulas (issue 17, "No recursion limit"): nothing raises RecursionError.

The four cases of the issue — 10,000 nested parentheses, 10,000 nested F, a 20,000-term
conjunction, a 10,000-term sum — parse, print, hash, compare and evaluate (exact, smoothed
with its torch gradient, and the online monitor), each checked against its closed-form value.
Random chains 50–300 deep are checked against the naive reference (tests/reference.py).
"""

from __future__ import annotations

import copy
import pickle
import sys

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests import reference
from tests import strategies as S
from tl_gym import parse
from tl_gym.tltl.ast import Always, And, Eventually, Formula, Implies, Next, Not, Or, Predicate, Then, Until
from tl_gym.tltl.online import PrefixMonitor

X0 = [3.0, 5.0, 4.0]  # the trace of x (T = 3)
BETA = 2.0


def _trace() -> dict[str, np.ndarray]:
    return {"x": np.array(X0)}


# text, exact robustness at position 0 on X0, d(robustness)/d x_0 as smoothed (None: not checked)
CASES = {
    "parentheses": ("(" * 10_000 + "x > 1" + ")" * 10_000, X0[0] - 1, 1.0),
    "arithmetic parentheses": ("(" * 10_000 + "x" + ")" * 10_000 + " > 1", X0[0] - 1, 1.0),
    "nested F": ("F " * 10_000 + "x > 1", max(X0) - 1, None),
    "conjunction": (" & ".join(f"x > {i}" for i in range(20_000)), X0[0] - 19_999, 1.0),
    "sum": (" + ".join(["x"] * 10_000) + " > 1", 10_000 * X0[0] - 1, 10_000.0),
}


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    text, expected, slope = CASES[request.param]
    return request.param, parse(text), expected, slope


def test_parse_print_hash_and_equality(case):
    name, formula, _, _ = case
    again = parse(str(formula))
    assert again == formula and again is not formula
    assert hash(again) == hash(formula)
    assert str(again) == str(formula)
    assert formula.signals == ("x",)
    assert repr(formula).startswith(type(formula).__name__ + "(")
    if name == "nested F":
        assert formula.depth == 10_001 and formula.is_temporal
        assert formula != parse("F " * 9_999 + "x > 1")  # one level apart: not equal


def test_pickle_and_deepcopy(case):
    """Deep trees are pickled and copied through their text, shallow ones field by field: equal either way."""
    _, formula, expected, _ = case
    for copied in (pickle.loads(pickle.dumps(formula)), copy.deepcopy(formula)):
        assert copied == formula and copied is not formula
        assert copied.robustness(_trace()) == expected
    shallow = parse("F(x > -2 & -(y) < 3) U G(x * y > 1e-3)")
    assert pickle.loads(pickle.dumps(shallow)) == shallow == copy.deepcopy(shallow)


def test_exact_robustness(case):
    _, formula, expected, slope = case
    shift = expected / (slope or 1.0)
    batch = {"x": np.array([X0, [x - shift for x in X0]])}  # the second trajectory sits on the boundary
    rho = formula.robustness(batch)
    np.testing.assert_allclose(rho, [expected, 0.0], atol=1e-9)
    np.testing.assert_array_equal(formula.satisfied(batch), rho > 0)  # (the sum's boundary is rounded)


def test_smoothed_robustness_and_its_gradient(case):
    name, formula, expected, slope = case
    x = torch.tensor(X0, dtype=torch.float64, requires_grad=True)
    value = formula.smooth_robustness({"x": x}, beta=BETA)
    value.backward()
    below, above = formula.smoothing_bracket(len(X0), BETA)
    assert expected - below - 1e-9 <= value.item() <= expected + above + 1e-9
    assert torch.isfinite(x.grad).all()
    if slope is None:  # F over F …: the soft max over t … T-1 of the level below, 10,000 times
        reference_x = torch.tensor(X0, dtype=torch.float64, requires_grad=True)
        level = reference_x - 1.0
        for _ in range(10_000):
            level = torch.stack([torch.logsumexp(BETA * level[t:], 0) / BETA for t in range(len(X0))])
        level[0].backward()
        assert value.item() == pytest.approx(level[0].item(), rel=1e-9)
        np.testing.assert_allclose(x.grad.numpy(), reference_x.grad.numpy(), rtol=1e-9)
        assert x.grad.sum().item() == pytest.approx(1.0)  # softmax weights over time
    else:
        assert x.grad[0].item() == pytest.approx(slope)
        assert x.grad[1:].abs().max().item() == 0.0
    if name != "conjunction":  # (20,000 predicates at every position: slow, and nothing new)
        over_time = formula.smooth_robustness_over_time({"x": torch.tensor(X0)}, beta=BETA)
        assert over_time[0].item() == pytest.approx(value.item())


def test_online_monitor(case):
    name, formula, _, _ = case
    monitor = PrefixMonitor(formula)
    assert monitor.incremental == (name != "nested F")  # F F φ is outside the fragment: replayed
    for t, v in enumerate(X0):
        # the prefix's robustness: F … F (x > 1) is the best x so far; the others judge s_0 alone
        expected = max(X0[: t + 1]) - 1 if name == "nested F" else CASES[name][1]
        assert monitor.update({"x": v}) == pytest.approx(expected)


@pytest.mark.parametrize(
    "text",
    ["X " * 200 + "x > 1", "!" * 101 + "x > 1", "- " * 1_001 + "x > 1", "x > 1 & " + "!" * 101 + "X x < 4"],
    ids=["X^200", "!^101", "-^1001", "mixed"],
)
def test_online_monitor_beyond_its_closures(text):
    """Past the depth where the monitor nests closures, it still agrees with the exact evaluator."""
    formula = parse(text)
    monitor = PrefixMonitor(formula)
    assert monitor.incremental
    xs = np.linspace(-3.0, 4.0, 203)
    for t in (0, 1, 2, 100, 201, 202):
        monitor.reset()
        for v in xs[: t + 1]:
            value = monitor.update({"x": v})
        assert value == pytest.approx(formula.robustness({"x": xs[: t + 1]}))
    assert len(monitor.state()) == len(monitor.slots)
    assert monitor.value_of_state(monitor.state()) == value


# --------------------------------------------------------------------------- random deep chains

CHAIN_OPERATORS = (Not, Next, Eventually, Always, And, Or, Implies, Until, Then)


@st.composite
def deep_chains(draw: st.DrawFn) -> Formula:
    """A chain 50–300 operators deep, built bottom-up in a loop (no recursion).

    Each level wraps the chain in an operator (depth + 1 levels in all); a binary or n-ary one
    gets a fresh predicate as its other operand. U and T take the chain on their right, so that
    no U/T has a temporal left operand (that case costs O(T^depth) in any evaluator).
    """
    depth = draw(st.integers(50, 300))
    chain: Formula = draw(S.predicates())
    for _ in range(depth):
        op = draw(st.sampled_from(CHAIN_OPERATORS))
        if op is type(chain) and op in (And, Or):
            op = Not  # an & of an & would flatten into one node: keep every level a level
        if op in (Not, Next, Eventually, Always):
            chain = op(chain)
            continue
        other: Predicate = draw(S.predicates())
        if op in (Until, Then) or draw(st.booleans()):
            chain = op(other, chain) if op not in (And, Or) else op((other, chain))
        else:
            chain = op(chain, other) if op not in (And, Or) else op((chain, other))
    return chain


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(deep_chains(), S.batched_traces(max_length=5, rescale=False), st.sampled_from((0.5, 3.0)))
def test_deep_chains_agree_with_the_reference(formula, trace, beta):
    assert formula.depth >= 51
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 20_000))  # the naive reference recurses; the engine must not
    try:
        expected = reference.robustness(formula, trace)
        expected_smooth = reference.smooth_robustness(formula, trace, beta)
    finally:
        sys.setrecursionlimit(limit)
    np.testing.assert_allclose(formula.robustness(trace), expected, rtol=1e-12, atol=1e-12)
    smooth = formula.smooth_robustness(trace, beta)
    finite = np.isfinite(expected_smooth)
    np.testing.assert_allclose(smooth[finite], expected_smooth[finite], rtol=1e-7, atol=1e-7)
    assert parse(str(formula)) == formula



@pytest.mark.parametrize("op", [Until, Then])
def test_a_chain_nested_through_left_operands_is_evaluated_once_per_prefix(op, monkeypatch):
    """((x > 0 U x > 1) U x > 2) U ...: each temporal left operand is judged on every prefix, once.

    Without sharing the prefixes' values the cost grows as T**depth (a depth-10 chain on 20 states took
    27 s); with it, each of the chain's operators runs its left operand's plan once per prefix length.
    """
    from tl_gym.tltl import exact

    depth, length = 5, 7
    chain: Formula = parse("x > 0")
    for i in range(depth):
        chain = op(chain, parse(f"x > {i + 1}"))
    rng = np.random.default_rng(3)
    trace = {"x": rng.uniform(-1, 7, size=(3, length))}
    runs = []
    original = exact.run
    monkeypatch.setattr(exact, "run", lambda plan, group: runs.append(group.length) or original(plan, group))
    values = chain.robustness(trace)
    assert len(runs) <= 1 + depth * length  # the root's plan, then each left operand once per prefix
    expected = reference.robustness(chain, trace)
    np.testing.assert_allclose(values, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(chain.satisfied(trace), reference.satisfied(chain, trace))
