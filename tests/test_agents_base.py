"""The agent framework: construction checks, learn loop, history, callbacks, predict, evaluate, save/load.

Most tests run REPS (the simplest final agent) on a tiny stand-in env: a point that must
reach a square within 20 steps, which exercises the `SyncVectorEnv` path and episodes
that end early; a few check the car's batched env.
"""

from __future__ import annotations

import io
import json
import math
import re
import sys
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from tl_gym.agents import (
    REPS,
    Agent,
    CallbackList,
    CheckpointCallback,
    EvalCallback,
    LinearGaussianPolicy,
    SB3Agent,
    StopOnRobustness,
    StopOnSuccessRate,
)
from tl_gym.agents.base import _env_from_source
from tl_gym.agents.evaluation import evaluate_policy
from tl_gym.agents.sampling import rollout

import tl_gym
from tl_gym.errors import IncompatibleSaveError

POINT_ID = "tests/PointStandIn-v0"
HORIZON = 20


class PointEnv(gym.Env):
    """A point moved by its velocity action that must reach the square [1, 1.5]^2.

    Reports the wrapper's terminal info (``robustness``, ``satisfied``, ``trace``) itself, so that the
    framework's tests do not depend on the reward wrapper.
    """

    metadata = {"render_modes": []}

    def __init__(self, horizon: int = HORIZON, terminate_in_goal: bool = False, goal: float = 1.0):
        self.horizon = horizon
        self.terminate_in_goal = terminate_in_goal
        self.goal = goal
        self.formula = tl_gym.parse(f"F(x > {goal} & x < {goal + 0.5} & y > {goal} & y < {goal + 0.5})")
        self.observation_space = gym.spaces.Box(-10, 10, (2,), np.float64)
        self.action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = self.np_random.normal(0, 0.05, 2)
        self.path = [self.pos.copy()]
        return self.pos.copy(), {}

    def step(self, action):
        self.pos = self.pos + 0.1 * np.clip(action, -1, 1) + self.np_random.normal(0, 0.01, 2)
        self.path.append(self.pos.copy())
        inside = self.goal < self.pos[0] < self.goal + 0.5 and self.goal < self.pos[1] < self.goal + 0.5
        terminated = bool(self.terminate_in_goal and inside)
        truncated = not terminated and len(self.path) - 1 >= self.horizon
        info, reward = {}, 0.0
        if terminated or truncated:
            path = np.array(self.path)
            trace = {"x": path[:, 0], "y": path[:, 1]}
            reward = float(self.formula.robustness(trace))
            info = {"robustness": reward, "satisfied": reward > 0, "trace": trace}
        return self.pos.copy(), reward, terminated, truncated, info


if POINT_ID not in gym.registry:
    gym.register(POINT_ID, entry_point=PointEnv)


def make_agent(seed: int = 0, **kwargs) -> REPS:
    kwargs.setdefault("n_episodes", 8)
    return REPS(POINT_ID, seed=seed, **kwargs)


def strip_time(history):
    return [{k: v for k, v in row.items() if k != "wall_time"} for row in history]


# construction --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"n_episodes": 1}, ValueError, "n_episodes"),
        ({"horizon": 0}, ValueError, "horizon"),
        ({"epsilon": 0.0}, ValueError, "epsilon"),
        ({"epsilon": -1.0}, ValueError, "epsilon"),
        ({"init_std": 0.0}, ValueError, "init_std"),
        ({"min_std": -1.0}, ValueError, "min_std"),
        ({"covariance": "banded"}, ValueError, "covariance"),
        ({"horizon": 5}, ValueError, "horizon=20"),  # disagrees with the env's 20 steps
        ({"learning_rate": 0.1}, TypeError, "learning_rate"),
    ],
)
def test_bad_hyperparameters_fail_at_construction(kwargs, error, match):
    with pytest.raises(error, match=match):
        make_agent(**kwargs)


def test_env_without_formula_is_rejected():
    with pytest.raises(TypeError, match="TLTLRewardWrapper"):
        REPS("Pendulum-v1", n_episodes=2)


def test_seed_must_be_an_int():
    with pytest.raises(TypeError, match="seed"):
        make_agent(seed=1.5)


@pytest.mark.parametrize("form", ["id", "env", "vector"])
def test_accepts_an_id_an_env_or_a_vector_env(form):
    env = {
        "id": POINT_ID,
        "env": gym.make(POINT_ID),
        "vector": gym.make_vec(POINT_ID, num_envs=4, vectorization_mode="sync"),
    }[form]
    agent = REPS(env, seed=0, n_episodes=8).learn(1)
    assert agent.history[0]["env_steps"] == 8 * HORIZON
    assert agent.horizon == HORIZON


def test_car_uses_its_batched_simulator():
    agent = REPS("TLCarNav-v0", n_episodes=4, env_kwargs={"task": 1})
    assert type(agent.env).__name__ == "CarNavVectorEnv"
    assert agent.horizon == 200 and str(agent.formula) == str(gym.make("TLCarNav-v0").get_wrapper_attr("formula"))


# learn, history, callbacks --------------------------------------------------------------------------
def test_history_rows():
    agent = make_agent().learn(3)
    assert [row["iteration"] for row in agent.history] == [1, 2, 3]
    assert [row["env_steps"] for row in agent.history] == [160, 320, 480]
    for row in agent.history:
        assert list(row)[:5] == ["iteration", "env_steps", "mean_robustness", "success_rate", "wall_time"]
        assert 0.0 <= row["success_rate"] <= 1.0 and np.isfinite(row["mean_robustness"])
        assert {"eta", "kl", "policy_std"} <= set(row)
    assert agent.history[0]["wall_time"] < agent.history[-1]["wall_time"]


def test_history_csv_holds_every_row_as_training_goes(tmp_path):
    import csv

    from tl_gym.agents import HistoryCSV

    path = tmp_path / "live" / "history.csv"
    seen = []

    def rows_on_disk():
        with path.open() as handle:
            return list(csv.DictReader(handle))

    def read_back(agent, row):
        seen.append([r["iteration"] for r in rows_on_disk()])

    agent = make_agent().learn(3, callback=[HistoryCSV(path), read_back])
    assert seen == [["1"], ["1", "2"], ["1", "2", "3"]]
    rows = rows_on_disk()
    assert [float(r["mean_robustness"]) for r in rows] == [row["mean_robustness"] for row in agent.history]


def test_learn_continues_and_chains():
    agent = make_agent()
    assert agent.learn(2) is agent
    agent.learn(1)
    assert [row["iteration"] for row in agent.history] == [1, 2, 3]
    assert agent.num_iterations == 3 and agent.env_steps == 3 * 8 * HORIZON


