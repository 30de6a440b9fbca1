"""TLTLRewardWrapper on scripted envs, in vector envs and in SB3 VecEnvs."""

import math
import pickle
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

import tl_gym
from tl_gym import SpecError, TLTLRewardWrapper, TraceError, UnknownSignalError, parse


class Scripted(gym.Env):
    """Replays ``values`` (T+1, 3) as observations; the env's own reward is 1 per step; truncates at T."""

    metadata = {"render_modes": []}

    def __init__(self, values=None, dict_obs=False, terminate=False):
        default = np.linspace(0, 1, 18).reshape(6, 3)
        self.values = np.asarray(values if values is not None else default, dtype=np.float64)
        self.dict_obs = dict_obs
        self.terminate = terminate
        box = spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float64)
        if dict_obs:
            self.observation_space = spaces.Dict({
                "pos": spaces.Box(-np.inf, np.inf, shape=(2,), dtype=np.float64),
                "speed": spaces.Box(-np.inf, np.inf, shape=(1,), dtype=np.float64),
            })
        else:
            self.observation_space = box
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.t = 0

    def _obs(self):
        row = self.values[self.t]
        if self.dict_obs:
            return {"pos": row[:2].copy(), "speed": row[2:].copy()}
        return row.copy()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self._obs(), {"t": 0}

    def step(self, action):
        self.t += 1
        end = self.t == len(self.values) - 1
        return self._obs(), 1.0, end and self.terminate, end and not self.terminate, {"t": self.t}


def run(env, seed=0):
    """One episode with zero actions: (rewards, last info)."""
    env.reset(seed=seed)
    rewards = []
    while True:
        _, reward, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        rewards.append(reward)
        if terminated or truncated:
            return rewards, info


SPEC = "F(a > 0.5) & G(b < 0.9)"


@pytest.mark.parametrize("terminate", [False, True])
def test_terminal_reward_is_the_robustness_of_the_recorded_trace(terminate):
    env = TLTLRewardWrapper(Scripted(terminate=terminate), SPEC, signals={"a": 0, "b": 2})
    rewards, info = run(env)
    values = env.unwrapped.values
    trace = {"a": values[:, 0], "b": values[:, 2]}
    expected = parse(SPEC).robustness(trace)
    assert rewards[:-1] == [0.0] * (len(values) - 2)
    assert rewards[-1] == expected and type(rewards[-1]) is float
    assert info["robustness"] == expected
    assert info["satisfied"] == (expected > 0)
    assert set(info["trace"]) == {"a", "b"}
    np.testing.assert_array_equal(info["trace"]["a"], values[:, 0])
    assert "smooth_robustness" not in info


def test_smooth_reward_and_info():
    env = TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2}, reward="smooth", beta=3.0)
    rewards, info = run(env)
    values = env.unwrapped.values
    trace = {"a": values[:, 0], "b": values[:, 2]}
    assert rewards[-1] == pytest.approx(parse(SPEC).smooth_robustness(trace, 3.0))
    assert info["smooth_robustness"] == rewards[-1]
    assert info["robustness"] == parse(SPEC).robustness(trace)


@pytest.mark.parametrize("spec", [SPEC, "G(a > 0.1 -> F(b > 0.8))", "a < 0.2 U (b > 0.5 & X a > 0.6)"])
def test_dense_rewards_sum_to_the_terminal_robustness(spec):
    values = np.random.default_rng(0).uniform(-1, 1, size=(30, 3))
    dense = TLTLRewardWrapper(Scripted(values), spec, signals={"a": 0, "b": 2}, reward_mode="dense")
    rewards, info = run(dense)
    assert math.fsum(rewards) == pytest.approx(info["robustness"], abs=1e-12)
    # each step pays the change of the prefix robustness
    formula = parse(spec)
    prefix = [formula.robustness({"a": values[: t + 1, 0], "b": values[: t + 1, 2]}) for t in range(1, 30)]
    np.testing.assert_allclose(np.cumsum(rewards), prefix, atol=1e-12)
    assert dense._monitor.incremental == (spec == SPEC)


def test_dense_rewards_are_clipped_and_sum_to_the_clipped_robustness():
    env = TLTLRewardWrapper(Scripted(), "G(a > -1) & true", signals={"a": 0}, reward_mode="dense", clip=0.5)
    rewards, info = run(env)
    assert sum(rewards) == pytest.approx(0.5) and max(abs(r) for r in rewards) <= 0.5
    assert info["robustness"] == 1.0


