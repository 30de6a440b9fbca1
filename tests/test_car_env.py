"""TLCarNav-v0: satisfiability by scripted controllers, checkers, determinism, vector env, rendering."""

import math
import os
import pickle
import subprocess
import sys
import warnings

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # the checkers and the human-mode test open no window
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from tl_gym.envs.car import CarNavEnv  # noqa: E402
from tl_gym.envs.dynamics import CarParams, car_step  # noqa: E402
from tl_gym.envs.tasks import TASK1_LAYOUT, task_formula  # noqa: E402
from tl_gym.envs.vector import CarNavVectorEnv  # noqa: E402

import tl_gym  # noqa: E402, F401  (registers TLCarNav-v0)

# --------------------------------------------------------------------------- scripted controllers


def _wrap(angle):
    return (angle + math.pi) % (2 * math.pi) - math.pi


def drive(env, legs, seed):
    """Run one episode of closed-loop legs and return the terminal info.

    Legs: ("goto", x, y, tolerance, speed) steers at a point and never overshoots it;
    ("line", x0, y0, heading, along, speed) follows a line until ``along`` units past
    (x0, y0); ("sprint", x0, y0, heading, n) drives n full-speed steps along that line.
    After the last leg the car stops (a_v = 0).
    """
    p = env.unwrapped.params
    obs, _ = env.reset(seed=seed)
    legs = list(legs)
    sprint_left = 0
    rewards = []
    while True:
        x, y, theta = obs[:3]
        speed, steer = 0.0, 0.0
        while legs:
            kind, *args = legs[0]
            if kind == "goto":
                tx, ty, tolerance, cruise = args
                distance = math.hypot(tx - x, ty - y)
                if distance < tolerance:
                    legs.pop(0)
                    continue
                error = _wrap(math.atan2(ty - y, tx - x) - theta)
                speed = min(cruise, distance / p.dt)
            else:
                x0, y0, heading = args[:3]
                along = (x - x0) * math.cos(heading) + (y - y0) * math.sin(heading)
                cross = -(x - x0) * math.sin(heading) + (y - y0) * math.cos(heading)
                error = _wrap(heading - math.atan(0.05 * cross) - theta)
                if kind == "line":
                    stop_at, cruise = args[3:]
                    if stop_at - along < 0.5:
                        legs.pop(0)
                        continue
                    speed = min(cruise, (stop_at - along) / p.dt)
                else:  # sprint
                    sprint_left = sprint_left or args[3]
                    speed = p.max_speed
                    sprint_left -= 1
                    if sprint_left == 0:
                        legs.pop(0)
            # turn by the whole heading error during this step, within the steering range
            steer = math.atan(error * p.wheelbase / max(speed * p.dt, 1e-9))
            steer = max(-p.max_steer, min(p.max_steer, steer))
            break
        action = np.array([2 * speed / p.max_speed - 1, steer / p.max_steer], dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        if terminated or truncated:
            return {**info, "rewards": rewards}


TASK1 = [("goto", 200, 70, 20, 60), ("goto", 255, 255, 2, 60)]  # pass right of the obstacle, park in g
TASK2_CRUISE = [("goto", 225, 60, 2, 40), ("goto", 225, 240, 2, 40), ("goto", 75, 240, 2, 40)]  # park in g3
# Eq. 19 strict: inside each goal for exactly one sample. Align on a line one step before the goal,
# then one full-speed step (30 units, a goal's width) lands on its centre and the next one leaves it.
TASK2_SPRINT = [
    ("goto", 100, 60, 15, 60), ("line", 0, 60, 0.0, 195, 30), ("sprint", 0, 60, 0.0, 2),
    ("goto", 360, 150, 20, 60), ("goto", 360, 210, 20, 60),
    ("line", 0, 240, math.pi, -255, 30), ("sprint", 0, 240, math.pi, 7),  # g2 and g3 on one straight run
]
SEEDS = range(4)


@pytest.mark.parametrize(
    ("kwargs", "legs", "low"),
    [
        ({"task": 1}, TASK1, 14.0),
        ({"task": 2}, TASK2_CRUISE, 2.5),
        ({"task": 2, "no_revisit": "strict"}, TASK2_SPRINT, 5.0),
        ({"task": 2}, TASK2_SPRINT, 5.0),  # strict implies the default reading
    ],
)
def test_scripted_controllers_satisfy_every_task(kwargs, legs, low):
    env = gym.make("TLCarNav-v0", **kwargs)
    for seed in SEEDS:
        info = drive(env, legs, seed)
        assert info["satisfied"] and info["robustness"] > low, (kwargs, seed, info["robustness"])
        # the robustness is bounded by half a goal's width (15 units)
        assert info["robustness"] < 15.0


@pytest.mark.parametrize(("no_revisit", "legs"), [("leave", TASK2_CRUISE), ("strict", TASK2_SPRINT)])
def test_dense_rewards_on_task_two_sum_to_the_robustness(no_revisit, legs):
    env = gym.make("TLCarNav-v0", task=2, no_revisit=no_revisit, reward_mode="dense")
    assert env.get_wrapper_attr("_monitor").incremental
    info = drive(env, legs, seed=0)
    assert math.fsum(info["rewards"]) == pytest.approx(info["robustness"], abs=1e-9)
    assert info["robustness"] > 0 and any(r > 0 for r in info["rewards"][:-1])


def test_cruising_through_goals_fails_the_strict_no_revisit():
    env = gym.make("TLCarNav-v0", task=2, no_revisit="strict")
    for seed in SEEDS:
        info = drive(env, TASK2_CRUISE, seed)
        assert not info["satisfied"] and info["robustness"] < 0


def test_smoothed_reward_is_close_to_exact_at_the_default_beta():
    """At this scale β = 9 smooths by a fraction of a unit while the margins are several units."""
    env = gym.make("TLCarNav-v0", task=2, reward="smooth")
    info = drive(env, TASK2_CRUISE, seed=0)
    assert info["smooth_robustness"] == pytest.approx(info["robustness"], abs=0.5)
    assert info["smooth_robustness"] > 0


# --------------------------------------------------------------------------- dynamics and spaces


def test_car_step_matches_the_model():
    state = np.array([[10.0, 20.0, 0.3, 0, 0, 0], [0.0, 0.0, -3.0, 0, 0, 0]])
    action = np.array([[40.0, 0.2], [60.0, -0.6]])
    out = car_step(state, action, 0.5, 15.0, np.zeros((2, 3)))
    np.testing.assert_allclose(out[:, 3], action[:, 0] * np.cos(state[:, 2]))
    np.testing.assert_allclose(out[:, 4], action[:, 0] * np.sin(state[:, 2]))
    np.testing.assert_allclose(out[:, 5], action[:, 0] / 15.0 * np.tan(action[:, 1]))
    np.testing.assert_allclose(out[:, :2], state[:, :2] + 0.5 * out[:, 3:5])
    heading = state[:, 2] + 0.5 * out[:, 5]
    np.testing.assert_allclose(out[:, 2], (heading + np.pi) % (2 * np.pi) - np.pi)
    assert -np.pi <= out[1, 2] < np.pi and out[1, 2] > 0  # -3 - 2.7 wrapped


def test_actions_are_normalised_and_clipped():
    params = CarParams()
    np.testing.assert_allclose(params.physical_action(np.array([-1.0, -1.0])), [0.0, -0.6])
    np.testing.assert_allclose(params.physical_action(np.array([1.0, 1.0])), [60.0, 0.6])
    np.testing.assert_allclose(params.physical_action(np.array([5.0, 0.5])), [60.0, 0.3])
    env = gym.make("TLCarNav-v0")
    obs0, _ = env.reset(seed=0)
    obs1, *_ = env.step(np.array([-1.0, 1.0], dtype=np.float32))
    assert np.hypot(*(obs1[:2] - obs0[:2])) < 1.5  # stopped: only noise moves it
    np.testing.assert_array_equal(obs1[3:], 0.0)


def test_observations_stay_in_their_box_at_full_turn():
    env = gym.make("TLCarNav-v0", horizon=50).unwrapped
    obs, _ = env.reset(seed=1)
    for _ in range(50):
        obs, *_ = env.step(np.array([1.0, 1.0], dtype=np.float32))
        assert env.observation_space.contains(obs)
    assert obs[5] == env.observation_space.high[5]


def test_horizon_and_truncation_belong_to_the_env():
    env = gym.make("TLCarNav-v0", horizon=7)
    assert env.spec.max_episode_steps is None
    env.reset(seed=0)
    flags = [env.step(np.zeros(2, dtype=np.float32))[3] for _ in range(7)]
    assert flags == [False] * 6 + [True]
    assert len(env.get_wrapper_attr("trace")["x"]) == 8


def test_make_returns_the_wrapped_car_with_its_formula():
    env = gym.make("TLCarNav-v0", task=2, no_revisit="strict", obstacle=(100, 120, 30))
    assert isinstance(env.unwrapped, CarNavEnv)
    assert env.get_wrapper_attr("formula") == task_formula(2, "strict", obstacle=(100, 120, 30))
    assert "sqrt((x - 100) ^ 2 + (y - 120) ^ 2) > 30" in str(env.get_wrapper_attr("formula"))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"task": 3}, "task"),
        ({"no_revisit": "sometimes"}, "no_revisit"),
        ({"horizon": 0}, "horizon"),
        ({"dt": -0.5}, "dt"),
        ({"max_steer": 2.0}, "max_steer"),
        ({"noise_std": (1.0, 1.0)}, "noise_std"),
        ({"task": 2, "goals": [(0, 1, 0, 1)]}, "3 goal"),
        ({"goals": [(5, 1, 0, 1)]}, "x_low < x_high"),
        ({"obstacle": (0, 0, -1)}, "radius"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"reward": "shaped"}, "reward"),
        # not a sequence of numbers at all: the message still names the keyword (was a bare TypeError)
        ({"start_std": 15}, "start_std"),
        ({"start_std": "123"}, "start_std"),
        ({"noise_std": None}, "noise_std"),
        ({"start": 5}, "start must be three"),
        ({"goals": [(240, 270, 240)]}, r"goals\[0\] must be four numbers"),
        ({"goals": 5}, "1 goal"),
        ({"obstacle": "abc"}, "obstacle must be"),
        ({"arena": 300}, "arena"),
        ({"arena": (300, -1)}, r"arena must be \(width, height\) > 0"),
        ({"start": (0, 0, float("inf"))}, "start must be three finite numbers"),
        ({"goals": [(0, float("nan"), 0, 1)]}, "a goal is four finite numbers"),
    ],
)
def test_bad_env_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("TLCarNav-v0", **kwargs)
    with pytest.raises(ValueError, match=match):
        gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)