def test_iterations_must_be_non_negative():
    with pytest.raises(ValueError, match="iterations"):
        make_agent().learn(-1)


def test_callbacks_see_rows_and_stop_training(tmp_path):
    seen = []

    def stop_after_two(agent, row):
        seen.append(row["iteration"])
        return row["iteration"] < 2

    agent = make_agent().learn(5, callback=stop_after_two)
    assert seen == [1, 2] and len(agent.history) == 2

    agent = make_agent().learn(5, callback=[CheckpointCallback(1, tmp_path), StopOnSuccessRate(0.0)])
    assert len(agent.history) == 1
    assert (tmp_path / "agent_1.zip").exists()
    assert CallbackList([lambda a, r: None]).on_iteration(agent, agent.history[0]) is True


def test_stop_on_robustness_stops_once_the_mean_robustness_exceeds_its_threshold():
    stopped = make_agent().learn(4, callback=StopOnRobustness(-1e9))  # every mean exceeds it
    assert len(stopped.history) == 1
    unreachable = make_agent().learn(3, callback=StopOnRobustness(1e9))
    assert len(unreachable.history) == 3


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: StopOnSuccessRate(1.5), ValueError, r"threshold must be in \[0, 1\], got 1.5"),
        (lambda: StopOnSuccessRate("0.5"), ValueError, "threshold must be a finite number, got '0.5'"),
        (lambda: StopOnRobustness(float("nan")), ValueError,
         "threshold must be a finite number, got nan"),
        (lambda: CheckpointCallback(0, "ckpt"), ValueError, "every must be an int >= 1, got 0"),
        (lambda: CheckpointCallback(2.5, "ckpt"), ValueError, "every must be an int >= 1, got 2.5"),
        (lambda: EvalCallback(1, n_episodes=0), ValueError,
         "n_episodes must be an int >= 1, got 0"),
        (lambda: make_agent().learn(1, callback=3), TypeError,
         "callback must be an AbstractCallback, a function or a list of them, got 3"),
    ],
)
def test_a_bad_callback_argument_is_refused_naming_it(make, error, match):
    with pytest.raises(error, match=match):
        make()


def test_a_callback_returning_none_continues_alone_and_in_a_list():
    from tl_gym.agents import AbstractCallback

    class Counts(AbstractCallback):  # forgets to return: None, which is not False
        def on_iteration(self, agent, row):
            pass

    assert len(make_agent().learn(3, callback=Counts()).history) == 3
    assert len(make_agent().learn(3, callback=[Counts(), Counts()]).history) == 3


def test_progress_bar_shows_robustness_and_success(capsys):
    make_agent().learn(2, progress_bar=True)
    err = capsys.readouterr().err
    assert "rho=" in err and "success=" in err and "2/2" in err


def test_same_seed_same_results():
    a, b, c = make_agent(seed=3).learn(3), make_agent(seed=3).learn(3), make_agent(seed=4).learn(3)
    assert strip_time(a.history) == strip_time(b.history)
    np.testing.assert_array_equal(a.policy.mean, b.policy.mean)
    assert strip_time(a.history) != strip_time(c.history)


# predict, evaluate, sampling ------------------------------------------------------------------------
def test_predict_keeps_the_time_index_in_state():
    agent = make_agent()
    agent.policy.mean = np.linspace(-0.5, 0.5, 2 * HORIZON).reshape(HORIZON, 2)
    obs = np.zeros(2)
    action, state = agent.predict(obs)
    np.testing.assert_allclose(action, agent.policy.mean[0])
    assert state == 1
    action, state = agent.predict(obs, state=state)
    np.testing.assert_allclose(action, agent.policy.mean[1])
    batch, states = agent.predict(np.zeros((3, 2)), state=np.array([0, 5, 7]), episode_start=[False, True, False])
    np.testing.assert_allclose(batch, agent.policy.mean[[0, 0, 7]])
    np.testing.assert_array_equal(states, [1, 1, 8])
    noisy, _ = agent.predict(np.zeros((3, 2)), deterministic=False)
    assert not np.allclose(noisy, agent.policy.mean[[0, 0, 0]])


def test_predict_clips_to_the_action_space():
    agent = make_agent(init_mean=3.0)
    action, _ = agent.predict(np.zeros(2))
    np.testing.assert_array_equal(action, [1.0, 1.0])


@pytest.mark.parametrize("shape", [(3,), (4,), (2, 3), (), (0, 5)])
def test_predict_refuses_observations_of_another_size_instead_of_regrouping_them(shape):
    """The point env observes 2 numbers: a 4-vector is not two observations, and 3 are not 1.5 of them."""
    agent = make_agent()
    message = rf"obs must have 2 components \(last axis\), got shape {re.escape(str(shape))}"
    with pytest.raises(ValueError, match=message):
        agent.predict(np.zeros(shape))
    assert agent.predict(np.zeros((5, 2)))[0].shape == (5, 2)
    assert agent.predict(np.zeros((0, 2)))[0].shape == (0, 2)  # an empty batch of the right width is no error


def test_evaluate_matches_a_rollout_of_the_mean_actions():
    agent = make_agent().learn(2)
    result = agent.evaluate(n_episodes=10, seed=7)
    assert set(result) == {"mean_robustness", "success_rate", "robustness", "traces"}
    assert result["robustness"].shape == (10,)
    # the traces are the episodes': the formula's robustness of each is the reported one
    for i, value in enumerate(result["robustness"]):
        assert agent.formula.robustness({k: v[i] for k, v in result["traces"].items()}) == value
    assert result["success_rate"] == np.mean(result["robustness"] > 0)
    means = np.repeat(agent.policy.mean[None], 10, axis=0)
    batch = rollout(agent.env, means, agent.policy.feedback, seed=7)  # the mean policy, its feedback included
    np.testing.assert_allclose(result["robustness"], batch.robustness)
    assert agent.evaluate(n_episodes=10, seed=7)["mean_robustness"] == result["mean_robustness"]


def test_evaluate_policy_on_a_single_env():
    agent = make_agent()
    on_vector = evaluate_policy(agent, agent.env, n_episodes=3, seed=1)
    on_single = evaluate_policy(agent, gym.make(POINT_ID), n_episodes=3, seed=1)
    np.testing.assert_allclose(on_single["robustness"], on_vector["robustness"])
    with pytest.raises(ValueError, match="n_episodes"):
        evaluate_policy(agent, agent.env, n_episodes=0)