# x rises past 0.5 at step 3 (F x > 0.5 satisfied from then on) and past 0.9 at step 5 (G x < 0.9 broken)
RISE = np.array([[0.0], [0.2], [0.4], [0.6], [0.8], [1.0]]).repeat(3, axis=1)


@pytest.mark.parametrize(("spec", "satisfied"), [("F(a > 0.5)", True), ("F(a > 0.5) & G(a < 0.9)", False)])
def test_the_terminal_satisfaction_bonus_adds_to_a_satisfied_episode_only(spec, satisfied):
    rewards, info = run(TLTLRewardWrapper(Scripted(RISE), spec, signals={"a": 0}, satisfaction_bonus=10.0))
    assert info["satisfied"] is satisfied and rewards[:-1] == [0.0] * 4
    assert rewards[-1] == pytest.approx(info["robustness"] + (10.0 if satisfied else 0.0))
    smooth = TLTLRewardWrapper(Scripted(RISE), spec, signals={"a": 0}, reward="smooth", beta=2.0,
                               satisfaction_bonus=10.0)
    rewards, info = run(smooth)  # [ρ > 0] is the exact one's: the smooth value can differ in sign
    assert rewards[-1] == pytest.approx(info["smooth_robustness"] + (10.0 if satisfied else 0.0))


def test_the_dense_satisfaction_bonus_is_paid_when_the_prefix_is_satisfied_and_taken_back_when_broken():
    spec = "F(a > 0.5) & G(a < 0.9)"
    plain, info = run(TLTLRewardWrapper(Scripted(RISE), spec, signals={"a": 0}, reward_mode="dense"))
    bonus, info_bonus = run(TLTLRewardWrapper(Scripted(RISE), spec, signals={"a": 0}, reward_mode="dense",
                                              satisfaction_bonus=10.0))
    assert info_bonus["robustness"] == info["robustness"] < 0  # info keeps the exact ρ
    # prefixes: s_0..s_2 unsatisfied, s_0..s_3 and s_0..s_4 satisfied, s_0..s_5 broken
    np.testing.assert_allclose(np.subtract(bonus, plain), [0.0, 0.0, 10.0, 0.0, -10.0], atol=1e-12)
    assert math.fsum(bonus) == pytest.approx(info["robustness"], abs=1e-12)
    satisfied, info = run(TLTLRewardWrapper(Scripted(RISE), "F(a > 0.5)", signals={"a": 0}, reward_mode="dense",
                                            satisfaction_bonus=10.0))
    assert math.fsum(satisfied) == pytest.approx(info["robustness"] + 10.0, abs=1e-12)


def test_a_violation_takes_the_dense_bonus_back_and_ends_the_episode_with_end_on_violation():
    # the pair SAC's TLParking-v0 entry sets: the prefix is satisfied at s_3, broken at s_5; the episode stops there
    spec, values = "F(a > 0.5) & G(a < 0.9)", np.vstack([RISE, np.ones((4, 3))])
    env = TLTLRewardWrapper(Scripted(values), spec, signals={"a": 0}, reward_mode="dense",
                            satisfaction_bonus=10.0, end_on_violation=True)
    rewards, info = run(env)
    plain, _ = run(TLTLRewardWrapper(Scripted(RISE), spec, signals={"a": 0}, reward_mode="dense"))
    assert len(rewards) == 5 and info["violated"] == "G a < 0.9" and not info["satisfied"]
    np.testing.assert_allclose(np.subtract(rewards, plain), [0.0, 0.0, 10.0, 0.0, -10.0], atol=1e-12)
    assert math.fsum(rewards) == pytest.approx(info["robustness"], abs=1e-12)  # no bonus left in the return


def test_infinite_robustness_is_clipped_to_a_float():
    rewards, info = run(TLTLRewardWrapper(Scripted(), "true", signals={}))
    assert info["robustness"] == math.inf and rewards[-1] == tl_gym.wrapper.DEFAULT_CLIP
    rewards, _ = run(TLTLRewardWrapper(Scripted(), "G(X a > -5)", signals={"a": 0}, clip=7.0))
    assert rewards[-1] == -7.0 and type(rewards[-1]) is float
    rewards, info = run(TLTLRewardWrapper(Scripted(), "G(X a > -5)", signals={"a": 0}, rho_max=3.0))
    assert rewards[-1] == -3.0 == info["robustness"]


