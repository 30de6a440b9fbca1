"""stable-baselines3 algorithms behind the tl_gym agent interface, set up as rl-baselines3-zoo does.

`SB3Agent("TLCarNav-v0", "PPO")` trains any stable-baselines3 (or sb3-contrib)
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
  the raw observation. ``tl_reward="terminal"`` is the plain terminal reward, for the ablation.
- **Per-task hyperparameters** from one YAML file in the zoo's format
  (``agents/hyperparams/sb3.yml``, see `load_hyperparams`); explicit keyword arguments win.

Saving embeds stable-baselines3's own zip as the member ``sb3_model.zip`` and the
pickled `VecNormalize` as ``vecnormalize.pkl`` (the zoo's file; ``VecNormalize.load``
reads it). stable-baselines3 unpickles parts of the first, and the second is a pickle,
so **load only files you trust**. A loaded agent acts and evaluates exactly as the
saved one; it can continue learning, but not bit-identically to an uninterrupted run
(SB3 does not save its random state). An off-policy algorithm's replay buffer is saved apart:
`SB3Agent.save_replay_buffer`.
"""

from __future__ import annotations

import ast
import contextlib
import copy
import dataclasses
import functools
import importlib
import inspect
import io
import math
import pickle
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.checks import check_positive
from tl_gym.errors import IncompatibleSaveError
from tl_gym.relabel import RELABEL_STRATEGIES, EpisodeRecorder, GoalRelabeller, find_wrapper

from .base import Agent, _describe_env_source
from .hindsight import make_hindsight_feeder
from .registry import SB3_CONTRIB_ALGORITHMS
from .sampling import env_attribute
from .serialization import atomic_path, is_jsonable

#: Env steps of one TLPS iteration with the paper's settings (N = 40 episodes × T = 200).
DEFAULT_STEPS_PER_ITERATION = 40 * 200

#: Parallel training envs when neither the user nor the task's hyperparameters say.
DEFAULT_N_ENVS = 8

#: Archive member holding stable-baselines3's own model file.
SB3_MEMBER = "sb3_model.zip"

#: Archive member holding the pickled `VecNormalize` (observation and return statistics).
VECNORMALIZE_MEMBER = "vecnormalize.pkl"

#: Env keywords each ``tl_reward`` adds to an env id's ``env_kwargs`` (the user's own win).
#: ``"markov"`` appends the online monitor's state to the observation and pays the shaped
#: reward; ``"terminal"`` is the plain terminal robustness on the raw observation. Change
#: the shaping here, in one place, once measurements pick the best one.
TL_REWARD_ENV_KWARGS: dict[str, dict[str, Any]] = {
    "markov": {"observe_monitor": True, "reward_mode": "dense"},
    "terminal": {"observe_monitor": False, "reward_mode": "terminal"},
}

#: ``tl_reward`` of an agent built on an env id when the user does not choose.
DEFAULT_TL_REWARD = "markov"

#: VecNormalize settings when neither the user nor the task's hyperparameters say: the
#: observations only (reward normalisation is a per-task choice, as in the zoo).
DEFAULT_NORMALIZE: dict[str, Any] = {"norm_obs": True, "norm_reward": False}

#: The packaged per-task hyperparameters (the zoo's ``hyperparams/<algo>.yml``, all algorithms in one file).
HYPERPARAMS_FILE = Path(__file__).with_name("hyperparams") / "sb3.yml"

#: Keys of a hyperparameter entry that are not the algorithm's constructor arguments.
ENTRY_KEYS = ("n_envs", "policy", "n_timesteps", "normalize", "noise_type", "noise_std")

#: Exploration noise of off-policy algorithms, by the zoo's ``noise_type`` names.
NOISE_TYPES = ("normal", "ornstein-uhlenbeck")

#: Constructor arguments that may be the zoo's ``"lin_<x>"``, a value decaying linearly to 0 over ``n_timesteps``.
SCHEDULE_KEYS = ("learning_rate", "clip_range")

_ALGO_MODULES = ("stable_baselines3", "sb3_contrib")
# constructor arguments that SB3Agent sets itself
_RESERVED_ALGO_ARGS = ("self", "policy", "env", "seed", "verbose", "device", "_init_setup_model")