def test_evaluate_policy_refuses_an_env_whose_episodes_are_cut_outside_the_wrapper():
    agent = REPS(_walk(time_limit=20), n_episodes=2)
    with pytest.raises(ValueError, match="a TimeLimit of 5 steps wraps"):
        evaluate_policy(agent, gym.wrappers.TimeLimit(_walk(time_limit=20), 5), n_episodes=1)
def test_rollout_records_traces_and_robustness():
    agent = make_agent()
    k = agent.policy.sample_feedforward(12, np.random.default_rng(0))  # 12 episodes on 8 envs: two chunks
    batch = rollout(agent.env, k, seed=0)
    assert batch.traces["x"].shape == (12, HORIZON + 1) and batch.observations.shape == (12, HORIZON + 1, 2)
    np.testing.assert_allclose(batch.traces["x"], batch.observations[:, :, 0])
    np.testing.assert_allclose(batch.robustness, agent.formula.robustness(batch.traces))
    np.testing.assert_array_equal(batch.satisfied, batch.robustness > 0)
    assert batch.env_steps == 12 * HORIZON
    np.testing.assert_array_equal(batch.actions, np.clip(k, -1, 1))
    again = rollout(agent.env, k, seed=0)
    np.testing.assert_array_equal(again.robustness, batch.robustness)


def test_rollout_pads_episodes_that_end_early():
    env = gym.make_vec(POINT_ID, num_envs=3, vectorization_mode="sync", terminate_in_goal=True, goal=0.3)
    speeds = np.array([1.0, 0.5, 0.0])  # the first two reach the goal square early, the last never
    feedforward = np.repeat(speeds[:, None, None], HORIZON, axis=1).repeat(2, axis=2)
    batch = rollout(env, feedforward, seed=0)
    assert batch.lengths[0] < batch.lengths[1] < batch.lengths[2] == HORIZON
    assert batch.env_steps == batch.lengths.sum()
    first = batch.lengths[0]
    assert np.all(batch.traces["x"][0, first:] == batch.traces["x"][0, first])
    assert np.all(batch.actions[0, first:] == 0)
    assert batch.satisfied.tolist() == [True, True, False]


def test_rollout_fails_when_episodes_outlast_the_horizon():
    env = gym.make_vec(POINT_ID, num_envs=2, vectorization_mode="sync")
    with pytest.raises(RuntimeError, match="did not end within 5 steps; set the agent.s horizon"):
        rollout(env, np.zeros((2, 5, 2)), seed=0)


# save / load -----------------------------------------------------------------------------------------
def test_saved_agent_acts_evaluates_and_continues_like_the_original(tmp_path):
    agent = make_agent(seed=5).learn(2)
    path = agent.save(tmp_path / "agent.zip")
    loaded = Agent.load(path)
    assert type(loaded) is REPS and loaded.config == agent.config
    assert loaded.history == agent.history and loaded.env_steps == agent.env_steps
    obs = np.random.default_rng(0).normal(size=(4, 2))
    np.testing.assert_array_equal(loaded.predict(obs, state=np.arange(4))[0], agent.predict(obs, state=np.arange(4))[0])
    assert loaded.evaluate(5, seed=2)["robustness"].tolist() == agent.evaluate(5, seed=2)["robustness"].tolist()
    uninterrupted = make_agent(seed=5).learn(4)
    loaded.learn(2)
    assert strip_time(loaded.history) == strip_time(uninterrupted.history)
    np.testing.assert_array_equal(loaded.policy.cov, uninterrupted.policy.cov)


def test_stochastic_actions_go_on_alike_after_a_save_and_load_and_come_in_the_spaces_dtype(tmp_path):
    agent = make_agent(seed=5).learn(1)
    obs = np.random.default_rng(0).normal(size=(4, 2))
    agent.predict(obs, state=np.arange(4), deterministic=False)  # the draws have moved on since the seed
    loaded = Agent.load(agent.save(tmp_path / "agent.zip"))
    for _ in range(2):
        action, _ = agent.predict(obs, state=np.arange(4), deterministic=False)
        np.testing.assert_array_equal(loaded.predict(obs, state=np.arange(4), deterministic=False)[0], action)
    assert action.dtype == agent.action_space.dtype and agent.action_space.contains(action[0])


def test_load_rebuilds_a_wrapped_or_time_limited_env_or_asks_for_it(tmp_path):
    # a wrapper with a callable cannot be written down: load must ask for env=, not rebuild the bare env
    shifted = gym.wrappers.TransformObservation(gym.make(POINT_ID), lambda obs: obs + 0.5,
                                                gym.make(POINT_ID).observation_space)
    agent = REPS(shifted, seed=0, n_episodes=4).learn(1)
    path = agent.save(tmp_path / "shifted.zip")
    with pytest.raises(IncompatibleSaveError, match="pass env="):
        Agent.load(path)
    loaded = Agent.load(path, env=shifted)
    assert loaded.evaluate(3, seed=1)["robustness"].tolist() == agent.evaluate(3, seed=1)["robustness"].tolist()
    # another max_episode_steps than the registered one is part of the env: kept through the spec
    short = REPS(gym.make(COUNTER_ID, max_episode_steps=6), seed=0, n_episodes=4).learn(1)
    assert short.horizon == 6
    again = Agent.load(short.save(tmp_path / "short.zip")).learn(1)
    assert again.horizon == 6 and again.history[-1]["env_steps"] == 2 * 4 * 6
    assert Agent.load(tmp_path / "short.zip", env=COUNTER_ID).horizon == 6  # the saved id: the saved env, whole


def test_loading_on_an_env_of_another_episode_length_names_the_horizons(tmp_path):
    """It said "array 'policy_mean' has shape (6, 2) in the file, the agent expects (9, 2)"."""
    path = REPS(gym.make(COUNTER_ID, max_episode_steps=6), seed=0, n_episodes=4).learn(1).save(tmp_path / "six.zip")
    with pytest.raises(IncompatibleSaveError, match=r"trained on episodes of 6 steps and the env's last 9: .*load it "
                                                    r"on an env of 6-step episodes \(array 'policy_mean' has shape"):
        Agent.load(path, env=gym.make(COUNTER_ID, max_episode_steps=9))


class Watched(gym.Wrapper):
    """A wrapper that records no constructor arguments (as SB3's Monitor): its spec cannot be rebuilt."""