def test_numpy_numbers_are_arguments():
    """Values read from numpy arrays or configs work as Python's do (max_steer refused np.float32 as out of range)."""
    env = gym.make("TLCarNav-v0", max_steer=np.float32(0.5), start_std=np.array([15.0, 15.0, 0.3]))
    assert env.unwrapped.params.max_steer == pytest.approx(0.5) and env.unwrapped.params.start_std == (15, 15, 0.3)


# --------------------------------------------------------------------------- checkers, determinism, pickling


@pytest.mark.parametrize("task", [1, 2])
def test_gymnasium_and_sb3_env_checkers(task):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    check_env(gym.make("TLCarNav-v0", task=task).unwrapped)
    with warnings.catch_warnings():  # the one expected warning: we check the wrapped env on purpose
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")
        check_env(gym.make("TLCarNav-v0", task=task, disable_env_checker=True))
    sb3_check_env(gym.make("TLCarNav-v0", task=task))


def _rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rewards = []
    for action in actions:
        obs, reward, *_ = env.step(action)
        out.append(obs)
        rewards.append(reward)
    return np.array(out), rewards


def test_same_seed_and_actions_give_the_same_trajectory():
    actions = np.random.default_rng(0).uniform(-1, 1, size=(200, 2)).astype(np.float32)
    first = _rollout(gym.make("TLCarNav-v0", task=2), 5, actions)
    second = _rollout(gym.make("TLCarNav-v0", task=2), 5, actions)
    np.testing.assert_array_equal(first[0], second[0])
    assert first[1] == second[1]
    other = _rollout(gym.make("TLCarNav-v0", task=2), 6, actions)
    assert not np.array_equal(first[0], other[0])


