"""The experiment runner: config expansion, parallel runs, resume, crash safety, Ray, aggregation.

The runs use `StandInAgent`, a deterministic agent with the agents' interface whose
robustness follows a known curve, so that the runner and the aggregation can be checked
exactly and fast; the real agents have their own tests and the benchmarks run them.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tomllib

from benchmarks import results
from benchmarks.report import write_per_seed_report
from benchmarks.run_one import (
    AGENT,
    CHECKPOINT,
    DONE,
    HISTORY,
    RunInProgress,
    execute_run,
    install_files,
    run_files,
)
from benchmarks.runner import SweepReport, check_only, iterations_done, run_sweep
from benchmarks.runner import main as runner_main
from benchmarks.sweep_config import ConfigError, RunSpec, expand_config, load_config

ROOT = Path(__file__).resolve().parents[1]
STAND_IN = "tests.test_runner:StandInAgent"


class StandInAgent:
    """The agents' interface with a known learning curve: ρ_m = rate · m − 1 + seed / 100.

    ``marker_dir``: if ``<marker_dir>/hang`` exists, iteration 2 writes ``<marker_dir>/started``
    and sleeps (the crash test kills it there); if ``<marker_dir>/fail`` exists, iteration 3 raises.
    """

    def __init__(self, env, *, seed=None, env_kwargs=None, rate=0.5, marker_dir=None, fail=False):
        if fail:
            raise RuntimeError("stand-in told to fail")
        self.seed, self.rate, self.marker_dir = seed or 0, rate, marker_dir
        self.task = (env_kwargs or {}).get("task", 1)
        self.history = []

    def learn(self, iterations, callback=None, progress_bar=False):
        for m in range(len(self.history) + 1, len(self.history) + iterations + 1):
            if m == 2 and self.marker_dir and Path(self.marker_dir, "hang").exists():
                Path(self.marker_dir, "started").write_text(str(os.getpid()))
                time.sleep(120)
            if m == 3 and self.marker_dir and Path(self.marker_dir, "fail").exists():
                raise RuntimeError("stand-in stopped at iteration 3")
            rho = self.rate * m - 1 + self.seed / 100
            row = {"iteration": m, "env_steps": 100 * m, "mean_robustness": rho,
                   "success_rate": min(1.0, max(0.0, rho)), "wall_time": 0.01 * m, "task": self.task}
            self.history.append(row)
            if callback is not None and callback(self, row) is False:
                break
        return self

    def evaluate(self, n_episodes=100, seed=None, deterministic=True):
        rho = self.history[-1]["mean_robustness"]
        return {"mean_robustness": rho, "success_rate": float(rho > 0), "robustness": np.full(n_episodes, rho)}

    def save(self, path):
        saved = {"seed": self.seed, "rate": self.rate, "marker_dir": self.marker_dir, "history": self.history}
        Path(path).write_text(json.dumps(saved))

    @classmethod
    def load(cls, path):
        saved = json.loads(Path(path).read_text())
        agent = cls(None, seed=saved["seed"], rate=saved["rate"], marker_dir=saved["marker_dir"])
        agent.history = saved["history"]
        return agent

    def close(self):
        pass


def config(**overrides):
    data = {
        "name": "tiny", "env": "TLCarNav-v0", "tasks": [1, 2], "seeds": [0, 1], "iterations": 4,
        "evaluate_episodes": 3,
        "agents": [{"label": "stand-in r={rate}", "agent": STAND_IN, "grid": {"rate": [0.5, 0.25]}}],
    }
    data.update(overrides)
    return data


def test_expansion_grid_labels_and_quick_overrides():
    variants = {"quick": {"seeds": [0], "iterations": 2}}
    sweep = expand_config(config(variants=variants))
    assert len(sweep.runs) == 2 * 2 * 2
    assert {r.label for r in sweep.runs} == {"stand-in r=0.5", "stand-in r=0.25"}
    assert {r.env_kwargs["task"] for r in sweep.runs} == {1, 2}
    assert len({r.run_id for r in sweep.runs}) == len(sweep.runs)
    quick = expand_config(config(variants=variants), variant="quick")
    assert quick.name == "tiny-quick" and len(quick.runs) == 4
    assert all(r.iterations == 2 and r.seed == 0 for r in quick.runs)
    agent = {"label": "a", "agent": STAND_IN, "hyperparameters": {"rate": 1.0, "marker_dir": "x"},
             "variants": {"quick": {"hyperparameters": {"rate": 2.0}, "seeds": [3]}}}
    skipped = {"label": "b", "agent": STAND_IN, "variants": {"quick": {"skip": True}}}
    (run,) = expand_config(config(agents=[agent, skipped], tasks=[1], variants=variants), variant="quick").runs
    assert dict(run.hyperparameters) == {"rate": 2.0, "marker_dir": "x"} and run.seed == 3
    assert expand_config(config(seeds=3)).runs[-1].seed == 2
    # an unused variant does not leak into the chosen one; overrides apply last
    two = {"quick": {"seeds": [0]}, "other": {"seeds": 4}}
    assert {r.seed for r in expand_config(config(variants=two), variant="quick").runs} == {0}
    capped = expand_config(config(variants=two), variant="quick", overrides={"seeds": [5], "iterations": 1})
    assert {(r.seed, r.iterations) for r in capped.runs} == {(5, 1)}
    # a budget by task; an agent's own budget can only lower the config's
    by_task = expand_config(config(iterations={"1": 3, "2": 4}))
    assert {(r.env_kwargs["task"], r.iterations) for r in by_task.runs} == {(1, 3), (2, 4)}
    agents = [{"label": "a", "agent": STAND_IN, "iterations": {"1": 2, "2": 9}}]
    assert {r.iterations for r in expand_config(config(agents=agents)).runs} == {2, 4}
    # sb3-contrib's algorithms are agents too (checked by name: registry.is_known_agent)
    contrib = expand_config(config(agents=[{"label": "TQC", "agent": "tqc"}], tasks=[1], seeds=[0]))
    assert [r.agent for r in contrib.runs] == ["tqc"]


@pytest.mark.parametrize("change, culprit", [
    ({"sedes": [0]}, "sedes"),
    ({"iterations": 0}, "iterations"),
    ({"seeds": ["a"]}, "seeds"),
    ({"agents": []}, "agents"),
    ({"agents": [{"agent": "dqn-please"}]}, "dqn-please"),
    ({"agents": [{"agent": "sb3:"}]}, "sb3:"),
    ({"agents": [{"agent": "sb3:PPO"}]}, "sb3:PPO"),  # the old form: the message says to write "ppo"
    ({"iterations": {"1": 3}}, "for task 2"),
    ({"agents": [{"agent": "tlps", "lable": "x"}]}, "lable"),
    ({"agents": [{"agent": "tlps", "label": "β={beta}"}]}, "beta"),
    ({"agents": [{"agent": "tlps", "grid": {"beta": 9}}]}, "grid.beta"),
    ({"agents": [{"agent": "tlps"}, {"agent": "tlps"}]}, "twice"),
    ({"variants": {"quick": {"agents": []}}}, "variants.quick"),
    # checked before any run starts, not in a worker hours into the sweep
    ({"agents": [{"agent": "reps", "hyperparameters": {"n_episodez": 4}}]}, "n_episodez"),
    ({"agents": [{"agent": "reps", "hyperparameters": {"n_episodes": -4}}]}, "n_episodes must be an int >= 2"),
    ({"agents": [{"agent": "sac", "hyperparameters": {"learning_rat": 1e-3}}]}, "did you mean 'learning_rate'"),
    ({"agents": [{"agent": "ppo", "grid": {"gamma": [0.99, 2.0]}}]}, r"gamma must lie in \(0, 1\]"),
    ({"env": "NoSuchEnv-v0"}, "env 'NoSuchEnv-v0'"),
    ({"evaluate_episodes": "many"}, "evaluate_episodes"),
    ({"evaluate_every": -1}, "evaluate_every"),
    ({"trajectory_episodes": 0}, "trajectory_episodes"),
    ({"agents": [{"agent": "tlps", "note": 5}]}, "note must be a string"),
    ({"variants": {"tiny": {"seeds": [0]}}, "agents": [{"agent": "tlps", "variants": {"tinyy": {"skip": True}}}]},
     r"\['tinyy'\] is not a variant of the config \(\['tiny'\]\)"),
])
def test_bad_configs_name_the_culprit(change, culprit):
    with pytest.raises(ConfigError, match=culprit.replace("{", r"\{")):
        expand_config(config(**change))


def test_shipped_configs_expand():
    paths = sorted((ROOT / "benchmarks" / "configs").glob("*.toml"))  # (suite/*.toml: test_suite_benchmark.py)
    assert {"paper.toml", "quick.toml", "ablations.toml"} <= {p.name for p in paths}  # the loop below checks some
    for path in paths:
        data = tomllib.loads(path.read_text())
        for variant in (None, *data.get("variants", {})):
            assert load_config(path, variant=variant).runs, (path, variant)


PAPER_GRID_SB3 = {"tl_reward": "terminal", "normalize": False, "hyperparams": False, "end_is_terminal": False}


def test_paper_config_pins_the_sb3_setup_of_the_paper_grid_in_every_variant():
    """The paper grid's PPO/SAC ran SB3's defaults on the plain terminal reward (2026-11-23), before the
    library's SB3 defaults (Markov view, VecNormalize, per-task hyperparameters, end as termination)."""
    path = ROOT / "benchmarks" / "configs" / "paper.toml"
    for variant in (None, *tomllib.loads(path.read_text()).get("variants", {})):
        sb3_runs = [r for r in load_config(path, variant=variant).runs if r.agent in ("ppo", "sac")]
        assert {r.agent for r in sb3_runs} == {"ppo", "sac"}, variant
        assert {r.env_kwargs["task"] for r in sb3_runs} == {1, 2}, variant
        for run in sb3_runs:
            assert {k: run.hyperparameters.get(k) for k in PAPER_GRID_SB3} == PAPER_GRID_SB3, (variant, run.label)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_paper_config_builds_sb3_agents_without_the_librarys_defaults(algo):
    from tl_gym.agents.registry import make_agent

    spec = next(r for r in load_config(ROOT / "benchmarks" / "configs" / "paper.toml", "quick").runs if r.agent == algo)
    agent = make_agent(spec.agent, spec.env, seed=0, env_kwargs=dict(spec.env_kwargs), **spec.hyperparameters)
    config = agent.config
    assert {k: getattr(config, k) for k in PAPER_GRID_SB3} == PAPER_GRID_SB3
    assert agent.sb3_env.observation_space.shape == (6,)  # the car's own observation, no monitor view
    assert not hasattr(agent.model.get_env(), "obs_rms")  # no VecNormalize


