"""PrefixMonitor against the offline engine on every prefix.

Set TL_GYM_HYPOTHESIS_EXAMPLES (default 300) for a longer search of the incremental fragment.
"""

import copy
import math
import os
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tl_gym import TraceError, UnknownSignalError, parse
from tl_gym.logic import F, G, T, U, X, signal
from tl_gym.tltl.ast import Always, Constant, Eventually, Formula
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.online_nodes import is_incremental, outside_fragment

a, b = signal("a"), signal("b")

# Temporal-free formulas over two signals, with arithmetic the engine checks for NaN/inf; a number on the left
# and a predicate of numbers alone take their own paths in the monitors.
predicates = st.sampled_from([
    a < 1, a > -1, b < 0.5, a + b > 0, abs(a - b) < 1, a * b < 0.25, (a - 1) ** 2 < 2, b >= 0, a <= b,
    parse("sqrt(a * a + 1) > 1.5"), parse("exp(b) < 2"), parse("0.5 > a"), parse("-1 <= b"), parse("1 < 2"),
])


def _connectives(leaves: st.SearchStrategy[Formula], max_leaves: int) -> st.SearchStrategy[Formula]:
    """``leaves`` under negations, conjunctions, disjunctions and implications."""
    return st.recursive(
        leaves,
        lambda inner: st.one_of(
            inner.map(lambda f: ~f),
            st.tuples(inner, inner).map(lambda p: p[0] & p[1]),
            st.tuples(inner, inner).map(lambda p: p[0] | p[1]),
            st.tuples(inner, inner).map(lambda p: p[0] >> p[1]),
        ),
        max_leaves=max_leaves,
    )


def _chain(fs):
    out = fs[-1]
    for f in reversed(fs[:-1]):
        out = T(f, out)
    return out


def fragment_strategies(predicates: st.SearchStrategy[Formula]) -> dict[str, st.SearchStrategy[Formula]]:
    """The incremental fragment's formulas built on ``predicates``, and the pieces the tests draw from."""
    state_formulas = _connectives(predicates | st.sampled_from([Constant(True), Constant(False)]), max_leaves=3)
    # Bounded lookahead: Boolean combinations of X^d over temporal-free formulas.
    windowed = st.recursive(
        state_formulas,
        lambda inner: st.one_of(
            inner.map(X),
            inner.map(lambda f: ~f),
            st.tuples(inner, inner).map(lambda p: p[0] & p[1]),
            st.tuples(inner, inner).map(lambda p: p[0] | p[1]),
            st.tuples(inner, inner).map(lambda p: p[0] >> p[1]),
        ),
        max_leaves=4,
    )
    then_chains = st.lists(state_formulas, min_size=2, max_size=4).map(_chain)
    never_again = st.one_of(
        st.tuples(windowed, state_formulas).map(lambda p: G(p[0] >> X(G(p[1])))),
        st.tuples(windowed, state_formulas).map(lambda p: G(p[0] | X(G(p[1])))),
    )
    temporal_atoms = st.one_of(
        windowed, windowed.map(F), windowed.map(G), then_chains, never_again,
        windowed.map(lambda f: F(G(f))), windowed.map(lambda f: G(F(f))), then_chains.map(lambda f: F(G(f))),
        # F G / G F over any temporal φ: φ at the last state, φ's signals any of the formula's
        st.one_of(never_again, windowed.map(F), windowed.map(G)).map(lambda f: F(G(f))),
        st.one_of(then_chains, windowed.map(G)).map(lambda f: G(F(f))),
        st.tuples(state_formulas, state_formulas).map(lambda p: U(p[0], p[1])),
    )
    fragment = _connectives(temporal_atoms | state_formulas, max_leaves=4)
    return {"state_formulas": state_formulas, "windowed": windowed, "then_chains": then_chains,
            "never_again": never_again, "fragment": fragment}


_built = fragment_strategies(predicates)
state_formulas, windowed, then_chains, never_again, fragment = (
    _built[name] for name in ("state_formulas", "windowed", "then_chains", "never_again", "fragment"))