def resolve_algorithm(algo: Any) -> type:
    """An SB3 algorithm class from a class or a case-insensitive name (``"ppo"``, ``"SAC"``, ``"TQC"``).

    stable-baselines3's names are looked up first; sb3-contrib is imported only for a name SB3 lacks.

    Raises:
        ValueError: no stable-baselines3 / sb3-contrib algorithm has that name; for one of
            `SB3_CONTRIB_ALGORITHMS` when sb3-contrib does not import, the pip command and why.
    """
    from stable_baselines3.common.base_class import BaseAlgorithm

    if isinstance(algo, type) and issubclass(algo, BaseAlgorithm):
        return algo
    if not isinstance(algo, str):
        raise TypeError(f"algo must be an SB3 algorithm class or its name, got {algo!r}")
    known: dict[str, type] = {}
    for module_name in _ALGO_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            if algo.lower() in SB3_CONTRIB_ALGORITHMS:
                raise ValueError(f"algorithm {algo!r} is sb3-contrib's, which does not import ({exc}): "
                                 f"pip install sb3-contrib") from exc
            continue
        for name in dir(module):
            value = getattr(module, name)
            if isinstance(value, type) and issubclass(value, BaseAlgorithm) and value is not BaseAlgorithm:
                known.setdefault(name.lower(), value)
        if algo.lower() in known:
            return known[algo.lower()]
    available = sorted(c.__name__ for c in known.values())
    raise ValueError(f"unknown algorithm {algo!r}; available: {available}")


# Checked settings ---------------------------------------------------------------------------------
def check_tl_reward(value: Any) -> str:
    """Return ``value`` if it is a key of `TL_REWARD_ENV_KWARGS`.

    Raises:
        ValueError: naming the field and the allowed values.
    """
    if not isinstance(value, str) or value not in TL_REWARD_ENV_KWARGS:
        raise ValueError(f"tl_reward must be one of {sorted(TL_REWARD_ENV_KWARGS)}, got {value!r}")
    return value


def parse_normalize(value: Any) -> dict[str, Any] | None:
    """VecNormalize keyword arguments from a zoo-style ``normalize`` value; ``None`` means off.

    ``True`` is VecNormalize's defaults (observations and rewards, as ``normalize: true`` in
    the zoo), ``False`` is off, and a dict or its text (``"{'norm_obs': True, 'norm_reward':
    False}"``, read with `ast.literal_eval`, never `eval`) gives the keywords.

    Example:
        >>> parse_normalize("{'norm_obs': True, 'norm_reward': False}")
        {'norm_obs': True, 'norm_reward': False}
        >>> parse_normalize(True), parse_normalize(False)
        ({}, None)

    Raises:
        ValueError: a keyword VecNormalize does not take, or text that is not a literal dict.
    """
    if isinstance(value, str):
        try:
            value = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            raise ValueError(f"normalize must be true, false or a dict of VecNormalize keywords, got {value!r}") \
                from None
    if value is None or value is False:
        return None
    if value is True:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"normalize must be true, false or a dict of VecNormalize keywords, got {value!r}")
    allowed = _vecnormalize_keywords()
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise ValueError(f"normalize has keyword(s) {unknown} that VecNormalize does not take; valid ones: {allowed}")
    return dict(value)


@functools.lru_cache(maxsize=1)
def _vecnormalize_keywords() -> list[str]:
    from stable_baselines3.common.vec_env import VecNormalize

    return [n for n in inspect.signature(VecNormalize.__init__).parameters if n not in ("self", "venv", "training")]


def parse_policy_kwargs(value: Any) -> dict[str, Any] | None:
    """``policy_kwargs`` as a JSON-able dict, activations named by string.

    Takes a dict (activation as a `torch.nn` class or its name) or the zoo's text,
    ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"``, read safely: only ``dict(...)``
    calls, ``{...}`` literals, plain literals and ``nn.<Activation>`` names are accepted.

    Example:
        >>> parse_policy_kwargs("dict(log_std_init=-2, net_arch=dict(pi=[64], vf=[64]), activation_fn=nn.ReLU)")
        {'log_std_init': -2, 'net_arch': {'pi': [64], 'vf': [64]}, 'activation_fn': 'ReLU'}

    Raises:
        ValueError: text that is not such an expression, or an unknown activation.
    """
    if value is None:
        return None
    if isinstance(value, str):
        try:
            tree = ast.parse(value.strip(), mode="eval").body
        except SyntaxError:
            raise ValueError(f"policy_kwargs text does not parse: {value!r}") from None
        value = _policy_kwargs_node(tree, value)
    if not isinstance(value, Mapping):
        raise ValueError(f"policy_kwargs must be a dict or its text, got {value!r}")
    out = dict(value)
    if "activation_fn" in out:
        out["activation_fn"] = _activation(out["activation_fn"]).__name__
    return out


