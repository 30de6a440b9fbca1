"""The speed benchmark's script runs, and its hand-written numpy functions equal tl_gym's values."""

import numpy as np
import pytest

from benchmarks import bench_robustness as bench
from benchmarks import handwritten
from benchmarks.formulas import TASKS, task_formula
from benchmarks.peers import Evaluator


@pytest.mark.parametrize("key", TASKS)
@pytest.mark.parametrize("length", [1, 2, 7, 200])
def test_handwritten_equals_tl_gym(key, length):
    task = task_formula(key)
    x, y = bench.trajectories(300, length, seed=length, tasks=[task_formula(k) for k in TASKS])
    expected = task.formula.robustness({"x": x, "y": y})
    np.testing.assert_allclose(handwritten.robustness(task, x, y), expected, rtol=1e-12, atol=1e-12)


def test_trajectories_are_seeded_in_the_arena_and_satisfy_phi1_phi2_sometimes():
    tasks = [task_formula(k) for k in TASKS]
    x, y = bench.trajectories(400, 200, seed=0, tasks=tasks)
    assert x.shape == y.shape == (400, 200)
    assert x.min() >= 0 and x.max() <= 300 and y.min() >= 0 and y.max() <= 300
    for task in tasks[:2]:  # strict φ2 is unsatisfiable at this speed: a goal takes more than one step to cross
        rho = task.formula.robustness({"x": x, "y": y})
        assert 0 < (rho > 0).sum() < len(rho), task.key  # both outcomes occur, so the checks see both
    again = bench.trajectories(400, 200, seed=0, tasks=tasks)
    np.testing.assert_array_equal(x, again[0])


def test_quick_run_with_tl_gym_and_handwritten_only(tmp_path):
    out = tmp_path / "speed.md"
    rows = bench.main(["--quick", "--tasks", "phi1", "phi2", "--peers", "--out", str(out)])
    hand = [r for r in rows if r.library == bench.HANDWRITTEN]
    assert {(r.task, r.n) for r in hand} == {("phi1", 1), ("phi1", 40), ("phi2", 1), ("phi2", 40)}
    # a row is timed only after its values matched tl_gym's
    assert all(r.per_second and r.per_second > 0 and r.note == "" for r in hand)
    ours = [r for r in rows if r.library == bench.TL_GYM]
    assert all(r.per_second and r.ratio == 1 for r in ours)
    assert {r.mode for r in ours} == {"exact", "smooth+grad", bench.SMOOTH_LINEAR}
    text = out.read_text()
    assert "| formula | N | T | library | mode | traj/s | tl_gym × | note |" in text
    assert "Machine:" in text and "## Targets" in text
    assert "the two calls alternated in one loop (N = 40" in text  # the drift-free ratio, at the largest N


def test_alternated_timing_reports_both_calls_and_the_target():
    task = task_formula("phi1")
    x, y = bench.trajectories(8, 30, seed=2, tasks=[task])
    exact_s, smooth_s = bench.interleaved(task, x, y, 9.0, rounds=2)
    assert 0 < exact_s < 10 and 0 < smooth_s < 10
    (line,) = bench.targets([], alternated=(8, 0.010, 0.060))
    assert "**6.00×** (target ≤ 5×: not met)" in line
    (line,) = bench.targets([], alternated=(8, 0.010, 0.040))
    assert "**4.00×** (target ≤ 5×: met)" in line


def test_a_disagreeing_library_is_reported_not_timed():
    task = task_formula("phi1")
    x, y = bench.trajectories(5, 50, seed=1, tasks=[task])
    wrong = Evaluator("liar", "exact", lambda x, y: handwritten.robustness(task, x, y) + 1.0, per_trajectory=False)
    rows = bench.run_cell(task, x, y, [*bench.tl_gym_evaluators(task, 9.0), wrong], bench.Settings(1, 0.01), print)
    liar = next(r for r in rows if r.library == "liar")
    assert liar.per_second is None and liar.ratio is None
    assert "disagrees with tl_gym on 5/5 trajectories" in liar.note


def test_bad_arguments_are_rejected():
    with pytest.raises(SystemExit):
        bench.parse_args(["--n", "0"])
    with pytest.raises(ValueError, match="unknown task 'phi3'"):
        task_formula("phi3")