def test_env_reward_is_added_with_its_weight():
    rewards, info = run(TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2}, env_reward_weight=0.5))
    assert rewards[:-1] == [0.5] * 4
    assert rewards[-1] == pytest.approx(info["robustness"] + 0.5)


def test_signals_from_keys_tuples_and_callables():
    values = np.random.default_rng(1).uniform(size=(6, 3))
    spec = "F(x > 0.5) & G(v < 0.99) & F(d > 0) & F(t >= 0)"
    signals = {
        "x": ("pos", 0),
        "v": "speed",
        "d": lambda obs: obs["pos"][1] - obs["pos"][0],
        "t": lambda obs, info: info["t"],
        "unused": ("pos", 1),
    }
    env = TLTLRewardWrapper(Scripted(values, dict_obs=True), spec, signals=signals)
    _, info = run(env)
    expected_trace = {"x": values[:, 0], "v": values[:, 2], "d": values[:, 1] - values[:, 0], "t": np.arange(6.0)}
    assert set(info["trace"]) == set(expected_trace)
    for name, expected in expected_trace.items():
        np.testing.assert_allclose(info["trace"][name], expected)
    assert info["robustness"] == parse(spec).robustness(expected_trace)


def test_one_callable_returning_every_signal():
    env = TLTLRewardWrapper(Scripted(), SPEC, signals=lambda obs, info: {"a": obs[0], "b": obs[2], "c": 1.0})
    rewards, info = run(env)
    values = env.unwrapped.values
    assert rewards[-1] == parse(SPEC).robustness({"a": values[:, 0], "b": values[:, 2]})


def test_trace_property_is_read_only_and_grows():
    env = TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2})
    env.reset()
    env.step(np.zeros(1))
    trace = env.trace
    assert len(trace["a"]) == 2
    with pytest.raises(ValueError, match="read-only"):
        trace["a"][0] = 1.0
    with pytest.raises(AttributeError, match="no setter"):
        env.trace = {}


def test_the_terminal_infos_trace_cannot_be_written_either():
    """docs/wrapper.md calls info["trace"] read-only: its arrays were writable (env.trace's were not)."""
    env = TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2})
    env.reset()
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(np.zeros(1))
        done = terminated or truncated
    with pytest.raises(ValueError, match="read-only"):
        info["trace"]["a"][0] = 1.0
    with pytest.raises(TypeError):
        info["trace"]["a"] = np.zeros(3)  # a Mapping, not a dict


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"spec": "F(a >"}, SpecError, "column"),
        ({"spec": 3}, TypeError, "spec"),
        ({"signals": {"a": 0}}, UnknownSignalError, "'b'"),
        ({"signals": {"a": 0, "b": 3}}, ValueError, "'b'.*index 3.*outside"),
        ({"signals": {"a": 0, "b": (0, 1)}}, ValueError, "'b'.*does not pick one element"),
        ({"signals": {"a": 0, "b": "speed"}}, TypeError, "'b'.*Dict"),
        ({"signals": {"a": 0, "b": 1.5}}, TypeError, "'b'"),
        ({"signals": [("a", 0)]}, TypeError, "mapping"),
        ({"reward": "fast"}, ValueError, "reward"),
        ({"reward_mode": "sparse"}, ValueError, "reward_mode"),
        ({"reward_mode": "dense", "reward": "smooth"}, ValueError, "dense"),
        ({"beta": 0.0}, ValueError, "beta"),
        ({"rho_max": -1.0}, ValueError, "rho_max"),
        ({"clip": math.inf}, ValueError, "clip"),
        ({"env_reward_weight": math.nan}, ValueError, "env_reward_weight"),
        ({"satisfaction_bonus": -1.0}, ValueError, "satisfaction_bonus must be a finite number >= 0"),
        ({"satisfaction_bonus": math.inf}, ValueError, "satisfaction_bonus"),
        ({"satisfaction_bonus": math.nan}, ValueError, "satisfaction_bonus"),
        ({"satisfaction_bonus": "10"}, ValueError, "satisfaction_bonus"),
        ({"horizon": 0}, ValueError, "horizon must be"),  # without observe_monitor too: it is written into the spec
        ({"horizon": 2.5}, ValueError, "horizon must be"),
    ],
)
def test_bad_arguments_fail_at_construction(kwargs, error, match):
    arguments = {"spec": SPEC, "signals": {"a": 0, "b": 2}, **kwargs}
    with pytest.raises(error, match=match):
        TLTLRewardWrapper(Scripted(), **arguments)