# Outside the fragment: a temporal operator over a temporal operand.
unbounded = st.one_of(then_chains, never_again, windowed.map(F), windowed.map(G))
nested = st.one_of(
    unbounded.filter(lambda f: not isinstance(f, Always)).map(F),
    unbounded.filter(lambda f: not isinstance(f, Eventually)).map(G), unbounded.map(X),
    st.tuples(unbounded, fragment).map(lambda p: U(p[0], p[1])),
    st.tuples(fragment, unbounded).map(lambda p: U(p[0], p[1])),
    st.tuples(unbounded, fragment).map(lambda p: T(p[0], p[1])),
    st.tuples(windowed.filter(lambda f: f.is_temporal), fragment).map(lambda p: T(p[0], p[1])),
)
values = st.floats(-3, 3, allow_nan=False, width=32)
traces = st.integers(1, 9).flatmap(lambda n: st.tuples(st.lists(values, min_size=n, max_size=n),
                                                        st.lists(values, min_size=n, max_size=n)))
rho_maxes = st.sampled_from([math.inf, 5.0])


def _check_every_prefix(formula: Formula, trace: tuple, rho_max: float) -> PrefixMonitor:
    xs, ys = np.array(trace[0], dtype=np.float64), np.array(trace[1], dtype=np.float64)
    monitor = PrefixMonitor(formula, rho_max)
    for t in range(len(xs)):
        got = monitor.update({"a": xs[t], "b": ys[t]})
        expected = formula.robustness({"a": xs[: t + 1], "b": ys[: t + 1]}, rho_max)
        assert got == pytest.approx(expected, rel=1e-12, abs=1e-12), (str(formula), t)
        if monitor.incremental:  # the exported state alone gives the value
            assert monitor.value_of_state(monitor.state()) == got, (str(formula), t)
    assert monitor.length == len(xs)
    return monitor


@settings(max_examples=int(os.environ.get("TL_GYM_HYPOTHESIS_EXAMPLES", 300)), deadline=None)
@given(fragment, traces, rho_maxes)
def test_incremental_fragment_matches_engine_on_every_prefix(formula, trace, rho_max):
    monitor = _check_every_prefix(formula, trace, rho_max)
    assert monitor.incremental


@settings(max_examples=80, deadline=None)
@given(nested, traces, rho_maxes)
def test_replay_fallback_matches_engine_on_every_prefix(formula, trace, rho_max):
    monitor = _check_every_prefix(formula, trace, rho_max)
    assert not monitor.incremental


def test_replay_fallback_past_its_first_buffer_matches_engine_and_survives_a_copy():
    """Outside the fragment the monitor keeps the prefix in a buffer of 64 states that doubles when full; the
    values stay the engine's on every prefix across the growths (64, 128), and a copy taken past one continues."""
    formula = parse("G(a > 2 -> F b < 0)")
    rng = np.random.default_rng(0)
    a, b = rng.normal(2.0, 1.0, 200), rng.normal(0.5, 1.0, 200)
    monitor = PrefixMonitor(formula, 5.0)
    assert not monitor.incremental
    for t in range(150):
        expected = float(formula.robustness({"a": a[: t + 1], "b": b[: t + 1]}, 5.0))
        assert monitor.update({"a": float(a[t]), "b": float(b[t])}) == pytest.approx(expected, abs=1e-12), t
    copied = pickle.loads(pickle.dumps(monitor))
    for t in range(150, 200):
        expected = float(formula.robustness({"a": a[: t + 1], "b": b[: t + 1]}, 5.0))
        state = {"a": float(a[t]), "b": float(b[t])}
        assert copied.update(state) == monitor.update(state) == pytest.approx(expected, abs=1e-12), t
    assert copied.length == monitor.length == 200


@settings(max_examples=100, deadline=None)
@given(fragment | nested, traces, st.integers(0, 9), st.sampled_from(["pickle", "deepcopy"]))
def test_a_copy_taken_mid_trace_continues_as_the_original(formula, trace, split, how):
    """Pickled or copied after ``split`` states (the generated code compiled again, the state loaded), a
    monitor reports what the original reports on every later state, to the bit."""
    original = PrefixMonitor(formula, 5.0)
    states = [{"a": float(x), "b": float(y)} for x, y in zip(*trace)]
    split = min(split, len(states))
    for state in states[:split]:
        original.update(state)
    copied = pickle.loads(pickle.dumps(original)) if how == "pickle" else copy.deepcopy(original)
    assert copied.length == original.length == split
    for state in states[split:]:
        assert copied.update(state) == original.update(state), str(formula)
    if original.incremental and states:
        assert copied.state() == original.state()
    copied.reset()  # and it starts over as a fresh monitor does
    fresh = PrefixMonitor(formula, 5.0)
    assert [copied.update(s) for s in states] == [fresh.update(s) for s in states]