def test_only_a_pattern_that_matches_no_label_is_an_error_listing_the_labels(tmp_path, capsys):
    sweep = expand_config(config())
    with pytest.raises(ConfigError, match=r"--only 'stand-in\*x' matches no label of tiny \(case counts\): "
                                          r"'stand-in r=0.5', 'stand-in r=0.25'"):
        check_only([sweep], ["stand-in*", "stand-in*x"])
    other = expand_config(config(name="other", agents=[{"label": "x", "agent": STAND_IN}]))
    check_only([sweep, other], ["x", "stand-in*"])  # several configs: a pattern matches in one of them
    path = tmp_path / "tiny.toml"
    path.write_text('name = "tiny"\nenv = "TLCarNav-v0"\nseeds = 1\niterations = 1\n[[agents]]\nagent = "reps"\n')
    with pytest.raises(SystemExit):
        runner_main([str(path), "--only", "REPS", "--out", str(tmp_path / "cli")])
    assert "--only 'REPS' matches no label of tiny (case counts): 'reps'" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("")
    for out in (tmp_path / "a_file", tmp_path / "a_file" / "sub"):
        with pytest.raises(SystemExit):
            runner_main([str(path), "--out", str(out)])
        assert "a_file is a file: name a folder" in capsys.readouterr().err