def _policy_kwargs_node(node: ast.AST, text: str) -> Any:
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        return {kw.arg: _policy_kwargs_node(kw.value, text) for kw in node.keywords}
    if isinstance(node, ast.Dict):
        return {ast.literal_eval(k): _policy_kwargs_node(v, text) for k, v in zip(node.keys, node.values)}
    if isinstance(node, (ast.List, ast.Tuple)):
        return [_policy_kwargs_node(e, text) for e in node.elts]
    if isinstance(node, ast.Attribute):  # nn.Tanh, th.nn.Tanh, torch.nn.Tanh
        return node.attr
    try:
        return ast.literal_eval(node)
    except ValueError:
        raise ValueError(f"policy_kwargs {text!r}: cannot read {ast.unparse(node)!r} (only literals, dict(...) "
                         "and nn.<Activation> are allowed)") from None


def _activation(value: Any) -> type:
    """A `torch.nn` activation class from the class or its case-insensitive name (``"tanh"``, ``"nn.ReLU"``)."""
    import torch.nn.modules.activation as activations

    known = {name.lower(): cls for name, cls in vars(activations).items()
             if isinstance(cls, type) and issubclass(cls, activations.Module)
             and cls.__module__ == activations.__name__}
    if isinstance(value, type) and value in known.values():
        return value
    name = value.rsplit(".", 1)[-1].lower() if isinstance(value, str) else None
    if name not in known:
        raise ValueError(f"unknown activation_fn {value!r}; use a torch.nn activation name, e.g. 'Tanh' or 'ReLU'")
    return known[name]


@dataclass(frozen=True)
class SB3Config:
    """Hyperparameters of `SB3Agent` (the algorithm's own go in ``algo_kwargs``)."""

    algo: str
    """Algorithm class name, e.g. ``"PPO"``."""
    steps_per_iteration: int = DEFAULT_STEPS_PER_ITERATION
    """Env steps per iteration; on-policy algorithms get ``n_steps = steps_per_iteration // n_envs`` by default."""
    n_envs: int = DEFAULT_N_ENVS
    """Parallel envs of SB3's ``DummyVecEnv``."""
    policy: str | None = None
    """SB3 policy name; ``None`` picks ``"MultiInputPolicy"`` for Dict observations, else ``"MlpPolicy"``."""
    tl_reward: str = DEFAULT_TL_REWARD
    """``"markov"`` (monitor view + shaped reward) or ``"terminal"`` (the ablation); see `TL_REWARD_ENV_KWARGS`."""
    normalize: bool | dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_NORMALIZE))
    """VecNormalize: ``False`` (off), ``True`` (its defaults) or its keywords (see `parse_normalize`)."""
    hyperparams: bool | str = True
    """Per-task hyperparameters: ``True`` the packaged file, ``False`` none, or the path of a file."""
    n_timesteps: int | None = None
    """The env-step budget the task's hyperparameters were set for (``tl-gym train`` uses it by default)."""
    noise_type: str | None = None
    """Off-policy exploration noise: ``None``, ``"normal"`` or ``"ornstein-uhlenbeck"`` (std ``noise_std``)."""
    noise_std: float = 0.1
    """Standard deviation of ``noise_type`` noise, in action units."""
    end_is_terminal: bool = True
    """Report the end of every episode to SB3 as a termination. The robustness is of the finite trace
    s_0 … s_T: nothing after its end counts, so SB3 must not add a bootstrapped value past a time-limit
    truncation (which it does, as for infinite-horizon tasks). ``False`` keeps Gymnasium's flags."""
    her_goals: int = 0
    """Hindsight relabelling on goal-conditioned envs (off-policy algorithms): every finished episode is also
    added to the replay buffer ``her_goals`` times, each time with a goal it achieved later and the TL reward
    recomputed for that goal (`tl_gym.relabel`, `agents.hindsight`). 0 is off."""
    her_strategy: str = "future"
    """Which achieved goals `her_goals` relabels with: ``"future"`` (HER's: steps drawn uniformly) or
    ``"satisfied"`` (goals under which the episode satisfies the formula first; `GoalRelabeller.sample`)."""
    algo_kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments for the algorithm's constructor (``learning_rate``, ``n_steps``, ...)."""

    def __post_init__(self) -> None:
        if not isinstance(self.steps_per_iteration, (int, np.integer)) or self.steps_per_iteration < 1:
            raise ValueError(f"steps_per_iteration must be an int >= 1, got {self.steps_per_iteration!r}")
        if not isinstance(self.n_envs, (int, np.integer)) or self.n_envs < 1:
            raise ValueError(f"n_envs must be an int >= 1, got {self.n_envs!r}")
        check_tl_reward(self.tl_reward)
        if not (isinstance(self.normalize, bool) or isinstance(self.normalize, Mapping)):
            raise ValueError(f"normalize must be a bool or a dict of VecNormalize keywords, got {self.normalize!r}")
        parse_normalize(self.normalize)
        if not isinstance(self.hyperparams, (bool, str)):
            raise ValueError(f"hyperparams must be true, false or a file path, got {self.hyperparams!r}")
        if self.n_timesteps is not None and (not isinstance(self.n_timesteps, (int, np.integer))
                                             or self.n_timesteps < 1):
            raise ValueError(f"n_timesteps must be an int >= 1 or None, got {self.n_timesteps!r}")
        if not isinstance(self.end_is_terminal, bool):
            raise ValueError(f"end_is_terminal must be true or false, got {self.end_is_terminal!r}")
        if not isinstance(self.her_goals, (int, np.integer)) or isinstance(self.her_goals, bool) or self.her_goals < 0:
            raise ValueError(f"her_goals must be an int >= 0, got {self.her_goals!r}")
        if self.her_strategy not in RELABEL_STRATEGIES:
            raise ValueError(f"her_strategy must be one of {RELABEL_STRATEGIES}, got {self.her_strategy!r}")
        if self.noise_type is not None and self.noise_type not in NOISE_TYPES:
            raise ValueError(f"noise_type must be None or one of {NOISE_TYPES}, got {self.noise_type!r}")
        check_positive("noise_std", self.noise_std, allow_zero=True)
        for key, value in self.algo_kwargs.items():
            if is_linear_schedule(value):
                linear_start(key, value)
                if self.n_timesteps is None:
                    raise ValueError(f"{key}={value!r} decays over n_timesteps, which is not set; give n_timesteps")


