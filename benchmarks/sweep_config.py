"""The experiment runner's configs: a TOML file expands into runs (task × agent × hyperparameters × seed).

`load_config` reads a config and `expand_config` checks every key, applies a variant and expands the agents' grids,
tasks and seeds into a `Sweep` of `RunSpec`s, in config order; a `ConfigError` names the file and the culprit. A
`RunSpec` is everything one run needs, in JSON values, and its hash names the run's folder (`RunSpec.run_id`).
Kept apart from the runs (`benchmarks.run_one`) and the sweep (`benchmarks.runner`), which take its specs as they
are: a config is checked whole, and names its runs, before anything trains. Config keys: ``docs/benchmarks.md``.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import itertools
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

#: Keys an agent entry inherits from the top level (a variant may override them at either level).
INHERITED = {"tasks": None, "seeds": None, "iterations": None, "evaluate_episodes": 0, "evaluate_every": 0,
             "trajectory_iterations": [], "trajectory_episodes": 40}
TOP_KEYS = {"name", "description", "env", "env_kwargs", "agents", "variants", *INHERITED}
AGENT_KEYS = {"label", "agent", "hyperparameters", "grid", "env_kwargs", "note", "variants", "skip", *INHERITED}
VARIANT_KEYS = TOP_KEYS - {"name", "variants", "agents"}


class ConfigError(ValueError):
    """A config that cannot be run; the message names the file and the culprit."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything that defines one training run, in JSON values (docs/benchmarks.md); a ``label``'s seeds: one curve."""

    env: str
    env_kwargs: Mapping[str, Any]
    agent: str
    label: str
    hyperparameters: Mapping[str, Any]
    seed: int
    iterations: int
    evaluate_episodes: int = 0
    evaluate_every: int = 0
    trajectory_iterations: Sequence[int] = ()
    trajectory_episodes: int = 40
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """The spec as a JSON-able dict (`from_json` inverts it)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunSpec:
        """Rebuild a spec from `to_json`'s output (or from the older sweep runner's, which had ``save_agent``)."""
        data = {key: value for key, value in data.items() if key != "save_agent"}
        return cls(**{**data, "trajectory_iterations": tuple(data.get("trajectory_iterations", ()))})

    @property
    def run_id(self) -> str:
        """Folder name: task, label and seed, plus a hash of the whole spec (a changed spec gets a new folder)."""
        digest = hashlib.sha256(json.dumps(self.to_json(), sort_keys=True).encode()).hexdigest()[:10]
        task = self.env_kwargs.get("task")
        slug = re.sub(r"[^A-Za-z0-9=.+-]+", "-", self.label.replace("β", "beta").replace("ε", "eps"))
        return f"{'' if task is None else f'task{task}__'}{slug.strip('-').lower() or 'run'}__seed{self.seed}__{digest}"


@dataclasses.dataclass(frozen=True)
class Sweep:
    """An expanded config: its name (``<name>[-<variant>]``) and its runs, in config order."""

    name: str
    description: str
    runs: tuple[RunSpec, ...]


def load_config(path: str | Path, variant: str | None = None, overrides: Mapping[str, Any] | None = None) -> Sweep:
    """Read a TOML config and expand it into runs (`expand_config`); a `ConfigError` names the file."""
    try:
        return expand_config(tomllib.loads(Path(path).read_text()), variant=variant, overrides=overrides)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"cannot read config {path}: {exc}") from exc
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def expand_config(data: Mapping[str, Any], variant: str | None = None,
                  overrides: Mapping[str, Any] | None = None) -> Sweep:
    """Expand a parsed config into its runs, checking every field first.

    ``variant`` applies ``[variants.<variant>]`` and each agent's ``variants.<variant>``; ``overrides`` are
    top-level keys set after it (e.g. ``{"seeds": 3}``). A `ConfigError` names the culprit.
    """
    _check_keys(data, TOP_KEYS, "top level")
    variants = _table(data.get("variants", {}), "variants")
    for name, table in variants.items():  # all checked, not only the one asked for
        _check_keys(table, VARIANT_KEYS, f"variants.{name}")
    if variant is not None and variant not in variants:
        raise ConfigError(f"no variant {variant!r}; the config has {sorted(variants)}")
    overrides = _check_keys(overrides or {}, VARIANT_KEYS, "overrides")
    top = {**INHERITED, "env_kwargs": {}, **data, **variants.get(variant, {}), **overrides}
    for key in ("name", "env"):
        if not isinstance(top.get(key), str) or not top[key]:
            raise ConfigError(f"'{key}' must be a non-empty string, got {top.get(key)!r}")
    if not isinstance(top.get("agents"), list) or not top["agents"]:
        raise ConfigError("no [[agents]] entries")
    _check_env(top["env"])
    runs: list[RunSpec] = []
    for index, entry in enumerate(top["agents"]):
        where = f"agents[{index}]"
        entry = _check_keys(entry, AGENT_KEYS, where)
        at = f"{where}.variants.{variant}"
        own_variants = _table(entry.get("variants", {}), f"{where}.variants")
        stray = sorted(set(own_variants) - set(variants))
        if stray:  # a variant no --variant can select: a misspelling, silently running the agent unchanged
            raise ConfigError(f"{where}.variants: {stray} is not a variant of the config ({sorted(variants)})")
        changes = _check_keys(own_variants.get(variant, {}), AGENT_KEYS, at)
        hyper = {**_table(entry.get("hyperparameters", {}), f"{where}.hyperparameters"),
                 **_table(changes.get("hyperparameters", {}), f"{at}.hyperparameters")}
        entry = {**entry, **changes, "hyperparameters": hyper}
        if not entry.get("skip", False):
            runs.extend(_expand_agent(entry, top, where))
    duplicates = sorted(i for i, count in collections.Counter(run.run_id for run in runs).items() if count > 1)
    if duplicates:
        raise ConfigError(f"the same run appears twice: {duplicates} (two agents with one label and hyperparameters?)")
    if not runs:
        raise ConfigError(f"variant {variant!r} skips every agent")
    return Sweep(top["name"] + (f"-{variant}" if variant else ""), str(top.get("description", "")), tuple(runs))


def _check_keys(table: Any, valid: set[str], where: str) -> dict[str, Any]:
    unknown = sorted(set(_table(table, where)) - valid)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; valid: {sorted(valid)}")
    return dict(table)


def _table(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where} must be a table, got {value!r}")
    return dict(value)


def _ints(value: Any, where: str, minimum: int) -> list[int]:
    if not isinstance(value, list) or not value or not all(
            isinstance(v, int) and not isinstance(v, bool) and v >= minimum for v in value):
        raise ConfigError(f"{where} must be a non-empty list of ints >= {minimum}, got {value!r}")
    return value


def _budget(value: Any, task: int | None, where: str) -> int:
    """An ``iterations`` value: an int, or a table by task (``{ 1 = 30, 2 = 50 }``)."""
    if isinstance(value, Mapping):
        value = value.get(str(task))
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"{where}: iterations must be an int >= 1 (or a table of them by task), got {value!r}"
                          + (f" for task {task}" if task is not None else ""))
    return value


def _check_agent(name: Any, where: str) -> str:
    from tl_gym.agents.registry import check_agent_name, is_known_agent, unknown_agent_message

    try:
        check_agent_name(name)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if not is_known_agent(name):
        raise ConfigError(f"{where}: {unknown_agent_message(name)}")
    return name


def _check_hyperparameters(agent: str, values: Mapping[str, Any], where: str) -> None:
    """The agent's own check of its hyperparameters, without an env (`tl_gym.agents.registry.check_hyperparameters`)."""
    from tl_gym.agents.registry import check_hyperparameters

    try:
        check_hyperparameters(agent, values)
    except ImportError:  # an SB3 name without stable-baselines3 here (a config read to report): its worker will say
        return
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{where}.hyperparameters {values}: {exc}") from None


