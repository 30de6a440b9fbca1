r"""The ``tl-gym`` command line: train an agent on a TLTL task, evaluate it, watch it.

``tl-gym train`` trains TLPS, REPS or a stable-baselines3 / sb3-contrib algorithm and writes a run
folder::

    runs/NAME/
        run.json            how the run was made (env, formula, agent, hyperparameters, seed)
        agent.zip           the trained agent (`tl_gym.agents.Agent.load`)
        best_agent.zip      with --eval-every N: the agent at its best evaluation (`EvalCallback`)
        evaluations.csv     with --eval-every N: each evaluation (iteration, env steps, success rate, mean rho)
        history.csv         one row per iteration (mean exact robustness, success rate, env steps, ...)
        learning_curve.png  mean robustness and success rate per iteration
        trajectories.png    sampled trajectories at selected iterations (over the task layout for the car)

``tl-gym eval runs/NAME`` reloads the agent (``--best``: the best one), prints its mean robustness
and success rate over fresh episodes (``--why``: and which of the formula's conjuncts broke,
`tl_gym.diagnosis`) and can save a GIF of one episode.

Examples::

    tl-gym train --env TLCarNav-v0 --task 2 --agent tlps --iterations 50 --seed 0 --out runs/demo
    tl-gym train --env TLCarNav-v0 --agent reps --iterations 30 --epsilon 1.5 --out runs/reps
    tl-gym train --env TLCarNav-v0 --agent ppo --iterations 20 --learning-rate 1e-3 --out runs/ppo
    tl-gym train --env Pendulum-v1 --spec "F(G(cos_th > 0.95))" --signals cos_th=0 --agent reps \
        --horizon 200 --iterations 30 --out runs/pendulum
    tl-gym eval runs/demo --episodes 100 --gif runs/demo/episode.gif
    tl-gym eval runs/demo --why

Hyperparameters are passed as ``--name value`` (dashes or underscores); values are read as
numbers, booleans (``true``/``false``), ``none`` or JSON when they parse as such, else as text.
"""

from __future__ import annotations

import argparse
import difflib
import inspect
import json
import math
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tl_gym.agents import Agent
from tl_gym.agents.callbacks import EvalCallback, HistoryCSV, as_callback
from tl_gym.agents.env_ids import env_keywords
from tl_gym.agents.evaluation import UNSTATED_EPISODE_GUARD, as_vector_env, collect_episodes, predictor_controller
from tl_gym.agents.horizon import env_attribute, infer_horizon
from tl_gym.agents.registry import is_episodic, is_sb3, make_agent
from tl_gym.agents.run_folder import AGENT_FILE, HISTORY_FILE, RUNNER_DONE_FILE, RUNNER_SPEC_FILE
from tl_gym.agents.sampling import run_episodes
from tl_gym.agents.sb3_settings import wrap_env

import tl_gym
from tl_gym.checks import check_count
from tl_gym.diagnosis import conjunct_breakdown, format_breakdown
from tl_gym.errors import TLGymError

from .arguments import build_parser, parse_hyperparameters

RUN_FILE = "run.json"
BEST_FILE = "best_agent.zip"
EVALUATIONS_FILE = "evaluations.csv"
#: Every file `train` may write in its run folder: an earlier run's are removed first, so none is left over.
RUN_OUTPUTS = (RUN_FILE, AGENT_FILE, BEST_FILE, EVALUATIONS_FILE, HISTORY_FILE, "learning_curve.png",
               "trajectories.png")