def test_tiny_sweep_runs_in_parallel_resumes_and_aggregates(tmp_path, capsys):
    sweep = expand_config(config())
    assert iterations_done(sweep.runs, tmp_path) == 0  # nothing written yet
    report = run_sweep(sweep, tmp_path, workers=2)
    assert not report.failed and len(report.finished) == 8 and not report.skipped
    assert iterations_done(sweep.runs, tmp_path) == sum(run.iterations for run in sweep.runs)  # what the bar ends at
    assert capsys.readouterr().err.count(f"{sweep.name}: ") == 8  # a line per finished run, also off a terminal
    run_dir = tmp_path / "runs" / sweep.runs[0].run_id
    stamp = (run_dir / DONE).stat().st_mtime_ns
    # rerun: every run is finished already, nothing is redone
    again = run_sweep(sweep, tmp_path, workers=2)
    assert len(again.skipped) == 8 and not again.finished
    assert (run_dir / DONE).stat().st_mtime_ns == stamp

    runs = results.load_runs(tmp_path)
    assert len(runs) == 8
    history = results.read_history(run_dir / HISTORY)
    np.testing.assert_allclose(history["mean_robustness"], [0.5 * m - 1 for m in range(1, 5)])
    tables = results.summaries_by_task(runs)
    fast = next(row for row in tables[2] if row.label == "stand-in r=0.5")
    # seeds 0 and 1: ρ = -0.5, 0, 0.5, 1 and -0.49, 0.01, 0.51, 1.01
    assert fast.final_robustness[0] == pytest.approx(1.005)
    assert fast.first_positive == [3, 2] and fast.first_success == [4, 4]
    assert fast.eval_success == 1.0 and fast.env_steps == 400
    slow = next(row for row in tables[2] if row.label == "stand-in r=0.25")
    assert slow.first_positive == [None, 4]
    table = results.markdown_table(tables[1])
    assert "| stand-in r=0.25 | 2 | 4 |" in table and "never (0/2)" in table
    # the run folder: the spec first, the history row by row, the summary last
    assert json.loads((run_dir / "spec.json").read_text()) == sweep.runs[0].to_json()
    assert json.loads((tmp_path / "sweep.json").read_text())["runs"][sweep.runs[0].run_id] == sweep.runs[0].to_json()
    assert json.loads((run_dir / DONE).read_text())["eval_stochastic"]["episodes"] == 3
    assert len(json.loads((run_dir / AGENT).read_text())) == 4  # the final agent, saved with the run


