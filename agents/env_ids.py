"""Env ids and copies: what a user hands an agent (an id, an `Env`, a `VectorEnv`) made into a `VectorEnv`.

`make_vector_env` turns an env id into the env's own batched simulator (its ``vector_entry_point``, one numpy
call per step for all cars) rather than `SyncVectorEnv`; an `Env` object is copied (`env_copies`). Also the
registry lookups that the agents' messages and the benchmark configs read (`registered_spec`, `env_keywords`).
"""

from __future__ import annotations

import copy
import importlib
import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator

from tl_gym.tltl.ast import Formula

from .horizon import env_attribute


def registered_spec(env_id: str) -> gym.envs.registration.EnvSpec:
    """`gymnasium.spec` of an env id, Gymnasium's ``"module:EnvId"`` form included.

    As `gymnasium.make` does, the module is imported first (it registers the id), so that an agent,
    a run config or ``tl-gym train --env`` takes the ids ``gym.make`` takes.

    Example:
        >>> registered_spec("gymnasium.envs.classic_control:Pendulum-v1").id
        'Pendulum-v1'
    """
    module, _, name = env_id.rpartition(":")  # Gymnasium's ids hold no ":" themselves
    if module:
        importlib.import_module(module)
    return gym.spec(name)


def env_keywords(env_id: str) -> frozenset[str]:
    """The keywords ``gym.make(env_id, ...)`` takes by name; empty when the id is unknown or they cannot be read.

    The entry point's named parameters, and for one that takes ``**kwargs`` the names its ``env_keywords()``
    attribute lists (tl_gym's ids declare theirs; one that lists none takes keywords that cannot be read: empty).
    For the messages that tell an env keyword given to an agent, and the CLI's ``--task``.

    Example:
        >>> sorted(env_keywords("Pendulum-v1"))
        ['g', 'render_mode']
    """
    try:
        spec = registered_spec(env_id)
        creator = load_env_creator(spec.entry_point) if isinstance(spec.entry_point, str) else spec.entry_point
        parameters = inspect.signature(creator).parameters
    except (gym.error.Error, ImportError, AttributeError, TypeError, ValueError):
        return frozenset()
    named = {name for name, p in parameters.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    declared = getattr(creator, "env_keywords", None)
    if declared is None and any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
        return frozenset()  # **kwargs it does not list: which keywords it takes cannot be read
    return frozenset(named | set(declared() if declared is not None else ()))


def env_keyword_hint(env: Any, names: Iterable[str], hyperparameters: Mapping[str, Any]) -> str:
    """``"; 'task' is a keyword of the env TLCarNav-v0: pass env_kwargs={'task': 2}"`` for ``names`` the env takes.

    ``""`` when ``env`` is not an id or takes none of them. Agents add it to the error of a hyperparameter they do
    not have, the usual slip being an env keyword given to the agent.
    """
    if not isinstance(env, str):
        return ""
    keywords = env_keywords(env)
    taken = [name for name in names if name in keywords]
    if not taken:
        return ""
    which = ", ".join(map(repr, taken))
    kwargs = "{" + ", ".join(f"{name!r}: {hyperparameters[name]!r}" for name in taken) + "}"
    return (f"; {which} {'is a keyword' if len(taken) == 1 else 'are keywords'} of the env {env}, not of the agent: "
            f"pass env_kwargs={kwargs}")


def unqualified_id(env_id: str) -> str:
    """``EnvId`` of an id in Gymnasium's ``"module:EnvId"`` form, the id itself otherwise (`registered_spec`'s name).

    Example:
        >>> unqualified_id("my_tasks:SwingUp-v0"), unqualified_id("Pendulum-v1")
        ('SwingUp-v0', 'Pendulum-v1')
    """
    return env_id.rpartition(":")[2]


def make_vector_env(env: Any, num_envs: int, env_kwargs: Mapping[str, Any] | None = None) -> gym.vector.VectorEnv:
    """Build a vector env of ``num_envs`` copies of ``env``.

    Args:
        env: an env id (``"TLCarNav-v0"``), an `Env` (copied, `env_copies`) or a `VectorEnv`
            (returned as is).
        num_envs: number of parallel envs wanted.
        env_kwargs: keyword arguments for the env constructor (env ids only).

    Raises:
        TypeError: ``env`` is none of the above, or ``env_kwargs`` come with an env object.
    """
    env_kwargs = dict(env_kwargs or {})
    if isinstance(env, gym.vector.VectorEnv):
        if env_kwargs:
            raise TypeError("env_kwargs can only be used with an env id, not with a VectorEnv")
        return env
    if isinstance(env, str):
        spec = registered_spec(env)
        mode = "vector_entry_point" if spec.vector_entry_point is not None else "sync"
        return gym.make_vec(env, num_envs=num_envs, vectorization_mode=mode, **env_kwargs)
    if isinstance(env, gym.Env):  # copied: only an id gets the batched simulator of its vector_entry_point
        if env_kwargs:
            raise TypeError("env_kwargs can only be used with an env id, not with an Env object")
        return gym.vector.SyncVectorEnv(env_copies(env, num_envs))
    raise TypeError(f"env must be an env id, a gymnasium Env or a VectorEnv, got {type(env).__name__}")


def env_copies(env: gym.Env, n: int) -> list[Callable[[], gym.Env]]:
    """Constructors of ``n`` copies of the env object ``env``, for the agents' vector envs.

    Copies (`copy.deepcopy`), so that what was set after ``gym.make`` stays (``env.unwrapped.configure(...)``
    of highway-env, an attribute changed by hand), as SB3 keeps the env object it is given; the user's env
    itself is not stepped. Each copy's random generator is drawn afresh: copies of an env that was seeded would
    otherwise share its stream, and their unseeded resets (an SB3 agent without seed) would play one episode
    ``n`` times. An env that cannot be copied (a live render window) is rebuilt from its spec.

    Raises:
        TypeError: the env can be neither copied nor rebuilt (naming both reasons).
    """
    try:
        copies = [copy.deepcopy(env) for _ in range(n)]
    except Exception as copy_error:  # noqa: BLE001 - any failure of a user's env to copy: try its spec
        if env.spec is None:
            raise TypeError(f"the env cannot be copied ({copy_error!r}) and has no spec to rebuild it from: "
                            "pass an env id or a factory-registered id instead") from copy_error
        try:
            gym.make(env.spec).close()
        except Exception as make_error:  # noqa: BLE001
            raise TypeError(f"the env can neither be copied ({copy_error!r}) nor rebuilt from its spec "
                            f"({make_error!r})") from make_error
        spec = env.spec
        return [lambda: gym.make(spec) for _ in range(n)]
    for duplicate in copies:
        duplicate.unwrapped.np_random = np.random.default_rng()  # fresh entropy; a seeded reset still decides
    return [lambda e=e: e for e in copies]


def find_formula(venv: gym.vector.VectorEnv) -> Formula:
    """The TLTL formula the env pays as reward (its ``formula`` attribute).

    Raises:
        TypeError: the env exposes no formula; wrap it in `tl_gym.TLTLRewardWrapper`.
    """
    formula = env_attribute(venv, "formula")
    if not isinstance(formula, Formula):
        raise TypeError(
            "the env has no `formula`: wrap it in tl_gym.TLTLRewardWrapper(env, spec, signals) "
            "so that agents can read the TLTL robustness"
        )
    return formula