def test_load_asks_for_the_env_when_a_wrapper_cannot_be_rebuilt_and_the_saved_id_makes_it_without(tmp_path):
    # the spec of a Monitor-like wrapper writes to JSON (kwargs null) but gym.make cannot recreate it
    agent = REPS(Watched(gym.make(POINT_ID)), seed=0, n_episodes=4).learn(1)
    path = agent.save(tmp_path / "watched.zip")
    with pytest.raises(IncompatibleSaveError, match=f"wrapped in Watched.*pass env=.*env='{POINT_ID}'"):
        Agent.load(path)
    by_id = Agent.load(path, env=POINT_ID)
    again = Agent.load(path, env=Watched(gym.make(POINT_ID)))
    def rho(a):
        return a.evaluate(3, seed=1)["robustness"].tolist()

    assert rho(by_id) == rho(again) == rho(agent)



def test_a_car_saved_in_a_monitor_like_wrapper_loads_by_id_on_the_batched_car(tmp_path):
    path = REPS(Watched(gym.make("TLCarNav-v0")), seed=0, n_episodes=2).learn(1).save(tmp_path / "car.zip")
    assert type(Agent.load(path, env="TLCarNav-v0").env).__name__ == "CarNavVectorEnv"  # not SyncVectorEnv copies


def test_the_saved_id_keeps_the_wrappers_gymnasium_can_rebuild_and_the_time_limit(tmp_path):
    """Only the Monitor-like wrapper is left out: the TL wrapper and the time limit around Pendulum were dropped too."""
    def wrapped():
        return Watched(tl_gym.TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=20), "F(c > 0.5)",
                                                signals={"c": 0}))

    agent = REPS(wrapped(), seed=0, n_episodes=4).learn(1)
    path = agent.save(tmp_path / "pendulum.zip")
    with pytest.raises(IncompatibleSaveError, match="wrapped in Watched"):
        Agent.load(path)
    by_id = Agent.load(path, env="Pendulum-v1")
    assert by_id.horizon == 20 and by_id.evaluate(2, seed=3)["robustness"].tolist() == agent.evaluate(
        2, seed=3)["robustness"].tolist()
    # a file saved before: its spec_json holds the wrapper with no arguments, which gym.make cannot rebuild
    old_style = dict(agent._env_source, spec_json=wrapped().spec.to_json())
    del old_style["unrebuildable_wrappers"]
    with pytest.raises(IncompatibleSaveError, match="wrapped in Watched"):
        _env_from_source(old_style, "old.zip")
    env, _ = _env_from_source(old_style, "old.zip", by_id=True)
    assert env.get_wrapper_attr("formula") == agent.formula


class Counter(gym.Env):
    """Counts its steps; reports the prefix robustness of ``F(c > 4)`` at every step, so that any time limit ends it."""

    observation_space = gym.spaces.Box(-100, 100, (1,), np.float64)
    action_space = gym.spaces.Box(-1, 1, (1,), np.float32)
    formula = tl_gym.parse("F(c > 4)")

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([0.0]), {}

    def step(self, action):
        self.t += 1
        trace = {"c": np.arange(self.t + 1, dtype=float)}
        return np.array([float(self.t)]), 0.0, False, False, {"robustness": self.t - 4.0, "trace": trace}


COUNTER_ID = "tests/CounterStandIn-v0"
if COUNTER_ID not in gym.registry:
    gym.register(COUNTER_ID, entry_point=f"{__name__}:Counter")  # by name, so that its spec can be written


def test_save_writes_json_and_npz_only(tmp_path):
    path = make_agent(feedback="open").learn(1).save(tmp_path / "agent.zip")
    with zipfile.ZipFile(path) as archive:
        assert sorted(archive.namelist()) == ["arrays.npz", "meta.json"]
        meta = json.loads(archive.read("meta.json"))
        with np.load(io.BytesIO(archive.read("arrays.npz")), allow_pickle=False) as npz:
            assert sorted(npz.files) == ["policy_cov", "policy_gains", "policy_mean"]  # an open-loop policy's
    assert meta["class"] == "REPS" and meta["format_version"] == 1
    assert meta["env"]["id"] == POINT_ID and tl_gym.parse(meta["formula"]) == make_agent(feedback="open").formula
    assert meta["config"]["n_episodes"] == 8 and meta["observation_space"]["type"] == "Box"


def test_a_crash_mid_save_leaves_the_old_file(tmp_path, monkeypatch):
    agent = make_agent().learn(1)
    path = agent.save(tmp_path / "agent.zip")
    before = path.read_bytes()
    agent.learn(1)
    original = zipfile.ZipFile.writestr

    def crash(self, name, data, *args, **kwargs):
        if name == "arrays.npz":
            raise OSError("disk full")
        return original(self, name, data, *args, **kwargs)

    monkeypatch.setattr(zipfile.ZipFile, "writestr", crash)
    with pytest.raises(OSError, match="disk full"):
        agent.save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["agent.zip"]  # no temporary file left behind
    monkeypatch.undo()
    assert len(Agent.load(path).history) == 1


def _rewrite(path, meta_change=None, arrays_change=None):
    with zipfile.ZipFile(path) as archive:
        meta = json.loads(archive.read("meta.json"))
        with np.load(io.BytesIO(archive.read("arrays.npz"))) as npz:
            arrays = {k: npz[k] for k in npz.files}
    if meta_change:
        meta_change(meta)
    if arrays_change:
        arrays_change(arrays)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("meta.json", json.dumps(meta))
        archive.writestr("arrays.npz", buffer.getvalue())


def test_load_rejects_incompatible_files(tmp_path):
    path = make_agent().learn(1).save(tmp_path / "agent.zip")

    _rewrite(path, arrays_change=lambda a: a.update(policy_mean=np.zeros((3, 2))))
    with pytest.raises(IncompatibleSaveError, match="'policy_mean' has shape"):
        REPS.load(path)

    path = make_agent().save(tmp_path / "agent2.zip")
    _rewrite(path, meta_change=lambda m: m.update(format_version=99))
    with pytest.raises(IncompatibleSaveError, match="format_version 99"):
        REPS.load(path)

    not_zip = tmp_path / "junk.zip"
    not_zip.write_text("hello")
    with pytest.raises(IncompatibleSaveError, match="not a tl_gym agent file"):
        Agent.load(not_zip)


@pytest.mark.parametrize(
    ("env", "env_kwargs", "match"),
    [
        (PointEnv(), {"goal": 2.0}, "env_kwargs can only be used with an env id, not with an Env object"),
        (gym.vector.SyncVectorEnv([PointEnv, PointEnv]), {"goal": 2.0},
         "env_kwargs can only be used with an env id, not with a VectorEnv"),
        (3, None, "env must be an env id, a gymnasium Env or a VectorEnv, got int"),
    ],
)
def test_an_env_the_agent_cannot_use_is_refused_naming_it(env, env_kwargs, match):
    with pytest.raises(TypeError, match=match):
        REPS(env, env_kwargs=env_kwargs, n_episodes=4)