@pytest.mark.parametrize("kwargs", [{}, {"task": 2, "reward_mode": "dense", "observe_monitor": True},
                                    {"task": 2, "reward_mode": "potential", "observe_monitor": True}])
def test_pickled_env_continues_identically(kwargs):
    env = gym.make("TLCarNav-v0", **kwargs)
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.array([0.5, 0.1], dtype=np.float32))
    clone = pickle.loads(pickle.dumps(env))
    for _ in range(190):
        a, b = env.step(np.array([0.5, 0.1], dtype=np.float32)), clone.step(np.array([0.5, 0.1], dtype=np.float32))
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1] == b[1]
    assert a[3] and b[3]


def test_importing_is_not_needed():
    code = "import gymnasium as gym; env = gym.make('tl_gym:TLCarNav-v0', task=2); print(env.reset(seed=0)[0].shape)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().endswith("(6,)")


# --------------------------------------------------------------------------- batched env


@pytest.mark.parametrize(("task", "reward"), [(1, "exact"), (2, "exact"), (2, "smooth")])
def test_vector_env_matches_sync_vector_env(task, reward):
    n, horizon = 5, 30
    kwargs = {"task": task, "reward": reward, "horizon": horizon}
    batched = gym.make_vec("TLCarNav-v0", num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec("TLCarNav-v0", num_envs=n, vectorization_mode="sync", **kwargs)
    assert isinstance(batched.unwrapped, CarNavVectorEnv)
    assert batched.unwrapped.formula == sync.envs[0].get_wrapper_attr("formula")
    obs_b, _ = batched.reset(seed=11)
    obs_s, _ = sync.reset(seed=11)
    np.testing.assert_array_equal(obs_b, obs_s)
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(2 * (horizon + 1) + 3):  # two episodes, the autoreset steps and a bit of a third
        actions = rng.uniform(-1.2, 1.2, size=(n, 2)).astype(np.float32)
        out_b, out_s = batched.step(actions), sync.step(actions)
        np.testing.assert_array_equal(out_b[0], out_s[0])
        np.testing.assert_allclose(out_b[1], out_s[1], rtol=1e-12)
        np.testing.assert_array_equal(out_b[2], out_s[2])
        np.testing.assert_array_equal(out_b[3], out_s[3])
        info_b, info_s = out_b[4], out_s[4]
        assert info_b.keys() == info_s.keys()
        if out_b[3].any():
            ends += 1
            assert [dict(t).keys() for t in info_b["trace"]] == [dict(t).keys() for t in info_s["trace"]]
            for trace_b, trace_s in zip(info_b["trace"], info_s["trace"]):
                np.testing.assert_array_equal(trace_b["x"], trace_s["x"])
                np.testing.assert_array_equal(trace_b["y"], trace_s["y"])
            np.testing.assert_array_equal(info_b["_trace"], info_s["_trace"])
            np.testing.assert_allclose(info_b["robustness"], info_s["robustness"], rtol=1e-12)
            np.testing.assert_array_equal(info_b["satisfied"], info_s["satisfied"])
            for key in info_b:
                assert type(info_b[key]) is type(info_s[key])
                if isinstance(info_b[key], np.ndarray):
                    assert info_b[key].dtype == info_s[key].dtype and info_b[key].shape == info_s[key].shape
    assert ends == 2


class ActionRecorder(gym.Wrapper):
    """Keeps every action it passes on."""

    def __init__(self, env):
        super().__init__(env)
        self.actions = []

    def step(self, action):
        self.actions.append(np.array(action, dtype=np.float32))
        return self.env.step(action)


def test_vector_env_pays_the_satisfaction_bonus_as_the_wrapper_does():
    """A satisfying drive replayed in the batched car: the same dense rewards, adding up to ρ + bonus."""
    recorder = ActionRecorder(gym.make("TLCarNav-v0", task=1, reward_mode="dense", satisfaction_bonus=50.0))
    info = drive(recorder, TASK1, seed=0)
    actions, rewards = recorder.actions, info["rewards"]
    assert info["satisfied"] and math.fsum(rewards) == pytest.approx(info["robustness"] + 50.0, abs=1e-9)
    batched = CarNavVectorEnv(num_envs=2, task=1, reward_mode="dense", satisfaction_bonus=50.0)
    batched.reset(seed=0)  # car 0 draws as the single env with seed 0
    for t, action in enumerate(actions):
        _, reward, _, truncated, infos = batched.step(np.stack([action, np.zeros(2, dtype=np.float32)]))
        assert reward[0] == pytest.approx(rewards[t], abs=1e-9), t
    assert truncated.all() and infos["satisfied"][0]
    terminal = CarNavVectorEnv(num_envs=2, task=1, satisfaction_bonus=50.0)
    terminal.reset(seed=0)
    for action in actions:
        _, reward, *_ = terminal.step(np.stack([action, np.zeros(2, dtype=np.float32)]))
    assert reward[0] == pytest.approx(info["robustness"] + 50.0, abs=1e-9)


def test_the_single_car_refuses_a_step_out_of_an_episode_or_of_the_wrong_shape():
    env = gym.make("TLCarNav-v0", horizon=2).unwrapped
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must have shape \(2,\).*got \(3,\)"):
        env.step(np.zeros(3))
    env.step(np.zeros(2))
    env.step(np.zeros(2))
    with pytest.raises(RuntimeError, match="the episode is over"):
        env.step(np.zeros(2))


def test_render_without_a_render_mode_warns_and_draws_nothing():
    single = gym.make("TLCarNav-v0").unwrapped
    single.reset(seed=0)
    with pytest.warns(UserWarning, match='render_mode="rgb_array"'):
        assert single.render() is None
    envs = CarNavVectorEnv(num_envs=2)
    envs.reset(seed=0)
    with pytest.warns(UserWarning, match='render_mode="rgb_array"'):
        assert envs.render() is None
    with pytest.raises(ValueError, match="seed must be an int or 2 seeds, got 3"):
        envs.reset(seed=[1, 2, 3])


def test_vector_env_autoreset_and_errors():
    envs = CarNavVectorEnv(num_envs=3, horizon=2)
    with pytest.raises(RuntimeError, match="reset"):
        envs.step(np.zeros((3, 2)))
    envs.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.zeros((2, 2)))
    envs.step(np.zeros((3, 2)))
    _, rewards, _, truncated, info = envs.step(np.zeros((3, 2)))
    assert truncated.all() and (rewards == info["robustness"]).all()
    obs, rewards, terminated, truncated, info = envs.step(np.ones((3, 2)))  # the autoreset step
    assert not truncated.any() and not terminated.any() and (rewards == 0).all() and info == {}
    np.testing.assert_array_equal(obs[:, 3:], 0.0)
    with pytest.raises(ValueError, match="reward_mode must be one of"):
        CarNavVectorEnv(num_envs=2, reward_mode="sparse")
    with pytest.raises(ValueError, match="dense.*reward='exact'"):
        CarNavVectorEnv(num_envs=2, reward_mode="dense", reward="smooth")
    with pytest.raises(ValueError, match="num_envs"):
        CarNavVectorEnv(num_envs=0)