# The hyperparameter file --------------------------------------------------------------------------
def load_hyperparams(path: str | Path | None = None) -> dict[str, dict[str, dict[str, Any]]]:
    """Read and check a per-task hyperparameter file (by default the packaged ``sb3.yml``).

    The file maps an env key to algorithm names to settings, like rl-baselines3-zoo's
    ``hyperparams/<algo>.yml`` with the algorithm as a second level::

        TLCarNav-v0:task=2:          # env id, then optional env keywords it applies to
          ppo:
            n_envs: 8                # tl_gym / zoo keys: n_envs, policy, n_timesteps, normalize,
            n_timesteps: 1.5e6       #   noise_type, noise_std
            normalize: "{'norm_obs': True, 'norm_reward': False}"
            gamma: 0.999             # everything else: the algorithm's constructor arguments
            policy_kwargs: "dict(net_arch=[64, 64], activation_fn=nn.Tanh)"

    Values come back checked and in canonical form: ``n_timesteps`` an int, ``normalize``
    a dict or ``None`` (`parse_normalize`), ``policy_kwargs`` a dict (`parse_policy_kwargs`),
    ``train_freq`` lists as tuples.

    Raises:
        ValueError: naming the entry and the culprit: an unknown algorithm, a key that is neither
            in `ENTRY_KEYS` nor an argument of the algorithm, or a bad value.
    """
    import yaml

    path = HYPERPARAMS_FILE if path is None else Path(path)
    table = yaml.safe_load(path.read_text()) or {}
    if not isinstance(table, Mapping):
        raise ValueError(f"{path}: expected a mapping of env keys to algorithms")
    checked: dict[str, dict[str, dict[str, Any]]] = {}
    for env_key, algos in table.items():
        _split_env_key(str(env_key))
        if not isinstance(algos, Mapping):
            raise ValueError(f"{path}: {env_key}: expected a mapping of algorithm names to settings")
        checked[str(env_key)] = {}
        for algo_name, settings in algos.items():
            where = f"{path}: {env_key} / {algo_name}"
            try:
                algo_class = resolve_algorithm(str(algo_name))
            except ValueError as error:
                raise ValueError(f"{where}: {error}") from None
            if not isinstance(settings, Mapping):
                raise ValueError(f"{where}: expected a mapping of settings")
            checked[str(env_key)][str(algo_name).lower()] = _check_entry(dict(settings), algo_class, where)
    return checked


