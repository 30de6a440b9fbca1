"""The TL task suite (tl_gym.envs.suite): the ids make, run, score and vectorise; the formulas tell good from bad."""

import copy
import math
import pickle
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import DependencyNotInstalled
from gymnasium.utils.env_checker import check_env
from tl_gym.envs.suite import InfoValue, PendulumAngle, StepClock, pendulum_formula

import tl_gym  # noqa: F401  (registers the ids)
from benchmarks.parking_starts import ParkingController
from tl_gym import TLTLRewardWrapper

CLASSIC = ["TLPendulum-v0", "TLMountainCar-v0"]
ALL = CLASSIC + ["TLParking-v0"]


def needs(env_id):
    if env_id == "TLParking-v0":
        pytest.importorskip("highway_env")


def run_episode(env, policy, seed):
    """One episode with ``policy(obs) -> action``; return (number of steps, rewards, terminal info)."""
    obs, info = env.reset(seed=seed)
    rewards = []
    while True:
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        rewards.append(reward)
        if terminated or truncated:
            return len(rewards), rewards, info


# ----------------------------------------------------------------------------- hand-written policies


def pendulum_swing_up(obs):
    """Energy pumping towards just below the upright energy, PD balance within cos θ > 0.7."""
    cos_th, sin_th, th_dot = (float(v) for v in obs)
    th = math.atan2(sin_th, cos_th)
    if cos_th > 0.7:
        u = -(10.0 * th + 2.0 * th_dot)
    else:
        energy = 0.5 * th_dot**2 - 15.0 * (1.0 - cos_th)  # per unit inertia; 0 at rest upright
        u = 2.0 * math.copysign(1.0, th_dot * (-2.0 - energy) + 1e-9)
    return np.array([np.clip(u, -2.0, 2.0)], dtype=np.float32)


def pendulum_pump(obs):
    """Always full torque along the motion: the pendulum spins up to its speed clip."""
    return np.array([2.0 if obs[2] >= 0 else -2.0], dtype=np.float32)


def mountain_car_regulated(obs, target=0.039):
    """Push along the velocity, but only up to ``target`` speed (brake above it)."""
    velocity = float(obs[1])
    direction = 1.0 if velocity >= 0 else -1.0
    return np.array([direction * np.clip((target - abs(velocity)) / 0.0015, -1.0, 1.0)], dtype=np.float32)


def mountain_car_bang_bang(obs):
    """Full push along the velocity: reaches the flag in about 105 steps, at speeds up to 0.069."""
    return np.array([1.0 if obs[1] >= 0 else -1.0], dtype=np.float32)


# ----------------------------------------------------------------------------- every id


@pytest.mark.parametrize("env_id", ALL)
def test_random_episode_ends_with_the_robustness(env_id):
    needs(env_id)
    env = gym.make(env_id)
    env.action_space.seed(8)
    steps, rewards, info = run_episode(env, lambda obs: env.action_space.sample(), seed=8)
    formula = env.get_wrapper_attr("formula")
    assert steps <= env.get_wrapper_attr("horizon")
    assert info["robustness"] == formula.robustness(info["trace"])
    assert info["satisfied"] == (info["robustness"] > 0)
    assert not info["satisfied"]  # random actions solve none of the tasks
    assert rewards[-1] == info["robustness"] and all(r == 0.0 for r in rewards[:-1])
    assert all(len(v) == steps + 1 for v in info["trace"].values())


