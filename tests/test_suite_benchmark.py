"""The suite benchmark: its configs expand, runs record fresh-episode evaluations, the report reads them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomllib

from benchmarks import results, suite
from benchmarks.runner import run_sweep
from benchmarks.sweep_config import RunSpec, expand_config, load_config

from .test_runner import STAND_IN

ROOT = Path(__file__).resolve().parents[1]


def test_every_suite_config_expands_in_every_variant_with_one_budget_per_task():
    paths = suite.config_paths()
    assert {p.stem for p in paths} >= {"car1", "car2", "car1_spread", "car2_spread", "pendulum", "mountaincar",
                                       "parking"}
    for path in paths:
        data = tomllib.loads(path.read_text())
        for variant in (None, *data.get("variants", {})):
            sweep = load_config(path, variant=variant)
            assert sweep.runs, (path, variant)
        full = load_config(path)
        labels = {run.label for run in full.runs}
        # every agent and the SB3 ablations; a task may add tuned variants of them (labelled "AGENT, change")
        core = {"TLPS", "REPS", "PPO", "SAC", "PPO, terminal reward", "SAC, terminal reward"}
        candidates = {"CrossQ"} if path.stem == "parking" else set()  # a further agent, tried on a task
        assert labels >= core and all(label.split(",")[0] in core | candidates for label in labels), path
        assert {run.iterations for run in full.runs} == {data["iterations"]}  # the same budget for every agent
        sb3 = [run for run in full.runs if run.agent in ("ppo", "sac")]
        assert {run.hyperparameters["steps_per_iteration"] for run in sb3} == {
            40 * (250 if path.stem == "mountaincar" else 100 if path.stem == "parking" else 200)}
    assert [p.stem for p in suite.config_paths(["pendulum", "car1"])] == ["car1", "pendulum"]
    with pytest.raises(SystemExit):  # the command line names the configs there are
        suite.main(["--tasks", "nope"])


def test_runs_evaluate_along_training_and_the_report_reads_them(tmp_path):
    sweep = expand_config({
        "name": "tiny-suite", "env": "TLCarNav-v0", "seeds": [0, 1], "iterations": 5, "evaluate_episodes": 3,
        "evaluate_every": 2, "agents": [{"label": "fast", "agent": STAND_IN, "hyperparameters": {"rate": 0.5}},
                                        {"label": "slow", "agent": STAND_IN, "hyperparameters": {"rate": 0.1}}],
    })
    report = run_sweep(sweep, tmp_path, workers=0)
    assert not report.failed
    runs = results.load_runs(tmp_path)
    history = runs[0].history
    # evaluated after iterations 2, 4 and the last (5); NaN elsewhere
    assert np.isnan(history["eval_success_rate"]).tolist() == [True, False, True, False, False]
    steps, success = suite.eval_curve([r for r in runs if r.spec.label == "fast"])
    assert steps.tolist() == [[200, 400, 500]] * 2 and success.tolist() == [[0.0, 1.0, 1.0], [1.0, 1.0, 1.0]]
    assert suite.steps_to_solve(steps[0], success[0]) == 400.0
    table, rows = suite.task_table(runs)
    assert "| fast | 2 | 500 | 100% (100%–100%) | 300 (2/2) |" in table
    assert rows[1][0] == "slow" and rows[1][2] is None  # ρ = 0.1 m − 1 stays below 0: never solved
    assert suite.headline("tiny", rows) == "| tiny | fast | 300 env steps (median over 2 seeds, 2 got there) |"
    assert "none solved it" in suite.headline("tiny", rows[1:])
    planned = ["fast", "slow", "SAC", "PPO, terminal"]
    page = suite.write_report({"tiny": ("tiny", runs, planned), "empty": ("empty", [], [])},
                              "python -m benchmarks.suite", tmp_path)
    text = page.read_text()
    assert (tmp_path / "suite_tiny.png").is_file() and "| tiny | fast |" in text
    assert "Not run for this report: SAC; PPO, terminal." in text
    assert "| empty | not run for this report | |" in text
    # notes written by hand into the page survive a redraw, each where it stood; the generated parts are redrawn
    edited = text.replace("\n\n| task |", "\n\nA page note.\n\n| task |", 1).replace(
        "\n\n![tiny]", "\n\nWhy fast is fast.\n\n| a hand table |\n|---|\n\n![tiny]", 1)
    page.write_text(edited)
    again = suite.write_report({"tiny": ("tiny", runs, planned[:2]), "empty": ("empty", [], [])},
                               "python -m benchmarks.suite", tmp_path).read_text()
    assert again == edited.replace("\n\nNot run for this report: SAC; PPO, terminal.", "")  # all planned ran now
    assert again.count("A page note.") == 1 and again.count("Why fast is fast.") == 1
    # the figure: success on the left, the mean ρ of the same evaluations on the right; per agent each seed
    # as a thin unlabelled line, then the median over seeds as the labelled one
    success_ax, rho_ax = suite.plot_task("tiny", runs, None).axes
    fast_rho = suite.eval_curve([r for r in runs if r.spec.label == "fast"], "eval_mean_robustness")[1]
    seed_lines, median_line = rho_ax.lines[:2], rho_ax.lines[2]
    np.testing.assert_allclose([line.get_ydata() for line in seed_lines], fast_rho)
    np.testing.assert_allclose(median_line.get_ydata(), np.median(fast_rho, axis=0))
    assert all(line.get_label().startswith("_") for line in seed_lines)  # not in the legend
    labelled = [line.get_label() for line in success_ax.lines if not line.get_label().startswith("_")]
    assert labelled == ["fast (2 seeds)", "slow (2 seeds)"]
    # the stand-in's ρ stays within ±1: a linear axis; ρ beyond ±SYMLOG_FROM gets a symlog one
    assert rho_ax.get_yscale() == "linear" and "symlog" not in rho_ax.get_ylabel()
    for run in runs:
        run.history["eval_mean_robustness"] = run.history["eval_mean_robustness"] * 100
    rho_ax = suite.plot_task("tiny", runs, None).axes[1]
    assert rho_ax.get_yscale() == "symlog" and "(symlog)" in rho_ax.get_ylabel()


def test_suite_run_finds_a_label_and_names_the_labels_it_lacks():
    spec = suite.suite_run("parking", "SAC")
    assert (spec.env, spec.agent, spec.label, spec.seed) == ("TLParking-v0", "sac", "SAC", 0)
    with pytest.raises(KeyError, match=r"parking.toml has no run labelled 'SACC'.*'SAC'"):
        suite.suite_run("parking", "SACC")


def test_plot_seeds_draws_every_seed_and_the_median_not_the_mean():
    from matplotlib.figure import Figure

    from benchmarks.figures import plot_seeds

    ax = Figure().subplots()
    values = np.array([[0.0, 0.0], [0.0, 0.2], [1.0, 1.0]])  # median (0, 0.2), mean (1/3, 0.4)
    plot_seeds(ax, np.array([1.0, 2.0]), values, "C0", "agent (3 seeds)")
    *seeds, median = ax.lines
    np.testing.assert_array_equal([line.get_ydata() for line in seeds], values)
    np.testing.assert_array_equal(median.get_ydata(), [0.0, 0.2])
    assert median.get_label() == "agent (3 seeds)" and all(line.get_label().startswith("_") for line in seeds)


def test_report_covers_every_task_whatever_tasks_run(tmp_path):
    """--tasks chooses what runs; the page it rewrites keeps a section for every task (from the records there are)."""
    assert suite.main(["--quick", "--report-only", "--tasks", "pendulum", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "suite.md").read_text()
    titles = [load_config(path).description for path in suite.config_paths()]
    assert all(f"## {title}\n" in text for title in titles) and len(titles) == 7


def test_a_report_elsewhere_leaves_docs_results_alone_and_keeps_the_notes_of_tasks_without_runs(tmp_path,
                                                                                                 monkeypatch):
    """--out sends the report there (it rewrote docs/results/suite.md); a task with no records keeps its notes."""
    monkeypatch.setattr(suite, "RESULTS", tmp_path / "docs_results")  # where the records in git report
    out = tmp_path / "elsewhere"
    out.mkdir()
    title = load_config(suite.config_paths()[0]).description
    (out / "suite.md").write_text(f"# The TL task suite\n\n## {title}\n\nA note written by hand.\n")
    assert suite.main(["--variant", "session", "--report-only", "--out", str(out)]) == 0
    assert not (tmp_path / "docs_results").exists()
    text = (out / "suite.md").read_text()
    assert "No finished run for this report." in text and "A note written by hand." in text


def _evaluated_run(seed: int, steps: list[float], success: list[float], label: str = "agent",
                   done: dict | None = None) -> results.RunResult:
    """A finished run whose every row evaluated, at its own env steps (episodes that end early: uneven steps)."""
    spec = RunSpec(env="TLMountainCar-v0", env_kwargs={}, agent="reps", label=label, hyperparameters={},
                   seed=seed, iterations=len(steps), evaluate_episodes=100, evaluate_every=1)
    history = {"iteration": np.arange(1.0, len(steps) + 1), "env_steps": np.array(steps, dtype=float),
               "eval_success_rate": np.array(success, dtype=float),
               "eval_mean_robustness": np.array(success, dtype=float) - 0.5}
    return results.RunResult(spec, history, done or {}, Path("."))


def test_final_success_pools_the_last_evaluation_with_the_final_one():
    """100 episodes at 100 % along training and 100 other ones at 80 % at the end: 90 %, the verdict's line."""
    done = {"eval_deterministic": {"success_rate": 0.8, "mean_robustness": 0.1, "episodes": 100}}
    runs = [_evaluated_run(seed, [100, 200], [0.5, 1.0], done=done) for seed in range(3)]
    assert suite.final_success(runs[0]) == pytest.approx(0.9)
    table, rows = suite.task_table(runs)
    assert rows[0][1] == pytest.approx(0.9) and "| 90% (90%–90%) |" in table
    uneven = {"eval_deterministic": {"success_rate": 0.7, "episodes": 300}}  # weighed by episodes
    assert suite.final_success(_evaluated_run(0, [100], [1.0], done=uneven)) == pytest.approx((100 + 210) / 400)
    assert suite.final_success(_evaluated_run(0, [100], [1.0])) == 1.0  # no final evaluation: the last one alone