def test_vector_env_refuses_a_partial_reset():
    """options={"reset_mask": ...} resets only those cars in SyncVectorEnv; this env restarted them all, silently."""
    envs = CarNavVectorEnv(num_envs=2, horizon=3)
    envs.reset(seed=0, options={"reset_mask": np.array([True, True])})  # all of them: a reset
    with pytest.raises(ValueError, match="reset_mask"):
        envs.reset(options={"reset_mask": np.array([True, False])})


def test_vector_env_seeds_car_i_with_seed_plus_i():
    envs = CarNavVectorEnv(num_envs=4, task=2)
    obs, _ = envs.reset(seed=100)
    single = gym.make("TLCarNav-v0", task=2)
    for i in range(4):
        np.testing.assert_array_equal(single.reset(seed=100 + i)[0], obs[i])
    # reset(seed=None) continues each car's generator, as SyncVectorEnv's sub-envs do
    sync = gym.make_vec("TLCarNav-v0", num_envs=4, vectorization_mode="sync", task=2)
    sync.reset(seed=100)
    np.testing.assert_array_equal(envs.reset()[0], sync.reset()[0])
    np.testing.assert_array_equal(envs.reset(seed=[None, 7, None, 8])[0], sync.reset(seed=[None, 7, None, 8])[0])