def test_per_seed_report_tables_summary_and_curves(tmp_path):
    sweep = expand_config(config(tasks=[1, 2], seeds=[0, 1, 2]))
    run_sweep(sweep, tmp_path / "out", workers=0)
    runs = results.load_runs(tmp_path / "out")
    written = write_per_seed_report(runs, tmp_path / "report")
    assert {p.name for p in written} == {"tables.md", "summary.csv", *(f"task{t}_{k}.png" for t in (1, 2)
                                                                     for k in ("success", "robustness", "medians"))}
    text = (tmp_path / "report" / "tables.md").read_text()
    # task 1: first iteration with mean ρ > 0 per seed (ρ = rate · m − 1 + seed / 100); r=0.25 never for seed 0
    assert "| stand-in r=0.5 | 3 | 3, 2, 2 | 2 | 100.0%–100.0% | 100.0% | 1.01 |" in text
    assert "| stand-in r=0.25 | 3 | –, 4, 4 | 4 |" in text
    # task 2: first iteration with success ≥ 80 %
    assert "### Task 2" in text and "| stand-in r=0.5 | 3 | 4, 4, 4 | 4 |" in text
    summary = results.read_history(tmp_path / "report" / "summary.csv")
    assert summary["seed"].tolist() == [0, 1, 2] * 4 and set(summary["iterations"]) == {4.0}
    assert (tmp_path / "report" / "summary.csv").read_text().splitlines()[1].startswith("1,stand-in r=0.25,0,4,,,")


def test_failed_run_is_reported_and_leaves_no_result(tmp_path):
    agents = [{"label": "bad", "agent": STAND_IN, "hyperparameters": {"fail": True}},
              {"label": "good", "agent": STAND_IN}]
    sweep = expand_config(config(agents=agents, tasks=[1], seeds=[0]))
    report = run_sweep(sweep, tmp_path, workers=0)
    assert len(report.finished) == 1 and len(report.failed) == 1
    (failed_id, text), = report.failed.items()
    assert "stand-in told to fail" in text
    assert not (tmp_path / "runs" / failed_id / DONE).exists()
    assert [r.spec.label for r in results.load_runs(tmp_path)] == ["good"]


def start_hanging_sweep(tmp_path: Path) -> tuple[subprocess.Popen, Path, Path, int]:
    """A runner process whose one run hangs at iteration 2: (process, config, out, the worker's pid)."""
    markers = tmp_path / "markers"
    markers.mkdir()
    (markers / "hang").touch()
    path = tmp_path / "sweep.toml"
    path.write_text(
        'name = "crash"\nenv = "TLCarNav-v0"\ntasks = [1]\nseeds = [0]\niterations = 3\n'
        f'[[agents]]\nlabel = "stand-in"\nagent = "{STAND_IN}"\n'
        f'hyperparameters = {{ marker_dir = "{markers}" }}\n'
    )
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "benchmarks.runner", str(path), "--out", str(out), "--workers", "1"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )
    deadline = time.monotonic() + 40
    while not (markers / "started").exists() or not (markers / "started").read_text():
        if process.poll() is not None or time.monotonic() > deadline:
            os.killpg(process.pid, signal.SIGKILL)
            raise AssertionError("the sweep never reached iteration 2")
        time.sleep(0.1)
    return process, path, out, int((markers / "started").read_text())