def test_a_task_solved_only_with_the_final_evaluation_says_so():
    """Pooled with done.json's, the final success can reach 90 % where no evaluation along training did: the task
    is solved (the final success decides), at no evaluation's step (it said "none solved it" beside "90%")."""
    done = {"eval_deterministic": {"success_rate": 0.93, "mean_robustness": 0.1, "episodes": 100}}
    runs = [_evaluated_run(seed, [100, 200], [0.5, 0.88], done=done) for seed in range(3)]
    _, rows = suite.task_table(runs)
    assert rows[0][1] == pytest.approx(0.905) and rows[0][2] is None
    assert suite.headline("tiny", rows) == (
        "| tiny | agent | never at an evaluation along training (median over 3 seeds, 0 got there) |")


def test_steps_to_solve_and_final_success_are_each_seeds_own_on_uneven_env_steps():
    """A seed's env steps to ≥ 90 % are its own, not the seeds' mean at that evaluation; its final success is its
    own last evaluation, not the one where the shortest seed stopped; each seed's line is drawn at its own steps."""
    runs = [_evaluated_run(0, [100, 200, 300], [0.0, 1.0, 1.0]),   # solves at 200
            _evaluated_run(1, [50, 60, 70], [0.0, 0.0, 0.95])]     # solves at 70 (its episodes ended early)
    table, rows = suite.task_table(runs)
    # seed 0 at 200, seed 1 at 70: median 135 (the mean grid put them at 130 and 185: median 157.5)
    assert rows[0][2] == 135.0 and "| 135 (2/2) |" in table, table
    longer = [_evaluated_run(0, [100, 200, 300, 400], [0.0, 0.0, 0.0, 1.0]),
              _evaluated_run(1, [100, 200, 300], [0.0, 0.0, 0.0])]
    table, rows = suite.task_table(longer)
    # seed 0's last evaluation, at 400; seed 1 never got there, so the median seed never did
    assert "| 50% (0%–100%) | never (1/2) |" in table, table
    success_ax = suite.plot_task("uneven", runs, None).axes[0]
    assert [line.get_xdata().tolist() for line in success_ax.lines[:2]] == [[100, 200, 300], [50, 60, 70]]


def test_only_must_match_a_label_of_some_task(capsys):
    """Checked across every task the command runs: matching in one is enough, matching in none is an error."""
    with pytest.raises(SystemExit):
        suite.main(["--quick", "--only", "NOPE"])
    assert "--only 'NOPE' matches no label of suite-car1-quick" in capsys.readouterr().err