def test_an_env_without_a_formula_or_an_episode_length_is_refused_saying_what_to_do():
    with pytest.raises(TypeError, match=r"the env has no `formula`: wrap it in tl_gym.TLTLRewardWrapper"):
        REPS(gym.make("Pendulum-v1", max_episode_steps=20), n_episodes=2)
    endless = PointEnv()
    del endless.horizon
    with pytest.raises(ValueError, match=r"the env states no episode length: give it a time limit inside its "
                                         r"TLTLRewardWrapper.*; or, if its episodes end on their own after T steps, "
                                         r"give the agent horizon=T"):
        REPS(endless, n_episodes=2)


def _walk(time_limit: int | None = None):
    """A point env wrapped in the TL reward, ending only where a hand-applied TimeLimit says (or never)."""
    point = PointEnv()
    point.horizon = math.inf  # never reached, and no episode length a check reads
    inner = point if time_limit is None else gym.wrappers.TimeLimit(point, time_limit)
    return tl_gym.TLTLRewardWrapper(inner, "F(x > 1)", signals={"x": 0, "y": 1})


def test_a_time_limit_applied_by_hand_is_the_episode_length():
    """No spec says so: the agents and the Markov view read the TimeLimit itself."""
    assert REPS(_walk(time_limit=7), n_episodes=2).horizon == 7
    viewed = tl_gym.TLTLRewardWrapper(gym.wrappers.TimeLimit(PointEnv(), 7), "F(x > 1)", signals={"x": 0},
                                      observe_monitor=True, reward_mode="dense")
    assert viewed.monitor_view.horizon == 7


@pytest.mark.parametrize("agent", ["reps", "ppo"])
def test_a_time_limit_outside_the_reward_wrapper_is_refused_at_construction(agent):
    make = (lambda env, **kw: REPS(env, n_episodes=2, **kw)) if agent == "reps" else (
        lambda env, **kw: SB3Agent(env, "ppo", n_envs=1, n_steps=64, batch_size=32, steps_per_iteration=64, **kw))
    with pytest.raises(ValueError, match=r"a TimeLimit of 50 steps wraps the env's TLTLRewardWrapper from outside.*"
                                         r"horizon=50"):
        make("TLPendulum-v0", env_kwargs={"max_episode_steps": 50})
    with pytest.raises(ValueError, match="a TimeLimit of 5 steps wraps"):
        make(gym.wrappers.TimeLimit(_walk(time_limit=20), 5))
    with pytest.raises(ValueError, match="a TimeLimit of 5 steps wraps"):  # the only limit there is
        make(gym.wrappers.TimeLimit(_walk(), 5))
    with pytest.raises(ValueError, match="a TimeLimit of 5 steps wraps"):  # the cutting one under a longer one
        make(gym.wrappers.TimeLimit(gym.wrappers.TimeLimit(_walk(time_limit=20), 5), 500))
    longer = make(gym.wrappers.TimeLimit(_walk(time_limit=20), 30))  # cuts nothing: the wrapper ends first
    assert longer.formula == tl_gym.parse("F(x > 1)")


def test_the_time_limit_checks_reach_into_async_workers():
    """AsyncVectorEnv's sub-envs live in other processes: the wrapper's recorded episode length and the outermost
    TimeLimit are asked there, so a cutting limit is refused and one inside the wrapper is the horizon."""
    cut = gym.make_vec("TLPendulum-v0", num_envs=2, vectorization_mode="async", max_episode_steps=50)
    with pytest.raises(ValueError, match="a TimeLimit of 50 steps wraps"):
        REPS(cut, n_episodes=2)
    cut.close()
    inside = gym.make_vec("TLPendulum-v0", num_envs=2, vectorization_mode="async", horizon=150)
    assert REPS(inside, n_episodes=2).horizon == 150
    inside.close()


def test_a_make_vec_time_limit_inside_the_wrapper_is_the_horizon_not_the_registrys():
    """gym.make_vec(id, max_episode_steps=T) keeps the registry's value in its spec's max_episode_steps: what the
    envs themselves state wins."""
    def wrap(env):
        return tl_gym.TLTLRewardWrapper(env, "F(cos_th > 0.9)", signals={"cos_th": 0})

    venv = gym.make_vec("Pendulum-v1", num_envs=2, wrappers=[wrap], max_episode_steps=30)
    assert REPS(venv, n_episodes=2).learn(1).horizon == 30


def test_the_horizon_is_the_least_the_env_states():
    """The car says 200 (its own horizon), a TimeLimit inside the wrapper 50: episodes last 50."""
    from tl_gym.envs.car import CarNavEnv

    env = tl_gym.TLTLRewardWrapper(gym.wrappers.TimeLimit(CarNavEnv(task=1), 50), "F(x > 200)",
                                   signals={"x": 0}, observe_monitor=True, reward_mode="dense")
    assert env.episode_length == env.monitor_view.horizon == 50
    assert REPS(env, n_episodes=2).horizon == 50


def test_an_sb3_agent_on_an_env_that_states_no_episode_length_is_evaluated_with_a_guard(monkeypatch):
    """An env that ends its own episodes without stating a length (highway-env's) is an SB3 agent's to train; a
    policy that never ends one meets the guard, not an endless loop."""
    import tl_gym.agents.evaluation as evaluation

    monkeypatch.setattr(evaluation, "UNSTATED_EPISODE_GUARD", 30)
    agent = SB3Agent(_walk(), "ppo", n_envs=1, n_steps=64, batch_size=32, steps_per_iteration=64)
    with pytest.raises(RuntimeError, match=r"did not end within 30 steps; the env states no episode length"):
        agent.evaluate(n_episodes=1, seed=0)
def test_an_env_object_is_copied_with_what_was_set_after_make():
    """An attribute changed after gym.make (highway-env's configure, a physics constant) reaches every agent's
    envs, and the user's env itself is not stepped."""
    base = gym.make("Pendulum-v1", max_episode_steps=20)
    base.unwrapped.g = 0.0
    env = tl_gym.TLTLRewardWrapper(base, "F(cos_th > 0.9)", signals={"cos_th": 0})
    reps = REPS(env, n_episodes=2).learn(1)
    sac = SB3Agent(env, "sac", steps_per_iteration=40, learning_starts=20, batch_size=16)
    assert [e.unwrapped.g for e in reps.env.envs] == [0.0, 0.0]
    assert [e.unwrapped.g for e in sac.env.envs + sac.sb3_env.envs] == [0.0, 0.0]
    assert all(e.unwrapped is not base.unwrapped for e in reps.env.envs + sac.sb3_env.envs)
    assert not hasattr(base.unwrapped, "state")  # never reset: the agents stepped copies