def _check_entry(settings: dict[str, Any], algo_class: type, where: str) -> dict[str, Any]:
    allowed = set(ENTRY_KEYS) | (set(inspect.signature(algo_class.__init__).parameters) - set(_RESERVED_ALGO_ARGS))
    for key in settings:
        if key not in allowed:
            raise ValueError(f"{where}: unknown key {key!r}: neither one of {list(ENTRY_KEYS)} nor an argument of "
                             f"{algo_class.__name__}")
    try:
        return _canonical(settings)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None


def _canonical(settings: Mapping[str, Any]) -> dict[str, Any]:
    """Settings in the form the config holds (JSON-able where the value allows)."""
    out = dict(settings)
    for key, value in out.items():
        if is_linear_schedule(value):
            linear_start(key, value)  # checked here, built by the agent
    if "n_timesteps" in out:
        value = float(out["n_timesteps"])
        if not math.isfinite(value) or value < 1 or value != int(value):
            raise ValueError(f"n_timesteps must be a whole number >= 1, got {out['n_timesteps']!r}")
        out["n_timesteps"] = int(value)
    if "normalize" in out and not isinstance(out["normalize"], bool):
        normalize = parse_normalize(out["normalize"])
        out["normalize"] = False if normalize is None else normalize
    if "policy_kwargs" in out:
        out["policy_kwargs"] = parse_policy_kwargs(out["policy_kwargs"])
    if isinstance(out.get("train_freq"), list):
        out["train_freq"] = tuple(out["train_freq"])
    return out


def _split_env_key(key: str) -> tuple[str, dict[str, Any]]:
    """``"TLCarNav-v0:task=2"`` -> ``("TLCarNav-v0", {"task": 2})`` (values read as YAML scalars)."""
    import yaml

    env_id, _, conditions = key.partition(":")
    wanted: dict[str, Any] = {}
    for item in filter(None, (c.strip() for c in conditions.split(","))):
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"bad env key {key!r}: expected ID or ID:name=value,...")
        wanted[name.strip()] = yaml.safe_load(value)
    return env_id.strip(), wanted


def find_hyperparams(table: Mapping[str, Mapping[str, Mapping[str, Any]]], env_id: str | None,
                     env_kwargs: Mapping[str, Any], algo: str) -> dict[str, Any]:
    """The settings for ``algo`` on ``env_id`` with ``env_kwargs``; ``{}`` when the table has none.

    Among the keys naming ``env_id`` whose every ``name=value`` condition holds in
    ``env_kwargs`` and that list ``algo``, the one with the most conditions wins
    (``TLCarNav-v0:task=2`` over ``TLCarNav-v0``).

    Example:
        >>> table = {"Car": {"ppo": {"gamma": 0.99}}, "Car:task=2": {"ppo": {"gamma": 0.999}}}
        >>> find_hyperparams(table, "Car", {"task": 2}, "PPO"), find_hyperparams(table, "Car", {}, "ppo")
        ({'gamma': 0.999}, {'gamma': 0.99})
    """
    best: tuple[int, dict[str, Any]] = (-1, {})
    for key, algos in table.items():
        key_id, wanted = _split_env_key(key)
        if key_id != env_id or algo.lower() not in algos:
            continue
        if all(k in env_kwargs and env_kwargs[k] == v for k, v in wanted.items()) and len(wanted) > best[0]:
            best = (len(wanted), dict(algos[algo.lower()]))
    return best[1]


def merge_hyperparameters(entry: Mapping[str, Any], explicit: Mapping[str, Any], on_policy: bool) -> dict[str, Any]:
    """The task's settings overridden by the user's, name by name.

    One exception keeps an iteration at the size the user asked for: when the user sets
    ``steps_per_iteration`` or ``n_envs`` but not ``n_steps``, an on-policy entry's ``n_steps``
    is dropped (``n_steps`` then follows ``steps_per_iteration // n_envs``).

    Example:
        >>> merge_hyperparameters({"n_envs": 8, "n_steps": 1000, "gamma": 0.999}, {"n_envs": 2}, on_policy=True)
        {'n_envs': 2, 'gamma': 0.999}
    """
    merged = {**entry, **explicit}
    if on_policy and "n_steps" not in explicit and {"steps_per_iteration", "n_envs"} & set(explicit):
        merged.pop("n_steps", None)
    return merged


