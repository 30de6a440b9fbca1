"""benchmarks/parking_starts.py: the start geometry, the report's arithmetic, the controller's runs, bad input."""

import json
import math

import numpy as np
import pytest

from benchmarks.parking_starts import (
    ParkingController,
    Start,
    agent_successes,
    band_rows,
    main,
    plot_lot,
    policy_successes,
    report,
    start_of,
    starts,
)


def observation(car, slot, slot_heading):
    """A parking-v0 reset observation (scaled as parking-v0 scales it): the car at rest at ``car``."""
    scale = np.array([100.0, 100.0, 5.0, 5.0, 1.0, 1.0])
    o = np.array([*car, 0.0, 0.0, 1.0, 0.0]) / scale
    g = np.array([*slot, 0.0, 0.0, math.cos(slot_heading), math.sin(slot_heading)]) / scale
    return {"observation": o, "desired_goal": g, "achieved_goal": o}


def test_start_geometry_of_an_end_slot_and_of_a_slot_straight_ahead():
    end = start_of(observation((0.0, 0.0), (26.0, 14.0), math.pi / 2))
    assert end.slot == pytest.approx((26.0, 14.0))
    assert end.distance == pytest.approx(math.hypot(26.0, 14.0))
    assert end.axis_angle == pytest.approx(90.0 - math.degrees(math.atan2(14.0, 26.0)))
    # a slot is the same whichever way its axis points: the angle folds into [0°, 90°]
    assert start_of(observation((0.0, 0.0), (26.0, 14.0), -math.pi / 2)).axis_angle == pytest.approx(end.axis_angle)
    ahead = start_of(observation((0.0, 0.0), (0.0, 14.0), math.pi / 2))
    assert ahead.distance == pytest.approx(14.0) and ahead.axis_angle == pytest.approx(0.0)


def test_band_rows_count_starts_and_success_per_band():
    wins = {"a": np.array([True, False, True, True]), "b": np.array([False, False, False, True])}
    rows = band_rows(wins, np.array([5.0, 15.0, 25.0, 35.0]), (0.0, 20.0, math.inf), "m")
    assert rows == [["0–20 m", "2", "50%", "0%"], ["≥ 20 m", "2", "100%", "50%"]]
    empty = band_rows(wins, np.array([5.0, 15.0, 25.0, 35.0]), (0.0, 1.0, 2.0), "m")
    assert empty[0][1] == "0" and empty[0][2:] == ["", ""]


def test_report_counts_the_unions_and_what_only_the_controller_parks():
    agents = {"run1": np.array([True, False, False, False]), "run2": np.array([True, True, False, False])}
    controller = np.array([False, False, True, False])
    geometry = [Start((0.0, 14.0), d, a) for d, a in ((14.0, 0.0), (18.0, 40.0), (28.0, 70.0), (29.0, 80.0))]
    text = report(agents, controller, geometry)
    assert "| some agent parks | 50% |" in text
    assert "| some agent or the controller parks | 75% |" in text
    assert "| ≥ 20 m | 2 | 0% | 0% | 50% |" in text
    assert "starts no agent parks from: [2, 3] (episode indices), of which the controller parks 1." in text


def test_the_controller_parks_the_same_starts_every_time_and_idling_parks_none():
    pytest.importorskip("highway_env")
    first = policy_successes(ParkingController, n_episodes=3, seed=8)
    assert first.dtype == bool and first.shape == (3,) and first[0]  # seed 8: the tests' parking start
    np.testing.assert_array_equal(policy_successes(ParkingController, n_episodes=3, seed=8), first)
    idle = policy_successes(lambda: lambda obs: np.zeros(2, dtype=np.float32), n_episodes=3, seed=8)
    assert not idle.any()


def test_starts_of_the_env_lie_in_the_slot_rows():
    pytest.importorskip("highway_env")
    geometry = starts(5, seed=0)
    assert len(geometry) == 5
    for start in geometry:
        assert abs(abs(start.slot[1]) - 14.0) < 1e-6  # slot centres: rows at y = ±14 (parking-v0's lot)
        assert 10.0 <= start.distance <= 32.0 and 0.0 <= start.axis_angle <= 90.0


def test_an_agent_of_another_env_or_a_folder_without_a_run_file_is_refused(tmp_path):
    (tmp_path / "pendulum").mkdir()
    (tmp_path / "pendulum" / "spec.json").write_text(json.dumps({"env": "TLPendulum-v0"}))
    with pytest.raises(ValueError, match="trained on 'TLPendulum-v0', not TLParking-v0"):
        agent_successes(tmp_path / "pendulum", 2, 0)
    with pytest.raises(ValueError, match="trained on None"):
        agent_successes(tmp_path, 2, 0)


def test_no_episodes_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["somewhere", "--episodes", "0"])
    assert "--episodes must be >= 1, got 0" in capsys.readouterr().err


def test_the_lot_figure_is_written(tmp_path):
    geometry = [Start((26.0, 14.0), 29.5, 61.7), Start((-2.0, -14.0), 14.1, 8.1), Start((26.0, 14.0), 29.5, 61.7)]
    plot_lot({"a": np.array([False, True, True])}, geometry, tmp_path / "lot.png")
    assert (tmp_path / "lot.png").stat().st_size > 1000