def test_an_env_that_is_not_a_gymnasium_env_is_refused_naming_its_type():
    with pytest.raises(TypeError, match="env must be a gymnasium.Env, got str"):
        TLTLRewardWrapper("Pendulum-v1", SPEC, signals={"a": 0, "b": 2})


@pytest.mark.parametrize(
    ("signals", "error", "match"),
    [
        ({"a": ("pos",)}, ValueError, r"'a'.*'pos'.*not one number.*\('pos', 0\)$"),
        ({"a": ("nope", 0)}, ValueError, "'a'.*no key 'nope'"),
        ({"a": ("pos", 2)}, ValueError, "'a'.*outside"),
        ({"a": 0}, TypeError, "'a'.*Dict.*index"),
    ],
)
def test_bad_dict_signals_fail_at_construction(signals, error, match):
    with pytest.raises(error, match=match):
        TLTLRewardWrapper(Scripted(dict_obs=True), "F(a > 0)", signals=signals)


@pytest.mark.parametrize(
    ("signals", "error", "match"),
    [
        ({"a": lambda obs: obs[:2]}, ValueError, "'a'.*one real number.*shape \\(2,\\)"),
        ({"a": lambda obs: "high"}, TypeError, "'a'.*real number.*str"),
        ({"a": lambda obs: obs[0] > 0.5}, TypeError, "'a' must be a real number, got bool: np.False_"),  # numpy's too
        (lambda obs, info: {"b": 1.0}, UnknownSignalError, "'a'"),
        (lambda obs, info: [1.0], TypeError, "mapping"),
    ],
)
def test_bad_callable_signals_fail_at_the_first_reset(signals, error, match):
    env = TLTLRewardWrapper(Scripted(), "F(a > 0)", signals=signals)
    with pytest.raises(error, match=match):
        env.reset()


def test_a_callable_with_its_own_defaulted_parameter_gets_the_observation_alone():
    goal = np.array([0.5, 0.5])

    def dist(obs, goal=goal):  # its second parameter is its own: not handed info
        return float(np.linalg.norm(obs[:2] - goal))

    env = TLTLRewardWrapper(Scripted(), "F(d < 0.1) & F(n > 0) & F(i >= 0)",
                            signals={"d": dist, "n": np.linalg.norm, "i": lambda obs, info=None: info["t"]})
    _, info = run(env)
    values = env.unwrapped.values
    np.testing.assert_allclose(info["trace"]["d"], np.linalg.norm(values[:, :2] - goal, axis=1))
    np.testing.assert_allclose(info["trace"]["n"], np.linalg.norm(values, axis=1))
    np.testing.assert_array_equal(info["trace"]["i"], np.arange(6.0))  # the parameter named `info` was handed it


@pytest.mark.skipif(sys.version_info < (3, 11), reason="PEP 678 notes (add_note) are Python 3.11's")
def test_an_error_in_a_signal_callable_names_the_signal():
    def broken(obs):
        return obs["missing"]

    env = TLTLRewardWrapper(Scripted(), "F(a > 0)", signals={"a": broken})
    with pytest.raises(IndexError) as caught:
        env.reset()
    assert "raised by the callable of signal 'a', called as fn(obs)" in caught.value.__notes__
    every = TLTLRewardWrapper(Scripted(), "F(a > 0)", signals=lambda obs, info: {"a": info["missing"]})
    with pytest.raises(KeyError) as caught:
        every.reset()
    assert "raised by the signals callable" in caught.value.__notes__[0]
    later = TLTLRewardWrapper(Scripted(), "F(a > 0)", signals=lambda obs, info: {"a": [1.0, 2.0][info["t"]]})
    later.reset()
    later.step(np.zeros(1))
    with pytest.raises(IndexError) as caught:  # a failure after the first reset carries the note too
        later.step(np.zeros(1))
    assert "raised by the signals callable" in caught.value.__notes__[0]