def is_linear_schedule(value: Any) -> bool:
    """Whether a hyperparameter's value is the zoo's ``"lin_<x>"`` schedule."""
    return isinstance(value, str) and value.startswith("lin_")


def linear_start(key: str, value: str) -> float:
    """The start value of the zoo's ``"lin_<x>"`` schedule ``value`` given for ``key``.

    Raises:
        ValueError: ``key`` is not one of `SCHEDULE_KEYS`, or ``<x>`` is not a number > 0.

    Example:
        >>> linear_start("learning_rate", "lin_3e-4")
        0.0003
    """
    if key not in SCHEDULE_KEYS:
        raise ValueError(f"{key}={value!r}: a 'lin_' schedule is only for {list(SCHEDULE_KEYS)}")
    try:
        start = float(value.removeprefix("lin_"))
    except ValueError:
        raise ValueError(f"{key}={value!r}: expected 'lin_<number>', e.g. 'lin_3e-4'") from None
    if not math.isfinite(start) or start <= 0:
        raise ValueError(f"{key}={value!r}: the start value must be a finite number > 0")
    return start


class LinearSchedule:
    """rl-baselines3-zoo's ``lin_<start>``: ``start`` decaying linearly to 0 over ``budget`` env steps.

    SB3 calls a schedule with the progress remaining of the current ``learn`` call, counted
    against the call's last env step. The agent learns in iterations (a ``learn`` call each), so
    it sets `span` to that step before each call, and the schedule turns SB3's progress back into
    the budget's: ``start * (1 - steps / budget)``, the zoo's decay over its ``n_timesteps``, 0
    after the budget.

    Example:
        >>> schedule = LinearSchedule(1e-3, budget=1000)
        >>> schedule.span = 500  # a learn call from step 0 to step 500
        >>> schedule(1.0), schedule(0.0)  # at its start, and at its end (step 500: half the budget)
        (0.001, 0.0005)
    """

    def __init__(self, start: float, budget: int):
        self.start, self.budget, self.span = float(start), int(budget), int(budget)

    def __call__(self, progress_remaining: float) -> float:
        steps = (1.0 - progress_remaining) * self.span
        return self.start * max(0.0, 1.0 - steps / self.budget)


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
        env_kwargs: env constructor keywords for an env id; they win over the ones ``tl_reward`` adds.
        steps_per_iteration, n_envs, policy, normalize, n_timesteps, noise_type, noise_std: see
            `SB3Config`; ``None`` takes the task's value from the hyperparameter file, else the default.
        tl_reward: ``"markov"`` or ``"terminal"``. With an env id it adds the env keywords of
            `TL_REWARD_ENV_KWARGS` (default ``"markov"``). An `Env` or `VectorEnv` object cannot be
            rebuilt with other keywords: ``None`` reads what it does, and an explicit value it
            visibly contradicts (its ``observe_monitor`` / ``reward_mode``) is an error.
        hyperparams: ``True`` (the packaged ``sb3.yml``), ``False`` (none: SB3's defaults) or a file path.
        **algo_kwargs: the algorithm's constructor arguments; each one given wins over the file's.

    History rows add ``episodes`` (episodes that ended in the iteration).

    Raises:
        ValueError: a bad setting (naming it), an iteration more than 5% off ``steps_per_iteration``,
            or a ``tl_reward`` the env object contradicts.
        TypeError: an env id that does not take the keywords ``tl_reward`` adds.

    Example:
        >>> resolve_algorithm("ppo").__name__  # what SB3Agent("TLCarNav-v0", "ppo") trains
        'PPO'
    """

    config: SB3Config
    config_class = SB3Config

    def __init__(self, env: Any, algo: Any, *, seed: int | None = None, env_kwargs: Mapping[str, Any] | None = None,
                 steps_per_iteration: int | None = None, n_envs: int | None = None, policy: str | None = None,
                 tl_reward: str | None = None, normalize: Any = None, hyperparams: bool | str = True,
                 n_timesteps: int | None = None, noise_type: str | None = None, noise_std: float | None = None,
                 **algo_kwargs: Any):
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

        _check_argument_order(env, algo)
        self.algo_class = resolve_algorithm(algo)
        on_policy = issubclass(self.algo_class, OnPolicyAlgorithm)
        if tl_reward is not None:
            check_tl_reward(tl_reward)
        if isinstance(env, str):
            tl_reward = tl_reward or DEFAULT_TL_REWARD
            env_kwargs = {**TL_REWARD_ENV_KWARGS[tl_reward], **dict(env_kwargs or {})}
        else:
            tl_reward = _tl_reward_of(env, tl_reward)
        explicit = {k: v for k, v in dict(
            steps_per_iteration=steps_per_iteration, n_envs=n_envs, policy=policy, normalize=normalize,
            n_timesteps=n_timesteps, noise_type=noise_type, noise_std=noise_std).items() if v is not None}
        explicit = _canonical({**explicit, **algo_kwargs})
        entry = {}
        if hyperparams is not False:
            table = load_hyperparams(None if hyperparams is True else hyperparams)
            entry = find_hyperparams(table, *_env_key(env, env_kwargs), self.algo_class.__name__)
        settings = merge_hyperparameters(entry, explicit, on_policy)
        if isinstance(env, str) and env_kwargs.get("reward_mode") == "potential" and "gamma" not in env_kwargs:
            # potential shaping keeps the optimal policies only with the agent's own discount
            env_kwargs = {**env_kwargs, "gamma": settings.get("gamma", _default_argument(self.algo_class, "gamma",
                                                                                           0.99))}
        fields = {f.name for f in dataclasses.fields(SB3Config)} - {"algo_kwargs"}
        hyperparameters = {k: v for k, v in settings.items() if k in fields}
        hyperparameters.update(algo=self.algo_class.__name__, tl_reward=tl_reward, hyperparams=hyperparams,
                               algo_kwargs={k: v for k, v in settings.items() if k not in fields})
        config = self._make_config(hyperparameters)  # checked before any env is built
        self._env_argument = env
        self._train_env_kwargs = dict(env_kwargs or {})  # read by _setup, which runs inside Agent.__init__
        if isinstance(env, str):
            venv = _make_sync_vec(env, config.n_envs, self._train_env_kwargs, TL_REWARD_ENV_KWARGS[tl_reward])
            super().__init__(venv, seed=seed, **hyperparameters)
            self.env_kwargs = dict(self._train_env_kwargs)
            self._env_source = _describe_env_source(env, self.env_kwargs)
        else:
            super().__init__(env, seed=seed, env_kwargs=env_kwargs, **hyperparameters)

    def _num_envs(self) -> int:
        return self.config.n_envs

    @property
    def n_timesteps(self) -> int | None:
        """The env-step budget of the task's hyperparameters (``None`` when they state none)."""
        return self.config.n_timesteps

    def _setup(self) -> None:
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

        kwargs = dict(self.config.algo_kwargs)
        self._schedules = {key: LinearSchedule(linear_start(key, value), self.config.n_timesteps)  # type: ignore[arg-type]
                           for key, value in kwargs.items() if is_linear_schedule(value)}
        kwargs.update({key: schedule.start for key, schedule in self._schedules.items()})  # installed after
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
                                       "activation_fn": _activation(kwargs["policy_kwargs"]["activation_fn"])}
        if self.config.noise_type is not None and "action_noise" not in kwargs:
            kwargs["action_noise"] = _action_noise(self.config.noise_type, self.config.noise_std, self.action_space)
        factories = _single_env_factories(self._env_argument, self._train_env_kwargs, self.config.n_envs)
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
            normalize.setdefault("gamma", kwargs.get("gamma", _default_argument(self.algo_class, "gamma", 0.99)))
            self.vec_normalize = VecNormalize(self.sb3_env, **normalize)
        policy = self.config.policy or (
            "MultiInputPolicy" if isinstance(self.observation_space, gym.spaces.Dict) else "MlpPolicy"
        )
        self.model = self.algo_class(policy, self._training_env(), seed=self.seed, verbose=0, device="cpu", **kwargs)
        self._install_schedules()
        self._quiet_logger()

    def _install_schedules(self) -> None:
        """Put the ``lin_`` schedules where SB3 reads them (it rebuilds constant ones from the start values on load)."""
        for key, schedule in self._schedules.items():
            setattr(self.model, "lr_schedule" if key == "learning_rate" else key, schedule)

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
        collector = _make_collector()
        before = self.model.num_timesteps
        for schedule in self._schedules.values():  # the env step SB3 counts this call's progress against
            schedule.span = before + self.config.steps_per_iteration
        if self._schedules and before >= self.config.n_timesteps:  # type: ignore[operator]  # a whole iteration at 0
            warnings.warn(f"the 'lin_' schedules of {sorted(self._schedules)} end at n_timesteps: past it they are 0 "
                          "(a learning rate of 0 leaves the policy as it is)", stacklevel=2)
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
        """Actions for raw env observations: normalised with the VecNormalize statistics (not updated)."""
        if self.vec_normalize is not None:
            obs = self.vec_normalize.normalize_obs(obs)
        with one_torch_thread():
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)

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
                    if "robustness" not in info:
                        raise RuntimeError("the env's terminal info holds no 'robustness': wrap it in "
                                           "tl_gym.TLTLRewardWrapper")
                    self.robustness.append(float(info["robustness"]))
            return True

    return RobustnessCollector()