def test_copies_of_a_seeded_env_draw_their_own_episodes():
    """A seeded env's copies would share its random stream: unseeded resets (SB3 without a seed) would repeat one
    episode on every copy. Seeded resets still decide."""
    from tl_gym.agents.env_ids import env_copies

    env = gym.make("TLPendulum-v0")
    env.reset(seed=0)
    copies = [make() for make in env_copies(env, 3)]
    starts = [tuple(copy.reset()[0][:2]) for copy in copies]
    assert len(set(starts)) == 3
    assert len({tuple(copy.reset(seed=1)[0][:2]) for copy in copies}) == 1


def test_sb3_on_a_make_vec_env_keeps_its_wrappers():
    def wrap(env):
        return tl_gym.TLTLRewardWrapper(env, "F(cos_th > 0.9)", signals={"cos_th": 0}, observe_monitor=True,
                                        reward_mode="dense")

    venv = gym.make_vec("Pendulum-v1", num_envs=2, wrappers=[wrap], max_episode_steps=20)
    agent = SB3Agent(venv, "sac", n_envs=2, steps_per_iteration=40, learning_starts=20, batch_size=16)
    assert agent.model.observation_space == venv.single_observation_space  # the view's, not bare Pendulum's
    assert agent.learn(1).history[0]["env_steps"] == 40
    import dataclasses

    short = gym.make_vec(dataclasses.replace(gym.spec("Pendulum-v1"), max_episode_steps=20), num_envs=1,
                         wrappers=[wrap])  # a spec of its own: its time limit is the spec's, not the registry's
    assert SB3Agent(short, "sac", n_envs=1, steps_per_iteration=40, learning_starts=20,
                    batch_size=16).sb3_env.envs[0].get_wrapper_attr("episode_length") == 20
    sync = gym.vector.SyncVectorEnv([lambda: wrap(gym.make("Pendulum-v1", max_episode_steps=20))])
    sync.spec = None  # built by hand: no spec to rebuild from, so its env is copied
    copied = SB3Agent(sync, "sac", n_envs=1, steps_per_iteration=40, learning_starts=20, batch_size=16)
    assert copied.model.observation_space == sync.single_observation_space


class SilentPointEnv(PointEnv):
    """States its formula but reports no robustness at the end."""

    def step(self, action):
        obs, reward, terminated, truncated, _ = super().step(action)
        return obs, reward, terminated, truncated, {}


def test_an_env_that_reports_no_robustness_is_named_when_its_first_episode_ends():
    agent = REPS(SilentPointEnv(), n_episodes=2)
    with pytest.raises(RuntimeError, match="the env's terminal info holds no 'robustness': wrap it in"):
        agent.learn(1)


MODULE_TASK = """
import gymnasium as gym

import tl_gym


def make(**wrapper_kwargs):
    env = gym.make("Pendulum-v1", max_episode_steps=30)
    return tl_gym.TLTLRewardWrapper(env, "F(G(cos_th > 0.9))", signals={"cos_th": 0}, **wrapper_kwargs)


gym.register("ModuleFormTask-v0", entry_point=make)
"""


def test_an_id_in_gymnasiums_module_form_is_taken_as_gym_make_takes_it(tmp_path, monkeypatch):
    """ "module:EnvId" imports the module (which registers the id) before the id is looked up; the horizon is the
    wrapped env's own time limit, since the id registers none."""
    (tmp_path / "module_form_task.py").write_text(MODULE_TASK)
    monkeypatch.syspath_prepend(str(tmp_path))
    def forget() -> None:  # as in a new process: the id not registered, the module not imported
        gym.registry.pop("ModuleFormTask-v0", None)
        sys.modules.pop("module_form_task", None)

    try:
        agent = REPS("module_form_task:ModuleFormTask-v0", seed=0, n_episodes=3).learn(1)
        assert agent.horizon == 30 and agent.history[0]["env_steps"] == 3 * 30
        path = agent.save(tmp_path / "agent.zip")
        forget()
        loaded = Agent.load(path)  # imports the module again, which registers the id
        assert loaded.evaluate(2, seed=1)["robustness"].tolist() == agent.evaluate(2, seed=1)["robustness"].tolist()
    finally:
        forget()


def test_an_attribute_an_async_vector_envs_envs_lack_is_none_and_the_workers_live_on():
    from tl_gym.agents.horizon import env_attribute, infer_horizon

    envs = gym.make_vec("Pendulum-v1", num_envs=2, vectorization_mode="async")
    try:
        assert env_attribute(envs, "horizon") is None  # asking Gymnasium's get_attr would stop the workers
        assert infer_horizon(envs) == 200
        envs.reset(seed=0)
        assert envs.step(np.zeros((2, 1), dtype=np.float32))[0].shape == (2, 3)
    finally:
        envs.close()


def test_load_names_what_does_not_fit(tmp_path):
    from tl_gym.agents import TLPS

    path = make_agent().save(tmp_path / "agent.zip")
    with pytest.raises(IncompatibleSaveError, match="holds a REPS, not a TLPS"):
        TLPS.load(path)
    wider = PointEnv()  # no spec: the agent copies it, with its space
    wider.observation_space = gym.spaces.Box(-20, 20, (2,), np.float64)
    with pytest.raises(IncompatibleSaveError, match="the env's observation_space .* differs from the saved one"):
        REPS.load(path, env=wider)

    _rewrite(path, arrays_change=lambda a: a.update(bogus=np.zeros(2)))
    with pytest.raises(IncompatibleSaveError, match=r"missing \[\], unexpected \['bogus'\]"):
        REPS.load(path)
    path = make_agent().save(tmp_path / "agent2.zip")
    _rewrite(path, arrays_change=lambda a: a.update(policy_mean=a["policy_mean"].astype(np.int64)))
    with pytest.raises(IncompatibleSaveError, match="array 'policy_mean' has dtype int64 in the file"):
        REPS.load(path)
    path = make_agent().save(tmp_path / "agent3.zip")
    _rewrite(path, meta_change=lambda m: m.update({"class": "NoSuchAgent"}))
    with pytest.raises(IncompatibleSaveError, match="NoSuchAgent"):
        Agent.load(path)

    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as archive:
        archive.writestr("readme.txt", "not an agent")
    with pytest.raises(IncompatibleSaveError, match=r"is not a tl_gym agent file \(no meta.json / arrays.npz\)"):
        Agent.load(empty)