# --------------------------------------------------------------------------- rendering


def test_rgb_array_rendering_draws_the_layout_and_the_car():
    env = gym.make("TLCarNav-v0", task=2, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(20):
        env.step(np.array([1.0, 0.2], dtype=np.float32))
    frame = env.render()
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8
    assert not np.array_equal(first, frame)  # the car moved and left a trace
    green = (frame[..., 1] > frame[..., 0] + 30) & (frame[..., 1] > frame[..., 2] + 30)
    assert green.sum() > 1000  # goals and obstacle
    vector = CarNavVectorEnv(num_envs=3, render_mode="rgb_array")
    vector.reset(seed=0)
    assert vector.render().shape == (480, 480, 3)


def test_human_rendering_and_missing_pygame(monkeypatch):
    pytest.importorskip("pygame")
    env = gym.make("TLCarNav-v0", render_mode="human", horizon=2)
    env.reset(seed=0)
    env.step(np.zeros(2, dtype=np.float32))
    env.close()
    monkeypatch.setitem(sys.modules, "pygame", None)
    env = gym.make("TLCarNav-v0", render_mode="human")
    with pytest.raises(gym.error.DependencyNotInstalled, match=r"tl_gym\[render\]"):
        env.reset(seed=0)


def test_draw_layout_on_an_axes():
    from matplotlib.figure import Figure
    from tl_gym.envs.rendering import draw_layout

    ax = Figure().add_subplot()
    draw_layout(ax, TASK1_LAYOUT)
    assert len(ax.patches) == 2 and ax.get_xlim() == (0.0, 300.0)


def test_vector_env_scores_all_cars_in_one_engine_call(monkeypatch):
    envs = CarNavVectorEnv(num_envs=6, task=2, horizon=4)
    calls = []
    original = type(envs.formula).robustness

    def counting(self, trace, rho_max=math.inf):
        calls.append(np.shape(trace["x"]))
        return original(self, trace, rho_max)

    monkeypatch.setattr(type(envs.formula), "robustness", counting)
    envs.reset(seed=0)
    for _ in range(4):
        envs.step(np.zeros((6, 2)))
    assert calls == [(6, 5)]


def test_the_cars_defaults_live_in_car_params_alone():
    from tl_gym.envs.car import CarNavEnv
    from tl_gym.envs.dynamics import CarParams
    from tl_gym.envs.vector import CarNavVectorEnv

    assert CarNavEnv().params == CarNavVectorEnv(num_envs=1).params == CarParams()
    spread = {"start_std": (15, 15, 0.3), "horizon": 7}
    assert CarNavEnv(**spread).params == CarNavVectorEnv(num_envs=2, **spread).params == CarParams(**spread)
    for make in (CarNavEnv, lambda **kw: CarNavVectorEnv(num_envs=1, **kw)):
        with pytest.raises(TypeError, match=r"no keyword.*'start_spread'.*start_std"):
            make(start_spread=1.0)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"horizn": 5}, r"the car has no keyword 'horizn' \(did you mean 'horizon'\?\); the car takes \(dt, .*start_std.*"
                    r"render_mode\); TLCarNav-v0 also takes task, no_revisit and the reward's \(reward, .*"
                    r"satisfaction_bonus\)"),
    ({"end_on_violation": True}, r"'end_on_violation' \(a TLTLRewardWrapper keyword the car does not take: the car's "
                                 r"tasks keep the episode going"),
    ({"env_reward_weight": 1.0}, "the car pays no reward of its own"),
    # gym.make takes max_episode_steps itself (a TimeLimit outside, which the agents refuse); the batched car gets it
    ({"max_episode_steps": 50}, r"the car owns its episode length .*: pass horizon="),
])
def test_a_keyword_the_car_does_not_take_is_named_with_all_it_takes(kwargs, match):
    if "max_episode_steps" not in kwargs:
        with pytest.raises(TypeError, match=match):
            gym.make("TLCarNav-v0", **kwargs)
    with pytest.raises(TypeError, match=match):  # the batched car says the same
        gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)