def _default_argument(algo_class: type, name: str, fallback: Any) -> Any:
    parameter = inspect.signature(algo_class.__init__).parameters.get(name)
    return fallback if parameter is None or parameter.default is inspect.Parameter.empty else parameter.default


def _action_noise(noise_type: str, std: float, space: gym.Space) -> Any:
    """The zoo's ``noise_type`` / ``noise_std`` as an SB3 action noise object."""
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    shape = space.shape or (1,)
    mean, sigma = np.zeros(shape), np.full(shape, float(std))
    return NormalActionNoise(mean, sigma) if noise_type == "normal" else OrnsteinUhlenbeckActionNoise(mean, sigma)


def _env_key(env: Any, env_kwargs: Mapping[str, Any] | None) -> tuple[str | None, dict[str, Any]]:
    """The env id and keywords the hyperparameter file is looked up with."""
    if isinstance(env, str):
        return env, dict(env_kwargs or {})
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


def _tl_reward_of(env: Any, asked: str | None) -> str:
    """The ``tl_reward`` an env object implements: checked against ``asked``, else read from it.

    The object cannot be rebuilt with other keywords, so an explicit choice that one of its
    readable settings contradicts is an error; a setting it does not expose is not checked.
    """
    if asked is not None:
        has = {k: _env_setting(env, k) for k in TL_REWARD_ENV_KWARGS[asked]}
        wrong = {k: (v, has[k]) for k, v in TL_REWARD_ENV_KWARGS[asked].items() if has[k] is not None and has[k] != v}
        if wrong:
            detail = ", ".join(f"{k}={want!r} (the env has {got!r})" for k, (want, got) in wrong.items())
            raise ValueError(f"tl_reward={asked!r} needs the env keywords {detail}; an env object cannot be rebuilt "
                             f"by the agent: make it with those keywords, or pass the env id instead")
        return asked
    markov = TL_REWARD_ENV_KWARGS["markov"]
    return "markov" if all(_env_setting(env, k) == v for k, v in markov.items()) else "terminal"