def _wait_until_gone(pid: int, seconds: float = 10.0) -> None:
    """Wait for a killed worker to exit: until it has, it holds its run's lock."""
    deadline = time.monotonic() + seconds
    while _alive(pid):
        assert time.monotonic() < deadline, f"process {pid} outlived its kill"
        time.sleep(0.05)


def test_killed_sweep_leaves_no_half_result_and_rerun_completes(tmp_path):
    process, path, out, worker = start_hanging_sweep(tmp_path)
    markers = tmp_path / "markers"
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    _wait_until_gone(worker)
    (run,) = load_config(path).runs
    run_dir = out / "runs" / run.run_id
    assert (run_dir / HISTORY).read_text().count("\n") == 2  # header and iteration 1, then killed
    assert not (run_dir / DONE).exists()
    assert results.load_runs(out) == []

    (markers / "hang").unlink()
    report = run_sweep(load_config(path), out, workers=0)
    assert report.finished == [run.run_id]
    history = results.read_history(run_dir / HISTORY)
    assert history["iteration"].tolist() == [1, 2, 3]  # restarted from scratch, no duplicated rows


def test_a_second_runner_on_one_folder_leaves_the_run_being_trained_alone(tmp_path, capsys):
    process, path, out, worker = start_hanging_sweep(tmp_path)
    (run,) = load_config(path).runs
    run_dir = out / "runs" / run.run_id
    try:
        before = (run_dir / HISTORY).read_text()
        report = run_sweep(load_config(path), out, workers=0)  # the first runner's worker holds the run
        assert report.busy == [run.run_id] and not report.finished and not report.failed
        assert "lock" in (err := capsys.readouterr().err) and "is held, by a runner training it" in err
        assert (run_dir / HISTORY).read_text() == before  # not wiped, not restarted
        with pytest.raises(RunInProgress, match=run.run_id):
            install_files({DONE: b"{}"}, run_dir)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    _wait_until_gone(worker)
    (tmp_path / "markers" / "hang").unlink()
    report = run_sweep(load_config(path), out, workers=0)  # the kill freed the lock
    assert report.finished == [run.run_id] and not report.busy


