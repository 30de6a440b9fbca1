"""The interface every tl_gym agent implements, and the parts written once for all.

`Agent` is abstract (the abstract/final pattern): TLPS, REPS and SB3Agent are
final subclasses that fill a few hooks. The base owns

- building the batched env from an id, an `Env` or a `VectorEnv`, and finding the formula;
- validating hyperparameters at construction (each agent's config dataclass);
- the training loop `learn`, its progress bar, history and callbacks;
- `evaluate` (through the free function `evaluate_policy`), `save` and `load`.

A subclass names its `config_class` and implements `_num_envs`, `_setup`, `_update` (one policy
update; it returns that iteration's statistics), `predict`, `_config`,
`_state_arrays`, `_extra_files` and `_load_state`.
"""

from __future__ import annotations

import abc
import dataclasses
import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import tl_gym
from tl_gym.checks import check_count
from tl_gym.errors import IncompatibleSaveError

from .callbacks import CallbackLike, as_callback
from .env_ids import env_keyword_hint, find_formula, make_vector_env, registered_spec
from .evaluation import evaluate_policy
from .horizon import check_time_limits
from .registry import saved_class
from .serialization import (
    FORMAT_VERSION,
    check_arrays,
    describe_space,
    is_jsonable,
    read_archive,
    to_json,
    write_archive,
)

AgentT = TypeVar("AgentT", bound="Agent")

# keys make_vec adds to a vector env's spec kwargs; they are not env constructor arguments
_VECTOR_KEYS = ("num_envs", "vectorization_mode", "vector_kwargs", "wrappers")


def build_config(config_class: type, hyperparameters: Mapping[str, Any], agent: str) -> Any:
    """Instantiate an agent's config dataclass, naming unknown hyperparameters clearly.

    Raises:
        TypeError: a hyperparameter the agent does not have (the message lists the valid ones).
    """
    names = [f.name for f in dataclasses.fields(config_class)]
    unknown = sorted(set(hyperparameters) - set(names))
    if unknown:
        raise TypeError(f"{agent} has no hyperparameter(s) {unknown}; valid ones: {names}")
    return config_class(**hyperparameters)


def check_episodic(n_episodes: Any, horizon: Any) -> None:
    """Validate the batch size ``N`` and the horizon ``T`` shared by the episodic agents.

    Raises:
        ValueError: ``N < 2`` (a weighted fit needs two episodes) or ``T < 1``.
    """
    if not isinstance(n_episodes, (int, np.integer)) or n_episodes < 2:
        raise ValueError(f"n_episodes must be an int >= 2 (weights need several episodes), got {n_episodes!r}")
    check_count("horizon", horizon, allow_none=True)


