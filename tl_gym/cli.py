r"""The ``tl-gym`` command line: train an agent on a TLTL task, evaluate it, watch it.

``tl-gym train`` trains TLPS, REPS or any stable-baselines3 algorithm and writes a run
folder::

    runs/NAME/
        run.json            how the run was made (env, formula, agent, hyperparameters, seed)
        agent.zip           the trained agent (`tl_gym.agents.Agent.load`)
        history.csv         one row per iteration (mean exact robustness, success rate, env steps, ...)
        learning_curve.png  mean robustness and success rate per iteration
        trajectories.png    sampled trajectories at selected iterations (over the task layout for the car)

``tl-gym eval runs/NAME`` reloads the agent, prints its mean robustness and success rate
over fresh episodes and can save a GIF of one episode.

Examples::

    tl-gym train --env TLCarNav-v0 --task 2 --agent tlps --iterations 50 --seed 0 --out runs/demo
    tl-gym train --env TLCarNav-v0 --agent reps --iterations 30 --epsilon 1.5 --out runs/reps
    tl-gym train --env TLCarNav-v0 --agent ppo --iterations 20 --learning-rate 1e-3 --out runs/ppo
    tl-gym train --env Pendulum-v1 --spec "F(G(cos_th > 0.95))" --signals cos_th=0 --agent reps \
        --horizon 200 --iterations 30 --out runs/pendulum
    tl-gym eval runs/demo --episodes 100 --gif runs/demo/episode.gif

Hyperparameters are passed as ``--name value`` (dashes or underscores); values are read as
numbers, booleans (``true``/``false``), ``none`` or JSON when they parse as such, else as text.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: Agents known by name; any other name is taken as a stable-baselines3 algorithm.
EPISODIC_AGENTS = ("tlps", "reps")
RUN_FILE = "run.json"
AGENT_FILE = "agent.zip"


# Parsing -------------------------------------------------------------------------------------------
def parse_value(text: str) -> Any:
    """Read a command-line value: int, float, bool, None or JSON when it parses, else the text.

    Example:
        >>> [parse_value(v) for v in ["40", "0.5", "true", "none", "[64, 64]", "MlpPolicy"]]
        [40, 0.5, True, None, [64, 64], 'MlpPolicy']
    """
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered in ("none", "null"):
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    try:
        return json.loads(text)
    except ValueError:
        return text


def parse_signals(text: str) -> dict[str, Any]:
    """Parse ``name=source,...``: an integer source is an observation index, any other a Dict key.

    Example:
        >>> parse_signals("cos_th=0,th_dot=2")
        {'cos_th': 0, 'th_dot': 2}
    """
    signals: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, source = item.partition("=")
        if not sep or not name.strip() or not source.strip():
            raise ValueError(f"--signals expects name=index pairs separated by commas, got {item!r}")
        source = source.strip()
        signals[name.strip()] = int(source) if source.lstrip("-").isdigit() else source
    return signals


def parse_hyperparameters(extra: Sequence[str]) -> dict[str, Any]:
    """Turn ``--name value`` pairs into a dict (dashes in names become underscores).

    Example:
        >>> parse_hyperparameters(["--n-episodes", "20", "--epsilon", "1.5"])
        {'n_episodes': 20, 'epsilon': 1.5}
    """
    hyperparameters: dict[str, Any] = {}
    items = list(extra)
    while items:
        flag = items.pop(0)
        if not flag.startswith("--") or len(flag) < 3:
            raise ValueError(f"expected a hyperparameter --name value, got {flag!r}")
        name, sep, inline = flag[2:].partition("=")
        if sep:
            value = inline
        elif items and not items[0].startswith("--"):
            value = items.pop(0)
        else:
            raise ValueError(f"hyperparameter --{name} has no value")
        hyperparameters[name.replace("-", "_")] = parse_value(value)
    return hyperparameters


def hyperparameter_help() -> str:
    """The episodic agents' hyperparameters and defaults, read from their config dataclasses."""
    import dataclasses

    lines = ["hyperparameters (--name value):"]
    for name in EPISODIC_AGENTS:
        try:
            klass = agent_class(name)
        except ImportError:  # the TLPS module is optional until it exists
            continue
        config = klass._make_config({})
        fields = ", ".join(f"{f.name}={getattr(config, f.name)!r}" for f in dataclasses.fields(config))
        lines.append(f"  {name}: {fields}")
    lines.append("  stable-baselines3 agents: tl_reward='markov' (or 'terminal', the ablation), normalize, "
                 "hyperparams=true (agents/hyperparams/sb3.yml, or false, or a path), steps_per_iteration=8000, "
                 "n_envs, policy, n_timesteps, noise_type, noise_std, and the algorithm's own keywords "
                 "(learning_rate, batch_size, ...); unset ones come from the task's entry in the file")
    return "\n".join(lines)