def test_a_terminated_sweep_stops_its_workers(tmp_path):
    process, *_, worker = start_hanging_sweep(tmp_path)
    try:
        assert worker != process.pid  # the run is in a spawned worker process
        process.send_signal(signal.SIGTERM)  # the runner only, as `kill PID` does
        assert process.wait(timeout=30) != 0
        deadline = time.monotonic() + 10
        while _alive(worker):
            assert time.monotonic() < deadline, "the worker outlived its terminated sweep"
            time.sleep(0.1)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped, counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def test_run_files_round_trip_installs_done_last(tmp_path):
    spec = RunSpec(env="TLCarNav-v0", env_kwargs={"task": 1}, agent=STAND_IN, label="s", hyperparameters={},
                   seed=0, iterations=2)
    files = run_files(spec)
    assert set(files) == {DONE, HISTORY, AGENT, "spec.json"}
    assert install_files(files, tmp_path / "run") is True
    assert json.loads((tmp_path / "run" / DONE).read_text())["iterations"] == 2
    other = {**files, DONE: json.dumps({"iterations": 99}).encode()}  # a second result of the same run
    assert install_files(other, tmp_path / "run") is False  # the finished run stays as it is
    assert json.loads((tmp_path / "run" / DONE).read_text())["iterations"] == 2
    report = SweepReport()
    report.attempt(spec, lambda: install_files(other, tmp_path / "run"))
    assert report.skipped == [spec.run_id] and not report.finished
    with pytest.raises(ValueError, match="no done.json"):
        install_files({HISTORY: b""}, tmp_path / "other")
    assert execute_run(spec, tmp_path / "run")["iterations"] == 2  # finished: returned, not rerun


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
@pytest.mark.filterwarnings("ignore::FutureWarning")
@pytest.mark.filterwarnings("ignore::ResourceWarning")
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_sweep_on_a_local_ray(tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": str(ROOT)}})
    try:
        sweep = expand_config(config(tasks=[1], seeds=[0, 1]))
        report = run_sweep(sweep, tmp_path, ray_address="auto")
    finally:
        ray.shutdown()
    assert not report.failed and len(report.finished) == 4
    runs = results.load_runs(tmp_path)
    assert sorted(r.spec.seed for r in runs) == [0, 0, 1, 1]
    assert all(len(r.history["iteration"]) == 4 for r in runs)


def test_ray_missing_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    sweep = expand_config(config(tasks=[1], seeds=[0]))
    with pytest.raises(ImportError, match=r"tl_gym\[ray\]"):
        run_sweep(sweep, tmp_path, ray_address="auto")


def test_folders_of_the_older_sweep_runner_stay_readable(tmp_path):
    sweep = expand_config(config(tasks=[1], seeds=[0], agents=[{"label": "s", "agent": STAND_IN}]))
    run_sweep(sweep, tmp_path, workers=0)
    # the older runner's specs had save_agent (and agent names such as "sb3:PPO"); the reports still read them
    manifest = json.loads((tmp_path / "sweep.json").read_text())
    for spec in manifest["runs"].values():
        spec["save_agent"] = False
    (tmp_path / "sweep.json").write_text(json.dumps(manifest))
    (run,) = results.load_runs(tmp_path)
    assert run.spec == sweep.runs[0] and run.history["iteration"].tolist() == [1, 2, 3, 4]


def test_sweep_options_are_checked_and_failures_go_to_stderr(tmp_path, capsys):
    import argparse

    from benchmarks.runner import add_sweep_options, run_with_options, variant_of

    parser = argparse.ArgumentParser()
    add_sweep_options(parser)
    assert variant_of(parser, parser.parse_args(["--quick"])) == "quick"
    assert variant_of(parser, parser.parse_args(["--variant", "session"])) == "session"
    for bad in (["--quick", "--variant", "session"], ["--workers", "-1"], ["--checkpoint-every", "-2"]):
        with pytest.raises(SystemExit):
            variant_of(parser, parser.parse_args(bad))
    assert "--checkpoint-every must be >= 0, got -2" in capsys.readouterr().err
    agents = [{"label": "bad", "agent": STAND_IN, "hyperparameters": {"fail": True}},
              {"label": "good", "agent": STAND_IN}]
    sweep = expand_config(config(agents=agents, tasks=[1], seeds=[0]))
    report = run_with_options(sweep, tmp_path, parser.parse_args(["--workers", "0", "--only", "ba*"]))
    assert len(report.failed) == 1 and not report.finished  # --only left "good" out
    assert "stand-in told to fail" in capsys.readouterr().err


def test_aggregation_helpers_and_run_folder_names():
    """The examples the runner and results modules once carried as (unrun) doctests."""
    spec = RunSpec(env="TLCarNav-v0", env_kwargs={"task": 1}, agent="tlps", label="TLPS",
                   hyperparameters={"beta": 9.0}, seed=0, iterations=50)
    assert spec.run_id.startswith("task1__tlps__seed0__")
    mean, low, high = results.mean_band(np.array([[0.0, 1.0], [2.0, 3.0]]))
    assert mean.tolist() == [1.0, 2.0] and low[0] < 1.0 < high[0]
    assert results.first_iteration(np.array([1, 2, 3]), np.array([-1.0, 0.5, 2.0]), 0.0) == 2
    # a seed that never got there counts as later than any: the median speaks for every seed run
    assert results.median_first([4, None, 8]) == 8.0
    assert results.median_first([4, None]) is None and results.median_first([]) is None  # the median seed: never
    assert results.median_first([4, 6, 8, None, None]) == 8.0 and results.median_first([4, 8]) == 6.0
    assert (results.first_text([4, None, 8]), results.first_text([None])) == ("8 (2/3)", "never (0/1)")
    assert results.first_text([4, None, None]) == "never (1/3)"
    assert results.first_text([4, float("nan"), None]) == "never (1/3)"  # NaN is never, as None
    assert results.first_text([1500.0, 2500.0], ",.0f") == "2,000 (2/2)"
    assert results.table(["a", "b"], [[1, ""]]) == "| a | b |\n|---|---|\n| 1 |  |"


def test_done_records_the_code_the_run_started_with(tmp_path, monkeypatch):
    """A commit made while a run trains does not relabel it: the version is read when the run starts."""
    import benchmarks.run_one as run_one

    run_dir = tmp_path / "run"
    # the version "changes" once training has written its first history row
    monkeypatch.setattr(run_one, "code_version",
                        lambda: "0.1.0 (a later commit)" if (run_dir / HISTORY).exists() else "0.1.0 (at the start)")
    spec = expand_config(config(tasks=[1], seeds=[0], agents=[{"label": "stand-in", "agent": STAND_IN}])).runs[0]
    assert execute_run(spec, run_dir)["code"] == "0.1.0 (at the start)"


def test_tl_gym_eval_reads_a_runner_folder(tmp_path, capsys):
    """A finished run keeps its agent, so `tl-gym eval RUN_DIR --why` diagnoses a benchmark run."""
    from tl_gym.cli import main

    spec = RunSpec(env="TLCarNav-v0", env_kwargs={"task": 1}, agent="reps", label="REPS",
                   hyperparameters={"n_episodes": 4}, seed=3, iterations=1)
    run_dir = tmp_path / spec.run_id
    execute_run(spec, run_dir)
    assert (run_dir / AGENT).is_file()
    assert main(["eval", str(run_dir), "--episodes", "3", "--why"]) == 0
    out = capsys.readouterr().out
    assert "reps on TLCarNav-v0 {'task': 1}: 3 episodes" in out and "why (" in out


def start_failing_run(tmp_path: Path, **overrides) -> tuple[RunSpec, Path, Path]:
    """A stand-in run of 4 iterations, checkpointed every 2, that fails at iteration 3: (spec, run folder, marker)."""
    markers = tmp_path / "markers"
    markers.mkdir(exist_ok=True)
    (markers / "fail").touch()
    spec = RunSpec(env="TLCarNav-v0", env_kwargs={"task": 1}, agent=STAND_IN, label="stand-in",
                   hyperparameters={"marker_dir": str(markers)}, seed=0, iterations=4, evaluate_episodes=3,
                   evaluate_every=1, **overrides)
    run_dir = tmp_path / "run"
    with pytest.raises(RuntimeError, match="stopped at iteration 3"):
        execute_run(spec, run_dir, checkpoint_every=2)
    return spec, run_dir, markers / "fail"


def test_a_stopped_run_resumes_from_its_checkpoint(tmp_path):
    spec, run_dir, fail = start_failing_run(tmp_path)
    assert (run_dir / CHECKPOINT / AGENT).is_file() and not (run_dir / DONE).exists()
    assert results.read_history(run_dir / HISTORY)["iteration"].tolist() == [1, 2]
    fail.unlink()
    summary = execute_run(spec, run_dir, checkpoint_every=2)
    assert summary["resumed_at"] == [2] and summary["iterations"] == 4
    history = results.read_history(run_dir / HISTORY)
    assert history["iteration"].tolist() == [1, 2, 3, 4]
    assert history["eval_mean_robustness"].tolist() == [-0.5, 0.0, 0.5, 1.0]  # rows 1-2 kept as written
    assert not (run_dir / CHECKPOINT).exists()  # gone with the finished run
    uninterrupted = execute_run(spec, tmp_path / "uninterrupted", checkpoint_every=2)
    assert uninterrupted["resumed_at"] == [] and uninterrupted["final_mean_robustness"] == summary[
        "final_mean_robustness"]


@pytest.mark.parametrize("killed", ["writing the new checkpoint", "between the two renames",
                                    "removing a promoted checkpoint.new"])
def test_a_run_killed_while_it_checkpoints_resumes_from_a_whole_checkpoint(tmp_path, killed):
    """The new checkpoint is written aside and swapped in: a kill at any moment leaves a whole one to resume from
    (a kill after the old agent was deleted used to restart the run from iteration 0)."""
    import shutil

    from benchmarks.run_one import CHECKPOINT_NEW, CHECKPOINT_OLD

    spec, run_dir, fail = start_failing_run(tmp_path)
    whole = run_dir / CHECKPOINT
    if killed == "writing the new checkpoint":  # a partial .new beside the last whole checkpoint
        (run_dir / CHECKPOINT_NEW).mkdir()
        (run_dir / CHECKPOINT_NEW / "state.json").write_text("{}")
    elif killed == "between the two renames":  # the last checkpoint moved aside, the new one not yet in place
        shutil.copytree(whole, run_dir / CHECKPOINT_NEW)
        whole.rename(run_dir / CHECKPOINT_OLD)
    else:  # a removal cut short left a .new that looks whole (agent.zip) but lost its state: the next one is used
        shutil.copytree(whole, run_dir / CHECKPOINT_NEW)
        (run_dir / CHECKPOINT_NEW / "state.json").unlink()
    fail.unlink()
    summary = execute_run(spec, run_dir, checkpoint_every=2)
    assert summary["resumed_at"] == [2] and summary["iterations"] == 4
    assert not any((run_dir / name).exists() for name in (CHECKPOINT, CHECKPOINT_NEW, CHECKPOINT_OLD))


def test_a_checkpoint_of_another_spec_is_not_resumed(tmp_path):
    spec, run_dir, fail = start_failing_run(tmp_path)
    fail.unlink()
    other = RunSpec(**{**spec.to_json(), "iterations": 3})
    summary = execute_run(other, run_dir, checkpoint_every=2)
    assert summary["resumed_at"] == [] and summary["iterations"] == 3


@pytest.mark.parametrize("agent, hyperparameters, env, env_kwargs", [
    ("reps", {"n_episodes": 4}, "TLCarNav-v0", {"task": 1}),
    ("sac", {"steps_per_iteration": 64, "learning_starts": 32, "batch_size": 16, "buffer_size": 1000,
             "policy_kwargs": {"net_arch": [16, 16]}}, "TLPendulum-v0", {}),
])
def test_a_real_agent_resumes_with_its_state(tmp_path, monkeypatch, agent, hyperparameters, env, env_kwargs):
    """The checkpoint holds what the agent needs: REPS's policy and random state, SAC's model and replay buffer."""
    from tl_gym.agents.registry import agent_class

    klass = agent_class(agent)
    update, load_buffer = klass._update, getattr(klass, "load_replay_buffer", None)
    buffer_sizes = []

    def fail_at_3(self, iteration):
        if iteration == 3:
            raise RuntimeError("stopped at iteration 3")
        return update(self, iteration)

    def load_and_count(self, path):
        load_buffer(self, path)
        buffer_sizes.append(self.model.replay_buffer.size())

    spec = RunSpec(env=env, env_kwargs=env_kwargs, agent=agent, label=agent, hyperparameters=hyperparameters,
                   seed=0, iterations=3)
    monkeypatch.setattr(klass, "_update", fail_at_3)
    with pytest.raises(RuntimeError, match="stopped at iteration 3"):
        execute_run(spec, tmp_path / "run", checkpoint_every=1)
    assert (tmp_path / "run" / CHECKPOINT / "replay_buffer.pkl").is_file() == (agent == "sac")
    monkeypatch.setattr(klass, "_update", update)
    if load_buffer is not None:
        monkeypatch.setattr(klass, "load_replay_buffer", load_and_count)
    summary = execute_run(spec, tmp_path / "run", checkpoint_every=1)
    history = results.read_history(tmp_path / "run" / HISTORY)
    assert summary["resumed_at"] == [2] and history["iteration"].tolist() == [1, 2, 3]
    steps = history["env_steps"].tolist()
    assert steps == [steps[0], 2 * steps[0], 3 * steps[0]]
    assert buffer_sizes == ([128] if agent == "sac" else [])  # both iterations' transitions went back in
    if agent == "reps":  # its random state is saved too: the resumed run is the uninterrupted one
        assert execute_run(spec, tmp_path / "uninterrupted")["final_mean_robustness"] == summary[
            "final_mean_robustness"]


def test_serial_runs_say_their_progress_and_the_report_of_a_folder_without_a_sweep_is_one_line(tmp_path, capsys):
    """--workers 0 printed nothing until the end; `benchmarks.report` on a folder that is no sweep's gave a
    traceback."""
    from benchmarks.report import main as report_main

    sweep = expand_config(config(tasks=[1], seeds=[0], iterations=1))
    run_sweep(sweep, tmp_path / "serial", workers=0)
    err = capsys.readouterr().err
    assert f"{sweep.name}: 1/2 runs" in err and f"{sweep.name}: 2/2 runs" in err
    with pytest.raises(SystemExit):
        report_main([str(tmp_path / "nothing")])
    assert "holds no sweep.json: run `python -m benchmarks.runner CONFIG` first" in capsys.readouterr().err