class Agent(abc.ABC):
    """Abstract base of the agents: learn from a TLTL-rewarded env, act, evaluate, save.

    Args:
        env: an env id (``"TLCarNav-v0"``), a Gymnasium `Env` or a `VectorEnv`, wrapped so that it
            exposes ``formula`` and reports ``info["robustness"]`` at episode end
            (`tl_gym.TLTLRewardWrapper`; the car env is wrapped already). Episodes are sampled
            batched: an id from its ``vector_entry_point`` when it has one, else a `SyncVectorEnv`; an `Env`
            object in a `SyncVectorEnv` of copies of it (`agents.env_ids.env_copies`).
        seed: seed of every random choice the agent makes; same seed, same results.
        env_kwargs: keyword arguments for the env constructor when ``env`` is an id.
        **hyperparameters: the agent's hyperparameters (see its config class); checked here.

    Attributes:
        config: the validated hyperparameters (a dataclass).
        env: the vector env episodes are sampled from.
        formula: the env's TLTL formula.
        history: one dict per update: ``iteration``, ``env_steps``, ``mean_robustness``, ``success_rate``,
            ``wall_time``, then the agent's own keys.
    """

    def __init__(self, env: Any, *, seed: int | None = None, env_kwargs: Mapping[str, Any] | None = None,
                 **hyperparameters: Any):
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seed must be an int or None, got {seed!r}")
        self.config = self._config_for(env, dict(hyperparameters))
        self.seed = None if seed is None else int(seed)
        self.env_kwargs = dict(env_kwargs or {})
        self._env_source = describe_env_source(env, self.env_kwargs)
        self.env: gym.vector.VectorEnv = make_vector_env(env, self._num_envs(), self.env_kwargs)
        self.formula = find_formula(self.env)
        check_time_limits(self.env)
        self.observation_space = self.env.single_observation_space
        self.action_space = self.env.single_action_space
        self.history: list[dict[str, Any]] = []
        self.num_iterations = 0
        self.env_steps = 0
        self.rng = np.random.default_rng(self.seed)
        self._predict_rng = np.random.default_rng(None if self.seed is None else [self.seed, 1])
        self._setup()

    # Hooks -------------------------------------------------------------------------
    #: The agent's hyperparameter dataclass; it validates the values in ``__post_init__``.
    config_class: type

    @classmethod
    def _config_for(cls, env: Any, hyperparameters: dict[str, Any], given: Mapping[str, Any] | None = None) -> Any:
        """`_make_config`, its error saying which hyperparameters are ``env``'s keywords (`env_keyword_hint`).

        ``given``: the hyperparameters as the user named them, if ``hyperparameters`` regroups them.
        """
        try:
            return cls._make_config(hyperparameters)
        except (TypeError, ValueError) as error:
            given = hyperparameters if given is None else given
            named = [name for name in given if repr(name) in str(error)]
            hint = env_keyword_hint(env, named, given)
            if not hint:
                raise
            raise type(error)(f"{error}{hint}") from None

    @classmethod
    def _make_config(cls, hyperparameters: dict[str, Any]) -> Any:
        """Validate the hyperparameters and return the agent's config; raise on bad values (`build_config`)."""
        return build_config(cls.config_class, hyperparameters, cls.__name__)

    @abc.abstractmethod
    def _num_envs(self) -> int:
        """How many envs the batched env should run (from ``self.config``)."""

    @abc.abstractmethod
    def _setup(self) -> None:
        """Build the policy (or model) once ``env``, ``formula`` and the spaces are known."""

    @abc.abstractmethod
    def _update(self, iteration: int) -> dict[str, Any]:
        """One policy update; ``iteration`` counts from 1.

        Returns:
            The iteration's statistics: ``env_steps`` (steps taken in this iteration),
            ``mean_robustness`` and ``success_rate`` over the episodes it sampled, plus
            agent-specific keys (plain floats / ints).
        """

    @abc.abstractmethod
    def predict(
        self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        """Actions for one observation or a batch, stable-baselines3's signature.

        Time-varying policies keep each row's time index in ``state``; rows where
        ``episode_start`` is true restart at time 0.

        Returns:
            ``(action, state)``, the next state to pass back in.
        """

    @abc.abstractmethod
    def _config(self) -> dict[str, Any]:
        """JSON-able keyword arguments that rebuild this agent (hyperparameters) on load."""

    @abc.abstractmethod
    def _state_arrays(self) -> dict[str, np.ndarray]:
        """The learned arrays by name; on load, the saved ones must match these shapes."""

    @abc.abstractmethod
    def _extra_files(self) -> dict[str, bytes]:
        """Extra archive members (e.g. an embedded SB3 model); empty for most agents."""

    @abc.abstractmethod
    def _load_state(self, arrays: dict[str, np.ndarray], files: dict[str, bytes]) -> None:
        """Restore the learned state from checked arrays and the extra members."""

    # Training ----------------------------------------------------------------------
    def learn(self: AgentT, iterations: int, callback: CallbackLike = None, progress_bar: bool = False) -> AgentT:
        """Run ``iterations`` policy updates, appending one history row per update.

        Args:
            iterations: number of updates (>= 0); calling again continues where it stopped.
            callback: an `AbstractCallback`, a function ``f(agent, row)`` or a list of them;
                training stops after the update for which one returns ``False``.
            progress_bar: show a tqdm bar with the latest mean robustness and success rate.

        Returns:
            The agent, so that ``Agent(env).learn(50)`` chains.

        Raises:
            ValueError: ``iterations`` is not an int >= 0.
            TypeError: ``callback`` is none of the accepted kinds.
            EpisodeError: an episode outlived the horizon, or the env reports no robustness.
        """
        if not isinstance(iterations, (int, np.integer)) or iterations < 0:
            raise ValueError(f"iterations must be a non-negative int, got {iterations!r}")
        hook = as_callback(callback)
        elapsed = self.history[-1]["wall_time"] if self.history else 0.0
        with tqdm(total=int(iterations), disable=not progress_bar, desc=type(self).__name__,
                  unit="it", dynamic_ncols=True) as bar:
            for _ in range(int(iterations)):
                start = time.perf_counter()
                stats = dict(self._update(self.num_iterations + 1))
                elapsed += time.perf_counter() - start
                missing = [k for k in ("env_steps", "mean_robustness", "success_rate") if k not in stats]
                if missing:
                    raise RuntimeError(f"{type(self).__name__}._update returned no {missing}")
                self.num_iterations += 1
                self.env_steps += int(stats.pop("env_steps"))
                row = {
                    "iteration": self.num_iterations,
                    "env_steps": self.env_steps,
                    "mean_robustness": float(stats.pop("mean_robustness")),
                    "success_rate": float(stats.pop("success_rate")),
                    "wall_time": elapsed,
                    **to_json(stats),
                }
                self.history.append(row)
                bar.set_postfix(rho=f"{row['mean_robustness']:.3g}", success=f"{row['success_rate']:.0%}")
                bar.update(1)
                if hook is not None and hook.on_iteration(self, row) is False:
                    break
        return self

    # Evaluation --------------------------------------------------------------------
    def evaluate(self, n_episodes: int = 100, seed: int | None = None, deterministic: bool = True) -> dict[str, Any]:
        """Run fresh episodes with the current policy (no learning).

        Args:
            n_episodes: number of episodes.
            seed: episode ``i`` resets with ``seed + i`` (and stochastic actions draw from a
                generator seeded with ``seed``); ``None`` for fresh randomness.
            deterministic: act with the policy's mean.

        Returns:
            ``{"mean_robustness": float, "success_rate": float, "robustness": (n_episodes,) array,
            "traces": {signal: [each episode's s_0 … s_T]}}`` (`evaluate_policy`).

        Raises:
            ValueError: ``n_episodes`` < 1.
            EpisodeError: an episode did not end (see `evaluate_policy`).
        """
        if seed is not None:
            self._predict_rng = np.random.default_rng([seed, 2])
        return evaluate_policy(self, self.env, n_episodes=n_episodes, seed=seed, deterministic=deterministic)

    # Persistence -------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Save the agent atomically as a zip of ``meta.json`` and ``arrays.npz`` (nothing pickled).

        Returns:
            The path written.

        Raises:
            TypeError: ``path`` is not a path, or the agent's config holds a value JSON cannot write.
            OSError: the file cannot be written (the previous file at ``path``, if any, is left intact).
        """
        config = to_json(self._config())
        if not is_jsonable(config):
            raise TypeError(f"{type(self).__name__}'s config is not JSON-serialisable: {config!r}")
        meta = {
            "format_version": FORMAT_VERSION,
            "tl_gym_version": tl_gym.__version__,
            "class": type(self).__name__,
            "config": config,
            "seed": self.seed,
            "formula": str(self.formula),
            "env": self._env_source,
            "observation_space": describe_space(self.observation_space),
            "action_space": describe_space(self.action_space),
            "num_iterations": self.num_iterations,
            "env_steps": self.env_steps,
            "history": to_json(self.history),
            "rng_state": to_json(self.rng.bit_generator.state),
            "predict_rng_state": to_json(self._predict_rng.bit_generator.state),  # stochastic predict's draws
            "horizon": getattr(self, "horizon", None),  # an episodic agent's policy has one step per state
        }
        return write_archive(path, meta, self._state_arrays(), self._extra_files())

    @classmethod
    def load(cls, path: str | Path, env: Any = None, env_kwargs: dict[str, Any] | None = None) -> Agent:
        """Load a saved agent; it acts, evaluates and continues learning as the saved one would.

        Args:
            path: a file written by `save`.
            env: the env to attach (id, `Env` or `VectorEnv`); by default the saved env id and kwargs.
                Its spaces and formula must match the saved ones.
            env_kwargs: constructor keywords for an env id given as ``env``. Without them the saved id
                is rebuilt as the saved env, as ``env=None`` does (its keywords, the task's shaping
                included, and its recorded wrappers or time limit); another id gets none. Only with an
                env id.

        Raises:
            IncompatibleSaveError: wrong file, format version, class, spaces, formula or array shapes
                (the message names the culprit).
            ValueError: ``env_kwargs`` without an env id to make.
        """
        if env_kwargs is not None and not isinstance(env, str):
            raise ValueError(f"env_kwargs {env_kwargs!r} are the keywords of an env id; env is {env!r}: "
                             "build the env with them and pass it, or pass its id")
        meta, arrays, files = read_archive(path)
        klass = _agent_class(meta["class"]) if cls is Agent else cls
        if klass.__name__ != meta["class"]:
            raise IncompatibleSaveError(f"{path} holds a {meta['class']}, not a {klass.__name__}")
        source = meta["env"]
        saved_id = isinstance(env, str) and env == source.get("id") and env_kwargs is None
        if env is None or (saved_id and (source.get("spec_json") or source.get("kwargs") is not None)):
            env, env_kwargs = _env_from_source(source, path, by_id=saved_id)
        agent = klass(env=env, seed=meta["seed"], env_kwargs=env_kwargs, **klass._saved_config(dict(meta["config"])))
        for key in ("observation_space", "action_space"):
            got = describe_space(getattr(agent, key))
            if to_json(got) != meta[key]:
                raise IncompatibleSaveError(f"the env's {key} {got} differs from the saved one {meta[key]}")
        if str(agent.formula) != meta["formula"]:
            raise IncompatibleSaveError(
                f"the env's formula {str(agent.formula)!r} differs from the saved one {meta['formula']!r}"
            )
        try:
            check_arrays(arrays, agent._state_arrays())
        except IncompatibleSaveError as error:
            saved_horizon = meta.get("horizon")  # saved since 2026-12-06
            if saved_horizon is None or saved_horizon == getattr(agent, "horizon", saved_horizon):
                raise
            raise IncompatibleSaveError(
                f"the agent was trained on episodes of {saved_horizon} steps and the env's last {agent.horizon}: its "
                f"time-varying policy acts per step; load it on an env of {saved_horizon}-step episodes ({error})"
            ) from None
        agent._load_state(arrays, files)
        agent.history = [dict(row) for row in meta["history"]]
        agent.num_iterations = int(meta["num_iterations"])
        agent.env_steps = int(meta["env_steps"])
        agent.rng.bit_generator.state = meta["rng_state"]
        if "predict_rng_state" in meta:  # saved since 2026-12-06
            agent._predict_rng.bit_generator.state = meta["predict_rng_state"]
        return agent

    @classmethod
    def _saved_config(cls, config: dict[str, Any]) -> dict[str, Any]:
        """A saved config as this version reads it: a field added since keeps the saver's behaviour."""
        return config

    def close(self) -> None:
        """Close the agent's env."""
        self.env.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._env_source.get('id')!r}, iterations={self.num_iterations})"


