"""The tl-gym command line: train writes a complete run folder, eval reloads it."""

from __future__ import annotations

import csv
import json
import pathlib
import re
import shlex
import sys
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from tl_gym.agents import Agent
from tl_gym.cli import build_env, main


@pytest.fixture(scope="module")
def car_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "reps"
    status = main(["train", "--env", "TLCarNav-v0", "--task", "1", "--agent", "reps", "--iterations", "3",
                   "--seed", "1", "--n-episodes", "10", "--epsilon", "1.5", "--out", str(out), "--quiet"])
    assert status == 0
    return out


def test_train_writes_the_run_folder(car_run):
    names = {p.name for p in car_run.iterdir()}
    assert {"run.json", "agent.zip", "history.csv", "learning_curve.png", "trajectories.png"} <= names
    run = json.loads((car_run / "run.json").read_text())
    assert run["hyperparameters"] == {"n_episodes": 10, "epsilon": 1.5} and run["env_kwargs"] == {"task": 1}
    with (car_run / "history.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3]
    assert [int(r["env_steps"]) for r in rows] == [2000, 4000, 6000]
    assert {"mean_robustness", "success_rate", "wall_time", "kl"} <= set(rows[0])
    for png in ("learning_curve.png", "trajectories.png"):
        assert (car_run / png).read_bytes()[:4] == b"\x89PNG"


def test_train_writes_history_while_it_runs(tmp_path, monkeypatch):
    """history.csv grows after each iteration: a run killed midway keeps its rows so far."""
    import tl_gym.cli.commands as commands

    seen = []  # lines in history.csv right after each iteration's write
    monkeypatch.setattr(commands.HistoryCSV, "on_iteration", _counting(commands.HistoryCSV.on_iteration, seen))
    assert main(["train", "--env", "TLCarNav-v0", "--env-kwargs", '{"horizon": 10}', "--agent", "reps",
                 "--iterations", "3", "--n-episodes", "4", "--out", str(tmp_path), "--quiet"]) == 0
    assert seen == [2, 3, 4]  # header + 1, 2, 3 rows, each right after its iteration
    with (tmp_path / "history.csv").open() as handle:
        assert [int(r["iteration"]) for r in csv.DictReader(handle)] == [1, 2, 3]


def _counting(on_iteration, seen):
    def wrapped(self, agent, row):
        result = on_iteration(self, agent, row)
        seen.append(self.path.read_text().count("\n"))
        return result
    return wrapped


def test_eval_prints_robustness_and_success(car_run, capsys):
    expected = Agent.load(car_run / "agent.zip").evaluate(5, seed=3)
    capsys.readouterr()
    assert main(["eval", str(car_run), "--episodes", "5", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    assert (f"5 episodes, mean robustness {expected['mean_robustness']:.4g}, "
            f"success rate {expected['success_rate']:.1%}") in out


def test_eval_saves_a_gif(tmp_path, capsys):
    out = tmp_path / "short"
    assert main(["train", "--env", "TLCarNav-v0", "--env-kwargs", '{"horizon": 10}', "--agent", "reps",
                 "--iterations", "1", "--n-episodes", "4", "--out", str(out), "--quiet"]) == 0
    gif = tmp_path / "episode.gif"
    assert main(["eval", str(out), "--episodes", "2", "--gif", str(gif)]) == 0
    out_text = capsys.readouterr().out
    assert gif.read_bytes()[:3] == b"GIF" and "11 frames" in out_text
    assert "env keywords" not in out_text  # --quiet: no line but the result


def test_eval_gif_uses_the_env_keywords_the_agent_trained_with(tmp_path, capsys):
    """The GIF's env is made with the agent's own keywords, the task's markov_env_kwargs included (it was made with
    --env-kwargs and tl_reward's only: here a 200-step episode instead of the agent's 10)."""
    own = tmp_path / "short.yml"
    own.write_text("TLCarNav-v0:\n  ppo:\n    markov_env_kwargs: {horizon: 10}\n")
    out = tmp_path / "ppo"
    assert main(["train", "--env", "TLCarNav-v0", "--agent", "ppo", "--hyperparams", str(own), "--iterations", "1",
                 "--steps-per-iteration", "64", "--n-envs", "2", "--n-steps", "32", "--batch-size", "32",
                 "--n-epochs", "1", "--out", str(out)]) == 0
    said = ("SB3Agent on TLCarNav-v0 with the env keywords "
            "{'observe_monitor': True, 'reward_mode': 'dense', 'horizon': 10}")
    assert said in capsys.readouterr().out  # train says what the agent added to --env-kwargs
    gif = tmp_path / "episode.gif"
    assert main(["eval", str(out), "--episodes", "2", "--gif", str(gif)]) == 0
    assert "11 frames" in capsys.readouterr().out


def test_spec_and_signals_train_on_any_env(tmp_path, capsys):
    out = tmp_path / "pendulum"
    assert main(["train", "--env", "Pendulum-v1", "--spec", "F(cos_th > 0.9)", "--signals", "cos_th=0",
                 "--agent", "reps", "--iterations", "2", "--n-episodes", "4", "--out", str(out), "--quiet"]) == 0
    assert (out / "trajectories.png").exists()  # signals over time: Pendulum has no plane layout
    assert main(["eval", str(out), "--episodes", "2"]) == 0
    assert "2 episodes" in capsys.readouterr().out
    gif = tmp_path / "pendulum.gif"  # a --spec run records on its wrapped env, made to render
    assert main(["eval", str(out), "--episodes", "1", "--gif", str(gif)]) == 0
    assert gif.read_bytes()[:3] == b"GIF" and "201 frames" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--agent", "nope"], "unknown agent 'nope': tlps, reps, a stable-baselines3 algorithm"),
        (["--agent", "reps", "--signals", "a=0"], "--signals only makes sense with --spec"),
        (["--agent", "reps", "--wrapper-kwargs", '{"reward_mode": "dense"}'], "--wrapper-kwargs only makes sense"),
        (["--env", "Pendulum-v1", "--spec", "F(x > 1)", "--signals", "x=0", "--agent", "reps", "--wrapper-kwargs",
          '{"satisfaction_bonus": -1}'], "satisfaction_bonus must be a finite number >= 0"),
        (["--agent", "reps", "--bogus", "3"], "bogus"),
        (["--agent", "reps", "--epsilon", "-1"], "epsilon"),
        (["--agent", "reps", "--iterations", "0"], "--iterations"),
        (["--agent", "reps", "--eval-every", "0"], "--eval-every"),
        (["--env", "Pendulum-v1", "--spec", "F(x > 1", "--signals", "x=0", "--agent", "reps"], "column"),
        (["--env", "NoSuchEnv-v0", "--agent", "reps"], "NoSuchEnv"),  # Gymnasium's NameNotFound: was a traceback
        (["--env", "Pendulum-v1", "--spec", "F(x > 1)", "--agent", "reps"], "--spec needs --signals"),
        (["--agent", "reps", "-x", "3"], "expected a hyperparameter --name value, got '-x'"),
        (["--agent", "reps", "3"], "expected a hyperparameter --name value, got '3'"),
        (["--agent", "reps", "--epsilon"], "hyperparameter --epsilon has no value"),
    ],
)
def test_bad_input_exits_with_a_clear_message(tmp_path, capsys, argv, message):
    assert main(["train", "--out", str(tmp_path / "bad"), "--quiet", *argv]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--env-kwargs", "[1, 2]"], "argument --env-kwargs: must be a JSON object"),  # was "dictionary update ..."
        (["--env-kwargs", "{bad"], "argument --env-kwargs: not valid JSON"),
        (["--snapshots", "1,,a"], "argument --snapshots: expects iterations >= 1"),  # was int()'s own message
        (["--snapshots", "0"], "argument --snapshots"),
        (["--env", "Pendulum-v1", "--spec", "F(x > 1)", "--signals", "x"],
         "argument --signals: expects name=source pairs separated by commas"),  # was "invalid parse_signals value"
    ],
)
def test_an_argument_that_does_not_parse_is_argparses_error(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--out", str(tmp_path / "bad"), "--quiet", *argv])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_parking_without_highway_env_names_the_extra(tmp_path, capsys, monkeypatch):
    """DependencyNotInstalled is no ImportError: the command printed a traceback."""
    monkeypatch.setitem(sys.modules, "highway_env", None)  # `import highway_env` raises ImportError
    assert main(["train", "--env", "TLParking-v0", "--agent", "reps", "--out", str(tmp_path / "p"), "--quiet"]) == 2
    assert 'tl-gym train: error: TLParking-v0 needs highway-env' in capsys.readouterr().err


def test_out_that_is_a_file(tmp_path, capsys):
    (tmp_path / "taken").write_text("")
    assert main(["train", "--agent", "reps", "--out", str(tmp_path / "taken"), "--quiet"]) == 2  # was FileExistsError
    assert "--out" in capsys.readouterr().err


def test_out_under_a_file_is_an_error_not_a_traceback(tmp_path, capsys):
    (tmp_path / "taken").write_text("")
    assert main(["train", "--agent", "reps", "--iterations", "1", "--n-episodes", "2",
                 "--out", str(tmp_path / "taken" / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tl-gym train: error:") and "taken" in err


def test_a_new_run_in_an_old_folder_leaves_none_of_its_files(tmp_path, capsys):
    """An earlier run's best_agent.zip passed for the new run's in `tl-gym eval --best`."""
    tiny = ["--env", "TLCarNav-v0", "--env-kwargs", '{"horizon": 5}', "--agent", "reps", "--n-episodes", "4",
            "--out", str(tmp_path), "--quiet"]
    assert main(["train", *tiny, "--iterations", "2", "--eval-every", "1", "--eval-episodes", "2"]) == 0
    assert (tmp_path / "best_agent.zip").exists() and (tmp_path / "evaluations.csv").exists()
    capsys.readouterr()
    assert main(["train", *tiny, "--iterations", "1", "--snapshots", "3"]) == 0
    assert {p.name for p in tmp_path.iterdir()} == {"run.json", "agent.zip", "history.csv", "learning_curve.png"}
    captured = capsys.readouterr()
    assert "--snapshots 3 after the last iteration (1): not plotted" in captured.err
    assert captured.out.endswith("{run.json, agent.zip, history.csv, learning_curve.png}\n")  # what it wrote
    assert main(["eval", str(tmp_path), "--best"]) == 2


def test_eval_of_a_missing_run(tmp_path, capsys):
    assert main(["eval", str(tmp_path / "missing")]) == 2
    assert "tl-gym train" in capsys.readouterr().err


def test_eval_of_a_run_without_its_agent_or_with_a_broken_run_file(tmp_path, capsys):
    run = {"env": "TLCarNav-v0", "env_kwargs": {}, "spec": None, "signals": None, "agent": "reps", "iterations": 1,
           "seed": 0, "hyperparameters": {}}
    (tmp_path / "run.json").write_text(json.dumps(run))
    assert main(["eval", str(tmp_path)]) == 2
    assert "agent.zip not found: train writes it when training ends" in capsys.readouterr().err
    (tmp_path / "done.json").write_text("{}")  # a runner's record as git keeps it
    assert main(["eval", str(tmp_path)]) == 2
    assert "a runner's record in git keeps no agent" in capsys.readouterr().err
    (tmp_path / "run.json").write_text("{")
    assert main(["eval", str(tmp_path)]) == 2
    assert "run.json is not valid JSON" in capsys.readouterr().err
    (tmp_path / "run.json").write_text("{}")
    assert main(["eval", str(tmp_path)]) == 2
    assert "run.json names no env and no agent" in capsys.readouterr().err
    assert main(["eval", str(tmp_path), "--episodes", "0"]) == 2
    assert "--episodes must be" in capsys.readouterr().err


def test_task_on_an_env_without_one_is_named(tmp_path, capsys):
    assert main(["train", "--env", "TLPendulum-v0", "--task", "2", "--out", str(tmp_path / "r")]) == 2
    error = capsys.readouterr().err
    assert "--task is the car's task keyword (TLCarNav-v0: 1 or 2); TLPendulum-v0 takes no task" in error
    assert "up_by" in error and not (tmp_path / "r").exists()


def test_train_refuses_to_write_into_a_runner_run_folder(tmp_path, capsys):
    (tmp_path / "spec.json").write_text("{}")
    (tmp_path / "done.json").write_text("{}")
    assert main(["train", "--agent", "reps", "--out", str(tmp_path)]) == 2
    assert "is a run folder of the experiment runner" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["done.json", "spec.json"]  # nothing written or removed


def test_a_wrapper_keyword_misspelt_is_named_with_the_nearest(tmp_path, capsys):
    assert main(["train", "--env", "Pendulum-v1", "--spec", "F(c > 0)", "--signals", "c=0", "--wrapper-kwargs",
                 '{"reward_mod": "dense"}', "--agent", "reps", "--out", str(tmp_path / "r")]) == 2
    assert ("--wrapper-kwargs: TLTLRewardWrapper takes no keyword 'reward_mod'; did you mean 'reward_mode'?"
            in capsys.readouterr().err)
    assert not (tmp_path / "r").exists()  # refused before anything is written


def test_help_lists_the_hyperparameters(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "reps: n_episodes=40" in out and "epsilon=None" in out and "--spec" in out


SB3_TINY = ["--steps-per-iteration", "64", "--n-envs", "2", "--batch-size", "32", "--n-epochs", "1", "--snapshots", "9"]


def test_an_sb3_run_keeps_its_markov_view_and_vecnormalize(tmp_path, capsys):
    out = tmp_path / "ppo"
    # no --iterations: the task's budget, here set to two iterations of 64 steps
    assert main(["train", "--env", "TLCarNav-v0", "--agent", "ppo", "--n-timesteps", "128", "--out", str(out),
                 "--quiet", *SB3_TINY]) == 0
    assert json.loads((out / "run.json").read_text())["iterations"] == 2
    printed = capsys.readouterr()
    assert "note: n_timesteps" not in printed.err  # 128 is whole iterations: nothing to say
    # 64 steps of 2 envs end none of the car's 200-step episodes: said so, not "mean robustness nan"
    assert "iteration 2: no episode ended in it (an iteration shorter than an episode), 128 env steps" in printed.out
    with zipfile.ZipFile(out / "agent.zip") as archive:
        assert "vecnormalize.pkl" in archive.namelist()
    agent = Agent.load(out / "agent.zip")
    assert agent.config.tl_reward == "markov" and agent.observation_space.shape[0] > 6
    expected = agent.evaluate(3, seed=7)["mean_robustness"]
    capsys.readouterr()
    assert main(["eval", str(out), "--episodes", "3", "--seed", "7"]) == 0
    printed = capsys.readouterr().out
    assert f"mean robustness {expected:.4g}" in printed
    assert printed.startswith("ppo on TLCarNav-v0: 3 episodes")  # no env_kwargs: nothing between id and colon


def test_a_budget_that_is_not_whole_iterations_is_rounded_up_and_said(tmp_path, capsys):
    out = tmp_path / "rounded"
    assert main(["train", "--env", "TLCarNav-v0", "--agent", "ppo", "--n-timesteps", "100", "--out", str(out),
                 "--quiet", *SB3_TINY]) == 0
    assert json.loads((out / "run.json").read_text())["iterations"] == 2
    err = capsys.readouterr().err
    assert "n_timesteps=100 is not whole iterations of steps_per_iteration=64" in err and "128 env steps" in err


def test_tl_reward_terminal_is_the_ablation(tmp_path):
    out = tmp_path / "ablation"
    assert main(["train", "--agent", "ppo", "--iterations", "1", "--tl-reward", "terminal", "--out", str(out),
                 "--quiet", *SB3_TINY]) == 0
    agent = Agent.load(out / "agent.zip")
    assert agent.config.tl_reward == "terminal" and agent.observation_space.shape == (6,)


def test_sb3_with_spec_gets_the_markov_view_on_the_wrapper(tmp_path, capsys):
    out = tmp_path / "pendulum"
    assert main(["train", "--env", "Pendulum-v1", "--spec", "F(cos_th > 0.9)", "--signals", "cos_th=0",
                 "--agent", "ppo", "--iterations", "1", "--out", str(out), "--quiet", *SB3_TINY]) == 0
    run = json.loads((out / "run.json").read_text())
    agent = Agent.load(out / "agent.zip", env=build_env(run))
    assert agent.config.tl_reward == "markov" and agent.observation_space.shape[0] > 3
    assert agent.model.gamma == 0.9  # the Pendulum-v1 entry of the hyperparameter file
    assert main(["eval", str(out), "--episodes", "2"]) == 0
    assert "2 episodes" in capsys.readouterr().out


def test_wrapper_kwargs_reach_the_wrapper_over_the_sb3_defaults(tmp_path, capsys):
    out = tmp_path / "pendulum"
    assert main(["train", "--env", "Pendulum-v1", "--spec", "F(cos_th > 0.9)", "--signals", "cos_th=0",
                 "--wrapper-kwargs", '{"satisfaction_bonus": 5, "reward_mode": "potential"}',
                 "--agent", "ppo", "--iterations", "1", "--out", str(out), "--quiet", *SB3_TINY]) == 0
    run = json.loads((out / "run.json").read_text())
    env = build_env(run)
    # the shaping discounts as PPO's entry does, recorded so that eval rebuilds the env trained on
    assert run["wrapper_kwargs"] == {"satisfaction_bonus": 5, "reward_mode": "potential", "gamma": 0.9}
    assert env.satisfaction_bonus == 5.0 and env.reward_mode == "potential"  # over markov's "dense"
    assert env.observe_monitor  # the rest of markov's keywords stay
    assert env.gamma == Agent.load(out / "agent.zip").model.gamma == 0.9
    del run["wrapper_kwargs"]  # a run.json written before the option
    assert build_env(run).reward_mode == "dense"
    assert main(["eval", str(out), "--episodes", "2"]) == 0
    assert "2 episodes" in capsys.readouterr().out


def test_wrapper_kwargs_win_over_an_explicit_tl_reward_as_env_kwargs_do(tmp_path, capsys):
    """--tl-reward terminal with a dense wrapper was refused with "pass the env id instead", a message for the
    Python API; now the wrapper keywords win as env_kwargs do for an id, and only a contradicted view is an error."""
    base = ["train", "--env", "Pendulum-v1", "--spec", "F(cos_th > 0.9)", "--signals", "cos_th=0", "--agent", "ppo",
            "--iterations", "1", "--quiet", *SB3_TINY]
    out = tmp_path / "dense"
    assert main([*base, "--out", str(out), "--tl-reward", "terminal",
                 "--wrapper-kwargs", '{"reward_mode": "dense"}']) == 0
    agent = Agent.load(out / "agent.zip")
    assert agent.config.tl_reward == "terminal"
    env = build_env(json.loads((out / "run.json").read_text()))
    assert env.reward_mode == "dense" and not env.observe_monitor
    assert main(["eval", str(out), "--episodes", "2"]) == 0
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "bad"), "--tl-reward", "markov",
                 "--wrapper-kwargs", '{"observe_monitor": false}']) == 2
    assert ("tl_reward='markov' sets observe_monitor=True, but --wrapper-kwargs set observe_monitor=False"
            in capsys.readouterr().err)


def test_eval_every_keeps_the_best_agent_and_eval_best_reads_it(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", "--env", "TLCarNav-v0", "--env-kwargs", '{"horizon": 10}', "--agent", "reps",
                 "--iterations", "4", "--n-episodes", "4", "--eval-every", "2", "--eval-episodes", "3",
                 "--out", str(out), "--quiet"]) == 0
    assert "best_agent.zip" in capsys.readouterr().out
    best = Agent.load(out / "best_agent.zip")
    evaluations = (out / "evaluations.csv").read_text().splitlines()
    assert evaluations[0] == "iteration,env_steps,success_rate,mean_robustness"
    assert [row.split(",")[:2] for row in evaluations[1:]] == [["2", "80"], ["4", "160"]]  # 4 episodes x 10 steps
    scores = {int(row.split(",")[0]): (float(row.split(",")[2]), float(row.split(",")[3])) for row in evaluations[1:]}
    best_iteration = max(scores, key=lambda it: scores[it])  # the first of equals: a later one must beat it
    assert len(best.history) == best_iteration  # the agent saved at its best evaluation
    assert main(["eval", str(out), "--best", "--episodes", "3"]) == 0
    assert "3 episodes" in capsys.readouterr().out
    assert main(["eval", str(tmp_path / "run"), "--episodes", "3"]) == 0  # the final agent still there


def test_eval_best_of_a_run_without_it(car_run, capsys):
    assert main(["eval", str(car_run), "--best"]) == 2
    assert "without --eval-every" in capsys.readouterr().err


def test_eval_why_prints_each_conjuncts_breakdown(car_run, capsys):
    assert main(["eval", str(car_run), "--episodes", "6", "--why"]) == 0
    out = capsys.readouterr().out
    formula = Agent.load(car_run / "agent.zip").formula
    assert f"why ({formula})" in out and "violated in" in out and "median ρ" in out
    for conjunct in formula.operands:  # task 1 is a conjunction: one line each, with the episodes counted
        line = next(line for line in out.splitlines() if line.startswith(str(conjunct)))
        assert " of 6" in line


def _documented_command(doc: str, starts: str) -> list[str]:
    """The arguments of ``doc``'s one ``$ tl-gym <starts>...`` console line (continuation lines joined)."""
    text = (pathlib.Path(__file__).parents[1] / doc).read_text().replace("\\\n", " ")
    lines = [line[len("$ tl-gym "):] for line in text.splitlines() if line.startswith("$ tl-gym " + starts)]
    assert len(lines) == 1, f"{doc} has {len(lines)} console lines starting with 'tl-gym {starts}'"
    return shlex.split(lines[0])


def test_the_documented_own_formula_example_learns(tmp_path, capsys):
    """docs/cli.md's "your own formula" command, run as printed there, reaches the flag as it says."""
    args = _documented_command("docs/cli.md", "train --env MountainCarContinuous-v0")
    args[args.index("--out") + 1] = str(tmp_path / "mountaincar")
    assert main([*args, "--quiet"]) == 0
    assert main(["eval", str(tmp_path / "mountaincar"), "--episodes", "100"]) == 0
    out = capsys.readouterr().out.strip().splitlines()[-1]
    success = float(re.fullmatch(r".*: 100 episodes, mean robustness \S+, success rate (\S+)%", out).group(1))
    assert success >= 95.0, out  # 100.0 here; the margin is for other BLAS builds


def test_a_negative_seed_names_the_flag(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["train", "--agent", "reps", "--seed", "-1", "--out", str(tmp_path / "r")])
    assert "argument --seed: expects an int >= 0, got -1" in capsys.readouterr().err


def test_ctrl_c_is_one_line_saying_what_is_kept(tmp_path, capsys, monkeypatch):
    from tl_gym.agents import REPS

    def interrupted(self, iteration):
        raise KeyboardInterrupt

    monkeypatch.setattr(REPS, "_update", interrupted)
    out = tmp_path / "r"
    assert main(["train", "--agent", "reps", "--n-episodes", "2", "--iterations", "2", "--out", str(out),
                 "--quiet"]) == 130
    assert capsys.readouterr().err.strip() == f"tl-gym train: interrupted; {out}/history.csv keeps the iterations done"


def test_a_first_ctrl_c_stops_after_the_iteration_and_saves_the_agent(tmp_path, capsys, monkeypatch):
    """Ctrl-C threw the trained agent away: only run.json and history.csv were left, nothing to evaluate or resume."""
    import os
    import signal

    from tl_gym.agents import REPS

    update = REPS._update

    def interrupted_in_the_first(self, iteration):
        row = update(self, iteration)
        if iteration == 1:
            os.kill(os.getpid(), signal.SIGINT)  # as a Ctrl-C in the middle of the run
        return row

    monkeypatch.setattr(REPS, "_update", interrupted_in_the_first)
    out = tmp_path / "r"
    before = signal.getsignal(signal.SIGINT)
    assert main(["train", "--agent", "reps", "--n-episodes", "2", "--iterations", "3", "--out", str(out),
                 "--quiet"]) == 130
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back
    assert "stopped after iteration 1 of 3" in capsys.readouterr().err
    assert Agent.load(out / "agent.zip").num_iterations == 1
    assert len((out / "history.csv").read_text().splitlines()) == 2 and (out / "learning_curve.png").exists()


def test_eval_gif_path_is_checked_before_the_evaluation_and_best_of_a_runner_run_says_why(car_run, tmp_path,
                                                                                          capsys):
    (tmp_path / "a_file").write_text("")
    assert main(["eval", str(car_run), "--gif", str(tmp_path / "a_file" / "x.gif")]) == 2
    err = capsys.readouterr().err
    assert "a_file is a file, not a folder" in err and "episodes" not in err
    assert main(["eval", str(car_run), "--gif", str(tmp_path)]) == 2
    assert "is a folder: name a .gif file" in capsys.readouterr().err
    runner_run = tmp_path / "runner_run"
    runner_run.mkdir()
    (runner_run / "spec.json").write_text(json.dumps({"env": "TLCarNav-v0", "env_kwargs": {"task": 1},
                                                      "agent": "reps"}))
    assert main(["eval", str(runner_run), "--best"]) == 2
    assert "the experiment runner keeps no best agent, only the final one (drop --best)" in capsys.readouterr().err


class Endless(gym.Env):
    """Never ends its episodes, and states no length."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(1, np.float32), {}

    def step(self, action):
        return np.zeros(1, np.float32), 0.0, False, False, {}


gym.register("EndlessForCli-v0", entry_point=Endless)


def test_train_on_an_env_whose_episodes_never_end_is_one_error_line_and_keeps_the_history(tmp_path, capsys,
                                                                                         monkeypatch):
    """The snapshot's episodes met the guard with a traceback, and history.csv was not yet written."""
    import tl_gym.agents.evaluation as evaluation

    monkeypatch.setattr(evaluation, "UNSTATED_EPISODE_GUARD", 40)
    out = tmp_path / "endless"
    status = main(["train", "--env", "EndlessForCli-v0", "--spec", "F(x > 0.5)", "--signals", "x=0", "--agent", "ppo",
                   "--iterations", "1", "--out", str(out), "--quiet", *SB3_TINY[:-2], "--snapshots", "1"])
    assert status == 2
    error = capsys.readouterr().err
    assert error.startswith("tl-gym train: error: ")
    assert "did not end within 40 steps; the env states no episode length" in error
    assert len((out / "history.csv").read_text().splitlines()) == 2  # the header and the iteration trained


gym.register("DictForCli-v0", entry_point="tests.test_wrapper:Scripted", kwargs={"dict_obs": True}, max_episode_steps=5)


def test_signals_pick_an_element_of_a_dict_keys_array_with_brackets(tmp_path, capsys):
    """`--signals px=pos` named an array, and no command-line syntax could pick one of its elements."""
    out = tmp_path / "dict"
    assert main(["train", "--env", "DictForCli-v0", "--spec", "F(px > 0.5)", "--signals", "px=pos[1], v=speed",
                 "--agent", "reps", "--n-episodes", "4", "--iterations", "1", "--out", str(out), "--quiet"]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["signals"] == {"px": ["pos", 1], "v": "speed"}
    _, info = run_episode(build_env(run))
    np.testing.assert_array_equal(info["trace"]["px"], np.linspace(0, 1, 18).reshape(6, 3)[:, 1])
    assert main(["eval", str(out), "--episodes", "2"]) == 0
    with pytest.raises(SystemExit):
        main(["train", "--spec", "F(px > 0)", "--signals", "px=pos[a]", "--out", str(tmp_path / "bad")])
    assert "'px': 'pos[a]' is neither a key nor key[i]" in capsys.readouterr().err


def run_episode(env):
    env.reset(seed=0)
    while True:
        _, _, terminated, truncated, info = env.step(np.zeros(env.action_space.shape, np.float32))
        if terminated or truncated:
            return env, info


def _any_keywords(render_mode=None, **kwargs):
    return gym.make("TLCarNav-v0", render_mode=render_mode, **kwargs)


gym.register("AnyKeywordsForCli-v0", entry_point=_any_keywords)


def test_task_is_passed_to_an_entry_point_whose_keywords_cannot_be_read(tmp_path):
    """An entry point taking **kwargs without listing them was refused --task ("its keywords: render_mode")."""
    out = tmp_path / "any"
    assert main(["train", "--env", "AnyKeywordsForCli-v0", "--task", "2", "--agent", "reps", "--n-episodes", "2",
                 "--iterations", "1", "--out", str(out), "--quiet"]) == 0
    assert json.loads((out / "run.json").read_text())["env_kwargs"] == {"task": 2}
