"""The Markov view (``observe_monitor=True``): the monitor's state in the observation makes rewards Markov."""

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st

import tl_gym
from tl_gym import TLTLRewardWrapper, parse
from tl_gym.monitor_view import MonitorView, augment
from tl_gym.tltl.online import PrefixMonitor

from .test_online import fragment
from .test_wrapper import Scripted

values = st.floats(-3, 3, allow_nan=False, width=32)
episodes = st.integers(1, 10).flatmap(lambda n: st.lists(st.tuples(values, values, values), min_size=n + 1,
                                                          max_size=n + 1))


@settings(max_examples=200, deadline=None)
@given(fragment, episodes, st.sampled_from([math.inf, 5.0]), st.sampled_from([1e4, 2.0]), st.booleans(),
       st.sampled_from([1.0, 0.9]), st.sampled_from([0.0, 2.5]))
def test_dense_reward_is_a_function_of_the_augmented_observations(formula, rows, rho_max, clip, dict_obs, gamma,
                                                                 bonus):
    """Each step's reward from the observations around it (and the end flag); discounted, they add up to
    γ^(T-1) (ρ + bonus · [ρ > 0])."""
    env = TLTLRewardWrapper(Scripted(rows, dict_obs=dict_obs), formula, signals=SIGNALS[dict_obs], rho_max=rho_max,
                            clip=clip, reward_mode="dense", observe_monitor=True, monitor_scale=0.5, gamma=gamma,
                            satisfaction_bonus=bonus)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    total = 0.0
    for t in range(1, len(rows)):
        after, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        assert env.observation_space.contains(after)
        raw = after if dict_obs else after[:3]
        expected_raw = {"pos": np.array(rows[t][:2]), "speed": np.array(rows[t][2:])} if dict_obs else rows[t]
        if dict_obs:
            assert all(np.array_equal(raw[key], expected_raw[key]) for key in ("pos", "speed"))
        else:
            assert np.array_equal(raw, np.asarray(expected_raw, dtype=np.float64))  # raw first, unchanged
        recomputed = env.dense_reward(obs, after, last=terminated or truncated)
        assert recomputed == pytest.approx(reward, rel=1e-9, abs=1e-9), (str(formula), t)
        total += gamma ** (t - 1) * reward
        obs = after
    assert truncated
    rho = min(max(info["robustness"], -clip), clip) + bonus * info["satisfied"]
    assert total == pytest.approx(gamma ** (len(rows) - 2) * rho, rel=1e-9, abs=1e-9)


SIGNALS = {False: {"a": 0, "b": 1}, True: {"a": ("pos", 0), "b": "speed"}}


@settings(max_examples=150, deadline=None)
@given(fragment, episodes, st.sampled_from([math.inf, 5.0]), st.sampled_from([math.inf, 1e4, 2.0]))
def test_features_read_from_the_live_monitor_equal_the_encoded_state(formula, rows, rho_max, clip):
    """`features` reads the nodes directly: the same floats as `encode` of the exported state."""
    view = MonitorView(PrefixMonitor(formula, rho_max), scale=0.5, clip=clip, horizon=4)
    for t, (a, b, _) in enumerate(rows):
        view.update({"a": a, "b": b}, t)
        live = view.features(t)
        assert np.array_equal(live, view.encode(view.monitor.state(), t)), (str(formula), t)
        assert view.space.contains(np.array(live)), (str(formula), t)


def test_a_nan_value_is_encoded_as_in_the_batched_encoding():
    """Unchecked arithmetic can give NaN (inf - inf): the single encoding passes it on with flag 0, as `encode_rows`."""
    view = MonitorView(PrefixMonitor(parse("a * a - b * b > 0")), scale=1.0, clip=10.0, horizon=None)
    view.update({"a": 1e200, "b": 1e200}, 0)
    single = view.features(0)
    rows = view.encode_rows(np.array(view.monitor.state()).reshape(-1, 1), 0)[0]
    assert math.isnan(single[0]) and single[1:] == [0.0, 1.0]
    assert math.isnan(rows[0]) and rows[1:].tolist() == [0.0, 1.0]


