"""benchmarks/parking_starts.py: the start geometry, the report's arithmetic, the controller's runs, bad input."""

import contextlib
import json
import math

import numpy as np
import pytest

from benchmarks.parking_starts import (
    ENDINGS,
    HORIZON,
    ControllerPredictor,
    ParkingController,
    Start,
    band_rows,
    check_run,
    ending,
    main,
    plot_lot,
    policy_outcomes,
    report,
    start_of,
)


def observation(car, slot, slot_heading, car_heading=0.0):
    """A parking-v0 reset observation (scaled as parking-v0 scales it): the car at rest at ``car``."""
    scale = np.array([100.0, 100.0, 5.0, 5.0, 1.0, 1.0])
    o = np.array([*car, 0.0, 0.0, math.cos(car_heading), math.sin(car_heading)]) / scale
    g = np.array([*slot, 0.0, 0.0, math.cos(slot_heading), math.sin(slot_heading)]) / scale
    return {"observation": o, "desired_goal": g, "achieved_goal": o}


def test_start_geometry_of_an_end_slot_and_of_a_slot_behind():
    end = start_of(observation((0.0, 0.0), (26.0, 14.0), math.pi / 2))
    assert end.slot == pytest.approx((26.0, 14.0))
    assert end.distance == pytest.approx(math.hypot(26.0, 14.0))
    assert end.bearing == pytest.approx(math.degrees(math.atan2(14.0, 26.0)))  # the car faces +x
    # the bearing is the turn from the car's heading to the slot, either way: 0° ahead, 180° behind
    behind = start_of(observation((0.0, 0.0), (0.0, -14.0), -math.pi / 2, car_heading=math.pi / 2))
    assert behind.distance == pytest.approx(14.0) and behind.bearing == pytest.approx(180.0)
    left = start_of(observation((0.0, 0.0), (-26.0, 14.0), math.pi / 2, car_heading=-0.1))
    assert left.bearing == pytest.approx(180.0 - math.degrees(math.atan2(14.0, 26.0)) + math.degrees(0.1))


def test_band_rows_count_starts_and_success_per_band():
    wins = {"a": np.array([True, False, True, True]), "b": np.array([False, False, False, True])}
    rows = band_rows(wins, np.array([5.0, 15.0, 25.0, 35.0]), (0.0, 20.0, math.inf), "m")
    assert rows == [["0–20 m", "2", "50%", "0%"], ["≥ 20 m", "2", "100%", "50%"]]
    empty = band_rows(wins, np.array([5.0, 15.0, 25.0, 35.0]), (0.0, 1.0, 2.0), "m")
    assert empty[0][1] == "0" and empty[0][2:] == ["–", "–"]
    closed = band_rows(wins, np.array([0.0, 90.0, 135.0, 180.0]), (0.0, 90.0, 180.0), "°")  # 180° is in the last
    assert [row[1] for row in closed] == ["1", "3"]


def test_report_counts_the_unions_and_what_only_the_controller_parks():
    agents = {"run1": np.array([True, False, False, False]), "run2": np.array([True, True, False, False])}
    controller = np.array([False, False, True, False])
    geometry = [Start((0.0, 14.0), d, b) for d, b in ((14.0, 0.0), (18.0, 40.0), (28.0, 70.0), (29.0, 170.0))]
    text = report(agents, controller, geometry)
    assert "| some agent parks | 50% |" in text
    assert "| some agent or the controller parks | 75% |" in text
    assert "| ≥ 25 m | 2 | 0% | 0% | 50% |" in text and "| 20–25 m | 0 | – | – | – |" in text
    assert "| 135–180 ° | 1 | 0% | 0% | 0% |" in text
    assert "starts no agent parks from: [2, 3] (episode indices), of which the controller parks 1." in text


def test_endings_tell_the_four_failures_apart_and_a_violation_comes_first():
    far, near = np.full(HORIZON + 1, 10.0), np.r_[np.full(HORIZON, 10.0), 1.0]  # in the slot at the last state
    slow, fast = np.full(HORIZON + 1, 0.5), np.full(HORIZON + 1, 2.0)
    assert ending(near, slow, satisfied=True) == "parked"  # success is the formula's robustness, given
    assert ending(far, slow, satisfied=False) == "out of time"
    assert ending(near, fast, satisfied=False) == "at the slot, too fast"
    assert ending(far[:40], slow[:40], satisfied=False) == "crashed"  # ended before the horizon, within the limit
    over = slow.copy()
    over[3] = 5.0  # the limit itself breaks G(speed < 5)
    assert ending(near, over, satisfied=False) == "over the speed limit"
    assert ending(near[:4], over[:4], satisfied=False) == "over the speed limit"  # before "crashed"
    assert ending(near, np.full(HORIZON + 1, 1.0), satisfied=False) == "at the slot, too fast"


def test_the_report_counts_how_each_policys_episodes_ended():
    agents = {"run1": np.array([True, False, False])}
    geometry = [Start((0.0, 14.0), 14.0, 0.0)] * 3
    endings = {"agent 1": ["parked", "crashed", "crashed"], "controller": ["parked", "out of time", "parked"]}
    text = report(agents, np.array([True, False, True]), geometry, endings)
    assert "| how the episode ended | agent 1 | controller |" in text
    assert "| crashed | 2 | 0 |" in text and "| parked | 1 | 2 |" in text and "| out of time | 0 | 1 |" in text
    assert text.count("\n| ") >= len(ENDINGS) + 2 + 4  # every ending has a row, even at 0
    assert "how the episode ended" not in report(agents, np.array([True, False, True]), geometry)