def test_a_non_finite_action_is_refused_naming_the_car_before_it_moves():
    env = gym.make("TLCarNav-v0")
    obs, _ = env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action \[nan, 0.0\] is not finite"):
        env.step(np.array([np.nan, 0.0], dtype=np.float32))
    assert np.isfinite(env.step(np.zeros(2, dtype=np.float32))[0]).all()  # the episode goes on, unharmed
    batched = gym.make_vec("TLCarNav-v0", num_envs=3, vectorization_mode="vector_entry_point")
    batched.reset(seed=0)
    actions = np.zeros((3, 2))
    actions[2, 1] = -np.inf
    with pytest.raises(ValueError, match=r"the actions of car\(s\) \[2\] are not finite \(\[0.0, -inf\] for car 2\)"):
        batched.step(actions)
    assert np.isfinite(batched.step(np.zeros((3, 2)))[0]).all()


@pytest.mark.parametrize("mode", ["SameStep", "Disabled", "bad"])
def test_the_batched_car_names_the_autoreset_mode_it_offers(mode):
    from gymnasium.vector import AutoresetMode

    assert gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        autoreset_mode=AutoresetMode.NEXT_STEP).metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    with pytest.raises(ValueError, match="autoreset_mode"):
        gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode=mode)


def test_the_batched_car_ignores_a_non_finite_action_on_its_autoreset_step_as_sync_does():
    batched = gym.make_vec("TLCarNav-v0", num_envs=2, vectorization_mode="vector_entry_point", horizon=3)
    batched.reset(seed=0)
    for _ in range(3):
        batched.step(np.zeros((2, 2)))
    obs, *_ = batched.step(np.full((2, 2), np.nan))  # the autoreset step: the action is not used
    assert np.isfinite(obs).all()