# Building the env and the agent --------------------------------------------------------------------
def build_env(run: dict[str, Any], render_mode: str | None = None) -> Any:
    """The env of a run: its id (the agent adds the kwargs), or the env wrapped with ``--spec``.

    SB3 agents get the env keywords of their ``tl_reward`` (`tl_gym.agents.sb3_settings.TL_REWARD_ENV_KWARGS`)
    here too, since they cannot rewrap an env object: with ``--spec`` they go to the wrapper (the run's
    ``--wrapper-kwargs`` win). ``render_mode`` is for ``--spec`` runs; an id's rendered env is `rendered_env`'s.
    """
    if run.get("spec") is None:
        if render_mode is not None:
            raise ValueError("an env id's rendered env takes the agent's env keywords: use rendered_env(run, agent)")
        return run["env"]
    kwargs = dict(run["env_kwargs"])
    tl_kwargs = _tl_reward_env_kwargs(run)
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    if not run.get("signals"):
        raise ValueError("--spec needs --signals to say where each signal comes from, e.g. --signals cos_th=0")
    wrapper_kwargs = {**tl_kwargs, **run.get("wrapper_kwargs", {})}  # run.json files before --wrapper-kwargs lack it
    return tl_gym.TLTLRewardWrapper(gym.make(run["env"], **kwargs), run["spec"], run["signals"], **wrapper_kwargs)


def check_wrapper_keywords(wrapper_kwargs: dict[str, Any]) -> None:
    """Refuse a ``--wrapper-kwargs`` name `TLTLRewardWrapper` does not take, with the nearest one it does."""
    accepted = [name for name in inspect.signature(tl_gym.TLTLRewardWrapper).parameters
                if name not in ("env", "spec", "signals")]  # given by --env, --spec, --signals
    for name in wrapper_kwargs:
        if name not in accepted:
            near = difflib.get_close_matches(name, accepted, n=1)
            hint = f"; did you mean {near[0]!r}?" if near else f"; it takes {', '.join(accepted)}"
            raise ValueError(f"--wrapper-kwargs: TLTLRewardWrapper takes no keyword {name!r}{hint}")


def rendered_env(run: dict[str, Any], agent: Any) -> Any:
    """A single env of the run that renders frames.

    For an id it is made with the agent's own env keywords (what it trained on: ``--env-kwargs``, its
    ``tl_reward``'s and the task's shaping), so the recorded episode is the evaluated one; for ``--spec``,
    the run's wrapped env.
    """
    if run.get("spec") is None:
        env = gym.make(run["env"], **{**agent.env_kwargs, "render_mode": "rgb_array"})
    else:
        env = build_env(run, render_mode="rgb_array")
    return wrap_env(env, getattr(agent, "env_wrappers", []))  # an SB3 agent's env_wrapper, as it trained


def _tl_reward_env_kwargs(run: dict[str, Any]) -> dict[str, Any]:
    """The env keywords an SB3 run's ``tl_reward`` implies; none for TLPS and REPS."""
    if is_episodic(run["agent"]):
        return {}
    from tl_gym.agents.sb3_settings import DEFAULT_TL_REWARD, TL_REWARD_ENV_KWARGS, check_tl_reward

    return dict(TL_REWARD_ENV_KWARGS[check_tl_reward(run["hyperparameters"].get("tl_reward", DEFAULT_TL_REWARD))])


def agent_for_run(run: dict[str, Any]) -> Any:
    """Build the run's agent on its env (through the agent registry).

    With ``--spec`` the ``--wrapper-kwargs`` win over ``--tl-reward``'s keywords, as ``env_kwargs`` do for an
    id: the agent reads its ``tl_reward`` from the wrapped env, and only a contradicted view is an error
    (raised before the env is built).
    """
    hyperparameters = dict(run["hyperparameters"])
    if run.get("spec") is not None and "tl_reward" in hyperparameters and not is_episodic(run["agent"]):
        from tl_gym.agents.sb3_settings import tl_reward_of_env_kwargs

        merged = {**_tl_reward_env_kwargs(run), **run.get("wrapper_kwargs", {})}
        tl_reward_of_env_kwargs(hyperparameters.pop("tl_reward"), merged, "--wrapper-kwargs")  # the agent reads it
    env = build_env(run)
    env_kwargs = run["env_kwargs"] if isinstance(env, str) else None
    return make_agent(run["agent"], env, seed=run["seed"], env_kwargs=env_kwargs, **hyperparameters)