def build_parser(with_hyperparameters: bool = False) -> argparse.ArgumentParser:
    """The ``tl-gym`` argument parser (``train`` and ``eval`` sub-commands).

    Args:
        with_hyperparameters: list every agent's hyperparameters in ``train --help`` (imports the agents).
    """
    parser = argparse.ArgumentParser(prog="tl-gym", description="Reinforcement learning with TLTL rewards.")
    commands = parser.add_subparsers(dest="command", required=True)

    train = commands.add_parser(
        "train", help="train an agent and write a run folder",
        description="Train an agent; unknown --name value options are the agent's hyperparameters.",
        epilog=hyperparameter_help() if with_hyperparameters else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    train.add_argument("--env", default="TLCarNav-v0", help="registered env id (default: TLCarNav-v0)")
    train.add_argument("--task", type=int, default=None, help="the car's task, 1 or 2 (env keyword `task`)")
    train.add_argument("--env-kwargs", type=json.loads, default={}, help="env keywords as JSON")
    train.add_argument("--spec", default=None, help="a TLTL formula to pay as reward instead of the env's own")
    train.add_argument("--signals", type=parse_signals, default=None,
                       help="with --spec: signal sources, e.g. cos_th=0,th_dot=2 (observation indices or Dict keys)")
    train.add_argument("--agent", default="tlps", help="tlps, reps or a stable-baselines3 algorithm (ppo, sac, ...)")
    train.add_argument("--iterations", type=int, default=None,
                       help="policy updates (default: 50; SB3 agents: the task's n_timesteps budget, else 50)")
    train.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    train.add_argument("--out", type=Path, required=True, help="run folder to write")
    train.add_argument("--snapshots", default=None,
                       help="iterations whose sampled trajectories are plotted, e.g. 1,10,30 (default: spread)")
    train.add_argument("--quiet", action="store_true", help="no progress bar")

    evaluate = commands.add_parser("eval", help="evaluate a trained run")
    evaluate.add_argument("run", type=Path, help="run folder written by `tl-gym train`")
    evaluate.add_argument("--episodes", type=int, default=100, help="fresh episodes (default: 100)")
    evaluate.add_argument("--seed", type=int, default=12345, help="seed of the first episode (default: 12345)")
    evaluate.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean")
    evaluate.add_argument("--gif", type=Path, default=None, help="also save a GIF of one episode here")
    return parser


# Building the env and the agent --------------------------------------------------------------------
def build_env(run: dict[str, Any], render_mode: str | None = None) -> Any:
    """The env of a run: its id (the agent adds the kwargs), or the env wrapped with ``--spec``.

    SB3 agents get the env keywords of their ``tl_reward`` (`tl_gym.agents.sb3.TL_REWARD_ENV_KWARGS`)
    here too, since they cannot rewrap an env object: with ``--spec`` they go to the wrapper, for a
    rendered env to the id (the run's own ``env_kwargs`` win, as in the agent).
    """
    import gymnasium as gym

    import tl_gym

    kwargs = dict(run["env_kwargs"])
    tl_kwargs = _tl_reward_env_kwargs(run)
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    if run.get("spec") is None:
        return run["env"] if render_mode is None else gym.make(run["env"], **{**tl_kwargs, **kwargs})
    if not run.get("signals"):
        raise ValueError("--spec needs --signals to say where each signal comes from, e.g. --signals cos_th=0")
    return tl_gym.TLTLRewardWrapper(gym.make(run["env"], **kwargs), run["spec"], run["signals"], **tl_kwargs)


def _tl_reward_env_kwargs(run: dict[str, Any]) -> dict[str, Any]:
    """The env keywords an SB3 run's ``tl_reward`` implies; none for TLPS and REPS."""
    if run["agent"].lower() in EPISODIC_AGENTS:
        return {}
    from tl_gym.agents.sb3 import DEFAULT_TL_REWARD, TL_REWARD_ENV_KWARGS, check_tl_reward

    return dict(TL_REWARD_ENV_KWARGS[check_tl_reward(run["hyperparameters"].get("tl_reward", DEFAULT_TL_REWARD))])


def agent_class(name: str) -> Any:
    """The agent class for a name: TLPS, REPS, else `SB3Agent` (imported only when needed)."""
    if name.lower() == "tlps":
        from tl_gym.agents.tlps import TLPS

        return TLPS
    if name.lower() == "reps":
        from tl_gym.agents import REPS

        return REPS
    from tl_gym.agents.sb3 import SB3Agent

    return SB3Agent


def make_agent(run: dict[str, Any]) -> Any:
    """Build the run's agent on its env."""
    env = build_env(run)
    env_kwargs = run["env_kwargs"] if isinstance(env, str) else None
    klass = agent_class(run["agent"])
    if run["agent"].lower() in EPISODIC_AGENTS:
        return klass(env, seed=run["seed"], env_kwargs=env_kwargs, **run["hyperparameters"])
    return klass(run["agent"], env, seed=run["seed"], env_kwargs=env_kwargs, **run["hyperparameters"])


def default_iterations(agent: Any) -> int:
    """Iterations when ``--iterations`` is not given: the task's ``n_timesteps`` budget for SB3 agents, else 50."""
    budget = getattr(agent, "n_timesteps", None)
    if budget is None:
        return 50
    return max(1, -(-int(budget) // int(agent.config.steps_per_iteration)))


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
    from tl_gym.agents.callbacks import as_callback
    from tl_gym.agents.evaluation import collect_episodes

    env_kwargs = dict(args.env_kwargs)
    if args.task is not None:
        env_kwargs["task"] = args.task
    if args.signals is not None and args.spec is None:
        raise ValueError("--signals only makes sense with --spec")
    run = {
        "env": args.env, "env_kwargs": env_kwargs, "spec": args.spec, "signals": args.signals,
        "agent": args.agent, "iterations": args.iterations, "seed": args.seed,
        "hyperparameters": parse_hyperparameters(extra),
    }
    if args.iterations is not None and args.iterations < 1:
        raise ValueError(f"--iterations must be >= 1, got {args.iterations}")
    agent = make_agent(run)
    run["iterations"] = iterations = default_iterations(agent) if args.iterations is None else args.iterations
    snapshots_at = (sorted({int(s) for s in args.snapshots.split(",")}) if args.snapshots
                    else default_snapshots(iterations))
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    (out / RUN_FILE).write_text(json.dumps(run, indent=1))

    n_samples = int(getattr(agent.config, "n_episodes", 40))
    snapshots: list[tuple[int, dict[str, Any]]] = []

    def record(agent: Any, row: dict[str, Any]) -> bool:
        if row["iteration"] in snapshots_at:
            # samples of the updated policy, on seeds the training never uses
            _, traces = collect_episodes(agent, agent.env, n_samples, seed=10**6 + row["iteration"])
            snapshots.append((row["iteration"], traces))
        return True

    agent.learn(iterations, callback=as_callback(record), progress_bar=not args.quiet)
    agent.save(out / AGENT_FILE)
    write_history(agent.history, out / "history.csv")
    write_plots(agent, run, snapshots, out)
    last = agent.history[-1]
    print(f"iteration {last['iteration']}: mean robustness {last['mean_robustness']:.4g}, "
          f"success rate {last['success_rate']:.1%}, {last['env_steps']} env steps, {last['wall_time']:.1f} s")
    print(f"wrote {out}/{{{RUN_FILE}, {AGENT_FILE}, history.csv, learning_curve.png, trajectories.png}}")
    return 0


def write_history(history: Sequence[dict[str, Any]], path: Path) -> None:
    """Write the history rows as CSV, columns in order of first appearance."""
    columns: dict[str, None] = {}
    for row in history:
        columns.update(dict.fromkeys(row))
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns))
        writer.writeheader()
        writer.writerows(history)


def write_plots(agent: Any, run: dict[str, Any], snapshots: list[tuple[int, dict[str, Any]]], out: Path) -> None:
    """Write ``learning_curve.png`` and ``trajectories.png`` for a finished run."""
    from tl_gym.agents.plotting import plot_learning_curve, plot_signals, plot_trajectories
    from tl_gym.agents.sampling import env_attribute

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


def evaluate(args: argparse.Namespace) -> int:
    """``tl-gym eval``: print the evaluation of a saved run, optionally save a GIF."""
    from tl_gym.agents import Agent

    run_file = args.run / RUN_FILE
    if not run_file.exists():
        raise FileNotFoundError(f"{run_file} not found: is {args.run} a folder written by `tl-gym train`?")
    run = json.loads(run_file.read_text())
    env = build_env(run)
    agent = Agent.load(args.run / AGENT_FILE, env=None if isinstance(env, str) else env)
    result = agent.evaluate(n_episodes=args.episodes, seed=args.seed, deterministic=not args.stochastic)
    print(f"{run['agent']} on {run['env']} {run['env_kwargs'] or ''}: {args.episodes} episodes, "
          f"mean robustness {result['mean_robustness']:.4g}, success rate {result['success_rate']:.1%}")
    if args.gif is not None:
        frames = record_episode(agent, build_env(run, render_mode="rgb_array"), seed=args.seed,
                                deterministic=not args.stochastic)
        save_gif(frames, args.gif)
        print(f"wrote {args.gif} ({len(frames)} frames)")
    return 0


def record_episode(agent: Any, env: Any, seed: int, deterministic: bool = True) -> list[Any]:
    """Frames of one episode of ``agent`` on a single env made with ``render_mode="rgb_array"``."""
    import numpy as np

    obs, _ = env.reset(seed=seed)
    frames = [env.render()]
    state, start = None, np.ones(1, dtype=bool)
    done = False
    while not done:
        action, state = agent.predict(np.asarray(obs)[None], state=state, episode_start=start,
                                      deterministic=deterministic)
        obs, _, terminated, truncated, _ = env.step(np.asarray(action)[0])
        start = np.zeros(1, dtype=bool)
        frames.append(env.render())
        done = terminated or truncated
    env.close()
    return frames


def save_gif(frames: Sequence[Any], path: Path, fps: int = 20) -> None:
    """Write RGB frames as a looping GIF (needs imageio: ``pip install tl_gym[render]``)."""
    try:
        import imageio.v3 as iio
    except ImportError:
        raise SystemExit("saving a GIF needs imageio: pip install 'tl_gym[render]'") from None
    import numpy as np

    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), duration=1000 / fps, loop=0)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tl-gym``; returns the exit status."""
    from tl_gym.errors import TLGymError

    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(with_hyperparameters=bool({"-h", "--help"} & set(argv)))
    args, extra = parser.parse_known_args(argv)
    if args.command != "train" and extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        if args.command == "train":
            return train(args, extra)
        return evaluate(args)
    except (TLGymError, ValueError, TypeError, FileNotFoundError, ImportError) as error:
        print(f"tl-gym {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