def test_a_deep_copied_view_reads_its_own_monitor():
    """The written-out functions read the nodes they were written for: a deep copy writes its own."""
    import copy

    def view_after(*states):
        view = MonitorView(PrefixMonitor(parse("F(a > 1) & G(b < 2) & G(a > 0 | X G b > 1)")), scale=1.0, clip=10.0,
                           horizon=5)
        for t, (a, b) in enumerate(states):
            view.update({"a": a, "b": b}, t)
        return view

    view = view_after((0.5, 0.0))
    twin = copy.deepcopy(view)
    twin.update({"a": 3.0, "b": 1.5}, 1)  # only the twin moves on
    expected_twin, expected_view = view_after((0.5, 0.0), (3.0, 1.5)), view_after((0.5, 0.0))
    assert twin.monitor.state() == expected_twin.monitor.state() != expected_view.monitor.state()
    assert twin.features(1) == expected_twin.features(1)
    assert view.monitor.state() == expected_view.monitor.state() and view.features(0) == expected_view.features(0)


@given(st.lists(st.floats(allow_nan=False, width=32), min_size=1, max_size=6),
       st.lists(st.floats(allow_nan=False), max_size=8), st.sampled_from([np.float32, np.float64]))
def test_augment_packs_the_same_bits_as_concatenate(raw, features, dtype):
    obs = np.array(raw, dtype=dtype)
    packed = augment(obs, features, "monitor")
    assert packed.dtype == np.float64 and packed.flags.writeable and packed.flags.owndata
    expected = np.concatenate([obs.astype(np.float64), np.array(features, dtype=np.float64)])
    assert packed.tobytes() == expected.tobytes()
    assert augment(raw, features, "monitor").tobytes() == np.array([*raw, *features]).tobytes()  # a list observation


def test_box_grows_and_dict_gets_a_key():
    spec = "F(a > 0.5) & G(b < 2)"
    box = TLTLRewardWrapper(Scripted(), spec, signals={"a": 0, "b": 1}, observe_monitor=True)
    # 3 raw + 2 values x 2 features + first (the scripted env states no horizon: no t/T)
    assert box.observation_space.shape == (8,)
    assert box.observation_space.dtype == np.float64
    obs, _ = box.reset(seed=0)
    assert obs[:3].tolist() == Scripted().values[0].tolist() and obs[-1] == 1.0
    with_horizon = TLTLRewardWrapper(Scripted(), spec, signals={"a": 0, "b": 1}, observe_monitor=True, horizon=5)
    obs, _ = with_horizon.reset(seed=0)
    assert with_horizon.observation_space.shape == (9,)
    obs, *_ = with_horizon.step(np.zeros(1, dtype=np.float32))
    assert obs[-2:].tolist() == [0.0, 0.2]  # not first; t / T
    dict_env = TLTLRewardWrapper(Scripted(dict_obs=True), spec, signals=SIGNALS[True], observe_monitor=True)
    assert set(dict_env.observation_space.spaces) == {"pos", "speed", "monitor"}
    obs, _ = dict_env.reset(seed=0)
    assert dict_env.observation_space.contains(obs)


def test_horizon_is_read_from_the_env():
    env = TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=40), "F(c > 0.9)", signals={"c": 0},
                            observe_monitor=True)
    assert env.monitor_view.horizon == 40
    car = gym.make("TLCarNav-v0", observe_monitor=True, horizon=50)
    assert car.get_wrapper_attr("monitor_view").horizon == 50


def test_formula_outside_the_fragment_is_refused_at_construction_naming_it():
    with pytest.raises(ValueError, match=r"'G \(a > 0 -> F b > 1\)' is outside the incremental fragment"):
        TLTLRewardWrapper(Scripted(), "F(a > 1) & G(a > 0 -> F b > 1)", signals={"a": 0, "b": 1},
                          observe_monitor=True)