def test_key_index_signals_survive_the_specs_json_round_trip():
    """JSON writes a (key, index) tuple as a list; the spec's env must come back the same."""
    from gymnasium.envs.registration import EnvSpec

    gym.register("ScriptedDict-v0", entry_point="tests.test_wrapper:Scripted", kwargs={"dict_obs": True})
    try:
        env = TLTLRewardWrapper(gym.make("ScriptedDict-v0"), "F(x > 0.5)", signals={"x": ("pos", 0)})
        again = gym.make(EnvSpec.from_json(env.spec.to_json()))
        _, info = run(again)
        np.testing.assert_allclose(info["trace"]["x"], again.unwrapped.values[:, 0])
    finally:
        gym.registry.pop("ScriptedDict-v0")


def test_nan_signal_names_the_signal_and_the_step():
    values = np.zeros((6, 3))
    values[3, 2] = np.nan
    env = TLTLRewardWrapper(Scripted(values), SPEC, signals={"a": 0, "b": 2})
    env.reset()
    env.step(np.zeros(1))
    env.step(np.zeros(1))
    with pytest.raises(TraceError, match="signal 'b' is nan at step 3"):
        env.step(np.zeros(1))
    values[:] = 0.0
    values[0, 0] = np.inf
    with pytest.raises(TraceError, match="signal 'a' is inf at step 0"):
        env.reset()


def test_step_before_reset_or_after_the_end_raises():
    env = TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2})
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1))
    run(env)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1))


def test_formula_attribute_spec_and_rebuild_from_spec():
    env = gym.make("TLCarNav-v0", horizon=5)
    formula = env.get_wrapper_attr("formula")
    assert formula == tl_gym.envs.tasks.task_formula(1)
    recorded = env.spec.additional_wrappers[0]
    assert recorded.name == "TLTLRewardWrapper" and recorded.kwargs["spec"] == str(formula)
    rebuilt = gym.make(env.spec)
    assert rebuilt.get_wrapper_attr("formula") == formula
    (rewards, info), (rebuilt_rewards, rebuilt_info) = run(env, seed=3), run(rebuilt, seed=3)
    assert rewards == rebuilt_rewards
    np.testing.assert_array_equal(info["trace"]["x"], rebuilt_info["trace"]["x"])


def test_pickle_mid_episode():
    env = TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2})
    env.reset()
    env.step(np.zeros(1))
    clone = pickle.loads(pickle.dumps(env))
    assert len(clone.trace["a"]) == 2
    finish = [clone.step(np.zeros(1))[1] for _ in range(4)]
    assert finish[-1] == run(env)[0][-1]


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_gymnasium_vector_envs_across_autoreset(mode):
    horizon = 6
    envs = gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode=mode, horizon=horizon)
    envs.reset(seed=0)
    ended = 0
    actions = np.zeros((2, 2), dtype=np.float32)
    for _ in range(3 * (horizon + 1)):
        _, rewards, terminated, truncated, info = envs.step(actions)
        if truncated.any():
            ended += 1
            assert truncated.all() and info["_robustness"].all()
            np.testing.assert_array_equal(rewards, info["robustness"])
            assert [trace["x"].shape for trace in info["trace"]] == [(horizon + 1,)] * 2  # one trace per env
        else:
            assert (rewards == 0).all()
    envs.close()
    assert ended == 3


def test_sb3_vec_env_across_autoreset():
    from stable_baselines3.common.env_util import make_vec_env

    horizon = 5
    venv = make_vec_env(lambda: gym.make("TLCarNav-v0", task=2, horizon=horizon), n_envs=2, seed=0)
    venv.reset()
    ends = 0
    for _ in range(2 * horizon + 1):
        _, rewards, dones, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
        for reward, done, info in zip(rewards, dones, infos):
            if done:
                ends += 1
                assert reward == pytest.approx(info["robustness"])
                assert len(info["trace"]["x"]) == horizon + 1
                np.testing.assert_allclose(info["trace"]["x"][-1], info["terminal_observation"][0])
            else:
                assert reward == 0
    assert ends == 4


class ClaimsSuccess(gym.Wrapper):
    """Reports its own ``is_success`` at every step, as parking-v0 does."""

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {**info, "is_success": True}


