"""The settings of `SB3Agent`: its config, its checks, and the zoo-style hyperparameter file.

rl-baselines3-zoo keeps per-task hyperparameters in ``hyperparams/<algo>.yml``; tl_gym keeps
them in one file, ``agents/hyperparams/sb3.yml`` (`load_hyperparams`, `find_hyperparams`,
`merge_hyperparameters`), with the zoo's value forms: ``normalize`` (`parse_normalize`),
``policy_kwargs`` text (`parse_policy_kwargs`, read without `eval`) and ``lin_<x>`` schedules
(`LinearSchedule`). Everything here is checked at construction and names the culprit; nothing
here builds an env or a model (that is `tl_gym.agents.sb3`), and stable-baselines3 is imported
only where an algorithm or VecNormalize must be looked up.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import importlib
import importlib.util
import inspect
import math
import os
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.checks import check_count, check_fraction, check_positive, did_you_mean
from tl_gym.relabel import RELABEL_STRATEGIES

from .serialization import is_jsonable

#: The names a stable-baselines3 algorithm takes here.
SB3_ALGORITHMS = ("a2c", "ddpg", "dqn", "ppo", "sac", "td3")
#: The names of sb3-contrib's algorithms (``pip install sb3-contrib``; imported only for one of these names).
SB3_CONTRIB_ALGORITHMS = ("ars", "crossq", "maskableppo", "qrdqn", "recurrentppo", "tqc", "trpo")

#: Algorithms that resolve but that the agent refuses, and why (named at construction).
REFUSED_ALGORITHMS = {
    "ARS": "ARS updates from whole evaluation episodes of perturbed policies (2 × n_delta × n_eval_episodes of "
           "them an update), not from env steps, so it fits neither the agent's iterations of steps_per_iteration "
           "nor its episode statistics; for episodic policy search use tl_gym's REPS or TLPS",
    "MaskablePPO": "MaskablePPO needs the env's action masks at every prediction, which the agent's predict and "
                   "evaluate do not pass (a stochastic policy would take masked actions); use PPO, or sb3-contrib's "
                   "MaskablePPO directly on the wrapped env",
}

#: Env steps of one TLPS iteration with the paper's settings (N = 40 episodes × T = 200).
DEFAULT_STEPS_PER_ITERATION = 40 * 200

#: Parallel training envs of on-policy algorithms when neither the user nor the task's hyperparameters say; an
#: off-policy one gets 1 (the zoo's default: one gradient step per env step; 8 envs made it one per 8 steps).
DEFAULT_N_ENVS = 8

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

#: The entry key of env keywords a task adds to ``TL_REWARD_ENV_KWARGS["markov"]`` (its measured best shaping).
MARKOV_ENV_KWARGS = "markov_env_kwargs"

#: Keys of a hyperparameter entry that are not the algorithm's constructor arguments.
ENTRY_KEYS = ("n_envs", "policy", "n_timesteps", "normalize", "noise_type", "noise_std", "env_wrapper",
              MARKOV_ENV_KWARGS)

#: Exploration noise of off-policy algorithms, by the zoo's ``noise_type`` names.
NOISE_TYPES = ("normal", "ornstein-uhlenbeck")

#: Constructor arguments that may be a schedule of the training's progress: the zoo's ``"lin_<x>"`` (a value decaying
#: linearly to 0) or SB3's callable ``f(progress_remaining)``, both run over ``n_timesteps`` (`BudgetSchedule`).
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")

#: The constructor argument of algorithms whose exploration decays over a share of the training (DQN's ε).
EXPLORATION_FRACTION = "exploration_fraction"

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


def check_hyperparams_source(value: Any) -> bool | str:
    """``hyperparams`` as the config holds it: ``True`` (the packaged file), ``False`` (none) or a path as text.

    A `pathlib.Path` (any ``os.PathLike``) is taken and written as text, so the config stays JSON-able.

    Example:
        >>> check_hyperparams_source(Path("my_zoo.yml")), check_hyperparams_source(False)
        ('my_zoo.yml', False)

    Raises:
        ValueError: anything else, named.
    """
    if isinstance(value, os.PathLike):
        value = os.fspath(value)
    if not isinstance(value, (bool, str)):
        raise ValueError(f"hyperparams must be true, false or a file path, got {value!r}")
    return value


def tl_reward_of_view(observe_monitor: Any) -> str:
    """The ``tl_reward`` label of an env with or without the Markov view: ``"markov"`` iff it observes its monitor.

    The one rule for env keywords (`tl_reward_of_env_kwargs`) and env objects alike; the reward mode
    does not enter it (dense, potential, with a bonus: all are the view's shaped rewards).

    Example:
        >>> tl_reward_of_view(True), tl_reward_of_view(None)
        ('markov', 'terminal')
    """
    return "markov" if observe_monitor else "terminal"


def tl_reward_of_env_kwargs(asked: str | None, env_kwargs: Mapping[str, Any], source: str = "env_kwargs") -> str:
    """The ``tl_reward`` an env made with ``env_kwargs`` (the preset's merged under the user's) implements.

    The user's keywords win over the preset's, so the label follows the view they leave
    (``observe_monitor``), as it is read from an env object; an explicit ``tl_reward`` they
    contradict is an error rather than a label that would say ``"markov"`` of an env without the view.

    Args:
        asked: the ``tl_reward`` asked for, ``None`` when not.
        env_kwargs: the merged keywords the env is made with.
        source: what the user called those keywords, for the message.

    Raises:
        ValueError: ``asked`` and ``env_kwargs``'s ``observe_monitor`` disagree, naming both.

    Example:
        >>> tl_reward_of_env_kwargs(None, {"observe_monitor": False, "reward_mode": "dense"})
        'terminal'
    """
    read = tl_reward_of_view(env_kwargs.get("observe_monitor"))
    if asked is not None and asked != read:
        raise ValueError(f"tl_reward={asked!r} sets observe_monitor={asked == 'markov'}, but {source} set "
                         f"observe_monitor={env_kwargs.get('observe_monitor')!r}: drop one of the two "
                         f"(without tl_reward, these keywords make tl_reward='{read}')")
    return read


def parse_env_wrappers(value: Any) -> list[tuple[type, dict[str, Any]]]:
    """The zoo's ``env_wrapper`` as ``[(wrapper class, keywords), ...]``, innermost first.

    ``value`` is None, a class path (``"gymnasium.wrappers.FlattenObservation"``, or ``"module:Class"``), a
    ``{path: keywords}`` dict, or a list of either, as rl-baselines3-zoo's hyperparameter files write it.

    Raises:
        ValueError: naming the entry that is no importable Gymnasium wrapper, or the form that is not one of these.

    Example:
        >>> parse_env_wrappers(["gymnasium.wrappers.FlattenObservation"])
        [(<class 'gymnasium.wrappers.transform_observation.FlattenObservation'>, {})]
    """
    if value is None:
        return []
    items = value if isinstance(value, list) else [value]
    wrappers = []
    for item in items:
        if isinstance(item, dict) and len(item) == 1:
            (path, keywords), = item.items()
            keywords = {} if keywords is None else keywords
        elif isinstance(item, str):
            path, keywords = item, {}
        else:
            raise ValueError("env_wrapper entries are 'module.Class' or {'module.Class': {keywords}}, "
                             f"got {item!r}")
        if not isinstance(keywords, dict):
            raise ValueError(f"env_wrapper {path!r}: its keywords must be a dict, got {keywords!r}")
        module_name, _, name = path.rpartition(":") if ":" in path else path.rpartition(".")
        try:
            wrapper = getattr(importlib.import_module(module_name), name)
        except (ImportError, AttributeError, ValueError) as exc:
            raise ValueError(f"env_wrapper {path!r} does not import ({exc})") from None
        if not (isinstance(wrapper, type) and issubclass(wrapper, gym.Wrapper)):
            raise ValueError(f"env_wrapper {path!r} is not a gymnasium.Wrapper class")
        wrappers.append((wrapper, dict(keywords)))
    return wrappers


def wrap_env(env: gym.Env, wrappers: list[tuple[type, dict[str, Any]]]) -> gym.Env:
    """``env`` inside `parse_env_wrappers`' wrappers, innermost first."""
    for wrapper, keywords in wrappers:
        env = wrapper(env, **keywords)
    return env


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
    calls, ``{...}`` literals, plain literals and ``nn.<Activation>`` names (as ``activation_fn``) are accepted.

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
        out["activation_fn"] = activation_class(out["activation_fn"]).__name__
    return out


def _policy_kwargs_node(node: ast.AST, text: str, key: Any = None) -> Any:
    """The value of ``node``, the value of ``key`` in the policy_kwargs ``text``."""
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        return {kw.arg: _policy_kwargs_node(kw.value, text, kw.arg) for kw in node.keywords}
    if isinstance(node, ast.Dict):
        keys = [ast.literal_eval(k) for k in node.keys]
        return {k: _policy_kwargs_node(v, text, k) for k, v in zip(keys, node.values)}
    if isinstance(node, (ast.List, ast.Tuple)):
        return [_policy_kwargs_node(e, text) for e in node.elts]
    if isinstance(node, ast.Attribute) and key == "activation_fn":  # nn.Tanh, th.nn.Tanh, torch.nn.Tanh
        return node.attr
    try:
        return ast.literal_eval(node)
    except ValueError:
        raise ValueError(f"policy_kwargs {text!r}: cannot read {ast.unparse(node)!r} (only literals, dict(...) "
                         "and activation_fn=nn.<Activation> are allowed; pass other classes from Python)") from None


def activation_class(value: Any) -> type:
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
    n_envs: int | None = None
    """Parallel envs of SB3's ``DummyVecEnv``; ``None``: `DEFAULT_N_ENVS` for on-policy algorithms, 1 for off-policy
    ones (set at construction)."""
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
    """Standard deviation of ``noise_type`` noise on SB3's scaled actions, ``[-1, 1]`` across the Box (where SB3 adds
    it, as in the zoo): in the env's units it is ``noise_std * (high - low) / 2``."""
    env_wrapper: str | list[Any] | dict[str, Any] | None = None
    """The zoo's ``env_wrapper``: Gymnasium wrappers put around each env the agent trains and evaluates on, innermost
    first, as ``"module.Class"``, a list of them, or ``{"module.Class": {keywords}}`` items (`parse_env_wrappers`),
    e.g. ``"gymnasium.wrappers.FlattenObservation"`` for an algorithm without a policy for Dict observations."""
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
        check_count("steps_per_iteration", self.steps_per_iteration)
        if self.n_envs is None:
            from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

            on_policy = issubclass(resolve_algorithm(self.algo), OnPolicyAlgorithm)
            object.__setattr__(self, "n_envs", DEFAULT_N_ENVS if on_policy else 1)
        check_count("n_envs", self.n_envs)
        check_tl_reward(self.tl_reward)
        if not (isinstance(self.normalize, bool) or isinstance(self.normalize, Mapping)):
            raise ValueError(f"normalize must be a bool or a dict of VecNormalize keywords, got {self.normalize!r}")
        parse_normalize(self.normalize)
        check_hyperparams_source(self.hyperparams)
        if isinstance(self.hyperparams, os.PathLike):  # the config is JSON: SB3Agent writes a Path as text
            raise ValueError(f"hyperparams must be true, false or a file path as text, got {self.hyperparams!r}")
        check_count("n_timesteps", self.n_timesteps, allow_none=True)
        if not isinstance(self.end_is_terminal, bool):
            raise ValueError(f"end_is_terminal must be true or false, got {self.end_is_terminal!r}")
        if not isinstance(self.her_goals, (int, np.integer)) or isinstance(self.her_goals, bool) or self.her_goals < 0:
            raise ValueError(f"her_goals must be an int >= 0, got {self.her_goals!r}")
        if self.her_strategy not in RELABEL_STRATEGIES:
            raise ValueError(f"her_strategy must be one of {RELABEL_STRATEGIES}, got {self.her_strategy!r}")
        if self.noise_type is not None and self.noise_type not in NOISE_TYPES:
            raise ValueError(f"noise_type must be None or one of {NOISE_TYPES}, got {self.noise_type!r}")
        check_positive("noise_std", self.noise_std, allow_zero=True)
        parse_env_wrappers(self.env_wrapper)
        if not is_jsonable(self.env_wrapper):  # the agent saves its settings as JSON
            raise ValueError(f"env_wrapper={self.env_wrapper!r}: its keywords must be JSON values (numbers, text, "
                             "lists, dicts) so that the agent can be saved; wrap the env object yourself instead")
        algo_class = resolve_algorithm(self.algo)
        if algo_class.__name__ in REFUSED_ALGORITHMS:
            raise ValueError(REFUSED_ALGORITHMS[algo_class.__name__])
        check_algorithm_arguments(algo_class, self.algo_kwargs, setting_names())
        if self.noise_type is not None and "action_noise" not in algorithm_parameters(algo_class):
            raise ValueError(f"noise_type={self.noise_type!r}: {algo_class.__name__} takes no action noise (it "
                             f"explores through its own policy); noise_type is for off-policy algorithms such as TD3")
        for key, value in self.algo_kwargs.items():
            if is_schedule(key, value):
                if is_linear_schedule(value):
                    linear_start(key, value)
                if self.n_timesteps is None:
                    raise ValueError(f"{key}={value!r} is a schedule of the training's progress, which runs over "
                                     "n_timesteps here (each iteration is its own SB3 learn call); give n_timesteps "
                                     "(tl-gym train: --n-timesteps)")
            else:
                check_algorithm_value(key, value)


def setting_names() -> tuple[str, ...]:
    """`SB3Config`'s own settings, in its order; every other hyperparameter is an algorithm argument."""
    return tuple(f.name for f in dataclasses.fields(SB3Config) if f.name not in ("algo", "algo_kwargs"))


def split_settings(settings: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``settings`` as ``(SB3Config's own, the algorithm's arguments)``: the one rule that tells them apart.

    Example:
        >>> split_settings({"n_envs": 4, "learning_rate": 3e-4})
        ({'n_envs': 4}, {'learning_rate': 0.0003})
    """
    own = setting_names()
    return ({k: v for k, v in settings.items() if k in own}, {k: v for k, v in settings.items() if k not in own})


#: The common algorithm arguments whose values are checked here (SB3 takes any, and fails later or never).
_FRACTIONS = {"gamma": False, "tau": False, "gae_lambda": True}  # in (0, 1], or [0, 1] where True
_COUNTS = ("batch_size", "buffer_size", "n_steps", "n_epochs")


def check_algorithm_value(key: str, value: Any) -> None:
    """Check the value of a common algorithm argument: a discount or rate in its interval, a positive size.

    SB3 accepts ``gamma=2.0`` (and learns nothing) and meets ``learning_rate="fast"`` with an AssertionError deep
    in its setup; a schedule (a callable, ``"lin_3e-4"``) is checked elsewhere. Other arguments pass as they are.

    Example:
        >>> check_algorithm_value("gamma", 2.0)
        Traceback (most recent call last):
        ...
        ValueError: gamma must lie in (0, 1], got 2.0
    """
    if callable(value):
        return
    if key in _FRACTIONS:
        check_fraction(key, value, allow_zero=_FRACTIONS[key])
    elif key == "learning_rate":
        check_positive(key, value)
    elif key in _COUNTS:
        check_count(key, value)


# The hyperparameter file --------------------------------------------------------------------------
def load_hyperparams(path: str | Path | None = None) -> dict[str, dict[str, dict[str, Any]]]:
    """Read and check a per-task hyperparameter file (by default the packaged ``sb3.yml``).

    The file maps an env key to algorithm names to settings, like rl-baselines3-zoo's
    ``hyperparams/<algo>.yml`` with the algorithm as a second level::

        TLCarNav-v0:task=2:          # env id, then optional env keywords it applies to
          ppo:
            n_envs: 8                # tl_gym / zoo keys: n_envs, policy, n_timesteps, normalize,
            n_timesteps: 1.5e6       #   noise_type, noise_std, markov_env_kwargs
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
    table = yaml.load(path.read_text(), Loader=_yaml_loader()) or {}
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


@functools.lru_cache(maxsize=1)
def _yaml_loader() -> type:
    """PyYAML's safe loader, reading ``3e-4`` as a number as YAML 1.2 does.

    PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent (``3.0e-4``): ``3e-4``
    would reach the algorithm as the text ``'3e-4'`` and fail late and obscurely (the zoo's files
    write ``!!float 3e-4``, which still works).
    """
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    exponent = re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$")  # 3e-4, 1.5e6, .5E3
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", exponent, list("-+.0123456789"))
    return Loader


def algorithm_parameters(algo_class: type) -> Mapping[str, inspect.Parameter]:
    """The parameters of an SB3 algorithm's constructor, by name (``self``, ``policy``, ``env`` included)."""
    return inspect.signature(algo_class.__init__).parameters


def check_algorithm_arguments(algo_class: type, names: Iterable[str], settings: Iterable[str] = ()) -> None:
    """Check that every name is one of ``settings`` or an argument of the algorithm's constructor SB3Agent may pass.

    A misspelt hyperparameter fails here, when the agent (or a hyperparameter file) is read, naming
    the nearest accepted name, not later inside SB3's constructor.

    Raises:
        ValueError: naming the first culprit: an argument SB3Agent sets itself (``seed``, ``verbose``,
            ``device``, ...), or a name that is neither.

    Example:
        >>> from stable_baselines3 import SAC
        >>> check_algorithm_arguments(SAC, ["learning_rate", "tau"])
        >>> check_algorithm_arguments(SAC, ["learning_rat"])
        Traceback (most recent call last):
        ...
        ValueError: unknown hyperparameter 'learning_rat' (did you mean 'learning_rate'?): not an argument of SAC
    """
    accepted = set(algorithm_parameters(algo_class)) - set(_RESERVED_ALGO_ARGS)
    settings = tuple(settings)
    for name in names:
        if name in accepted or name in settings:
            continue
        if name in _RESERVED_ALGO_ARGS:
            raise ValueError(f"hyperparameter {name!r}: SB3Agent sets {algo_class.__name__}'s {name!r} itself "
                             f"(seed from seed=, verbose=0, device='cpu', the env from env=)")
        hint = did_you_mean(name, sorted(accepted | set(settings)))
        kinds = f"neither one of {list(settings)} nor an argument" if settings else "not an argument"
        raise ValueError(f"unknown hyperparameter {name!r}{hint}: {kinds} of {algo_class.__name__}")


def _check_entry(settings: dict[str, Any], algo_class: type, where: str) -> dict[str, Any]:
    try:
        check_algorithm_arguments(algo_class, settings, ENTRY_KEYS)
        return canonical_settings(settings)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None


def check_exploration_budget(algo_class: type, n_timesteps: int | None) -> None:
    """Refuse an algorithm whose exploration decays over a share of the training (DQN's ε) without a budget.

    Each iteration is its own SB3 ``learn`` call, so without ``n_timesteps`` the decay would start anew in every
    one. Checked when an agent is built, not when one is loaded (one saved before the rule keeps its own decay).

    Raises:
        ValueError: naming the algorithm and ``n_timesteps`` (``--n-timesteps`` of ``tl-gym train``).
    """
    if EXPLORATION_FRACTION in algorithm_parameters(algo_class) and n_timesteps is None:
        raise ValueError(f"{algo_class.__name__} decays its exploration over {EXPLORATION_FRACTION} × n_timesteps "
                         "env steps, as in rl-baselines3-zoo (each iteration is its own SB3 learn call, so without a "
                         "budget it would decay anew in every one); give n_timesteps (tl-gym train: --n-timesteps)")


def check_sb3_hyperparameters(algo: Any, hyperparameters: Mapping[str, Any]) -> None:
    """Check an SB3 agent's hyperparameters without an env, as `SB3Agent` checks them before building one.

    Names (an `SB3Config` setting or an argument of the algorithm, with the nearest name) and values (the
    settings', and the common arguments' of `check_algorithm_value`): a run config is checked this way before
    any run starts (`benchmarks.sweep_config`). The task's hyperparameter file is not read (it needs the env's id).

    Raises:
        ValueError, TypeError: naming the hyperparameter.
    """
    algo_class = resolve_algorithm(algo)
    own, algo_kwargs = split_settings(canonical_settings(hyperparameters))
    SB3Config(algo=algo_class.__name__, **{"n_timesteps": 1, **own}, algo_kwargs=algo_kwargs)
    check_tensorboard(algo_kwargs)


def check_tensorboard(algo_kwargs: Mapping[str, Any]) -> None:
    """Refuse ``tensorboard_log`` without the tensorboard package, which SB3 needs only at its first ``learn()``.

    Checked for an agent being built and when an agent learns, not when one is loaded: a saved agent acts and
    evaluates without it.
    """
    value = algo_kwargs.get("tensorboard_log")
    if value is not None and importlib.util.find_spec("tensorboard") is None:
        raise ImportError(f"tensorboard_log={value!r} needs the tensorboard package, which is not installed "
                          "(pip install tensorboard)")


def canonical_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
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
    if MARKOV_ENV_KWARGS in out:
        out[MARKOV_ENV_KWARGS] = parse_markov_env_kwargs(out[MARKOV_ENV_KWARGS])
    if isinstance(out.get("train_freq"), list):
        out["train_freq"] = tuple(out["train_freq"])
    return out


def parse_markov_env_kwargs(value: Any) -> dict[str, Any]:
    """An entry's ``markov_env_kwargs``: env keywords the task adds when ``tl_reward="markov"``.

    They sit between `TL_REWARD_ENV_KWARGS` ``["markov"]`` and the user's ``env_kwargs`` (the
    user's win), so a task can turn on the shaping measured best for it (``satisfaction_bonus``,
    ``reward_mode``, ...) without touching other tasks; the ``"terminal"`` ablation never gets
    them. They may not set ``observe_monitor`` (the view is what ``"markov"`` means) nor ``gamma``
    (potential shaping takes the agent's own discount).

    Example:
        >>> parse_markov_env_kwargs({"satisfaction_bonus": 10.0})
        {'satisfaction_bonus': 10.0}

    Raises:
        ValueError: not a mapping of keyword names, or one that sets ``observe_monitor`` or ``gamma``.
    """
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and k.isidentifier() for k in value):
        raise ValueError(f"{MARKOV_ENV_KWARGS} must be a mapping of env keyword names to values, got {value!r}")
    if "observe_monitor" in value:
        raise ValueError(f"{MARKOV_ENV_KWARGS} may not set observe_monitor (tl_reward='markov' is the monitor "
                         f"view; 'terminal' is the ablation without it), got {dict(value)!r}")
    if "gamma" in value:
        raise ValueError(f"{MARKOV_ENV_KWARGS} may not set gamma: the shaping's discount is the agent's (set the "
                         f"entry's own gamma), got {dict(value)!r}")
    return dict(value)


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


def is_schedule(key: str, value: Any) -> bool:
    """Whether ``key``'s value is run over ``n_timesteps``: ``"lin_<x>"``, or a callable for a `SCHEDULE_KEYS` key."""
    return is_linear_schedule(value) or (key in SCHEDULE_KEYS and callable(value))


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


class BudgetSchedule:
    """SB3's schedule ``f(progress_remaining)`` run over ``budget`` env steps instead of one ``learn`` call.

    SB3 calls a schedule with the progress remaining of the current ``learn`` call, counted
    against the call's last env step. The agent learns in iterations (a ``learn`` call each), so
    it sets `span` to that step before each call, and the schedule turns SB3's progress back into
    the budget's, ``1 - steps / budget`` (0 after the budget): a schedule falls once over the
    zoo's ``n_timesteps``, as ``model.learn(n_timesteps)`` would have it, instead of restarting
    in every iteration (a learning rate that fell to 0 at each iteration's end).

    Example:
        >>> schedule = BudgetSchedule(lambda progress: 1e-3 * progress, budget=1000)
        >>> schedule.span = 500  # a learn call from step 0 to step 500
        >>> schedule(1.0), schedule(0.0)  # at its start, and at its end (step 500: half the budget)
        (0.001, 0.0005)
    """

    def __init__(self, schedule: Callable[[float], float], budget: int):
        self.schedule, self.budget, self.span = schedule, int(budget), int(budget)

    def remaining(self, progress_remaining: float) -> float:
        """The budget's progress remaining, from SB3's progress remaining of the current ``learn`` call."""
        steps = (1.0 - progress_remaining) * self.span
        return max(0.0, 1.0 - steps / self.budget)

    def __call__(self, progress_remaining: float) -> float:
        return self.schedule(self.remaining(progress_remaining))


class LinearSchedule(BudgetSchedule):
    """rl-baselines3-zoo's ``lin_<start>``: ``start`` decaying linearly to 0 over ``budget`` env steps.

    Example:
        >>> schedule = LinearSchedule(1e-3, budget=1000)
        >>> schedule.span = 500  # a learn call from step 0 to step 500
        >>> schedule(1.0), schedule(0.0)  # at its start, and at its end (step 500: half the budget)
        (0.001, 0.0005)
    """

    def __init__(self, start: float, budget: int):  # its attributes are those agents saved with it pickle
        self.start, self.budget, self.span = float(start), int(budget), int(budget)

    def __call__(self, progress_remaining: float) -> float:
        return self.start * self.remaining(progress_remaining)