@pytest.mark.parametrize("view", [{}, {"observe_monitor": True}], ids=["plain", "observe_monitor"])
@pytest.mark.parametrize("env_id", ALL)
def test_gymnasium_and_sb3_env_checkers(env_id, view):
    """Gymnasium's check_env on every id, with and without the Markov view; SB3's on all but parking.

    SB3's check of a goal env (parking-v0 has `compute_reward`) calls `env.compute_reward` on the outermost
    wrapper, which Gymnasium 1.x wrappers do not forward: it fails on parking-v0 itself (AttributeError,
    'OrderEnforcing' object has no attribute 'compute_reward'), so parking is checked by Gymnasium's alone.
    """
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    needs(env_id)
    with warnings.catch_warnings():
        # the task is the wrapped env, so check it as a whole (the checker only suggests `.unwrapped`)
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")
        # the base envs' own spaces, which the suite keeps as they are: Pendulum's torque Box is
        # [-2, 2], parking's observation Boxes are unbounded
        warnings.filterwarnings("ignore", message=".*we recommend using a symmetric and normalized space")
        warnings.filterwarnings("ignore", message=".*use a symmetric and normalized Box action space")  # SB3's
        warnings.filterwarnings("ignore", message=".*observation space (minimum|maximum) value is")
        check_env(gym.make(env_id, **view), skip_render_check=True)
        if env_id != "TLParking-v0":
            sb3_check_env(gym.make(env_id, **view), warn=True)


def test_parking_refuses_its_goal_reward_which_is_not_the_tl_reward():
    """parking-v0's compute_reward prices one transition; the TL reward is the episode's robustness, so the
    wrapper shadows it (SB3's HerReplayBuffer would relabel with the wrong reward) and says what to use."""
    needs("TLParking-v0")
    env = gym.make("TLParking-v0")
    obs, _ = env.reset(seed=0)
    with pytest.raises(NotImplementedError, match=r"HerReplayBuffer cannot relabel it.*her_goals=k"):
        env.get_wrapper_attr("compute_reward")(obs["achieved_goal"], obs["desired_goal"], {})
    assert not gym.make("TLPendulum-v0").has_wrapper_attr("compute_reward")  # only goal envs get the refusal


@pytest.mark.parametrize("env_id", ALL)
def test_sync_vector_env(env_id):
    needs(env_id)
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="sync")
    obs, _ = envs.reset(seed=0)
    envs.action_space.seed(0)
    for _ in range(3):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert reward.shape == (2,)
    assert envs.get_attr("horizon") == (gym.make(env_id).get_wrapper_attr("horizon"),) * 2
    envs.close()


@pytest.mark.parametrize("mode", [{}, {"reward_mode": "dense"}, {"reward_mode": "dense", "observe_monitor": True},
                                  {"reward_mode": "potential", "observe_monitor": True}, {"end_on_violation": True}])
@pytest.mark.parametrize("env_id", CLASSIC)
def test_envs_pickle_and_deepcopy(env_id, mode):
    """A copy taken mid-episode continues it exactly as the original does, to the terminal robustness, in every
    reward mode (the monitors' generated code is compiled again by the copy)."""
    env = gym.make(env_id, **mode)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(env.action_space.low, env.action_space.high,
                                               size=(env.get_wrapper_attr("horizon"),) + env.action_space.shape)
    actions = actions.astype(env.action_space.dtype)
    for action in actions[:5]:
        env.step(action)
    clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    for action in actions[5:]:
        original = env.step(action)
        for clone in clones:
            copied = clone.step(action)
            np.testing.assert_array_equal(copied[0], original[0])
            assert copied[1:4] == original[1:4]
        if original[2] or original[3]:
            break
    assert (original[2] or original[3]) and "robustness" in original[4]  # the episode ran to its end
    for clone in clones:
        assert clone.unwrapped is not env.unwrapped


def test_wrapper_keywords_flow_through():
    env = gym.make("TLMountainCar-v0", reward_mode="dense", clip=2.0, horizon=40)
    wrapper = env.get_wrapper_attr("reward_mode"), env.get_wrapper_attr("clip"), env.get_wrapper_attr("horizon")
    assert wrapper == ("dense", 2.0, 40)
    steps, rewards, info = run_episode(env, mountain_car_bang_bang, seed=0)
    assert steps == 40 and sum(rewards) == pytest.approx(info["robustness"], abs=1e-12)
    with pytest.raises(TypeError, match="'rewrad' \\(did you mean 'reward'\\?\\)"):
        gym.make("TLPendulum-v0", rewrad="smooth")
    with pytest.raises(TypeError, match=r"'horizn' \(did you mean 'horizon'\?\): the task takes its own \(horizon, "
                                        r"up_by, max_angle, max_speed, render_mode\) and TLTLRewardWrapper's"):
        gym.make("TLPendulum-v0", horizn=5)