@pytest.mark.parametrize("spec", ["F(a > 0.5)", "F(a > 5)"])
def test_sb3s_success_rate_reads_the_formulas_satisfaction_and_the_envs_own_is_kept(spec):
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(lambda: TLTLRewardWrapper(ClaimsSuccess(Scripted()), spec, signals={"a": 0}), n_envs=1)
    model = PPO("MlpPolicy", venv, n_steps=10, batch_size=10, n_epochs=1, seed=0)
    model.learn(10)  # two episodes of five steps
    satisfied = parse(spec).robustness({"a": Scripted().values[:, 0]}) > 0
    assert list(model.ep_success_buffer) == [satisfied, satisfied]  # rollout/success_rate
    _, info = run(TLTLRewardWrapper(ClaimsSuccess(Scripted()), spec, signals={"a": 0}))
    assert info["is_success"] == info["satisfied"] == satisfied and info["env_is_success"] is True



def test_env_info_gives_the_envs_own_info_back_with_stacked_wrappers_and_violations():
    from tl_gym.wrapper import env_info

    inner = TLTLRewardWrapper(ClaimsSuccess(Scripted()), "F(a > 5)", signals={"a": 0})  # never satisfied
    outer = TLTLRewardWrapper(inner, "G(b < 2)", signals={"b": 2})  # always satisfied; both end at s_5
    _, info = run(outer)
    assert info["is_success"] is True and info["env_is_success"] is True  # the base env's, not the inner formula's
    assert env_info(info) == {"t": 5, "is_success": True}
    silent = TLTLRewardWrapper(TLTLRewardWrapper(Scripted(), "F(a > 5)", signals={"a": 0}), "G(b < 2)",
                               signals={"b": 2})  # an env with no is_success of its own: none comes back
    _, info = run(silent)
    assert "env_is_success" not in info and "is_success" not in env_info(info)
    early = TLTLRewardWrapper(TLTLRewardWrapper(ClaimsSuccess(Scripted()), "F(a > 0.5)", signals={"a": 0}),
                              "G(b < 0.5)", signals={"b": 2}, end_on_violation=True)  # the outer ends first, at s_3
    _, info = run(early)
    assert info["env_is_success"] is True and env_info(info) == {"t": 3, "is_success": True}
    broken = TLTLRewardWrapper(ClaimsSuccess(Scripted()), "G(b < 0.5)", signals={"b": 2}, end_on_violation=True)
    _, info = run(broken)  # b reaches 0.65 at s_3
    assert info["violated"] == "G b < 0.5" and info["is_success"] is False
    assert env_info(info) == {"t": 3, "is_success": True}


class Scalar(gym.Env):
    """A 0-D Box observation: one number with no axis."""

    observation_space = spaces.Box(-1.0, 1.0, shape=(), dtype=np.float64)
    action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.array(0.25), {}

    def step(self, action):
        return np.array(0.75), 0.0, False, True, {}


def test_a_zero_dimensional_box_is_read_by_the_empty_index():
    with pytest.raises(ValueError, match=r"a Box of shape \(\): its one number is the index \(\)"):
        TLTLRewardWrapper(Scalar(), "F(s > 0.5)", signals={"s": 0})
    _, info = run(TLTLRewardWrapper(Scalar(), "F(s > 0.5)", signals={"s": ()}))
    assert info["trace"]["s"].tolist() == [0.25, 0.75] and info["robustness"] == 0.25


def test_observation_space_an_index_cannot_address():
    with pytest.raises(TypeError, match="'state'.*Discrete space"):
        TLTLRewardWrapper(gym.make("FrozenLake-v1"), "F(state > 14)", signals={"state": 0})
    # a callable can still read it
    env = TLTLRewardWrapper(gym.make("FrozenLake-v1"), "F(state > 14)", signals={"state": lambda obs: float(obs)})
    assert env.reset(seed=0)[0] == 0 and env.trace["state"].tolist() == [0.0]


def _breaks_at(step, length=10):
    """Scripted values whose b (column 2) reaches 1 at ``step``; a rises past 0.5 after it."""
    values = np.zeros((length + 1, 3))
    values[:, 0] = np.linspace(0, 1, length + 1)
    values[step, 2] = 1.0
    return values