def _agent_class(name: str) -> type[Agent]:
    try:
        return saved_class(name)
    except LookupError as exc:
        raise IncompatibleSaveError(str(exc)) from None


def describe_env_source(env: Any, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """What `load` needs to rebuild the env: its id, kwargs and, when it can, its full spec.

    An env whose spec differs from its id's registration (wrappers added around it, another
    ``max_episode_steps``) is recorded by its full spec; when that spec cannot be written (a
    wrapper with a callable argument) nothing is recorded to rebuild it from, so that `load`
    asks for ``env=`` instead of rebuilding the bare registered env, which would act differently.
    A spec with wrappers Gymnasium cannot recreate (one that records no arguments, as SB3's ``Monitor``)
    records the spec without them and their names: `load` then asks for ``env=``, and the saved id
    given as ``env`` is rebuilt from that spec, every other wrapper and the time limit included.
    """
    if isinstance(env, str):
        return {"id": env, "kwargs": to_json(env_kwargs) if is_jsonable(env_kwargs) else None, "spec_json": None}
    spec = getattr(env, "spec", None)
    if spec is None:
        return {"id": None, "kwargs": None, "spec_json": None}
    kwargs = {k: v for k, v in spec.kwargs.items() if k not in _VECTOR_KEYS}
    recorded = {"id": spec.id, "kwargs": to_json(kwargs) if is_jsonable(kwargs) else None, "spec_json": None}
    spec, unrebuildable = _without_unrebuildable(spec)
    if unrebuildable:
        recorded["unrebuildable_wrappers"] = unrebuildable
    if not spec.additional_wrappers and spec.max_episode_steps == _registered_steps(spec.id):
        return recorded  # the id and its kwargs are the env (its own vector env, the batched car, is kept)
    try:
        return {**recorded, "spec_json": spec.to_json()}
    except Exception:  # noqa: BLE001 - callables in kwargs or the entry point: then the user passes env= on load
        # (the saved id named as env= then makes the id with its kwargs, when those could be written)
        return recorded if unrebuildable else {"id": spec.id, "kwargs": None, "spec_json": None}


def _without_unrebuildable(spec: gym.envs.registration.EnvSpec) -> tuple[gym.envs.registration.EnvSpec, list[str]]:
    """``spec`` without the wrappers Gymnasium cannot recreate (no arguments recorded: SB3's Monitor); their names."""
    names = [wrapper.name for wrapper in spec.additional_wrappers if wrapper.kwargs is None]
    if not names:
        return spec, []
    kept = tuple(wrapper for wrapper in spec.additional_wrappers if wrapper.kwargs is not None)
    return dataclasses.replace(spec, additional_wrappers=kept), names


def _is_the_ids_own(spec: gym.envs.registration.EnvSpec) -> bool:
    """Whether ``spec`` is what its id makes with its kwargs (the entry point's own wrappers and time limit)."""
    try:
        made = gym.make(spec.id, **spec.kwargs)
    except Exception:  # noqa: BLE001 - an id that no longer makes: the spec rebuilds it
        return False
    own = made.spec
    made.close()
    return own.additional_wrappers == spec.additional_wrappers and own.max_episode_steps == spec.max_episode_steps


def _registered_steps(env_id: str) -> int | None:
    """The ``max_episode_steps`` the registry gives ``env_id`` (None when it is not registered)."""
    try:
        return registered_spec(env_id).max_episode_steps
    except (gym.error.Error, ImportError):
        return None


def _env_from_source(source: Mapping[str, Any], path: Any, *, by_id: bool = False) -> tuple[Any, dict[str, Any] | None]:
    """The env (or id and kwargs) a file records; ``by_id``: the user named the saved id as ``env``."""
    spec = gym.envs.registration.EnvSpec.from_json(source["spec_json"]) if source.get("spec_json") else None
    unrebuildable = list(source.get("unrebuildable_wrappers", ()))
    if spec is not None:  # a file saved before they were left out keeps them in its spec
        spec, left_out = _without_unrebuildable(spec)
        unrebuildable = unrebuildable or left_out
    if unrebuildable and not by_id:
        raise IncompatibleSaveError(
            f"{path} was saved on a {source.get('id')} wrapped in {', '.join(unrebuildable)}, which Gymnasium cannot "
            f"rebuild; pass env= (the env wrapped again, or env={source.get('id')!r} for it without them)"
        )
    if spec is not None and unrebuildable and source.get("kwargs") is not None and _is_the_ids_own(spec):
        return source["id"], dict(source["kwargs"])  # the id's own vector env (the batched car) rather than copies
    if spec is not None:
        return gym.make(spec), None
    if source.get("id") is not None and source.get("kwargs") is not None:
        return source["id"], dict(source["kwargs"])
    raise IncompatibleSaveError(
        f"{path} does not record how to rebuild its env ({json.dumps(source)}); pass env= to load"
    )