@pytest.mark.parametrize("env_id, scale", [("TLPendulum-v0", 1.0), ("TLMountainCar-v0", 0.5), ("TLParking-v0", 10.0)])
def test_observe_monitor_flows_through_with_the_task_scale(env_id, scale):
    needs(env_id)
    plain, viewed = gym.make(env_id), gym.make(env_id, observe_monitor=True)
    assert viewed.get_wrapper_attr("monitor_view").scale == scale
    assert gym.make(env_id, observe_monitor=True, monitor_scale=2.0).get_wrapper_attr("monitor_view").scale == 2.0
    obs, _ = viewed.reset(seed=0)
    raw, _ = plain.reset(seed=0)
    if isinstance(obs, dict):
        assert set(obs) == set(raw) | {"monitor"}
    else:
        np.testing.assert_array_equal(obs[: raw.shape[0]], raw)  # the raw observation comes first, unchanged
        assert obs.shape[0] > raw.shape[0]


def test_bad_task_arguments_name_the_culprit():
    with pytest.raises(ValueError, match="up_by must be below horizon"):
        gym.make("TLPendulum-v0", horizon=50)
    with pytest.raises(ValueError, match="speed_limit"):
        gym.make("TLMountainCar-v0", speed_limit=-1.0)
    with pytest.raises(ValueError, match="horizon"):
        gym.make("TLMountainCar-v0", horizon=0)


@pytest.mark.parametrize("env_id", ALL)
def test_a_numpy_integer_horizon_is_a_horizon(env_id):
    """horizon=np.int64(12), a sweep's value, passed the check, then Gymnasium's TimeLimit refused it."""
    needs(env_id)
    kwargs = {"horizon": np.int64(12), **({"up_by": 5} if env_id == "TLPendulum-v0" else {})}
    size = 1 if env_id in CLASSIC else 2
    steps, _, info = run_episode(gym.make(env_id, **kwargs), lambda obs: np.zeros(size, dtype=np.float32), seed=0)
    assert steps <= 12 and "robustness" in info


def test_parking_terminate_on_success_must_be_a_bool():
    pytest.importorskip("highway_env")
    with pytest.raises(ValueError, match="terminate_on_success must be True or False"):
        gym.make("TLParking-v0", terminate_on_success="no")  # bool("no") is True: it ended episodes at the slot


def test_step_clock_is_the_trace_index():
    env = TLTLRewardWrapper(
        StepClock(gym.make("Pendulum-v1", max_episode_steps=7), horizon=7),
        "G(t >= 0)", signals={"t": InfoValue("t"), "th": PendulumAngle()},
    )
    _, _, info = run_episode(env, lambda obs: np.zeros(1, dtype=np.float32), seed=0)
    np.testing.assert_array_equal(info["trace"]["t"], np.arange(8))


# ----------------------------------------------------------------------------- the formulas against behaviour


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pendulum_swing_up_satisfies_and_pumping_does_not(seed):
    env = gym.make("TLPendulum-v0")
    _, _, good = run_episode(env, pendulum_swing_up, seed)
    assert good["satisfied"] and good["robustness"] > 0.05
    _, _, spin = run_episode(env, pendulum_pump, seed)
    assert spin["robustness"] < 0 and np.abs(spin["trace"]["th_dot"]).max() == 8.0  # at the speed clip