@pytest.mark.parametrize("reward_mode, gamma", [("terminal", 1.0), ("dense", 1.0), ("potential", 0.9)])
def test_end_on_violation_ends_at_the_first_state_that_breaks_an_invariant(reward_mode, gamma):
    values = _breaks_at(3)
    env = TLTLRewardWrapper(Scripted(values), SPEC, signals={"a": 0, "b": 2}, reward_mode=reward_mode,
                            gamma=gamma, end_on_violation=True)
    env.reset(seed=0)
    steps = [env.step(np.zeros(1, dtype=np.float32)) for _ in range(3)]
    assert [s[2] for s in steps] == [False, False, True] and not any(s[3] for s in steps)
    info = steps[-1][4]
    assert info["violated"] == "G b < 0.9" and len(info["trace"]["b"]) == 4
    shorter = {"a": values[:4, 0], "b": values[:4, 2]}
    assert info["robustness"] == parse(SPEC).robustness(shorter) and not info["satisfied"]
    if reward_mode != "potential":  # the discounted return is γ^(T-1) ρ of the shorter trace (Φ(s_T) = 0)
        assert math.fsum(s[1] * gamma ** t for t, s in enumerate(steps)) == pytest.approx(
            gamma ** 2 * info["robustness"], abs=1e-12)
    assert all("violated" not in s[4] for s in steps[:-1])
    # the verdict is the one the whole episode gets without the option
    _, whole = run(TLTLRewardWrapper(Scripted(values), SPEC, signals={"a": 0, "b": 2}))
    assert len(whole["trace"]["b"]) == 11 and whole["satisfied"] == info["satisfied"]


def test_end_on_violation_keeps_an_episode_that_breaks_nothing_and_ends_on_a_broken_start():
    values = _breaks_at(3)
    values[3, 2] = 0.0
    rewards, info = run(TLTLRewardWrapper(Scripted(values), SPEC, signals={"a": 0, "b": 2}, end_on_violation=True))
    assert len(rewards) == 10 and "violated" not in info and info["satisfied"]
    env = TLTLRewardWrapper(Scripted(_breaks_at(0)), SPEC, signals={"a": 0, "b": 2}, end_on_violation=True)
    rewards, info = run(env)  # reset cannot end an episode: the first step does
    assert len(rewards) == 1 and info["violated"] == "G b < 0.9" and len(info["trace"]["b"]) == 2
    rewards, _ = run(env)  # and a reset starts over
    assert len(rewards) == 1


@pytest.mark.parametrize("terminate", [False, True])
def test_a_violation_on_the_envs_last_step_is_a_termination_and_named(terminate):
    env = TLTLRewardWrapper(Scripted(_breaks_at(10), terminate=terminate), SPEC, signals={"a": 0, "b": 2},
                            end_on_violation=True)
    rewards, info = run(env)
    assert len(rewards) == 10 and info["violated"] == "G b < 0.9" and not info["satisfied"]
    env.reset()
    *_, terminated, truncated, _ = [env.step(np.zeros(1, dtype=np.float32)) for _ in range(10)][-1]
    assert terminated and truncated == (not terminate)


def test_end_on_violation_pickles_mid_episode_and_runs_in_a_vector_env_across_autoreset():
    env = TLTLRewardWrapper(Scripted(_breaks_at(3)), SPEC, signals={"a": 0, "b": 2}, end_on_violation=True)
    env.reset()
    env.step(np.zeros(1, dtype=np.float32))
    clone = pickle.loads(pickle.dumps(env))
    ends = [clone.step(np.zeros(1, dtype=np.float32))[2] for _ in range(2)]
    assert ends == [False, True]
    # the suite's mountain car with a speed limit of 0.01, pushed right from the start: it breaks the limit
    # within about a dozen steps, far before its 250-step horizon
    envs = gym.make_vec("TLMountainCar-v0", num_envs=2, vectorization_mode="sync", speed_limit=0.01,
                        end_on_violation=True)
    envs.reset(seed=[0, 1])
    ended = []
    for t in range(30):
        *_, terminated, truncated, _ = envs.step(np.ones((2, 1), dtype=np.float32))
        ended += [(t, i) for i in range(2) if terminated[i]]
        assert not truncated.any()
    assert {i for _, i in ended} == {0, 1} and len(ended) >= 4  # both ended, were reset and ended again