def default_iterations(agent: Any) -> int:
    """Iterations when ``--iterations`` is not given: the task's ``n_timesteps`` budget for SB3 agents, else 50."""
    budget = getattr(agent, "n_timesteps", None)
    if budget is None:
        return 50
    return max(1, -(-int(budget) // int(agent.config.steps_per_iteration)))


def rounding_notice(agent: Any, iterations: int) -> str | None:
    """The line to print when the ``n_timesteps`` budget is not whole iterations, else None.

    A user who asked for 4,000 steps at 8,000 per iteration gets 8,000: say so instead of doing it silently.
    """
    budget = getattr(agent, "n_timesteps", None)
    if budget is None:
        return None
    per_iteration = int(agent.config.steps_per_iteration)
    if iterations * per_iteration == int(budget):
        return None
    # "about": an SB3 iteration is whole rollouts, within 5 % of steps_per_iteration (SB3Agent checks that)
    return (f"note: n_timesteps={int(budget)} is not whole iterations of steps_per_iteration={per_iteration}: "
            f"training {iterations} iteration(s), about {iterations * per_iteration} env steps "
            "(set --steps-per-iteration or --iterations to choose)")


def default_snapshots(iterations: int) -> list[int]:
    """Iterations to plot: the first, then spread to the last.

    Example:
        >>> default_snapshots(50)
        [1, 5, 10, 20, 30, 40, 50]
    """
    picks = {1, iterations} | {round(iterations * f) for f in (0.1, 0.2, 0.4, 0.6, 0.8)}
    return sorted(p for p in picks if 1 <= p <= iterations)


# Commands ------------------------------------------------------------------------------------------
def train(args: argparse.Namespace, extra: Sequence[str]) -> int:
    """``tl-gym train``: train, then write the run folder."""
    env_kwargs = dict(args.env_kwargs)
    if args.task is not None:
        takes = env_keywords(args.env)
        if takes and "task" not in takes:  # known keywords without one: say so before Gymnasium's long message
            raise ValueError(f"--task is the car's task keyword (TLCarNav-v0: 1 or 2); {args.env} takes no task "
                             f"(its keywords: {', '.join(sorted(takes))})")
        env_kwargs["task"] = args.task
    if args.signals is not None and args.spec is None:
        raise ValueError("--signals only makes sense with --spec")
    if args.wrapper_kwargs and args.spec is None:
        raise ValueError("--wrapper-kwargs only makes sense with --spec (a TL id such as TLCarNav-v0 takes the "
                         "wrapper's keywords in --env-kwargs)")
    check_wrapper_keywords(args.wrapper_kwargs)
    hyperparameters = parse_hyperparameters(extra)
    wrapper_kwargs = dict(args.wrapper_kwargs)
    if wrapper_kwargs.get("reward_mode") == "potential" and "gamma" not in wrapper_kwargs and is_sb3(args.agent):
        # the shaping keeps the optimal policies only with the agent's discount, which an env id gets from the
        # agent; written into run.json, so that `eval` rebuilds the env the agent trained on
        from tl_gym.agents.sb3 import agent_discount

        wrapper_kwargs["gamma"] = agent_discount(args.agent, args.env, env_kwargs,
                                                 hyperparameters.get("hyperparams", True), hyperparameters.get("gamma"))
    run = {
        "env": args.env, "env_kwargs": env_kwargs, "spec": args.spec, "signals": args.signals,
        "wrapper_kwargs": wrapper_kwargs,
        "agent": args.agent, "iterations": args.iterations, "seed": args.seed,
        "hyperparameters": hyperparameters,
    }
    if args.iterations is not None:
        check_count("--iterations", args.iterations)
    if args.eval_every is not None:  # checked here, in the flags' names, before the agent is built
        check_count("--eval-every", args.eval_every)
        check_count("--eval-episodes", args.eval_episodes)
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file: name a folder for the run")
    if (out / RUNNER_SPEC_FILE).exists():  # its done.json and spec.json would describe another run's history and agent
        raise ValueError(f"--out {out} is a run folder of the experiment runner: training there would corrupt its "
                         "record; name another folder")
    agent = agent_for_run(run)
    if args.iterations is None:
        iterations = default_iterations(agent)
        notice = rounding_notice(agent, iterations)
        if notice is not None:
            print(notice, file=sys.stderr)
    else:
        iterations = args.iterations
    run["iterations"] = iterations
    snapshots_at = args.snapshots or default_snapshots(iterations)
    late = [str(s) for s in snapshots_at if s > iterations]
    if late:  # never sampled: say so, rather than leave trajectories.png short (or unwritten) silently
        print(f"note: --snapshots {','.join(late)} after the last iteration ({iterations}): not plotted",
              file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    for name in RUN_OUTPUTS:  # an earlier run's best_agent.zip would pass for this run's in `tl-gym eval --best`
        (out / name).unlink(missing_ok=True)
    (out / RUN_FILE).write_text(json.dumps(run, indent=1))

    n_samples = int(getattr(agent.config, "n_episodes", 40))
    snapshots: list[tuple[int, dict[str, Any]]] = []

    def record(agent: Any, row: dict[str, Any]) -> bool:
        if row["iteration"] in snapshots_at:
            # samples of the updated policy, on seeds the training never uses
            _, traces = collect_episodes(agent, agent.env, n_samples, seed=10**6 + row["iteration"])
            snapshots.append((row["iteration"], traces))
        return True

    # history.csv is written after every iteration (all of this fresh agent's rows), so a long run can be
    # watched and a killed one keeps its rows
    callbacks = [HistoryCSV(out / HISTORY_FILE), record]  # the row is kept even if the snapshot's episodes fail
    if args.eval_every is not None:
        callbacks.append(EvalCallback(args.eval_every, args.eval_episodes, best_path=out / BEST_FILE,
                                      log_path=out / EVALUATIONS_FILE))
    if not args.quiet and run["spec"] is None:  # what the agent adds to --env-kwargs is said, not silent
        print(f"{type(agent).__name__} on {run['env']} with the env keywords {agent.env_kwargs}")
    with StopAfterIteration() as stop:  # Ctrl-C: finish the iteration, then save and plot what was trained
        agent.learn(iterations, callback=as_callback([*callbacks, stop.callback]), progress_bar=not args.quiet)
    agent.save(out / AGENT_FILE)
    write_plots(agent, run, snapshots, out)
    last = agent.history[-1]
    scores = (f"mean robustness {last['mean_robustness']:.4g}, success rate {last['success_rate']:.1%}"
              if last.get("episodes", 1) else "no episode ended in it (an iteration shorter than an episode)")
    print(f"iteration {last['iteration']}: {scores}, {last['env_steps']} env steps, {last['wall_time']:.1f} s")
    # an earlier run's were removed: these exist if this run evaluated (not before --eval-every's first N iterations)
    best = "".join(f", {name}" for name in (BEST_FILE, EVALUATIONS_FILE) if (out / name).exists())
    trajectories = ", trajectories.png" if snapshots else ""  # write_plots draws them only from snapshots
    print(f"wrote {out}/{{{RUN_FILE}, {AGENT_FILE}{best}, {HISTORY_FILE}, learning_curve.png{trajectories}}}")
    if stop.requested:
        print(f"tl-gym train: interrupted: stopped after iteration {last['iteration']} of {iterations}; the agent "
              "continues with Agent.load", file=sys.stderr)
        return 130
    return 0


class StopAfterIteration:
    """A first Ctrl-C asks training to stop once the iteration under way ends; a second one interrupts at once.

    The agent's state is whole only between iterations (a policy update half done is no agent to save), so
    the first SIGINT is turned into a request that ``callback`` answers after the iteration (SB3's callback
    convention: ``False`` stops). Off the main thread, where no handler can be set, Ctrl-C interrupts as usual.
    """

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def __enter__(self) -> StopAfterIteration:
        if threading.current_thread() is not threading.main_thread():
            return self
        previous = signal.getsignal(signal.SIGINT)
        if previous is signal.SIG_IGN:  # ignored (a background job): left so, as Python leaves it
            return self
        self._previous = signal.default_int_handler if previous is None else previous  # None: set outside Python
        signal.signal(signal.SIGINT, self._request)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)

    def _request(self, signum: int, frame: Any) -> None:
        self.requested = True
        signal.signal(signal.SIGINT, self._previous)  # the next Ctrl-C interrupts
        print("\ntl-gym train: stopping after this iteration, then saving (Ctrl-C again to stop at once)",
              file=sys.stderr)

    def callback(self, agent: Any, row: dict[str, Any]) -> bool:
        return not self.requested


def write_plots(agent: Any, run: dict[str, Any], snapshots: list[tuple[int, dict[str, Any]]], out: Path) -> None:
    """Write ``learning_curve.png`` and, given snapshots, ``trajectories.png`` for a finished run."""
    # matplotlib loads only when a run is plotted, not for `tl-gym --help`
    from tl_gym.agents.plotting import plot_learning_curve, plot_signals, plot_trajectories

    steps = agent.history[0]["env_steps"]
    title = f"{run['agent']} on {run['env']}" + (f" task {run['env_kwargs']['task']}" if "task" in run["env_kwargs"]
                                                  else "")
    plot_learning_curve(agent.history, out / "learning_curve.png", title=f"{title} ({steps} env steps / iteration)")
    if not snapshots:
        return
    layout = env_attribute(agent.env, "layout")
    signals = snapshots[0][1]
    if layout is not None and run.get("spec") is None and {"x", "y"} <= set(signals):
        from tl_gym.envs.rendering import draw_layout

        plot_trajectories(snapshots, out / "trajectories.png", background=lambda ax: draw_layout(ax, layout),
                          title=f"{title}: sampled trajectories (mean ± 2σ)")
    else:
        plot_signals(snapshots, out / "trajectories.png", title=f"{title}: sampled signals (mean ± 2σ)")


def read_run(folder: Path) -> dict[str, Any]:
    """What a run folder trained: `tl-gym train`'s ``run.json``, or the experiment runner's ``spec.json``.

    A runner folder (written by ``benchmarks/run_one.py``, docs/benchmarks.md) names a registered id, so it has no
    ``--spec``; both kinds keep the final agent as ``agent.zip``.
    """
    run_file, runner_file = folder / RUN_FILE, folder / RUNNER_SPEC_FILE
    if run_file.exists():
        return _checked_run(_read_json(run_file), run_file)
    if runner_file.exists():
        return _checked_run({**_read_json(runner_file), "spec": None, "signals": None}, runner_file)
    raise FileNotFoundError(f"{run_file} not found: is {folder} a folder written by `tl-gym train` "
                            f"(or a run folder of the experiment runner, with {RUNNER_SPEC_FILE})?")


def _checked_run(run: Any, path: Path) -> dict[str, Any]:
    """A run's description with the keys `eval` reads (a ``ValueError`` naming the file and the missing ones)."""
    missing = [key for key in ("env", "agent") if not isinstance(run, dict) or key not in run]
    if missing:
        raise ValueError(f"{path} names no {' and no '.join(missing)}: not a run written by tl-gym train or the runner")
    return {"env_kwargs": {}, **run}


def _read_json(path: Path) -> dict[str, Any]:
    """A run folder's JSON file; a ``ValueError`` naming the file when it does not parse."""
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not valid JSON ({error})") from None


def evaluate(args: argparse.Namespace) -> int:
    """``tl-gym eval``: print the evaluation of a saved run, optionally save a GIF."""
    check_count("--episodes", args.episodes)
    run = read_run(args.run)
    env = build_env(run)
    saved = args.run / (BEST_FILE if args.best else AGENT_FILE)
    if not saved.exists():
        runner_run = not (args.run / RUN_FILE).exists()
        why = ("the experiment runner keeps no best agent, only the final one (drop --best)" if args.best and
               runner_run else "the run was trained without --eval-every" if args.best
               else "a runner's record in git keeps no agent (spec.json, history.csv and done.json only): rerun its "
               "spec on this machine to get it (docs/benchmarks.md)" if (args.run / RUNNER_DONE_FILE).exists()
               else "train writes it when training ends or stops after a Ctrl-C (was the run killed?)")
        raise FileNotFoundError(f"{saved} not found: {why}")
    if args.gif is not None:  # before the evaluation and the rendering, not after them
        check_gif_path(args.gif)
    agent = Agent.load(saved, env=None if isinstance(env, str) else env)
    result = agent.evaluate(n_episodes=args.episodes, seed=args.seed, deterministic=not args.stochastic)
    kwargs = f" {run['env_kwargs']}" if run["env_kwargs"] else ""
    print(f"{run['agent']} on {run['env']}{kwargs}: {args.episodes} episodes, "
          f"mean robustness {result['mean_robustness']:.4g}, success rate {result['success_rate']:.1%}")
    if args.why:
        rho_max = env_attribute(agent.env, "rho_max")
        rows = conjunct_breakdown(agent.formula, result["traces"], math.inf if rho_max is None else rho_max)
        print(f"\nwhy ({agent.formula}): each top-level conjunct's robustness over the same episodes\n"
              + format_breakdown(rows))
    if args.gif is not None:
        frames = record_episode(agent, rendered_env(run, agent), seed=args.seed,
                                deterministic=not args.stochastic)
        save_gif(frames, args.gif)
        print(f"wrote {args.gif} ({len(frames)} frames)")
    return 0


def record_episode(agent: Any, env: Any, seed: int, deterministic: bool = True) -> list[Any]:
    """Frames of one episode of ``agent`` on a single env made with ``render_mode="rgb_array"``."""
    frames: list[Any] = []
    policy = predictor_controller(agent, deterministic)

    def act(t: int, obs: Any, episode_start: np.ndarray) -> Any:
        frames.append(env.render())
        return policy(t, obs, episode_start)

    venv = as_vector_env(env)
    guard = None if infer_horizon(venv) is not None else UNSTATED_EPISODE_GUARD  # as evaluation's: never forever
    run_episodes(venv, act, seed=seed, max_steps=guard)
    frames.append(env.render())  # the last state: the next-step autoreset has not reset it
    env.close()
    return frames


def check_gif_path(path: Path) -> None:
    """Refuse a ``--gif`` path that cannot be written: a folder, or a file under something that is not one."""
    if path.is_dir():
        raise ValueError(f"--gif {path} is a folder: name a .gif file")
    parent = next((p for p in path.parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise ValueError(f"--gif {path}: {parent} is a file, not a folder")


def save_gif(frames: Sequence[Any], path: Path, fps: int = 20) -> None:
    """Write RGB frames as a looping GIF (needs imageio: ``pip install tl_gym[render]``)."""
    try:
        import imageio.v3 as iio
    except ImportError:
        raise SystemExit("saving a GIF needs imageio: pip install 'tl_gym[render]'") from None

    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), duration=1000 / fps, loop=0)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tl-gym``; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(with_hyperparameters=bool({"-h", "--help"} & set(argv)))
    args, extra = parser.parse_known_args(argv)
    if args.command != "train" and extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        if args.command == "train":
            return train(args, extra)
        return evaluate(args)
    # gym.error.Error: an unknown env id (NameNotFound), a missing extra (DependencyNotInstalled), ...;
    # OSError: a run folder that is missing, or cannot be made or written (--out under a file, no permission)
    except (TLGymError, ValueError, TypeError, OSError, ImportError, gym.error.Error) as error:
        print(f"tl-gym {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback through the callbacks
        kept = f"; {args.out}/history.csv keeps the iterations done" if args.command == "train" else ""
        print(f"\ntl-gym {args.command}: interrupted{kept}", file=sys.stderr)
        return 130