def test_pendulum_up_too_late_fails():
    # the swing-up needs 25-70 steps: demanding upright from step 10 on fails
    env = gym.make("TLPendulum-v0", up_by=10)
    _, _, info = run_episode(env, pendulum_swing_up, seed=0)
    assert info["robustness"] < 0
    assert str(env.get_wrapper_attr("formula")) == str(pendulum_formula(up_by=10))


@pytest.mark.parametrize("seed", [0, 1])
def test_mountain_car_regulated_satisfies_and_bang_bang_speeds(seed):
    env = gym.make("TLMountainCar-v0")
    steps, _, good = run_episode(env, mountain_car_regulated, seed)
    assert good["satisfied"] and steps < 200
    steps, _, fast = run_episode(env, mountain_car_bang_bang, seed)
    assert fast["trace"]["position"][-1] >= 0.45 and steps < 120  # reaches the flag ...
    assert fast["robustness"] < 0  # ... too fast


def test_parking_controller_parks_and_full_throttle_speeds():
    pytest.importorskip("highway_env")
    env = gym.make("TLParking-v0")
    steps, _, good = run_episode(env, ParkingController(), seed=8)
    # the slot does not end the episode: the car drives on into it, and ρ measures how well it parked
    assert good["satisfied"] and steps == 100 and good["robustness"] > 0.3
    _, _, fast = run_episode(env, lambda obs: np.array([1.0, 0.0], dtype=np.float32), seed=8)
    assert fast["robustness"] < 0 and fast["trace"]["speed"].max() > 5.0


def test_parking_terminate_on_success_ends_at_the_slots_edge():
    """parking-v0's own rule: the episode ends as the car enters the slot, so ρ is at most a step of travel."""
    pytest.importorskip("highway_env")
    steps, _, info = run_episode(gym.make("TLParking-v0", terminate_on_success=True), ParkingController(), seed=8)
    assert info["satisfied"] and info["is_success"] and steps < 100
    assert 0 < info["robustness"] < 0.1


@pytest.mark.parametrize(
    ("config", "match"),
    [
        ({"observation": {"type": "Kinematics"}}, "reads parking's KinematicsGoal observation with features"),
        ({"observation": {"type": "Kinematics", "features": ["x", "y", "vx", "vy"], "scales": [100, 100, 5, 5]}},
         "reads parking's KinematicsGoal observation with features"),  # its scales are not the culprit
        ({"observation": {"type": "KinematicsGoal", "features": ["y", "x", "vx", "vy", "cos_h", "sin_h"],
                          "scales": [100, 100, 5, 5, 1, 1]}},
         r"features \['x', 'y', 'vx', 'vy', 'cos_h', 'sin_h'\]"),
        ({"observation": {"type": "KinematicsGoal", "features": ["x", "y", "vx", "vy", "cos_h", "sin_h"],
                          "scales": [100, 100, 5, 5, 1, 1], "normalize": True}}, "reads unnormalised observations"),
        ({"reward_weights": [1, 0.3, 0, 0]}, r"parking's reward_weights must be 6 finite numbers \(x, y, vx, vy, "
                                              r"cos_h, sin_h\), the x one > 0, got \[1, 0.3, 0, 0\]"),
        ({"reward_weights": [0, 0.3, 0, 0, 0.02, 0.02]}, "parking's reward_weights must be 6 finite numbers"),
        ({"observation": {"type": "KinematicsGoal", "features": ["x", "y", "vx", "vy", "cos_h", "sin_h"],
                          "scales": [0, 100, 5, 5, 1, 1]}}, "parking's observation scales must be"),
    ],
)
def test_a_parking_config_the_task_cannot_read_is_refused_naming_it(config, match):
    pytest.importorskip("highway_env")
    with pytest.raises(ValueError, match=match):
        gym.make("TLParking-v0", config=config)


def test_a_signal_from_a_missing_info_key_names_the_key_and_the_keys_there():
    from tl_gym.envs.suite import InfoValue

    with pytest.raises(KeyError, match=r"info\['t'\]: the env's info has no such key \(keys: \['other'\]\)"):
        InfoValue("t")(None, {"other": 1})


