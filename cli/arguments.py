"""The ``tl-gym`` command line's arguments: the parser, and reading ``--name value`` options."""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tl_gym.agents.registry import EPISODIC_AGENTS, agent_class


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


_KEY_INDEX = re.compile(r"(?P<key>[^\[\]]+)\[(?P<index>-?\d+)\]")


def parse_signals(text: str) -> dict[str, Any]:
    """Parse ``name=source,...``: an index, ``key[i]`` (the wrapper's ``(key, i)``) or a Dict key.

    An integer is an observation index, ``key[i]`` element ``i`` of a Dict key's array, any other
    text a Dict key holding one number.

    Raises ``argparse.ArgumentTypeError``, which argparse reports as ``argument --signals: ...``.

    Example:
        >>> parse_signals("cos_th=0,th_dot=2")
        {'cos_th': 0, 'th_dot': 2}
        >>> parse_signals("x=observation[0],gx=desired_goal[-5],mode=mode")
        {'x': ('observation', 0), 'gx': ('desired_goal', -5), 'mode': 'mode'}
    """
    signals: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, source = item.partition("=")
        if not sep or not name.strip() or not source.strip():
            raise argparse.ArgumentTypeError(f"expects name=source pairs separated by commas, such as "
                                             f"cos_th=0,th_dot=2 (an index, a Dict key, or key[i] for an element "
                                             f"of a Dict key's array), got {item!r}")
        source = source.strip()
        element = _KEY_INDEX.fullmatch(source)
        if element is not None:
            signals[name.strip()] = (element["key"].strip(), int(element["index"]))
        elif "[" in source or "]" in source:
            raise argparse.ArgumentTypeError(f"signal {name.strip()!r}: {source!r} is neither a key nor key[i] "
                                             "(one integer index in brackets, such as observation[0])")
        else:
            signals[name.strip()] = int(source) if source.lstrip("-").isdigit() else source
    return signals


def parse_env_kwargs(text: str) -> dict[str, Any]:
    """Read ``--env-kwargs``: a JSON object of env keywords (a list or a number is no set of keywords).

    Raises ``argparse.ArgumentTypeError``, which argparse reports as ``argument --env-kwargs: ...``.

    Example:
        >>> parse_env_kwargs('{"no_revisit": "strict", "horizon": 100}')
        {'no_revisit': 'strict', 'horizon': 100}
    """
    try:
        value = json.loads(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"not valid JSON ({error}): {text!r}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object of env keywords, such as '{{\"task\": 2}}', "
                                         f"got {text!r}")
    return value


def parse_snapshots(text: str) -> list[int]:
    """Read ``--snapshots``: iterations (>= 1) separated by commas, sorted and without repeats.

    Example:
        >>> parse_snapshots("30,1,10,10")
        [1, 10, 30]
    """
    try:
        picks = sorted({int(part) for part in text.split(",") if part.strip()})
    except ValueError:
        picks = []
    if not picks or picks[0] < 1:
        raise argparse.ArgumentTypeError(f"expects iterations >= 1 separated by commas, such as 1,10,30, got {text!r}")
    return picks


def parse_seed(text: str) -> int:
    """``--seed``: an int >= 0, as numpy's seeding takes (it said "expected non-negative integer", naming no flag).

    Example:
        >>> parse_seed("7")
        7
    """
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expects an int >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expects an int >= 0, got {value}")
    return value


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
    lines = ["hyperparameters (--name value):"]
    for name in EPISODIC_AGENTS:
        config = agent_class(name)._make_config({})
        fields = ", ".join(f"{f.name}={getattr(config, f.name)!r}" for f in dataclasses.fields(config))
        lines.append(f"  {name}: {fields}")
    lines.append("  stable-baselines3 agents: tl_reward='markov' (or 'terminal', the ablation), normalize, "
                 "hyperparams=true (agents/hyperparams/sb3.yml, or false, or a path), steps_per_iteration=8000, "
                 "n_envs, policy, n_timesteps, noise_type, noise_std, her_goals=0 (off-policy, goal-conditioned envs: "
                 "relabelled copies of each episode), and the algorithm's own keywords "
                 "(learning_rate, batch_size, ...); unset ones come from the task's entry in the file, whose "
                 "markov_env_kwargs add the task's shaping to tl_reward='markov' (--env-kwargs win)")
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
    train.add_argument("--env-kwargs", type=parse_env_kwargs, default={}, help="env keywords as a JSON object")
    train.add_argument("--spec", default=None, help="a TLTL formula to pay as reward instead of the env's own")
    train.add_argument("--signals", type=parse_signals, default=None,
                       help="with --spec: signal sources, e.g. cos_th=0,th_dot=2 (observation indices), speed=speed "
                            "(a Dict key) or x=observation[0] (an element of a Dict key's array)")
    train.add_argument("--wrapper-kwargs", type=parse_env_kwargs, default={},
                       help="with --spec: TLTLRewardWrapper keywords as a JSON object, e.g. "
                            "'{\"reward_mode\": \"dense\", \"satisfaction_bonus\": 5}'")
    train.add_argument("--agent", default="tlps",
                       help="tlps, reps, a stable-baselines3 or sb3-contrib algorithm (ppo, sac, td3, tqc, ...), "
                            "or package.module:Name of an agent class")
    train.add_argument("--iterations", type=int, default=None,
                       help="policy updates (default: 50; SB3 agents: the task's n_timesteps budget rounded up to "
                            "whole iterations of steps_per_iteration, else 50)")
    train.add_argument("--seed", type=parse_seed, default=0, help="random seed, >= 0 (default: 0)")
    train.add_argument("--out", type=Path, required=True, help="run folder to write")
    train.add_argument("--snapshots", type=parse_snapshots, default=None,
                       help="iterations whose sampled trajectories are plotted, e.g. 1,10,30 (default: spread)")
    train.add_argument("--quiet", action="store_true",
                       help="no progress bar, and no line saying the env keywords the agent trains with")
    train.add_argument("--eval-every", type=int, default=None, metavar="N",
                       help="every N iterations, evaluate the deterministic policy and keep the best agent as "
                            "best_agent.zip (rl-baselines3-zoo's --eval-freq and best_model.zip)")
    train.add_argument("--eval-episodes", type=int, default=100, help="episodes of each --eval-every evaluation")

    evaluate = commands.add_parser("eval", help="evaluate a trained run")
    evaluate.add_argument("run", type=Path, help="run folder written by `tl-gym train`")
    evaluate.add_argument("--episodes", type=int, default=100, help="fresh episodes (default: 100)")
    evaluate.add_argument("--seed", type=parse_seed, default=12345, help="seed of the first episode (default: 12345)")
    evaluate.add_argument("--stochastic", action="store_true", help="sample actions instead of the mean")
    evaluate.add_argument("--gif", type=Path, default=None, help="also save a GIF of one episode here")
    evaluate.add_argument("--best", action="store_true", help="the run's best_agent.zip (train --eval-every)")
    evaluate.add_argument("--why", action="store_true",
                          help="also print each top-level conjunct's robustness: how often it broke, and how often "
                               "it was the lowest in a failed episode")
    return parser