@settings(max_examples=50, deadline=None)
@given(fragment, traces, traces)
def test_reset_forgets_the_previous_trace(formula, first, second):
    reused, fresh = PrefixMonitor(formula), PrefixMonitor(formula)
    for x, y in zip(*first):
        reused.update({"a": x, "b": y})
    reused.reset()
    assert reused.length == 0
    for x, y in zip(*second):
        assert reused.update({"a": x, "b": y}) == fresh.update({"a": x, "b": y})


def test_fragment_membership():
    assert is_incremental(parse("F(a > 1) & G(b < 2) | !X(a < 0) -> (a < 1 U b > 0)"))
    assert is_incremental(parse("a > 1 & (b < 0 T a > 2 T b > 3)"))
    assert is_incremental(parse("G((a > 1 & X a < 1) -> X G a < 1) & F(X X b > 0)"))
    assert not is_incremental(parse("G(a > 1 -> F b > 0)"))
    assert is_incremental(parse("F G a > 1"))  # on a finite trace: a > 1 at the last state
    assert is_incremental(parse("G F (a > 1 U b > 0) & F G (a > 0 T b > 0)"))
    assert not is_incremental(parse("F F G a > 1"))
    assert not is_incremental(parse("(F a > 1) T b > 0"))


@pytest.mark.parametrize(("task", "no_revisit"), [(1, "leave"), (2, "leave"), (2, "strict")])
def test_both_car_tasks_are_incremental(task, no_revisit):
    from tl_gym.envs.tasks import task_formula

    formula = task_formula(task, no_revisit)
    monitor = PrefixMonitor(formula)
    assert monitor.incremental
    rng = np.random.default_rng(task)
    xy = np.cumsum(rng.normal(0, 25, size=(120, 2)), axis=0) + 150  # a car wandering through the goals
    for t in range(len(xy)):
        got = monitor.update({"x": xy[t, 0], "y": xy[t, 1]})
        expected = formula.robustness({"x": xy[: t + 1, 0], "y": xy[: t + 1, 1]})
        assert got == pytest.approx(expected, rel=1e-12, abs=1e-12), t


def test_nan_signal_and_undefined_arithmetic_raise():
    monitor = PrefixMonitor(parse("F(sqrt(a) > 1)"))
    monitor.update({"a": 4.0})
    with pytest.raises(TraceError, match="'a'.*position 1"):
        monitor.update({"a": float("nan")})
    monitor.reset()
    with pytest.raises(TraceError, match="sqrt"):
        monitor.update({"a": -1.0})
    with pytest.raises(TraceError, match=r"'1 / a > 0' is NaN or infinite"):
        PrefixMonitor(parse("G(1 / a > 0)")).update({"a": 0.0})


# Arithmetic through ±inf to a finite margin: Python's floats raise on log(0), 1 / 0, exp(1000) where numpy's (the
# offline evaluators') go on; the single-state monitors must give the offline value, not an error.
through_infinity = st.sampled_from([
    parse("max(log(abs(a)), -20) < 1"), parse("min(max(1 / b, -10), 10) > 0.2"), parse("exp(0 - 1 / (a * a)) < 0.5"),
    parse("max(1, log(a)) > 0"), parse("min(exp(1000 * b), 3) > 1"),
])


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_arithmetic_through_infinity_matches_the_offline_value(data):
    states = st.sampled_from([0.0, -0.0, 1.0, -2.0, 0.5, 3.0])
    formula = data.draw(st.one_of(through_infinity.map(F), through_infinity.map(G),
                                  st.tuples(through_infinity, through_infinity).map(lambda p: U(p[0], p[1]))))
    trace = np.array(data.draw(st.lists(st.tuples(states, states), min_size=1, max_size=6)))
    monitor = PrefixMonitor(formula)
    for t, (x, y) in enumerate(trace.tolist()):  # Python floats, as the wrapper's signals
        try:
            expected = formula.robustness({"a": trace[: t + 1, 0], "b": trace[: t + 1, 1]})
        except TraceError:  # a margin that ends NaN or infinite (log of a negative): both raise
            with pytest.raises(TraceError, match="is NaN or infinite at this state"):
                monitor.update({"a": x, "b": y})
            return
        assert monitor.update({"a": x, "b": y}) == expected, (formula, trace, t)


@pytest.mark.parametrize("text", ["min(0, a * a - a * a) < 1", "G(max(a * a - a * a, 1) > 0)",
                                  "F(min(1, 2, sqrt(a - 1e300)) < 3)"])