def test_load_rejects_an_env_with_another_formula(tmp_path):
    path = make_agent().save(tmp_path / "agent.zip")
    other = gym.make(POINT_ID, goal=2.0)
    with pytest.raises(IncompatibleSaveError, match="formula"):
        REPS.load(path, env=other)


# the policy ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("covariance", ["diag", "full"])
def test_weighted_maximum_likelihood_update(covariance):
    rng = np.random.default_rng(0)
    policy = LinearGaussianPolicy(horizon=4, obs_dim=3, act_dim=2, covariance=covariance, min_std=1e-6)
    k = rng.normal(size=(6, 4, 2))
    w = rng.uniform(size=6)
    policy.update(k, w)
    wn = w / w.sum()
    mean = (wn[:, None, None] * k).sum(axis=0)
    np.testing.assert_allclose(policy.mean, mean)
    for t in range(4):
        dev = k[:, t] - mean[t]
        cov = (wn[:, None, None] * dev[:, :, None] * dev[:, None, :]).sum(axis=0)
        expected = cov if covariance == "full" else np.diag(np.diag(cov))
        np.testing.assert_allclose(policy.cov[t], expected, atol=1e-12)


@pytest.mark.parametrize("covariance", ["diag", "full"])
def test_covariance_floor(covariance):
    policy = LinearGaussianPolicy(horizon=3, obs_dim=1, act_dim=2, covariance=covariance, min_std=0.1)
    k = np.zeros((5, 3, 2))
    policy.update(k, np.ones(5))
    np.testing.assert_allclose(np.linalg.eigvalsh(policy.cov), 0.01)
    policy.update(k, np.ones(5), min_std=0.3)
    np.testing.assert_allclose(policy.std, 0.3)


def test_feedforward_samples_follow_the_policy():
    policy = LinearGaussianPolicy(horizon=2, obs_dim=1, act_dim=2, covariance="full")
    policy.mean = np.array([[0.5, -0.5], [0.0, 1.0]])
    policy.cov = np.array([[[0.04, 0.03], [0.03, 0.09]], [[0.01, 0.0], [0.0, 0.25]]])
    k = policy.sample_feedforward(20000, np.random.default_rng(1))
    np.testing.assert_allclose(k.mean(axis=0), policy.mean, atol=0.01)
    for t in range(2):
        np.testing.assert_allclose(np.cov(k[:, t].T), policy.cov[t], atol=0.01)


def test_feedback_gains_act_on_the_state():
    gains = np.array([[1.0, 0.0], [0.0, -2.0]])
    policy = LinearGaussianPolicy(horizon=3, obs_dim=2, act_dim=2, gains=gains)
    action, _ = policy.predict(np.array([0.5, 0.25]), None, None, True, np.random.default_rng(0))
    np.testing.assert_allclose(action, [0.5, -0.5])
    with pytest.raises(ValueError, match="gains must have shape"):
        LinearGaussianPolicy(horizon=3, obs_dim=2, act_dim=2, gains=np.zeros((3, 3)))


