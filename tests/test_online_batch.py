"""BatchPrefixMonitor against n PrefixMonitor's, and the batched car's Markov view against n single cars."""

import copy
import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tl_gym.envs.tasks import task_formula
from tl_gym.envs.vector import CarNavVectorEnv

import tl_gym  # noqa: F401  (registers TLCarNav-v0)
from tl_gym import TraceError, UnknownSignalError, parse
from tl_gym.monitor_view import MonitorView
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.online_batch import BatchPrefixMonitor

from .test_online import fragment, fragment_strategies, predicates

values = st.floats(-3, 3, allow_nan=False, width=32)


def _same(got, expected):
    """Equal up to the last bits of exp and powers (numpy's and the math module's may round differently)."""
    np.testing.assert_allclose(np.asarray(got), np.asarray(expected, dtype=np.float64), rtol=1e-12, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(fragment, st.integers(1, 3), st.integers(1, 10), st.data(), st.sampled_from([math.inf, 5.0]))
def test_batch_reports_the_values_and_states_of_n_monitors(formula, n, length, data, rho_max):
    traces = data.draw(st.lists(st.lists(st.tuples(values, values), min_size=length, max_size=length),
                                min_size=n, max_size=n))
    batch = BatchPrefixMonitor(formula, n, rho_max)
    scalars = [PrefixMonitor(formula, rho_max) for _ in range(n)]
    assert batch.slots == scalars[0].slots
    for _ in range(2):  # a reset in between: nothing of the first episode is left
        batch.reset()
        for monitor in scalars:
            monitor.reset()
        for t in range(length):
            a, b = (np.array([trace[t][k] for trace in traces]) for k in (0, 1))
            got = batch.update({"a": a, "b": b})
            _same(got, [m.update({"a": float(a[i]), "b": float(b[i])}) for i, m in enumerate(scalars)])
            _same(batch.state(), [m.state() for m in scalars])
        assert batch.length == length


# Predicates whose arithmetic is undefined at some states of the traces drawn (a < 0, b <= 0).
partial_fragment = fragment_strategies(predicates | st.sampled_from([parse("sqrt(a) > 1"), parse("log(b) < 0.5")]))[
    "fragment"]


@settings(max_examples=200, deadline=None)
@given(partial_fragment, st.integers(1, 3), st.integers(1, 8), st.data())
def test_undefined_arithmetic_raises_where_the_monitors_read_it_and_nowhere_else(formula, n, length, data):
    """A predicate undefined at a state raises in the batch exactly when one of the n monitors reads it there.

    ``log(b) > 0`` alone is judged on s_0: a later state with b <= 0 is never read, and raises in neither.
    """
    traces = data.draw(st.lists(st.lists(st.tuples(values, values), min_size=length, max_size=length),
                                min_size=n, max_size=n))
    batch = BatchPrefixMonitor(formula, n)
    scalars = [PrefixMonitor(formula) for _ in range(n)]
    for t in range(length):
        a, b = (np.array([trace[t][k] for trace in traces]) for k in (0, 1))
        expected, raised = [], []
        for i, monitor in enumerate(scalars):
            try:
                expected.append(monitor.update({"a": float(a[i]), "b": float(b[i])}))
            except TraceError:
                raised.append(i)
        if raised:
            with pytest.raises(TraceError, match="is NaN or infinite at"):
                batch.update({"a": a, "b": b})
            return
        _same(batch.update({"a": a, "b": b}), expected)


def test_a_state_no_part_reads_is_not_evaluated():
    batch, scalar = BatchPrefixMonitor(parse("X(log(b) > 0) & F(a > 1)"), 1), PrefixMonitor(parse(
        "X(log(b) > 0) & F(a > 1)"))
    for a, b in [(0.0, -1.0), (2.0, 3.0), (0.0, -1.0), (0.0, 0.0)]:  # log(b) is read at s_1 alone
        _same(batch.update({"a": np.array([a]), "b": np.array([b])}), [scalar.update({"a": a, "b": b})])


@pytest.mark.parametrize("text", [
    "x > 0 & G F F y > 0",  # φ reads the formula's second signal alone
    "G F (F z > 0 & y < 1) | x > 2",
    "F G (G y > 0) & F G (F x > 1) & z < 0",
])
def test_at_end_nodes_read_their_own_signals_whatever_the_formulas_order(text):
    """``F G φ`` / ``G F φ`` judge φ on its signals' rows of the window, not on the formula's first rows."""
    formula = parse(text)
    rng = np.random.default_rng(0)
    batch = BatchPrefixMonitor(formula, 4)
    scalars = [PrefixMonitor(formula) for _ in range(4)]
    for _ in range(6):
        state = {name: rng.normal(size=4) for name in formula.signals}
        got = batch.update(state)
        _same(got, [m.update({k: float(v[i]) for k, v in state.items()}) for i, m in enumerate(scalars)])
        _same(batch.state(), [m.state() for m in scalars])


CAR_CASES = [(1, "leave", "dense"), (2, "leave", "dense"), (2, "strict", "dense"), (2, "leave", "potential")]


@pytest.mark.parametrize(("task", "no_revisit", "reward_mode"), CAR_CASES)
def test_batched_car_view_equals_single_cars_exactly(task, no_revisit, reward_mode):
    n, horizon = 4, 20
    kwargs = {"task": task, "no_revisit": no_revisit, "observe_monitor": True, "reward_mode": reward_mode,
              "horizon": horizon}
    envs = CarNavVectorEnv(n, **kwargs)
    singles = [gym.make("TLCarNav-v0", **kwargs) for _ in range(n)]
    obs, _ = envs.reset(seed=7)
    assert np.array_equal(obs, np.stack([env.reset(seed=7 + i)[0] for i, env in enumerate(singles)]))
    rng = np.random.default_rng(1)
    ended, restarting = 0, False
    for _ in range(3 * (horizon + 1) - 1):  # three episodes, with the two autoreset steps between them
        actions = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
        obs, rewards, terminated, truncated, info = envs.step(actions)
        assert envs.observation_space.contains(obs)
        if restarting:  # the autoreset step after an episode's end: every car restarts
            expected_obs, expected_rewards = np.stack([env.reset()[0] for env in singles]), np.zeros(n)
            restarting = False
        else:
            steps = [env.step(a) for env, a in zip(singles, actions)]
            expected_obs, expected_rewards = np.stack([s[0] for s in steps]), np.array([s[1] for s in steps])
            assert truncated.tolist() == [s[3] for s in steps]
            if truncated.all():
                ended += 1
                restarting = True
                for key in ("robustness", "satisfied"):
                    assert info[key].tolist() == [s[4][key] for s in steps]
        assert np.array_equal(obs, expected_obs)
        assert np.array_equal(rewards, expected_rewards)
    assert ended == 3


def test_batch_encoding_equals_the_single_encoding():
    formula = task_formula(2)
    view = MonitorView(PrefixMonitor(formula), scale=50.0, clip=100.0, horizon=30)
    batch = BatchPrefixMonitor(formula, 5)
    rng = np.random.default_rng(0)
    flagged = clipped = 0
    for t in range(12):  # the Then chain's later stages are −inf after s_0 (flagged); beyond ±clip, clipped
        batch.update({"x": rng.uniform(-200, 400, 5), "y": rng.uniform(-200, 400, 5)})
        encoded = view.encode_rows(batch.rows, t)
        assert encoded.shape == (5, view.size)
        for i, state in enumerate(batch.state()):
            assert np.array_equal(encoded[i], view.encode(state.tolist(), t))
        flagged += np.isinf(batch.state()).sum()
        clipped += (np.abs(encoded) == 2.0).sum()
    assert flagged and clipped  # both were exercised


@pytest.mark.parametrize("clone", [copy.deepcopy, lambda m: pickle.loads(pickle.dumps(m))])
def test_a_copied_batch_continues_on_its_own(clone):
    formula = parse("G(a > 0 -> X G b < 1) & F(X a > 1) & (a > -1 U b > 1) & X a > 0")
    batch = BatchPrefixMonitor(formula, 3)
    rng = np.random.default_rng(2)
    steps = [{"a": rng.uniform(-2, 2, 3), "b": rng.uniform(-2, 2, 3)} for _ in range(8)]
    for state in steps[:4]:
        batch.update(state)
    twin = clone(batch)
    for state in steps[4:]:
        assert np.array_equal(batch.update(state), twin.update(state))
        assert np.array_equal(batch.state(), twin.state())


@pytest.mark.parametrize("text", ["F(a > 0)", "F(a > 0) & G(a < 2)"])
def test_returned_values_are_not_changed_by_later_updates(text):
    batch = BatchPrefixMonitor(parse(text), 2)
    first = batch.update({"a": np.array([0.5, 1.0])})
    kept = first.copy()
    batch.update({"a": np.array([1.5, 1.5])})
    assert np.array_equal(first, kept)


def test_errors_name_their_culprit():
    with pytest.raises(ValueError, match=r"'G \(a > 0 -> F b > 1\)' is outside the incremental fragment"):
        BatchPrefixMonitor(parse("F(a > 1) & G(a > 0 -> F b > 1)"), 2)
    with pytest.raises(ValueError, match="n must be an int >= 1"):
        BatchPrefixMonitor(parse("F(a > 1)"), 0)
    batch = BatchPrefixMonitor(parse("F(sqrt(a) > 1) & G(b < 2)"), 2)
    with pytest.raises(UnknownSignalError, match="no signal 'b'"):
        batch.update({"a": np.ones(2)})
    with pytest.raises(TraceError, match="signal 'b' is NaN or infinite at trace 1, position 0"):
        batch.update({"a": np.ones(2), "b": np.array([0.0, np.nan])})
    with pytest.raises(TraceError, match=r"predicate 'sqrt\(a\) > 1' is NaN or infinite at trace 0, position 0"):
        batch.update({"a": np.array([-1.0, 1.0]), "b": np.zeros(2)})
    for bad, message in [("7", "'b' must be numbers, got str"), (None, "'b' must be numbers, got NoneType"),
                         (np.zeros(3), r"'b' must hold 2 values \(one per trace\) or one, got shape \(3,\)"),
                         (["1", "2"], "'b' must be numbers, got list")]:
        with pytest.raises(TraceError, match=message):
            BatchPrefixMonitor(parse("F(a > 1) & G(b < 2)"), 2).update({"a": np.ones(2), "b": bad})
    one = BatchPrefixMonitor(parse("F(a > 1) & G(b < 2)"), 2)  # one number, a list, ints: every trace alike
    assert one.update({"a": [0.0, 3], "b": np.array([1])}).tolist() == [-1.0, 1.0]
    assert one.update({"a": np.array([0.0, 3.0]), "b": 1}).tolist() == [-1.0, 1.0]  # a plain number too