def test_min_and_max_propagate_a_nan_operand_as_the_offline_evaluators(text):
    """Python's min and max drop a NaN that is not their first argument; the monitors' must not (engine.md)."""
    formula = parse(text)
    with pytest.raises(TraceError):
        formula.robustness({"a": [1e200]})
    with pytest.raises(TraceError):
        PrefixMonitor(formula).update({"a": 1e200})


@pytest.mark.parametrize(
    ("value", "shown"), [("3", "str"), (None, "NoneType"), (np.array([3.0]), r"ndarray of shape \(1,\)")]
)
def test_a_state_that_is_not_one_number_is_named(value, shown):
    """`obs[0:1]` or a string: math.isfinite's TypeError ("only 0-dimensional arrays...") named no signal."""
    monitor = PrefixMonitor(parse("F(a > 2) & G(b < 5)"))
    with pytest.raises(TraceError, match=f"signal 'b' must be one number, got {shown}"):
        monitor.update({"a": 1.0, "b": value})


def test_missing_signal_and_bad_arguments():
    with pytest.raises(UnknownSignalError, match="'b'"):
        PrefixMonitor(parse("F(a > b)")).update({"a": 1.0})
    with pytest.raises(ValueError, match="rho_max"):
        PrefixMonitor(parse("F(a > 0)"), rho_max=0.0)
    with pytest.raises(TypeError, match="Formula"):
        PrefixMonitor("F(a > 0)")  # type: ignore[arg-type]


@pytest.mark.parametrize("module", ["tl_gym.tltl.online", "tl_gym.tltl.online_nodes", "tl_gym.tltl.windowed"])
def test_online_module_does_not_import_gymnasium(module):
    import ast
    import importlib.util

    with open(importlib.util.find_spec(module).origin) as handle:
        source = handle.read()
    imported = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            imported.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert imported <= {"__future__", "math", "collections", "operator", "typing", "numpy", "tl_gym"}, imported


@settings(max_examples=150, deadline=None)
@given(fragment, traces, traces, st.integers(0, 8))
def test_the_state_determines_every_later_value(formula, first, second, cut):
    """Markov: a monitor restored from another's state at step t reports the same values afterwards."""
    original = PrefixMonitor(formula)
    states = list(zip(*first)) + list(zip(*second))
    cut = min(cut, len(states) - 1)
    for x, y in states[: cut + 1]:
        original.update({"a": x, "b": y})
    restored = PrefixMonitor(formula)
    restored._root.load(original.state(), 0)
    for x, y in states[cut + 1 :]:
        assert restored._root.update({"a": x, "b": y}) == original.update({"a": x, "b": y}), str(formula)
        assert restored.state() == original.state()


def test_state_outside_the_fragment_names_the_culprit():
    monitor = PrefixMonitor(parse("F(a > 1) & G(a > 2 -> F b < 0)"))
    assert str(outside_fragment(monitor.formula)) == "G (a > 2 -> F b < 0)"
    with pytest.raises(ValueError, match=r"'G \(a > 2 -> F b < 0\)' is outside the incremental fragment"):
        monitor.state()
    assert outside_fragment(parse("F(a > 1)")) is None


def test_the_monitor_module_keeps_its_public_names():
    """`Slot`, `is_incremental` and `outside_fragment` live in online_nodes and import from online too."""
    from tl_gym.tltl import online, online_nodes

    for name in ("Slot", "is_incremental", "outside_fragment"):
        assert getattr(online, name) is getattr(online_nodes, name)


def test_value_of_state_checks_the_length():
    monitor = PrefixMonitor(parse("F(a > 1) & G(b < 0)"))
    assert len(monitor.slots) == 2
    with pytest.raises(ValueError, match="2 floats, got 3"):
        monitor.value_of_state([0.0, 1.0, 2.0])


@pytest.mark.parametrize("negations", [0, 33])
def test_formulas_deeper_than_the_closures_judge_a_window_as_the_shallow_ones(negations):
    """Past 64 levels a window is judged by the exact evaluator; it evaluated every part at every state of the
    window (robustness_over_time), so `log(a) > -5`, read at s_0 alone, raised at a = 0 in s_1."""
    formula = parse("(log(a) > -5) & X(b > 0)")
    for _ in range(negations):
        formula = ~~formula
    monitor = PrefixMonitor(formula)
    values = [monitor.update({"a": 1.0, "b": 0.0}), monitor.update({"a": 0.0, "b": 1.0})]
    assert values[-1] == formula.robustness({"a": np.array([1.0, 0.0]), "b": np.array([0.0, 1.0])}) == 1.0
