"""The one table of agents by name, read by the command line, `Agent.load` and the benchmarks.

A name is ``"tlps"``, ``"reps"``, a stable-baselines3 / sb3-contrib algorithm (``"ppo"``,
``"sac"``, ``"td3"``, ..., case-insensitive; trained through `SB3Agent`) or
``"package.module:Name"`` for an agent of your own (a class or factory with the agents'
signature ``f(env, *, seed, env_kwargs, **hyperparameters)``). Every agent takes the env
first: ``make_agent("ppo", env, seed=0)`` is ``SB3Agent(env, "ppo", seed=0)``.

Example:
    >>> from tl_gym.agents.registry import agent_class, is_episodic
    >>> agent_class("tlps").__name__, is_episodic("tlps"), is_episodic("ppo")
    ('TLPS', True, False)
    >>> agent_class("PPO").__name__
    'SB3Agent'
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from tl_gym.checks import did_you_mean

from .sb3_settings import (
    REFUSED_ALGORITHMS,
    SB3_ALGORITHMS,
    SB3_CONTRIB_ALGORITHMS,
    check_sb3_hyperparameters,
    resolve_algorithm,
)

#: The episodic agents by name -> "module:class"; any other plain name is an SB3 algorithm.
EPISODIC_AGENTS = {"tlps": "tl_gym.agents.tlps:TLPS", "reps": "tl_gym.agents.reps:REPS"}
#: The adapter every SB3 algorithm name is trained through.
SB3_AGENT = "tl_gym.agents.sb3:SB3Agent"


def is_known_agent(name: str) -> bool:
    """Whether ``name`` names an agent without importing anything: episodic, SB3, sb3-contrib or ``module:Name``.

    Example:
        >>> is_known_agent("TLPS"), is_known_agent("tqc"), is_known_agent("my.module:Agent"), is_known_agent("dqn2")
        (True, True, True, False)
    """
    return ":" in name or is_episodic(name) or name.lower() in SB3_ALGORITHMS + SB3_CONTRIB_ALGORITHMS


def check_agent_name(name: Any) -> str:
    """Check a name's form without importing anything; return it.

    Raises:
        ValueError: not a non-empty string, or ``"sb3"`` alone (which algorithm?).
    """
    if not isinstance(name, str) or not name.strip(": "):
        raise ValueError(f"an agent name must be a non-empty string, got {name!r}")
    if name.lower() == "sb3" or name.lower().startswith("sb3:"):
        raise ValueError(f"agent {name!r}: name the stable-baselines3 algorithm itself, e.g. 'ppo' or 'sac'")
    return name


def check_sb3_name(name: str) -> None:
    """Check that a name that is not an episodic agent's names a stable-baselines3 / sb3-contrib algorithm.

    The error lists every kind of name an agent takes, not only SB3's (``tl-gym train --agent``
    reads it), with the nearest known name when there is one.

    Raises:
        ValueError: no algorithm has that name.

    Example:
        >>> check_sb3_name("sca")
        Traceback (most recent call last):
        ...
        ValueError: unknown agent 'sca' (did you mean 'sac'?): tlps, reps, a stable-baselines3 algorithm ...
    """
    try:
        resolve_algorithm(name)
    except ValueError as exc:
        if name.lower() in SB3_CONTRIB_ALGORITHMS:  # known, but sb3-contrib does not import: its message says why
            raise
        raise ValueError(unknown_agent_message(name)) from exc


def unknown_agent_message(name: str) -> str:
    """What an unknown agent name is told: the nearest known name and every kind of name an agent takes."""
    refused = {algo.lower() for algo in REFUSED_ALGORITHMS}
    contrib = [algo for algo in SB3_CONTRIB_ALGORITHMS if algo not in refused]
    hint = did_you_mean(name.lower(), (*EPISODIC_AGENTS, *SB3_ALGORITHMS, *contrib))
    return (f"unknown agent {name!r}{hint}: {', '.join(EPISODIC_AGENTS)}, a stable-baselines3 algorithm "
            f"({', '.join(SB3_ALGORITHMS)}), an sb3-contrib one ({', '.join(contrib)}) or 'package.module:Name'")


def is_episodic(name: str) -> bool:
    """Whether ``name`` is one of the episodic agents (TLPS, REPS) rather than an SB3 algorithm."""
    return name.lower() in EPISODIC_AGENTS


def is_sb3(name: str) -> bool:
    """Whether ``name`` names an SB3 / sb3-contrib algorithm (not TLPS/REPS, not a ``module:Class`` agent)."""
    return ":" not in name and not is_episodic(name)


def _import(target: str) -> Any:
    module_name, _, attribute = target.partition(":")
    module = importlib.import_module(module_name)
    try:
        return getattr(module, attribute)
    except AttributeError as exc:
        raise ImportError(f"agent {target!r}: module {module_name!r} has no {attribute!r}") from exc


def agent_class(name: str) -> Any:
    """The class (or factory) a name stands for: TLPS, REPS, `SB3Agent` or your ``module:Name``.

    Raises:
        ValueError: a malformed name.
        ImportError: its module is missing (e.g. stable-baselines3 for an SB3 name).
    """
    check_agent_name(name)
    if ":" in name:
        return _import(name)
    return _import(EPISODIC_AGENTS.get(name.lower(), SB3_AGENT))


def check_hyperparameters(name: str, hyperparameters: Mapping[str, Any]) -> None:
    """Check the hyperparameters of agent ``name`` without building an env (a run config, before any run starts).

    TLPS and REPS check their config dataclass; an SB3 algorithm its settings and arguments
    (`tl_gym.agents.sb3_settings.check_sb3_hyperparameters`). A ``module:Name`` agent is left to its own
    constructor (it may take what its base class does not, as an `SB3Agent` subclass fixing its algorithm).
    The messages are the agents' own.

    Raises:
        ValueError, TypeError: a hyperparameter the agent does not take, or a bad value.
        ImportError: an SB3 name without stable-baselines3 installed.
    """
    if ":" in name:
        return
    if is_episodic(name):
        agent_class(name)._make_config(dict(hyperparameters))
    else:
        check_sb3_hyperparameters(name, hyperparameters)


def make_agent(name: str, env: Any, *, seed: int | None = None, env_kwargs: Mapping[str, Any] | None = None,
               **hyperparameters: Any) -> Any:
    """Build the agent ``name`` on ``env``: the one constructor the CLI and the benchmarks call.

    Raises:
        ValueError: an unknown SB3 algorithm or a bad hyperparameter (the agent's own message).
    """
    klass = agent_class(name)
    if is_sb3(name):
        check_sb3_name(name)
        return klass(env, name, seed=seed, env_kwargs=env_kwargs, **hyperparameters)
    return klass(env, seed=seed, env_kwargs=env_kwargs, **hyperparameters)


def saved_class(class_name: str) -> type:
    """The agent class a saved file names (`Agent.load`): one of the library's own.

    Raises:
        LookupError: no agent class of the library has that name.
    """
    targets = (*EPISODIC_AGENTS.values(), SB3_AGENT)
    for target in targets:
        if target.endswith(f":{class_name}"):
            try:
                return _import(target)
            except ImportError as exc:
                raise LookupError(f"agent class {class_name!r} needs a missing package: {exc}") from exc
    raise LookupError(f"unknown agent class {class_name!r}; the library's are "
                      f"{[t.partition(':')[2] for t in targets]}")