def _make_sync_vec(env_id: str, n_envs: int, env_kwargs: Mapping[str, Any],
                   added: Mapping[str, Any]) -> gym.vector.VectorEnv:
    """The evaluation env: ``n_envs`` of the very single envs SB3 trains on, so the observation layout matches."""
    try:
        return gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="sync", **env_kwargs)
    except TypeError as error:
        if not added:
            raise
        raise TypeError(f"{env_id} does not take the env keywords {dict(added)} that tl_reward adds ({error}); "
                        "pass tl_reward='terminal', or env_kwargs that set them") from error


def _single_env_factories(env: Any, env_kwargs: dict[str, Any], n_envs: int) -> list[Any]:
    """Constructors of ``n_envs`` single envs equivalent to ``env`` (an id, an Env or a VectorEnv)."""
    if isinstance(env, str):
        return [lambda: gym.make(env, **env_kwargs) for _ in range(n_envs)]
    spec = getattr(env, "spec", None)
    if isinstance(env, gym.vector.VectorEnv):
        if spec is None:
            raise TypeError("SB3Agent needs single envs: pass an env id or an Env, not a VectorEnv without spec")
        kwargs = {k: v for k, v in spec.kwargs.items()
                  if k not in ("num_envs", "vectorization_mode", "vector_kwargs", "wrappers")}
        return [lambda: gym.make(spec.id, **kwargs) for _ in range(n_envs)]
    if spec is not None:
        try:
            gym.make(spec).close()
            return [lambda: gym.make(spec) for _ in range(n_envs)]
        except Exception:  # noqa: BLE001 - a spec that cannot rebuild the env: copy the env instead
            pass
    copies = [copy.deepcopy(env) for _ in range(n_envs)]
    return [lambda e=e: e for e in copies]