def test_parking_terminate_on_success_in_config_is_refused():
    pytest.importorskip("highway_env")
    with pytest.raises(ValueError, match="terminate_on_success as TLParking-v0's own keyword"):
        gym.make("TLParking-v0", config={"terminate_on_success": True})


@pytest.mark.parametrize("terminate_on_success", [True, False])
def test_parking_compute_terminated_follows_the_env(terminate_on_success):
    pytest.importorskip("highway_env")
    from tl_gym.envs.fast_parking import NumpyParkingEnv

    env = NumpyParkingEnv(config={"terminate_on_success": terminate_on_success})
    obs, _ = env.reset(seed=0)
    goal = obs["desired_goal"]
    assert env.compute_terminated(goal, goal, {"crashed": False}) is terminate_on_success
    assert env.compute_terminated(goal + 1.0, goal, {"crashed": True}) is True
    assert env.compute_terminated(goal + 1.0, goal, {"crashed": False}) is False


@pytest.mark.parametrize("seed", [3, 8])
def test_parking_numpy_observation_equals_highway_envs(seed):
    """TLParking-v0's parking-v0 subclass (no pandas) steps exactly as highway-env's own parking-v0."""
    pytest.importorskip("highway_env")
    from tl_gym.envs.fast_parking import NumpyParkingEnv

    ours, theirs = NumpyParkingEnv(), gym.make("parking-v0").unwrapped
    assert type(theirs.observation_type).__name__ == "KinematicsGoalObservation"
    obs_ours, _ = ours.reset(seed=seed)
    obs_theirs, _ = theirs.reset(seed=seed)
    parker, actions = ParkingController(), np.random.default_rng(seed).uniform(-1, 1, size=(10, 2)).astype(np.float32)
    for step in range(80):  # random actions, then the parking controller until it parks
        for key in ("observation", "achieved_goal", "desired_goal"):
            np.testing.assert_array_equal(obs_ours[key], obs_theirs[key], err_msg=f"{key} at step {step}")
        action = actions[step] if step < len(actions) else parker(obs_ours)
        obs_ours, r_ours, term_ours, trunc_ours, info_ours = ours.step(action)
        obs_theirs, r_theirs, term_theirs, trunc_theirs, info_theirs = theirs.step(action)
        assert (r_ours, term_ours, trunc_ours, info_ours["is_success"]) == (
            r_theirs, term_theirs, trunc_theirs, info_theirs["is_success"])
        if term_ours or trunc_ours:
            break


def test_parking_without_highway_env_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "highway_env", None)  # `import highway_env` raises ImportError
    with pytest.raises(DependencyNotInstalled, match=r'pip install "tl_gym\[highway\]"'):
        gym.make("TLParking-v0")


# ----------------------------------------------------------------------------- agents find the horizon


@pytest.mark.parametrize("env_id", CLASSIC)
def test_agents_read_the_horizon(env_id):
    from tl_gym.agents import REPS, TLPS

    env_kwargs = {"horizon": 30, **({"up_by": 20} if env_id == "TLPendulum-v0" else {})}
    for agent_class in (TLPS, REPS):
        agent = agent_class(env_id, seed=0, n_episodes=4, env_kwargs=env_kwargs).learn(1)
        assert agent.horizon == 30
        assert agent.history[-1]["env_steps"] <= 4 * 30


@pytest.mark.parametrize("env_id", ALL)
def test_the_env_spec_is_the_ids_and_remakes_the_task(env_id):
    """Reading the inner env's length while the wrapper was built cached the inner id (Pendulum-v1) on env.spec."""
    env = gym.make(env_id)
    assert env.spec.id == env_id
    again = gym.make(env.spec)
    assert str(again.get_wrapper_attr("formula")) == str(env.get_wrapper_attr("formula"))