def test_bad_arguments_are_refused():
    with pytest.raises(TypeError, match="observe_monitor must be True or False"):
        TLTLRewardWrapper(Scripted(), "F(a > 1)", signals={"a": 0}, observe_monitor="yes")
    with pytest.raises(ValueError, match="monitor_scale must be a finite number > 0"):
        TLTLRewardWrapper(Scripted(), "F(a > 1)", signals={"a": 0}, observe_monitor=True, monitor_scale=0.0)

    class Image(Scripted):
        def __init__(self):
            super().__init__()
            self.observation_space = spaces.Box(0, 1, shape=(2, 2))

    with pytest.raises(TypeError, match="1-D Box or a Dict"):
        TLTLRewardWrapper(Image(), "F(a > 1)", signals={"a": (0, 0)}, observe_monitor=True)
    with pytest.raises(ValueError, match="without observe_monitor"):
        TLTLRewardWrapper(Scripted(), "F(a > 1)", signals={"a": 0}).dense_reward(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="without observe_monitor"):
        TLTLRewardWrapper(Scripted(), "F(a > 1)", signals={"a": 0}).monitor_features(np.zeros(3))

    class HasMonitorKey(Scripted):
        def __init__(self):
            super().__init__(dict_obs=True)
            self.observation_space = spaces.Dict({**self.observation_space.spaces, "monitor": spaces.Discrete(2)})

    with pytest.raises(TypeError, match="adds the key 'monitor', which the Dict observation already has"):
        TLTLRewardWrapper(HasMonitorKey(), "F(a > 1)", signals={"a": ("pos", 0)}, observe_monitor=True)


@pytest.mark.parametrize("dict_obs", [False, True])
def test_monitor_features_are_the_appended_part_and_decode_to_the_monitors_state(dict_obs):
    env = TLTLRewardWrapper(Scripted(dict_obs=dict_obs), "F(a > 0.5) & G(b < 2)",
                            signals={"a": ("pos", 0) if dict_obs else 0, "b": ("speed", 0) if dict_obs else 2},
                            observe_monitor=True, reward_mode="dense")
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
    features = env.monitor_features(obs)
    expected = obs["monitor"] if dict_obs else obs[-env.monitor_view.size:]
    assert features.shape == (env.monitor_view.size,) and np.array_equal(features, expected)
    state, first = env.monitor_view.decode(features)
    assert not first and state == pytest.approx(env.monitor_view.monitor.state(), abs=1e-12)
    raw = env.unwrapped._obs()  # the env's own observation, without the monitor
    with pytest.raises(ValueError, match="not an observation of this wrapper: (keys|shape)"):
        env.dense_reward(raw, raw)


@pytest.mark.parametrize("horizon", [0, -3, 2.5, True, "40"])
def test_the_view_refuses_a_horizon_that_is_not_a_positive_int(horizon):
    with pytest.raises(ValueError, match=f"horizon must be an int >= 1 or None, got {horizon!r}"):
        MonitorView(PrefixMonitor(parse("F(a > 1)")), scale=1.0, clip=100.0, horizon=horizon)


def test_decoding_features_of_the_wrong_size_names_both_sizes():
    view = MonitorView(PrefixMonitor(parse("F(a > 1) & G(a < 5)")), scale=1.0, clip=100.0, horizon=10)
    with pytest.raises(ValueError, match=f"expected {view.size} monitor features, got {view.size + 1}"):
        view.decode(np.zeros(view.size + 1))


def test_infinite_values_are_flagged_not_clipped_into_the_features():
    view = MonitorView(PrefixMonitor(parse("a > 0 T b > 0 T a > 1")), scale=1.0, clip=100.0, horizon=None)
    features = view.observe({"a": 0.5, "b": -1.0}, 0)
    # the chain's three values after one state: 0.5, -inf, -inf
    assert features.tolist() == [0.5, 0.0, 0.0, -1.0, 0.0, -1.0, 1.0]
    assert view.decode(features) == ([0.5, -math.inf, -math.inf], True)


