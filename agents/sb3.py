"""stable-baselines3 algorithms behind the tl_gym agent interface, set up as rl-baselines3-zoo does.

`SB3Agent("TLCarNav-v0", "PPO")` trains a stable-baselines3 (or sb3-contrib)
algorithm on a TLTL-rewarded env and reports on the same axes as TLPS and REPS:
one iteration is ``steps_per_iteration`` env steps (40 episodes × 200 steps by
default, a TLPS iteration's budget), and each history row holds the mean exact
robustness and success rate of the episodes that ended during the iteration,
read from the reward wrapper's terminal ``info``.

A fair baseline uses SB3's own tools the way the zoo does, so by default:

- **VecNormalize** wraps the training envs (observations always, rewards when the
  task's hyperparameters say so); `predict`, and so `evaluate`, normalise raw
  observations with its statistics without updating them, and the statistics are
  saved and loaded with the agent.
- **The Markov view and a shaped reward** (``tl_reward="markov"``): the env keywords
  of `TL_REWARD_ENV_KWARGS` append the online monitor's state to the observation and
  pay a dense reward, because the terminal robustness alone is not a Markov reward of
  the raw observation; a task's entry in the hyperparameter file may add its measured best
  shaping (``markov_env_kwargs``). ``tl_reward="terminal"`` is the plain terminal reward, for the ablation.
- **Per-task hyperparameters** from one YAML file in the zoo's format
  (``agents/hyperparams/sb3.yml``, read by `tl_gym.agents.sb3_settings`); explicit keyword arguments win.

Saving embeds stable-baselines3's own zip as the member ``sb3_model.zip`` and the
pickled `VecNormalize` as ``vecnormalize.pkl`` (the zoo's file; ``VecNormalize.load``
reads it). stable-baselines3 unpickles parts of the first, and the second is a pickle,
so **load only files you trust**. A loaded agent acts and evaluates exactly as the
saved one; it can continue learning, but not bit-identically to an uninterrupted run
(SB3 does not save its random state). An off-policy algorithm's replay buffer is saved apart:
`SB3Agent.save_replay_buffer`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import inspect
import io
import os
import pickle
import re
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.errors import IncompatibleSaveError
from tl_gym.relabel import EpisodeRecorder, GoalRelabeller, find_wrapper

from .base import Agent, describe_env_source
from .env_ids import env_copies, unqualified_id
from .hindsight import make_hindsight_feeder
from .horizon import env_attribute
from .sampling import require_robustness
from .sb3_settings import (
    DEFAULT_TL_REWARD,
    EXPLORATION_FRACTION,
    HYPERPARAMS_FILE,
    MARKOV_ENV_KWARGS,
    SCHEDULE_KEYS,
    TL_REWARD_ENV_KWARGS,
    BudgetSchedule,
    LinearSchedule,  # here too for agents saved before sb3_settings: they pickle tl_gym.agents.sb3.LinearSchedule
    SB3Config,
    activation_class,
    algorithm_parameters,
    canonical_settings,
    check_exploration_budget,
    check_hyperparams_source,
    check_tensorboard,
    check_tl_reward,
    find_hyperparams,
    is_linear_schedule,
    is_schedule,
    linear_start,
    load_hyperparams,
    merge_hyperparameters,
    parse_env_wrappers,
    parse_normalize,
    resolve_algorithm,
    split_settings,
    tl_reward_of_env_kwargs,
    tl_reward_of_view,
    wrap_env,
)
from .serialization import atomic_path, is_jsonable

#: Archive member holding stable-baselines3's own model file.
SB3_MEMBER = "sb3_model.zip"

#: Archive member holding the pickled `VecNormalize` (observation and return statistics).
VECNORMALIZE_MEMBER = "vecnormalize.pkl"


# The agent ------------------------------------------------------------------------------------------
def _check_argument_order(env: Any, algo: Any) -> None:
    """Name the culprit when a caller passes the algorithm first (the order before 0.2)."""
    from stable_baselines3.common.base_class import BaseAlgorithm

    algorithm_first = isinstance(env, type) and issubclass(env, BaseAlgorithm)
    if isinstance(env, str) and env not in gym.registry:
        with contextlib.suppress(ValueError):
            algorithm_first = resolve_algorithm(env) is not None
    if algorithm_first:
        raise TypeError(f"SB3Agent takes the env first, then the algorithm, as every agent does: "
                        f"SB3Agent({algo!r}, {env!r}), not SB3Agent({env!r}, {algo!r})")


class SB3Agent(Agent):
    """A stable-baselines3 algorithm trained on a TLTL-rewarded env, reported like TLPS.

    Args:
        env: env id, `Env` or `VectorEnv` (see `Agent`); SB3 trains on a ``DummyVecEnv`` of
            ``n_envs`` single envs rebuilt from it (wrapped in ``VecNormalize``), evaluation runs
            on a vector env of the same single envs. The env comes first, as for every agent.
        algo: an SB3 / sb3-contrib algorithm class or its name (``"PPO"``, ``"sac"``, ...).
        seed: seeds SB3 (torch, numpy, the envs).
        env_kwargs: env constructor keywords for an env id; they win over the ones ``tl_reward`` adds
            (and, with ``"markov"``, over the task's ``markov_env_kwargs`` in the hyperparameter file: its
            measured best shaping, e.g. ``satisfaction_bonus`` on ``TLParking-v0`` for SAC).
        steps_per_iteration, n_envs, policy, normalize, n_timesteps, noise_type, noise_std: see
            `SB3Config`; ``None`` takes the task's value from the hyperparameter file (all but
            ``steps_per_iteration``, which no entry sets), else the default.
        tl_reward: ``"markov"`` or ``"terminal"``. With an env id it adds the env keywords of
            `TL_REWARD_ENV_KWARGS` (default ``"markov"``) under ``env_kwargs``; the label follows the
            ``observe_monitor`` they leave, and an explicit value they contradict is an error. An `Env`
            or `VectorEnv` object cannot be rebuilt with other keywords: ``None`` reads what it does,
            and an explicit value it visibly contradicts (its ``observe_monitor`` / ``reward_mode``)
            is an error.
        hyperparams: ``True`` (the packaged ``sb3.yml``), ``False`` (none: SB3's defaults) or a file path
            (text or a `pathlib.Path`).
        **algo_kwargs: the algorithm's constructor arguments; each one given wins over the file's. Three more
            `SB3Config` settings come this way: ``end_is_terminal`` (default ``True``: every episode end is a
            termination for SB3, `TraceEndIsTerminal`), ``her_goals`` and ``her_strategy`` (hindsight
            relabelling of whole TL episodes on goal envs, off-policy algorithms; docs/agents.md).

    History rows add ``episodes`` (episodes that ended in the iteration).

    Raises:
        ValueError: a bad setting (naming it), an iteration more than 5% off ``steps_per_iteration``,
            or a ``tl_reward`` the env object or ``env_kwargs`` contradict.
        TypeError: an env id that does not take a keyword ``tl_reward`` or the task's ``markov_env_kwargs``
            add (naming it and where it comes from).

    Example:
        >>> agent = SB3Agent("TLCarNav-v0", "ppo", seed=0, steps_per_iteration=400, n_envs=2, batch_size=100)
        >>> agent.learn(1).history[0]["env_steps"], type(agent.model).__name__, agent.config.tl_reward
        (400, 'PPO', 'markov')
    """

    config: SB3Config
    config_class = SB3Config

    def __init__(self, env: Any, algo: Any, *, seed: int | None = None, env_kwargs: Mapping[str, Any] | None = None,
                 steps_per_iteration: int | None = None, n_envs: int | None = None, policy: str | None = None,
                 tl_reward: str | None = None, normalize: Any = None,
                 hyperparams: bool | str | os.PathLike = True,
                 n_timesteps: int | None = None, noise_type: str | None = None, noise_std: float | None = None,
                 **algo_kwargs: Any):
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

        _check_argument_order(env, algo)
        self.algo_class = resolve_algorithm(algo)
        on_policy = issubclass(self.algo_class, OnPolicyAlgorithm)
        if tl_reward is not None:
            check_tl_reward(tl_reward)
        saved = isinstance(hyperparams, _SavedSettings)  # Agent.load: the saved config holds the file's settings
        users_env_kwargs = dict(env_kwargs or {})
        if isinstance(env, str):
            env_kwargs = {**TL_REWARD_ENV_KWARGS[tl_reward or DEFAULT_TL_REWARD], **users_env_kwargs}
            # a saved agent's label is re-read: one saved before the check may say "markov" without the view
            tl_reward = tl_reward_of_env_kwargs(None if saved else tl_reward, env_kwargs)
        else:
            tl_reward = _tl_reward_of(env, tl_reward, loading=saved)
        explicit = {k: v for k, v in dict(
            steps_per_iteration=steps_per_iteration, n_envs=n_envs, policy=policy, normalize=normalize,
            n_timesteps=n_timesteps, noise_type=noise_type, noise_std=noise_std).items() if v is not None}
        explicit = canonical_settings({**explicit, **algo_kwargs})
        hyperparams = hyperparams.hyperparams if saved else check_hyperparams_source(hyperparams)
        entry = {} if saved else _task_entry(self.algo_class, env, env_kwargs, hyperparams)
        # the entry's policy is for the id's own observation; _setup drops it where the env (object, env_wrapper)
        # changed that observation
        self._entry_policy = entry.get("policy") if policy is None else None
        # where each keyword the agent adds comes from, for the message of an env that does not take it
        sources = dict.fromkeys(TL_REWARD_ENV_KWARGS[tl_reward], f"tl_reward={tl_reward!r}")
        task_shaping = entry.pop(MARKOV_ENV_KWARGS, {})  # only an entry the file gave has any
        if tl_reward == "markov" and task_shaping:  # the task's best shaping, under the user's keywords
            where = (f"{MARKOV_ENV_KWARGS} of {self.algo_class.__name__.lower()} on {_env_key(env, env_kwargs)[0]} in "
                     f"{HYPERPARAMS_FILE.name if hyperparams is True else hyperparams}")
            if isinstance(env, str):
                env_kwargs = {**TL_REWARD_ENV_KWARGS["markov"], **task_shaping, **users_env_kwargs}
                sources.update(dict.fromkeys(task_shaping, f"the {where}"))
            else:
                _warn_unshaped(env, task_shaping, where)
        settings = merge_hyperparameters(entry, explicit, on_policy)
        # potential shaping keeps the optimal policies only with the agent's own discount
        agent_gamma = _discount(self.algo_class, settings)
        if isinstance(env, str) and env_kwargs.get("reward_mode") == "potential" and "gamma" not in env_kwargs:
            env_kwargs = {**env_kwargs, "gamma": agent_gamma}
        elif not isinstance(env, str) and not saved:
            _warn_potential_gamma(env, agent_gamma, self.algo_class.__name__)
        hyperparameters, algo_kwargs = split_settings(settings)
        hyperparameters.update(algo=self.algo_class.__name__, tl_reward=tl_reward, hyperparams=hyperparams,
                               algo_kwargs=algo_kwargs)
        config = self._config_for(env, hyperparameters, given=settings)  # checked before any env is built
        if not saved:  # a saved agent loads and acts without them; tensorboard is checked again when it learns
            check_tensorboard(algo_kwargs)
            check_exploration_budget(self.algo_class, config.n_timesteps)
        self._env_wrappers = parse_env_wrappers(config.env_wrapper)  # the zoo's env_wrapper, innermost first
        if self._env_wrappers and config.her_goals:
            raise ValueError(f"her_goals={config.her_goals} relabels the goals of the env's own observation, which "
                             f"env_wrapper={config.env_wrapper!r} changes: use one or the other")
        users_env = env
        if self._env_wrappers and not isinstance(env, str):
            if isinstance(env, gym.vector.VectorEnv):
                raise TypeError(f"env_wrapper={config.env_wrapper!r} wraps single envs: pass an env id or an Env, "
                                f"not a {type(env).__name__}")
            env = wrap_env(env, self._env_wrappers)  # its copies, the envs SB3 trains on, are wrapped too
        self._env_argument = env
        self._train_env_kwargs = dict(env_kwargs or {})  # read by _setup, which runs inside Agent.__init__
        if isinstance(env, str):
            venv = _make_sync_vec(env, config.n_envs, self._train_env_kwargs, sources, self._env_wrappers)
            super().__init__(venv, seed=seed, **hyperparameters)
            self.env_kwargs = dict(self._train_env_kwargs)
            self._env_source = describe_env_source(env, self.env_kwargs)
        else:
            super().__init__(env, seed=seed, env_kwargs=env_kwargs, **hyperparameters)
            # loading rebuilds the env from this and wraps it again: the user's env, not the wrapped one
            self._env_source = describe_env_source(users_env, self.env_kwargs)

    @property
    def env_wrappers(self) -> list[tuple[type, dict[str, Any]]]:
        """The ``env_wrapper`` setting as ``[(wrapper class, keywords), ...]``, innermost first (`wrap_env`)."""
        return list(self._env_wrappers)

    @classmethod
    def _saved_config(cls, config: dict[str, Any]) -> dict[str, Any]:
        """The saved settings as they are: the hyperparameter file is not read again.

        The saved config holds every setting the file gave (its values are all JSON), so reading it
        again could only break the load (a relative path from another working directory, a file that
        moved) or change the agent (a file edited since, a key added to the packaged one).
        """
        return {**config, "hyperparams": _SavedSettings(config.get("hyperparams", True))}

    def _num_envs(self) -> int:
        return self.config.n_envs

    @property
    def n_timesteps(self) -> int | None:
        """The env-step budget of the task's hyperparameters (``None`` when they state none)."""
        return self.config.n_timesteps

    def _setup(self) -> None:
        from stable_baselines3.common.monitor import Monitor
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

        kwargs = dict(self.config.algo_kwargs)
        budget = self.config.n_timesteps  # set wherever a schedule is (SB3Config checks)
        self._schedules: dict[str, BudgetSchedule] = {
            key: LinearSchedule(linear_start(key, value), budget) if is_linear_schedule(value)  # type: ignore[arg-type]
            else BudgetSchedule(value, budget)  # type: ignore[arg-type]
            for key, value in kwargs.items() if is_schedule(key, value)}
        # the zoo's 'lin_' go in as their start values, installed after (SB3 rebuilds constant ones on load and the
        # config holds the string); a callable goes in as its budget schedule, which SB3's own file keeps
        kwargs.update({key: schedule(1.0) if isinstance(schedule, LinearSchedule) else schedule
                       for key, schedule in self._schedules.items()})
        on_policy = issubclass(self.algo_class, OnPolicyAlgorithm)
        if on_policy:
            kwargs.setdefault("n_steps", max(1, self.config.steps_per_iteration // self.config.n_envs))
            per_rollout = kwargs["n_steps"] * self.config.n_envs
            actual = -(-self.config.steps_per_iteration // per_rollout) * per_rollout
        else:
            actual = -(-self.config.steps_per_iteration // self.config.n_envs) * self.config.n_envs
        if abs(actual - self.config.steps_per_iteration) > 0.05 * self.config.steps_per_iteration:
            raise ValueError(
                f"one iteration would take {actual} env steps, more than 5% off steps_per_iteration="
                f"{self.config.steps_per_iteration}; choose n_envs (and n_steps) that divide it"
            )
        if kwargs.get("policy_kwargs") and "activation_fn" in kwargs["policy_kwargs"]:
            kwargs["policy_kwargs"] = {**kwargs["policy_kwargs"],
                                       "activation_fn": activation_class(kwargs["policy_kwargs"]["activation_fn"])}
        if self.config.noise_type is not None and "action_noise" not in kwargs:
            kwargs["action_noise"] = _action_noise(self.config.noise_type, self.config.noise_std, self.action_space)
        factories = _single_env_factories(self._env_argument, self._train_env_kwargs, self.config.n_envs)
        if isinstance(self._env_argument, str) and self._env_wrappers:  # an env object came wrapped
            factories = [lambda make=make: wrap_env(make(), self._env_wrappers) for make in factories]
        # SB3's Monitor, as make_vec_env and the zoo wrap every env: without it SB3 records no episode, and
        # logs no rollout/ep_rew_mean or ep_len_mean (tensorboard_log)
        factories = [lambda make=make: Monitor(make()) for make in factories]
        if self.config.her_goals:
            if on_policy:
                raise ValueError(f"her_goals={self.config.her_goals} relabels episodes into a replay buffer: use an "
                                 f"off-policy algorithm (SAC, TD3, ...), not {self.algo_class.__name__}")
            factories = [lambda make=make: EpisodeRecorder(make()) for make in factories]
        if self.config.end_is_terminal:
            factories = [lambda make=make: TraceEndIsTerminal(make()) for make in factories]
        self.sb3_env = DummyVecEnv(factories)
        self._hindsight = None
        if self.config.her_goals:
            recorders = [find_wrapper(env, EpisodeRecorder) for env in self.sb3_env.envs]
            relabeller = GoalRelabeller(self.sb3_env.envs[0], end_is_terminal=self.config.end_is_terminal)
            self._hindsight = make_hindsight_feeder(recorders, relabeller, self.config.her_goals,
                                                    np.random.default_rng(self.seed), self.config.her_strategy)
        normalize = parse_normalize(self.config.normalize)
        self.vec_normalize: VecNormalize | None = None
        if normalize is not None:
            normalize.setdefault("gamma", _discount(self.algo_class, kwargs))
            space = self.sb3_env.observation_space
            if isinstance(space, gym.spaces.Dict) and normalize.get("norm_obs", True):
                # VecNormalize refuses a Dict with a non-Box entry (a Discrete mode) unless told which keys to scale
                normalize.setdefault("norm_obs_keys", [k for k, sub in space.spaces.items()
                                                       if isinstance(sub, gym.spaces.Box)])
            self.vec_normalize = VecNormalize(self.sb3_env, **normalize)
        if (self.config.policy is not None and self.config.policy == self._entry_policy
                and not _policy_fits(self.config.policy, self.observation_space)):
            self.config = dataclasses.replace(self.config, policy=None)  # saved so: the default fits on load too
        policy = self.config.policy or _default_policy(self.algo_class, self.observation_space)
        try:
            self.model = self.algo_class(policy, self._training_env(), seed=self.seed, verbose=0, device="cpu",
                                         **kwargs)
        except AssertionError as error:  # SB3 asserts what it supports (DQN: Discrete actions only, batch_size > 1)
            raise ValueError(f"{self.algo_class.__name__} refused this env or these settings: {error}") from error
        if EXPLORATION_FRACTION in algorithm_parameters(self.algo_class) and budget is not None:  # DQN's ε too
            self._schedules["exploration_schedule"] = BudgetSchedule(self.model.exploration_schedule, budget)
        # (no budget: a DQN saved before the rule, which keeps the decay it trained with: anew in every iteration)
        self._install_schedules()
        self._quiet_logger()

    def _adopt_saved_schedules(self) -> None:
        """Register the callable schedules a loaded model holds (SB3's file keeps them; the JSON config cannot)."""
        for key in SCHEDULE_KEYS:
            value = getattr(self.model, key, None)
            while value is not None and not isinstance(value, BudgetSchedule):  # SB3 wraps it in FloatSchedule
                value = getattr(value, "value_schedule", None)
            if value is not None:
                self._schedules.setdefault(key, value)

    def _install_schedules(self) -> None:
        """Put the budget's schedules where SB3 reads them (it rebuilds constant ones from the start values on load)."""
        for key, schedule in self._schedules.items():
            setattr(self.model, "lr_schedule" if key == "learning_rate" else key, schedule)

    def close(self) -> None:
        """Close the evaluation env and SB3's training envs (a rendering or simulator env holds resources)."""
        super().close()
        self._training_env().close()

    def _training_env(self) -> Any:
        """The VecEnv SB3 steps: the VecNormalize wrapper when there is one."""
        return self.vec_normalize if self.vec_normalize is not None else self.sb3_env

    def _quiet_logger(self) -> None:
        """Give the model a logger that writes nothing, unless the user asked for tensorboard logs.

        Without one, every ``model.learn`` call (one per iteration here) makes a new empty
        ``SB3-<time>`` folder in the temp directory, SB3's default.
        """
        if not self.config.algo_kwargs.get("tensorboard_log"):
            from stable_baselines3.common.logger import Logger

            self.model.set_logger(Logger(folder=None, output_formats=[]))

    def _update(self, iteration: int) -> dict[str, Any]:
        check_tensorboard(self.config.algo_kwargs)  # a loaded agent too: SB3 needs it only now, at its logger
        collector = _make_collector()
        before = self.model.num_timesteps
        for schedule in self._schedules.values():  # the env step SB3 counts this call's progress against
            schedule.span = before + self.config.steps_per_iteration
        if self._schedules and before >= self.config.n_timesteps:  # type: ignore[operator]  # a whole iteration at 0
            warnings.warn(f"the schedules of {sorted(self._schedules)} end at n_timesteps: past it they stay at their "
                          "end values (a 'lin_' learning rate at 0 leaves the policy as it is)", stacklevel=2)
        with one_torch_thread():
            callbacks = [collector] if self._hindsight is None else [collector, self._hindsight]
            self.model.learn(total_timesteps=self.config.steps_per_iteration, reset_num_timesteps=False,
                             callback=callbacks, progress_bar=False)
        robustness = np.asarray(collector.robustness, dtype=float)
        return {
            "env_steps": self.model.num_timesteps - before,
            "mean_robustness": float(robustness.mean()) if robustness.size else float("nan"),
            "success_rate": float(np.mean(robustness > 0)) if robustness.size else float("nan"),
            "episodes": int(robustness.size),
        }

    def predict(
        self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, Any]:
        """Actions for raw env observations: normalised with the VecNormalize statistics (not updated).

        Stochastic actions draw from the agent's own generator (``evaluate(seed=s)`` seeds it), not from
        the global ones SB3's training draws from: sampling episodes between iterations (an evaluation,
        ``tl-gym train``'s trajectory plots) leaves training as it would have been without them.
        """
        self._check_observation(obs)
        if self.vec_normalize is not None:
            obs = self.vec_normalize.normalize_obs(obs)
        # epsilon-greedy predict (DQN, QR-DQN) explores with numpy's global generator and the action space's
        space = self.model.action_space if hasattr(self.model, "exploration_rate") else None
        own = contextlib.nullcontext() if deterministic else drawn_from(self._predict_rng, space)
        with one_torch_thread(), own:
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)

    def _check_observation(self, obs: Any) -> None:
        """Refuse an observation of another shape than the agent's, before VecNormalize meets it in numpy's words.

        The likely cause is the Markov view: an agent trained with ``tl_reward="markov"`` observes the env's
        observation with the monitor's state appended, which an env made without ``observe_monitor=True`` lacks.
        """
        space = self.observation_space
        if isinstance(space, gym.spaces.Dict) and isinstance(obs, Mapping):
            fits = set(obs) == set(space.spaces)
            got, wanted = sorted(obs), sorted(space.spaces)
        elif isinstance(space, gym.spaces.Box) and space.shape:
            got, wanted = np.shape(obs), space.shape
            fits = tuple(got[len(got) - len(wanted):]) == tuple(wanted)
        else:
            return
        if not fits:
            hint = (" The agent observes its env's monitor (the Markov view, tl_reward='markov'): act on observations "
                    "of an env made as the agent's, gym.make(id, **agent.env_kwargs), or of agent.env."
                    if self.config.tl_reward == "markov" else "")
            if self._env_wrappers:
                hint += (f" It also observes through env_wrapper={self.config.env_wrapper!r}: wrap the env so "
                         "(tl_gym.agents.sb3_settings.wrap_env(env, agent.env_wrappers)).")
            what = "keys" if isinstance(got, list) else "shape"
            raise ValueError(f"the observation has {what} {got}; the agent's observation space has {what} {wanted}."
                             f"{hint}")

    def _config(self) -> dict[str, Any]:
        config = dataclasses.asdict(self.config)
        algo_kwargs = config.pop("algo_kwargs")
        # kwargs that JSON cannot hold (classes, action noise...) live on in SB3's own file
        config.update({k: v for k, v in algo_kwargs.items() if is_jsonable(v)})
        return config

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return {}

    def _extra_files(self) -> dict[str, bytes]:
        buffer = io.BytesIO()
        self.model.save(buffer)
        files = {SB3_MEMBER: buffer.getvalue()}
        if self.vec_normalize is not None:
            # what VecNormalize.save writes: the object without its venv
            files[VECNORMALIZE_MEMBER] = pickle.dumps(self.vec_normalize)
        return files

    def _load_state(self, arrays: dict[str, np.ndarray], files: dict[str, bytes]) -> None:
        from stable_baselines3.common.vec_env import VecNormalize

        if SB3_MEMBER not in files:
            raise IncompatibleSaveError(f"the file holds no {SB3_MEMBER} member")
        if (self.vec_normalize is not None) != (VECNORMALIZE_MEMBER in files):
            raise IncompatibleSaveError(
                f"the file {'lacks' if self.vec_normalize is not None else 'has'} a {VECNORMALIZE_MEMBER} member "
                f"but the agent's normalize={self.config.normalize!r}"
            )
        if self.vec_normalize is not None:
            loaded = pickle.loads(files[VECNORMALIZE_MEMBER])  # documented: load only files you trust
            if not isinstance(loaded, VecNormalize):
                raise IncompatibleSaveError(
                    f"{VECNORMALIZE_MEMBER} holds a {type(loaded).__name__}, not a VecNormalize")
            loaded.set_venv(self.sb3_env)
            self.vec_normalize = loaded
        self.model = self.algo_class.load(io.BytesIO(files[SB3_MEMBER]), env=self._training_env(), device="cpu")
        self._adopt_saved_schedules()
        self._install_schedules()
        self._quiet_logger()

    # The replay buffer -------------------------------------------------------------
    @property
    def off_policy(self) -> bool:
        """Whether the algorithm learns from a replay buffer (SAC, TD3, DQN...), which `save` does not keep."""
        from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

        return isinstance(self.model, OffPolicyAlgorithm)

    def save_replay_buffer(self, path: str | Path) -> Path:
        """Save the replay buffer atomically (SB3's pickle), so that a loaded agent resumes training where it stopped.

        `save` leaves it out (it can hold a million transitions); a run that is to go on later, in
        another process, saves both, as rl-baselines3-zoo's ``--save-replay-buffer`` does. The
        file is a pickle: load only files you trust.

        Raises:
            ValueError: the algorithm keeps no replay buffer (PPO, A2C).
        """
        self._check_off_policy("save")
        with atomic_path(path) as tmp:
            self.model.save_replay_buffer(tmp)
        return Path(path)

    def load_replay_buffer(self, path: str | Path) -> None:
        """Load a buffer written by `save_replay_buffer` (typically into the agent `Agent.load` returned)."""
        self._check_off_policy("load")
        self.model.load_replay_buffer(Path(path))

    def _check_off_policy(self, verb: str) -> None:
        if not self.off_policy:
            raise ValueError(f"cannot {verb} a replay buffer: {self.algo_class.__name__} is on-policy and keeps none")


@dataclasses.dataclass(frozen=True)
class _SavedSettings:
    """A loaded agent's ``hyperparams`` value: what it was, with the settings already in the saved config."""

    hyperparams: bool | str


class TraceEndIsTerminal(gym.Wrapper):
    """Reports every episode end (terminated or truncated) as a termination.

    A TLTL reward is the robustness of the finite trace s_0 … s_T: when the trace ends, the
    task ends, and no value lies beyond it. stable-baselines3 adds ``γ V(s_T)`` to the last
    reward of a *truncated* episode (right for a time limit on an infinite-horizon task);
    here that value would be the critic's guess at a state it never trained on.
    """

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, bool(terminated or truncated), False, info


@contextlib.contextmanager
def one_torch_thread() -> Iterator[None]:
    """Run torch on one thread, restoring the setting after.

    SB3's default networks are tiny: a 64-unit layer on a few observations gains nothing
    from threads, and on a loaded 2-core machine the thread hand-offs made each forward
    pass 400 times slower (measured: 21 ms against 0.05 ms).
    """
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


@contextlib.contextmanager
def drawn_from(rng: np.random.Generator, action_space: gym.Space | None = None) -> Iterator[None]:
    """Seed the generators SB3 samples actions with from ``rng`` for the block, then restore them.

    SB3 samples a stochastic action with torch's global generator: the very generator its training
    draws from. Sampling with it between iterations would change what training does next, and
    could not be repeated with a seed. With ``action_space`` (epsilon-greedy algorithms, which explore
    with it and with numpy's global generator) those two are seeded and restored as well; they are
    left alone otherwise, numpy's state being slow to save (about 0.1 ms, a forward pass's time).
    """
    import torch

    seeds = [int(s) for s in rng.integers(2**32, size=3)]
    torch_state = torch.get_rng_state()
    torch.default_generator.manual_seed(seeds[0])
    if action_space is not None:
        numpy_state, space_state = np.random.get_state(), action_space.np_random.bit_generator.state
        np.random.seed(seeds[1])
        action_space.np_random.bit_generator.state = np.random.default_rng(seeds[2]).bit_generator.state
    try:
        yield
    finally:
        torch.set_rng_state(torch_state)
        if action_space is not None:
            np.random.set_state(numpy_state)
            action_space.np_random.bit_generator.state = space_state


def _make_collector() -> Any:
    """An SB3 callback recording the exact robustness of every episode that ends."""
    from stable_baselines3.common.callbacks import BaseCallback

    class RobustnessCollector(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.robustness: list[float] = []

        def _on_step(self) -> bool:
            for done, info in zip(self.locals["dones"], self.locals["infos"]):
                if done:
                    require_robustness(info)
                    self.robustness.append(float(info["robustness"]))
            return True

    return RobustnessCollector()


def _default_argument(algo_class: type, name: str, fallback: Any) -> Any:
    parameter = algorithm_parameters(algo_class).get(name)
    return fallback if parameter is None or parameter.default is inspect.Parameter.empty else parameter.default


def _action_noise(noise_type: str, std: float, space: gym.Space) -> Any:
    """The zoo's ``noise_type`` / ``noise_std`` as an SB3 action noise object."""
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    shape = space.shape or (1,)
    mean, sigma = np.zeros(shape), np.full(shape, float(std))
    return NormalActionNoise(mean, sigma) if noise_type == "normal" else OrnsteinUhlenbeckActionNoise(mean, sigma)


def agent_discount(algo: Any, env: Any, env_kwargs: Mapping[str, Any] | None = None,
                   hyperparams: bool | str | os.PathLike = True, gamma: float | None = None) -> float:
    """The discount ``SB3Agent(env, algo, env_kwargs=..., hyperparams=..., gamma=gamma)`` trains with.

    The ``gamma`` given, else the task's entry's in the hyperparameter file, else the algorithm's default:
    for a wrapper built before its agent (the CLI's ``--spec``) whose potential shaping must discount alike.

    Example:
        >>> agent_discount("ppo", "TLCarNav-v0"), agent_discount("ppo", "TLCarNav-v0", hyperparams=False)
        (0.999, 0.99)
    """
    algo_class = resolve_algorithm(algo)
    if gamma is not None:
        return float(gamma)
    return _discount(algo_class, _task_entry(algo_class, env, env_kwargs, check_hyperparams_source(hyperparams)))


def _task_entry(algo_class: type, env: Any, env_kwargs: Mapping[str, Any] | None,
                hyperparams: bool | str | os.PathLike) -> dict[str, Any]:
    """The hyperparameter file's entry for the algorithm on this env (empty with ``hyperparams=False``)."""
    if hyperparams is False:
        return {}
    table = load_hyperparams(None if hyperparams is True else hyperparams)
    env_id, key_kwargs = _env_key(env, env_kwargs)
    return find_hyperparams(table, env_id, key_kwargs, algo_class.__name__)


def _discount(algo_class: type, settings: Mapping[str, Any]) -> float:
    """The γ of merged settings: theirs, else the algorithm's default."""
    return settings.get("gamma", _default_argument(algo_class, "gamma", 0.99))


def _env_key(env: Any, env_kwargs: Mapping[str, Any] | None) -> tuple[str | None, dict[str, Any]]:
    """The env id and keywords the hyperparameter file is looked up with."""
    if isinstance(env, str):
        return unqualified_id(env), dict(env_kwargs or {})
    spec = getattr(env, "spec", None)
    if spec is None:
        return None, {}
    return spec.id, {k: v for k, v in spec.kwargs.items()
                     if k not in ("num_envs", "vectorization_mode", "vector_kwargs", "wrappers")}


def _env_setting(env: Any, name: str) -> Any:
    """The env object's attribute ``name`` (through its wrappers or sub-envs); ``None`` when absent."""
    if isinstance(env, gym.vector.VectorEnv):
        return env_attribute(env, name)
    try:
        return env.get_wrapper_attr(name)
    except AttributeError:
        return None


def _tl_reward_of(env: Any, asked: str | None, loading: bool = False) -> str:
    """The ``tl_reward`` an env object implements: checked against ``asked``, else read from it.

    Read: ``"markov"`` when the env observes its monitor (``observe_monitor=True``, whatever its reward
    mode: dense, potential, with a bonus...), else ``"terminal"``. The object cannot be rebuilt with
    other keywords, so an explicit choice that one of its readable settings contradicts is an error
    (``"markov"``: the view and a shaped reward, ``reward_mode`` dense or potential; ``"terminal"``: no
    view, the terminal reward); a setting it does not expose is not checked. ``loading`` (`Agent.load`,
    ``asked`` the saved value) checks only what the policy depends on: that the env has the view the
    agent was trained with, so the observations match.
    """
    if asked is None or loading:
        view = _env_setting(env, "observe_monitor")
        if loading and view is None and asked is not None:  # not exposed: nothing to check it against
            return asked
        read = tl_reward_of_view(view)
        if loading and read != asked:
            raise ValueError(f"the agent was trained with tl_reward={asked!r} (observe_monitor={asked == 'markov'}), "
                             f"the env has observe_monitor={bool(view)}: its observations are not the agent's; "
                             f"make the env with observe_monitor={asked == 'markov'}, or pass the env id instead")
        return read
    has = {k: _env_setting(env, k) for k in TL_REWARD_ENV_KWARGS[asked]}
    accepted = {k: (v,) for k, v in TL_REWARD_ENV_KWARGS[asked].items()}
    if asked == "markov":
        accepted["reward_mode"] = ("dense", "potential")  # both are the monitor's shaped rewards
    wrong = {k: (TL_REWARD_ENV_KWARGS[asked][k], got) for k, got in has.items()
             if got is not None and got not in accepted[k]}
    if wrong:
        detail = ", ".join(f"{k}={want!r} (the env has {got!r})" for k, (want, got) in wrong.items())
        raise ValueError(f"tl_reward={asked!r} needs the env keywords {detail}; an env object cannot be rebuilt "
                         f"by the agent: make it with those keywords, or pass the env id instead")
    return asked


def _warn_unshaped(env: Any, shaping: Mapping[str, Any], where: str) -> None:
    """Warn that an env object lacks the task's shaping keywords (the agent cannot rebuild it with them)."""
    missing = {k: v for k, v in shaping.items() if _env_setting(env, k) != v}
    if missing:
        warnings.warn(f"the env object does not have the {where}: {missing} (an env object is used as it was "
                      "built); make it with those keywords, or pass the env id", stacklevel=3)


def _warn_potential_gamma(env: Any, agent_gamma: float, algo: str) -> None:
    """Warn that an env object's potential shaping discounts by another γ than the agent (the env cannot be rebuilt)."""
    env_gamma = _env_setting(env, "gamma")
    if _env_setting(env, "reward_mode") == "potential" and env_gamma is not None and env_gamma != agent_gamma:
        warnings.warn(f"the env's potential shaping uses gamma={env_gamma!r} but {algo} discounts by {agent_gamma!r}: "
                      "the shaping keeps the optimal policies only with the agent's own discount; make the env "
                      f"with gamma={agent_gamma!r} (or pass the env id: the agent then sets it)", stacklevel=3)


def _make_sync_vec(env_id: str, n_envs: int, env_kwargs: Mapping[str, Any], sources: Mapping[str, str],
                   wrappers: list[tuple[type, dict[str, Any]]]) -> gym.vector.VectorEnv:
    """The evaluation env: ``n_envs`` of the very single envs SB3 trains on, so the observation layout matches.

    ``sources`` says where each keyword the agent added comes from; a keyword of theirs that the env
    refuses is named with its source, one of the user's own is left to the env's own error.
    """
    try:
        return gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="sync",
                            wrappers=[functools.partial(wrapper, **keywords) for wrapper, keywords in wrappers],
                            **env_kwargs)
    except TypeError as error:
        own_words = str(error).split(" was raised from the environment creator")[0]  # Gymnasium appends all kwargs
        culprit = re.search(r"'([^']+)'", own_words)  # the env names its culprit first; a hint may quote another
        refused = [k for k in sources if culprit is not None and culprit.group(1) == k]
        if not refused:
            raise
        detail = ", ".join(f"{k}={env_kwargs[k]!r} (from {sources[k]})" for k in refused)
        raise TypeError(f"{env_id} does not take the env keyword {detail}: {error}. tl_reward='terminal' "
                        f"adds no view keywords, hyperparams=False no {MARKOV_ENV_KWARGS}") from error


def _default_policy(algo_class: type, observation_space: gym.Space) -> str:
    """``MlpPolicy`` (``MultiInputPolicy`` for Dict observations), or the algorithm's own kind of it.

    sb3-contrib's RecurrentPPO names its policies ``MlpLstmPolicy`` and ``MultiInputLstmPolicy``: the first alias
    of the algorithm that starts as the plain name would is taken.

    Example:
        >>> from stable_baselines3 import SAC
        >>> _default_policy(SAC, gym.spaces.Box(-1, 1, (3,)))
        'MlpPolicy'
    """
    kind = _policy_kind(observation_space)
    aliases = list(getattr(algo_class, "policy_aliases", {}))
    if f"{kind}Policy" in aliases or not aliases:
        return f"{kind}Policy"
    policy = next((alias for alias in aliases if alias.startswith(kind)), None)
    if policy is None and kind == "MultiInput":
        raise ValueError(
            f"{algo_class.__name__} has no policy for Dict observations (its policies: {', '.join(aliases)}): flatten "
            "the observation, env_wrapper='gymnasium.wrappers.FlattenObservation' (the zoo's key), or use an "
            "algorithm with a MultiInputPolicy (SAC, TD3, TQC, PPO)")
    return policy or f"{kind}Policy"


def _policy_kind(observation_space: gym.Space) -> str:
    """The prefix of SB3's policy names for ``observation_space``: ``MultiInput`` for a Dict, else ``Mlp``."""
    return "MultiInput" if isinstance(observation_space, gym.spaces.Dict) else "Mlp"


def _policy_fits(policy: Any, observation_space: gym.Space) -> bool:
    """Whether a policy named by a hyperparameter entry is of the kind ``observation_space`` needs (a class: yes)."""
    if not isinstance(policy, str):
        return True
    return policy.startswith("MultiInput") == (_policy_kind(observation_space) == "MultiInput")


def _single_env_factories(env: Any, env_kwargs: dict[str, Any], n_envs: int) -> list[Any]:
    """Constructors of ``n_envs`` single envs equivalent to ``env`` (an id, an Env or a VectorEnv).

    An Env is copied (`env_copies`: what was set after ``gym.make`` stays). A VectorEnv is rebuilt from its spec
    as ``gym.make_vec`` made its sub-envs, its ``wrappers`` included; a `SyncVectorEnv` without spec is copied.
    """
    if isinstance(env, str):
        return [lambda: gym.make(env, **env_kwargs) for _ in range(n_envs)]
    if not isinstance(env, gym.vector.VectorEnv):
        return env_copies(env, n_envs)
    spec = getattr(env, "spec", None)
    if spec is None:
        if isinstance(env, gym.vector.SyncVectorEnv):
            return [make for i in range(n_envs) for make in env_copies(env.envs[i % len(env.envs)], 1)]
        raise TypeError("SB3Agent needs single envs: pass an env id, an Env or a VectorEnv made by gym.make_vec "
                        f"(a {type(env).__name__} without spec cannot be rebuilt)")
    kwargs = {k: v for k, v in spec.kwargs.items()
              if k not in ("num_envs", "vectorization_mode", "vector_kwargs", "wrappers")}
    wrappers = spec.kwargs.get("wrappers") or ()
    single_spec = dataclasses.replace(spec, kwargs={})  # its max_episode_steps and wrappers, as make_vec keeps them

    def make() -> gym.Env:
        single = gym.make(single_spec, **kwargs)
        for wrapper in wrappers:  # as gym.make_vec applies them to each sub-env
            single = wrapper(single)
        return single

    return [make for _ in range(n_envs)]