def test_the_task_bounds_the_endings_read_are_the_registered_tasks():
    pytest.importorskip("highway_env")
    import gymnasium as gym

    with contextlib.closing(gym.make("TLParking-v0")) as env:
        assert str(env.get_wrapper_attr("formula")) == "F (goal_error < 1.44 & speed < 1) & G speed < 5"
        assert env.get_wrapper_attr("horizon") == HORIZON


def test_the_controller_parks_the_same_starts_every_time_and_idling_parks_none():
    pytest.importorskip("highway_env")
    first, first_starts = policy_outcomes(ParkingController, n_episodes=3, seed=8)
    assert first.wins.dtype == bool and first.wins.shape == (3,) and first.wins[0]  # seed 8: the tests' parking start
    assert [kind == "parked" for kind in first.endings] == first.wins.tolist()  # each episode's own success
    again, again_starts = policy_outcomes(ParkingController, n_episodes=3, seed=8)
    np.testing.assert_array_equal(again.wins, first.wins)
    assert again_starts == first_starts and again.endings == first.endings
    idle, idle_starts = policy_outcomes(lambda: lambda obs: np.zeros(2, dtype=np.float32), n_episodes=3, seed=8)
    assert not idle.wins.any() and idle_starts == first_starts
    assert idle.endings == ["out of time"] * 3  # at rest at the lot's centre, never in the slot


def test_an_agents_evaluation_episodes_start_where_the_controllers_do():
    """Episode i of `evaluate_policy` (here 2 envs at a time, 5 episodes) starts from reset seed ``seed + i``."""
    pytest.importorskip("highway_env")
    import gymnasium as gym
    from tl_gym.agents.evaluation import evaluate_policy

    predictor = ControllerPredictor(lambda: lambda obs: np.zeros(2, dtype=np.float32))  # idles, records the starts
    with contextlib.closing(gym.make_vec("TLParking-v0", num_envs=2)) as venv:
        evaluate_policy(predictor, venv, n_episodes=5, seed=12345)
    seen = predictor.starts[:5]
    with contextlib.closing(gym.make("TLParking-v0")) as env:
        assert seen == [start_of(env.reset(seed=12345 + i)[0]) for i in range(5)]
    assert seen == policy_outcomes(ParkingController, n_episodes=5, seed=12345)[1]
    assert len({start.slot for start in seen} | {round(start.bearing, 3) for start in seen}) > 2  # not one start


def test_the_recorded_starts_lie_in_the_slot_rows():
    pytest.importorskip("highway_env")
    geometry = policy_outcomes(ParkingController, n_episodes=5, seed=0)[1]
    assert len(geometry) == 5
    lot = {round(math.hypot(4 * k - 26, 14.0), 6) for k in range(14)}  # slot centres (4k - 26, ±14), car at (0, 0)
    for start in geometry:
        assert abs(abs(start.slot[1]) - 14.0) < 1e-6
        assert round(start.distance, 6) in lot and 0.0 <= start.bearing <= 180.0


def write_run(folder, name="spec.json", **run):
    folder.mkdir()
    (folder / name).write_text(json.dumps({"env": "TLParking-v0", "env_kwargs": {}, **run}))
    return folder


def test_runs_of_another_task_or_without_an_agent_are_refused_naming_why(tmp_path):
    with pytest.raises(FileNotFoundError, match="has no run.json or spec.json"):
        check_run(tmp_path)
    with pytest.raises(ValueError, match="trained on 'TLPendulum-v0', not the registered TLParking-v0"):
        check_run(write_run(tmp_path / "pendulum", env="TLPendulum-v0"))
    with pytest.raises(ValueError, match="with --spec"):
        check_run(write_run(tmp_path / "spec", "run.json", spec="F(speed < 1)"))
    with pytest.raises(ValueError, match=r"env_kwargs \['horizon'\] change the task"):
        check_run(write_run(tmp_path / "longer", env_kwargs={"horizon": 300, "end_on_violation": True}))
    unfinished = write_run(tmp_path / "unfinished", env_kwargs={"end_on_violation": True, "reward_mode": "potential"})
    with pytest.raises(FileNotFoundError, match="agent.zip not found"):
        check_run(unfinished)
    (unfinished / "agent.zip").write_bytes(b"")
    assert check_run(unfinished) == unfinished


def test_no_episodes_a_run_given_twice_and_a_bad_run_are_refused_before_any_evaluation(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["somewhere", "--episodes", "0"])
    assert "--episodes must be >= 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["a", "b", "a"])
    assert "a run folder is given twice" in capsys.readouterr().err
    good = write_run(tmp_path / "good")
    (good / "agent.zip").write_bytes(b"")  # not loadable: it must not be reached
    with pytest.raises(ValueError, match="trained on 'TLPendulum-v0'"):
        main([str(good), str(write_run(tmp_path / "bad", env="TLPendulum-v0"))])


def test_the_lot_figure_draws_each_slot_in_place_coloured_by_success(tmp_path):
    geometry = [Start((26.0, 14.0), 29.5, 20.0), Start((-2.0, -14.0), 14.1, 90.0), Start((26.0, 14.0), 29.5, 160.0)]
    fig = plot_lot({"a": np.array([False, True, True]), "b": np.array([False, True, False])}, geometry,
                   tmp_path / "figures" / "lot.png")
    assert (tmp_path / "figures" / "lot.png").stat().st_size > 1000
    slots = {(p.get_x(), p.get_y(), p.get_width(), p.get_height()): p.get_facecolor() for p in fig.axes[0].patches}
    assert set(slots) == {(24.0, 10.0, 4.0, 8.0), (-4.0, -18.0, 4.0, 8.0)}  # 4 m across the row, 8 m along it
    red, green = slots[(24.0, 10.0, 4.0, 8.0)], slots[(-4.0, -18.0, 4.0, 8.0)]  # success 0.25 and 1
    assert green[1] > green[0] and red[0] > red[1]