@pytest.mark.parametrize("task", [1, 2])
def test_car_passes_gymnasium_and_sb3_env_checks(task):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("TLCarNav-v0", task=task, observe_monitor=True, reward_mode="dense")
    with warnings.catch_warnings():  # the checkers recommend checking the unwrapped env: we mean the wrapper
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version")
        check_env(env, skip_render_check=True)
        sb3_check_env(env, warn=True)


@pytest.mark.parametrize("mode", ["sync", "async", "vector_entry_point"])
def test_car_vector_envs_agree_with_the_single_env(mode):
    kwargs = {"task": 2, "observe_monitor": True, "reward_mode": "dense", "horizon": 30}
    envs = gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode=mode, **kwargs)
    singles = [gym.make("TLCarNav-v0", **kwargs) for _ in range(2)]
    obs, _ = envs.reset(seed=3)
    expected = np.stack([env.reset(seed=3 + i)[0] for i, env in enumerate(singles)])
    assert np.allclose(obs, expected)
    rng = np.random.default_rng(0)
    for _ in range(30):
        actions = rng.uniform(-1, 1, (2, 2)).astype(np.float32)
        obs, rewards, _, truncated, _ = envs.step(actions)
        steps = [env.step(a) for env, a in zip(singles, actions)]
        assert np.allclose(obs, np.stack([s[0] for s in steps]))
        assert np.allclose(rewards, [s[1] for s in steps])
    assert truncated.all()
    envs.close()


def test_sb3_vec_env_and_vec_normalize_run_on_the_view():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(make_vec_env("TLCarNav-v0", n_envs=2, seed=0,
                                     env_kwargs={"task": 1, "observe_monitor": True, "reward_mode": "dense",
                                                 "horizon": 10}))
    obs = venv.reset()
    assert obs.shape == (2, 12)
    total = np.zeros(2)
    for _ in range(10):
        obs, rewards, dones, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
        total += venv.get_original_reward()
    assert dones.all()
    assert np.allclose(total, [info["robustness"] for info in infos])
    assert tl_gym.TLTLRewardWrapper is TLTLRewardWrapper


def test_trace_before_the_first_reset_is_empty():
    env = TLTLRewardWrapper(Scripted(), "F(a > 0.5)", signals={"a": 0}, reward_mode="potential", observe_monitor=True)
    assert {name: values.size for name, values in env.trace.items()} == {"a": 0}


@pytest.mark.parametrize("mode", ["dense", "potential"])
def test_a_deep_copy_of_the_view_runs_on_its_own(mode):
    import copy

    env = gym.make("TLPendulum-v0", observe_monitor=True, reward_mode=mode)
    twin = copy.deepcopy(env)
    first, _ = env.reset(seed=4)
    second, _ = twin.reset(seed=4)
    for _ in range(5):
        action = np.array([0.5], dtype=np.float32)
        (obs_a, r_a, *_), (obs_b, r_b, *_) = env.step(action), twin.step(action)
        assert np.array_equal(obs_a, obs_b) and r_a == r_b


@pytest.mark.parametrize("spec", ["X(a > 1.5)", "F(a > 1.5 & X(a > 1.6))", "G(a > 1.1 | X G(a < 1.9))"])
def test_remembered_states_not_seen_yet_lie_in_the_space_of_a_signal_bounded_away_from_zero(spec):
    """A window's states not seen yet are shown as 0.0: the bounds hold them even when the signal's Box excludes 0."""

    class Positive(Scripted):
        def __init__(self):
            super().__init__(np.full((4, 3), 1.5))
            self.observation_space = spaces.Box(1.0, 2.0, shape=(3,), dtype=np.float64)

    env = TLTLRewardWrapper(Positive(), spec, signals={"a": 0}, observe_monitor=True, horizon=3)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    truncated = False
    while not truncated:
        obs, _, _, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        assert env.observation_space.contains(obs)