def _check_env(env_id: str) -> None:
    """A registered id (Gymnasium's ``module:EnvId`` form too), checked before any run starts."""
    import gymnasium as gym
    from tl_gym.agents.env_ids import registered_spec

    try:
        registered_spec(env_id)
    except (gym.error.Error, ImportError) as exc:
        raise ConfigError(f"env {env_id!r}: {exc}") from None


def _expand_agent(entry: dict[str, Any], top: Mapping[str, Any], where: str) -> list[RunSpec]:
    settings = {key: entry.get(key, top.get(key)) for key in INHERITED}
    agent = _check_agent(entry.get("agent"), f"{where}.agent")
    label = entry.get("label", agent)
    grid = _table(entry.get("grid", {}), f"{where}.grid")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{where}.grid.{key} must be a non-empty list, got {values!r}")
    env_kwargs = {**_table(top["env_kwargs"], "env_kwargs"),
                  **_table(entry.get("env_kwargs", {}), f"{where}.env_kwargs")}
    tasks = [None] if settings["tasks"] is None else _ints(settings["tasks"], f"{where}.tasks", 1)
    seeds = settings["seeds"]
    if isinstance(seeds, int) and not isinstance(seeds, bool) and seeds >= 1:
        seeds = list(range(seeds))  # seeds = 5 means seeds 0..4
    seeds = _ints(seeds, f"{where}.seeds", 0)
    trajectory_iterations = settings["trajectory_iterations"] or []
    if trajectory_iterations:
        _ints(trajectory_iterations, f"{where}.trajectory_iterations", 0)
    for key, minimum in (("evaluate_episodes", 0), ("evaluate_every", 0), ("trajectory_episodes", 1)):
        _ints([settings[key]], f"{where}.{key}", minimum)  # before a worker meets them, hours into a sweep
    if not isinstance(entry.get("note", ""), str):
        raise ConfigError(f"{where}.note must be a string, got {entry['note']!r}")
    runs = []
    for combo in itertools.product(*grid.values()):
        values = {**entry["hyperparameters"], **dict(zip(grid, combo))}
        _check_hyperparameters(agent, values, where)
        try:
            run_label = label.format(**values)
        except (KeyError, IndexError, ValueError) as exc:
            raise ConfigError(f"{where}.label {label!r} cannot be filled from {values}: {exc}") from None
        for task in tasks:
            # an agent's own budget can only lower the config's (e.g. SAC), so a variant's cap holds for all
            iterations = min(_budget(settings["iterations"], task, where),
                             _budget(top["iterations"], task, "top level"))
            for seed in seeds:
                runs.append(RunSpec(
                    env=top["env"], env_kwargs=env_kwargs if task is None else {**env_kwargs, "task": task},
                    agent=agent, label=run_label, hyperparameters=values, seed=seed, iterations=iterations,
                    evaluate_episodes=int(settings["evaluate_episodes"]),
                    evaluate_every=int(settings["evaluate_every"]),
                    trajectory_iterations=tuple(t for t in trajectory_iterations if t <= iterations),
                    trajectory_episodes=int(settings["trajectory_episodes"]), note=str(entry.get("note", "")),
                ))
    return runs