def test_end_on_violation_needs_an_invariant_and_passes_check_env():
    from gymnasium.utils.env_checker import check_env

    with pytest.raises(ValueError, match=r"F a > 0.5 has no safety invariant"):
        TLTLRewardWrapper(Scripted(), "F(a > 0.5)", signals={"a": 0}, end_on_violation=True)
    with pytest.raises(TypeError, match="end_on_violation"):
        TLTLRewardWrapper(Scripted(), SPEC, signals={"a": 0, "b": 2}, end_on_violation="yes")
    env = TLTLRewardWrapper(Scripted(_breaks_at(3)), SPEC, signals={"a": 0, "b": 2}, end_on_violation=True,
                            observe_monitor=True, reward_mode="dense")
    with warnings.catch_warnings():  # the checker recommends checking the unwrapped env: we mean the wrapper
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version")
        warnings.filterwarnings("ignore", message=".*infinity")  # Scripted's unbounded Box, not the wrapper's doing
        check_env(env, skip_render_check=True)


def test_a_dict_entry_that_is_not_one_number_is_refused_with_advice_that_works():
    """A key reads a one-number Box: for a larger Box the message proposes a tuple with one index per axis, for a
    Discrete entry a callable (no tuple can index it)."""

    class Rooms(Scripted):
        def __init__(self):
            super().__init__(dict_obs=True)
            self.observation_space = spaces.Dict({**self.observation_space.spaces, "room": spaces.Discrete(4)})

        def _obs(self):
            return {**super()._obs(), "room": np.int64(self.t % 4)}

    with pytest.raises(ValueError, match=r"'room' holds a Discrete space.*lambda obs: float\(obs\['room'\]\)"):
        TLTLRewardWrapper(Rooms(), "F(room > 2)", signals={"room": "room"})
    env = TLTLRewardWrapper(Rooms(), "F(room > 2)", signals={"room": lambda obs: float(obs["room"])})
    assert run(env)[1]["trace"]["room"].tolist() == [0.0, 1.0, 2.0, 3.0, 0.0, 1.0]

    class Grid(Scripted):
        def __init__(self):
            super().__init__(dict_obs=True)
            self.observation_space = spaces.Dict({"grid": spaces.Box(0.0, 1.0, shape=(2, 3))})

    with pytest.raises(ValueError, match=r"'grid' holds Box of shape \(2, 3\).*such as \('grid', 0, 0\)$"):
        TLTLRewardWrapper(Grid(), "F(a > 0)", signals={"a": "grid"})
    TLTLRewardWrapper(Grid(), "F(a > 0)", signals={"a": ("grid", 0, 0)})


def test_a_signal_callable_is_called_once_per_state_the_first_reset_included():
    """The first reset called each callable twice (once to check it, once to read it): a counter read 2 at s_0."""
    calls = {"one": 0, "all": 0}

    def counted(obs):
        calls["one"] += 1
        return float(calls["one"])

    def all_at_once(obs, info):
        calls["all"] += 1
        return {"a": float(calls["all"]), "b": 0.0}

    for signals, key in (({"a": counted, "b": 2}, "one"), (all_at_once, "all")):
        env = TLTLRewardWrapper(Scripted(), SPEC, signals=signals)
        _, info = run(env)
        assert info["trace"]["a"].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0] and calls[key] == 6


@pytest.mark.parametrize("name", ["reward", "beta", "clip", "gamma", "satisfaction_bonus", "reward_mode", "rho_max",
                                  "observe_monitor", "monitor_scale"])
def test_the_reward_attributes_are_the_settings_and_cannot_be_set(name):
    """A value set later paid one thing while the spec, the view's features and bounds kept another."""
    env = TLTLRewardWrapper(Scripted(), "F(a > 0.5)", signals={"a": 0}, reward_mode="dense", satisfaction_bonus=2.0)
    assert getattr(env, name) == getattr(env.settings, name)
    with pytest.raises(AttributeError, match=f"{name} is fixed when the env is built.*make the env again"):
        setattr(env, name, getattr(env, name))
    assert env.satisfaction_bonus == 2.0 and env.settings.satisfaction_bonus == 2.0


def test_the_terminal_infos_trace_stays_read_only_through_deepcopy_and_pickle():
    """SB3's DummyVecEnv deep-copies its infos; the async vector envs pickle them."""
    import copy
    import pickle

    from tl_gym.wrapper import Trace

    trace = Trace({"a": np.array([1.0, 2.0])})
    for again in (copy.deepcopy(trace), pickle.loads(pickle.dumps(trace))):
        assert again["a"].tolist() == [1.0, 2.0]
        with pytest.raises(ValueError, match="read-only"):
            again["a"][0] = 0.0