def test_policy_update_rejects_bad_weights():
    policy = LinearGaussianPolicy(horizon=2, obs_dim=1, act_dim=1)
    with pytest.raises(ValueError, match="weights"):
        policy.update(np.zeros((3, 2, 1)), np.array([0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="feedforward"):
        policy.update(np.zeros((3, 5, 1)), np.ones(3))


def test_rollout_handles_same_step_autoreset():
    from gymnasium.vector import AutoresetMode

    env = gym.make_vec(POINT_ID, num_envs=2, vectorization_mode="sync", terminate_in_goal=True, goal=0.3,
                       vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    feedforward = np.ones((2, HORIZON, 2))
    next_step = gym.make_vec(POINT_ID, num_envs=2, vectorization_mode="sync", terminate_in_goal=True, goal=0.3)
    batch = rollout(env, feedforward, seed=0)
    reference = rollout(next_step, feedforward, seed=0)
    np.testing.assert_array_equal(batch.observations, reference.observations)
    np.testing.assert_array_equal(batch.robustness, reference.robustness)
    assert np.all(batch.lengths < HORIZON)
    agent = make_agent()
    np.testing.assert_array_equal(evaluate_policy(agent, env, n_episodes=2, seed=1)["robustness"],
                                  evaluate_policy(agent, next_step, n_episodes=2, seed=1)["robustness"])


class DictPointEnv(PointEnv):
    """`PointEnv` with a Dict observation: ``{"x": (1,), "y": (1,)}``."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        box = gym.spaces.Box(-10, 10, (1,), np.float64)
        self.observation_space = gym.spaces.Dict({"x": box, "y": box})

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed, options=options)
        return {"x": obs[:1], "y": obs[1:]}, info

    def step(self, action):
        obs, *rest = super().step(action)
        return {"x": obs[:1], "y": obs[1:]}, *rest


@pytest.mark.parametrize("feedback", ["open", "fitted"])
def test_episodic_agents_read_dict_observations_concatenated(feedback):
    dict_agent = REPS(DictPointEnv(), seed=3, n_episodes=8, feedback=feedback).learn(2)
    box_agent = REPS(PointEnv(), seed=3, n_episodes=8, feedback=feedback).learn(2)
    # the same numbers in a Dict: the same learning, and the same actions
    assert strip_time(dict_agent.history) == strip_time(box_agent.history)
    obs = np.array([0.3, -0.2])
    single, _ = dict_agent.predict({"x": obs[:1], "y": obs[1:]}, state=4)
    rows = {"x": np.array([[0.3], [0.1]]), "y": np.array([[-0.2], [0.0]])}
    batch, _ = dict_agent.predict(rows, state=np.array([4, 4]))
    np.testing.assert_array_equal(single, box_agent.predict(obs, state=4)[0])
    np.testing.assert_array_equal(batch[0], single)
    assert single.shape == (2,) and batch.shape == (2, 2)


def test_a_dict_observation_with_a_key_missing_or_a_wrong_shape_is_named():
    agent = REPS(DictPointEnv(), seed=3, n_episodes=2)
    with pytest.raises(KeyError, match=r"the observation has no key 'y' \(the space's keys: x, y\)"):
        agent.predict({"x": np.zeros(1)})
    with pytest.raises(ValueError, match=r"observation\['x'\] has shape \(2,\): the space's is \(1,\)"):
        agent.predict({"x": np.zeros(2), "y": np.zeros(1)})
    with pytest.raises(ValueError, match=r"observation\['y'\] has shape \(3, 1\).*a batch of 2 is \(2, 1\)"):
        agent.predict({"x": np.zeros((2, 1)), "y": np.zeros((3, 1))})
    with pytest.raises(ValueError, match=r"observation\['y'\] has shape \(2,\): the space's is \(1,\), a batch of 2"):
        agent.predict({"x": np.zeros(1), "y": np.zeros(2)})  # x is one observation's: y's own size says the batch


def test_a_file_saved_before_fitted_feedback_loads_as_the_open_loop_it_holds(tmp_path):
    agent = make_agent(feedback="open").learn(1)
    path = agent.save(tmp_path / "old.zip")

    def as_before_issue_16(meta):  # the config fields that fitted feedback added did not exist
        meta["config"] = {k: v for k, v in meta["config"].items()
                          if not k.startswith(("feedback", "exploration"))}

    _rewrite(path, meta_change=as_before_issue_16)
    loaded = Agent.load(path)
    assert loaded.config.feedback == "open"
    obs = np.random.default_rng(1).normal(size=(3, 2))
    np.testing.assert_array_equal(loaded.predict(obs, state=np.arange(3))[0], agent.predict(obs, state=np.arange(3))[0])


class EndsEarly(gym.Env):
    """Counts up by one per step and terminates after ``3 + seed % 4`` steps: episodes of different lengths."""

    observation_space = gym.spaces.Box(-100, 100, (1,), np.float64)
    action_space = gym.spaces.Box(-1, 1, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t, self.length = 0, 3 + int(self.np_random.integers(4))
        return np.array([0.0]), {}

    def step(self, action):
        self.t += 1
        return np.array([float(self.t)]), 0.0, self.t >= self.length, False, {}


def test_episodes_of_different_lengths_ending_on_one_step_keep_their_traces():
    from tl_gym.agents.evaluation import collect_episodes

    envs = gym.vector.SyncVectorEnv(
        [lambda: tl_gym.TLTLRewardWrapper(EndsEarly(), "F(c > 4)", signals={"c": 0}) for _ in range(3)])
    agent = REPS(envs, seed=0, n_episodes=3, horizon=6, feedback="open")
    robustness, traces = collect_episodes(agent, envs, 9, seed=0)
    lengths = [len(values) for values in traces["c"]]
    assert len(set(lengths)) > 1  # the episodes did differ in length, and ended out of step
    for rho, values in zip(robustness, traces["c"]):
        np.testing.assert_array_equal(values, np.arange(len(values)))
        assert rho == max(values) - 4
    batch = agent.learn(1)  # and the batched sampler reads them too
    assert batch.history[-1]["env_steps"] < 3 * 6


def test_files_are_written_atomically_with_plain_permissions(tmp_path, monkeypatch):
    from tl_gym.agents import serialization

    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    target = serialization.write_atomic(tmp_path / "sub" / "file.bin", b"new")
    assert target.read_bytes() == b"new"
    assert target.stat().st_mode & 0o777 == plain.stat().st_mode & 0o777  # not mkstemp's owner-only 0o600

    def crash(*args):
        raise OSError("disk full")

    monkeypatch.setattr(serialization.os, "replace", crash)
    with pytest.raises(OSError, match="disk full"):
        serialization.write_atomic(target, b"newer")
    assert target.read_bytes() == b"new"  # the old file, whole
    assert [p.name for p in target.parent.iterdir()] == ["file.bin"]  # no temporary file left behind
    monkeypatch.undo()
    with pytest.raises(RuntimeError, match="writer failed"), serialization.atomic_path(target) as tmp:
        tmp.write_bytes(b"half")  # a writer that takes a file name, as SB3's save_replay_buffer does
        raise RuntimeError("writer failed")
    assert target.read_bytes() == b"new"
    assert [p.name for p in target.parent.iterdir()] == ["file.bin"]


def test_eval_callback_keeps_the_best_evaluated_policy(tmp_path):
    best = tmp_path / "best.zip"
    callback = EvalCallback(every=2, n_episodes=4, best_path=best, seed=7)
    make_agent().learn(6, callback=[CheckpointCallback(2, tmp_path), callback])
    assert [e[0] for e in callback.evaluations] == [2, 4, 6]
    for iteration, success, mean_rho in callback.evaluations:  # the same episodes, the agent as it was then
        again = REPS.load(tmp_path / f"agent_{iteration}.zip").evaluate(n_episodes=4, seed=7)
        assert (again["success_rate"], again["mean_robustness"]) == pytest.approx((success, mean_rho))
    assert callback.best == max(callback.evaluations, key=lambda e: (e[1], e[2]))
    assert len(REPS.load(best).history) == callback.best[0]  # saved at its best evaluation
    with pytest.raises(ValueError, match="every"):
        EvalCallback(every=0)
    with pytest.raises(ValueError, match="n_episodes"):
        EvalCallback(every=1, n_episodes=0)


@pytest.mark.parametrize(("make", "hint"), [
    (lambda: REPS("TLCarNav-v0", task=2), r"'task' is a keyword of the env TLCarNav-v0, not of the agent: pass "
                                          r"env_kwargs=\{'task': 2\}"),
    (lambda: REPS("TLPendulum-v0", observe_monitor=True, start_std=1), r"'observe_monitor' is a keyword of the env "
                                                                        r"TLPendulum-v0"),
    (lambda: REPS("Pendulum-v1", g=9.0), r"'g' is a keyword of the env Pendulum-v1.*env_kwargs=\{'g': 9.0\}"),
])
def test_an_env_keyword_given_to_an_agent_is_named_as_the_envs(make, hint):
    with pytest.raises(TypeError, match=r"has no hyperparameter\(s\).*" + hint):
        make()


def test_env_keywords_lists_what_each_id_takes_by_name():
    from tl_gym.agents.env_ids import env_keywords

    assert {"task", "no_revisit", "start_std", "horizon", "observe_monitor", "goals"} <= env_keywords("TLCarNav-v0")
    assert {"horizon", "up_by", "observe_monitor", "satisfaction_bonus"} <= env_keywords("TLPendulum-v0")
    assert "tsk" not in env_keywords("TLCarNav-v0") and env_keywords("NoSuchEnv-v0") == frozenset()
    with pytest.raises(TypeError, match=r"\['tsk'\]; valid ones: \[[^]]*\]$"):  # a typo gets no env hint
        REPS("TLCarNav-v0", tsk=2)


def test_an_integer_action_box_gets_its_actions_unrounded_as_the_sampler_sends_them():
    class IntegerActions(PointEnv):
        def __init__(self):
            super().__init__()
            self.action_space = gym.spaces.Box(-3, 3, (2,), np.int64)

    agent = REPS(IntegerActions(), n_episodes=2, init_mean=0.7, init_std=0.1)
    action, _ = agent.predict(np.zeros(2))
    np.testing.assert_allclose(action, [0.7, 0.7])
