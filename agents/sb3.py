"""stable-baselines3 algorithms behind the tl_gym agent interface.

`SB3Agent("PPO", "TLCarNav-v0")` trains any stable-baselines3 (or sb3-contrib)
algorithm on a TLTL-rewarded env and reports on the same axes as TLPS and REPS:
one iteration is ``steps_per_iteration`` env steps (40 episodes × 200 steps by
default, a TLPS iteration's budget), and each history row holds the mean exact
robustness and success rate of the episodes that ended during the iteration,
read from the reward wrapper's terminal ``info``.

Saving embeds stable-baselines3's own zip as the member ``sb3_model.zip``.
stable-baselines3 unpickles parts of that file when loading, so **load only files
you trust**. A loaded agent acts and evaluates exactly as the saved one; it can
continue learning, but not bit-identically to an uninterrupted run (SB3 does not
save its random state, nor, for off-policy algorithms, its replay buffer).
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import importlib
import io
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from .base import Agent, build_config
from .serialization import is_jsonable

#: Env steps of one TLPS iteration with the paper's settings (N = 40 episodes × T = 200).
DEFAULT_STEPS_PER_ITERATION = 40 * 200

#: Archive member holding stable-baselines3's own model file.
SB3_MEMBER = "sb3_model.zip"

_ALGO_MODULES = ("stable_baselines3", "sb3_contrib")


def resolve_algorithm(algo: Any) -> type:
    """An SB3 algorithm class from a class or a case-insensitive name (``"ppo"``, ``"SAC"``, ``"TQC"``).

    Raises:
        ValueError: no stable-baselines3 / sb3-contrib algorithm has that name.
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
        except ImportError:
            continue
        for name in dir(module):
            value = getattr(module, name)
            if isinstance(value, type) and issubclass(value, BaseAlgorithm) and value is not BaseAlgorithm:
                known.setdefault(name.lower(), value)
    try:
        return known[algo.lower()]
    except KeyError:
        available = sorted(c.__name__ for c in known.values())
        raise ValueError(f"unknown algorithm {algo!r}; available: {available}") from None


@dataclass(frozen=True)
class SB3Config:
    """Hyperparameters of `SB3Agent` (the algorithm's own go in ``algo_kwargs``)."""

    algo: str
    """Algorithm class name, e.g. ``"PPO"``."""
    steps_per_iteration: int = DEFAULT_STEPS_PER_ITERATION
    """Env steps per iteration; on-policy algorithms get ``n_steps = steps_per_iteration // n_envs`` by default."""
    n_envs: int = 8
    """Parallel envs of SB3's ``DummyVecEnv``."""
    policy: str | None = None
    """SB3 policy name; ``None`` picks ``"MultiInputPolicy"`` for Dict observations, else ``"MlpPolicy"``."""
    algo_kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments for the algorithm's constructor (``learning_rate``, ``n_steps``, ...)."""

    def __post_init__(self) -> None:
        if not isinstance(self.steps_per_iteration, (int, np.integer)) or self.steps_per_iteration < 1:
            raise ValueError(f"steps_per_iteration must be an int >= 1, got {self.steps_per_iteration!r}")
        if not isinstance(self.n_envs, (int, np.integer)) or self.n_envs < 1:
            raise ValueError(f"n_envs must be an int >= 1, got {self.n_envs!r}")


class SB3Agent(Agent):
    """A stable-baselines3 algorithm trained on a TLTL-rewarded env, reported like TLPS.

    Args:
        algo: an SB3 / sb3-contrib algorithm class or its name (``"PPO"``, ``"sac"``, ...).
        env: env id, `Env` or `VectorEnv` (see `Agent`); SB3 trains on a ``DummyVecEnv`` of
            ``n_envs`` single envs rebuilt from it, evaluation runs on the batched env.
        seed: seeds SB3 (torch, numpy, the envs).
        env_kwargs: env constructor keywords for an env id.
        steps_per_iteration, n_envs, policy: see `SB3Config`.
        **algo_kwargs: passed to the algorithm's constructor.

    History rows add ``episodes`` (episodes that ended in the iteration).

    Example:
        >>> resolve_algorithm("ppo").__name__  # what SB3Agent("ppo", "TLCarNav-v0") trains
        'PPO'
    """

    config: SB3Config

    def __init__(self, algo: Any, env: Any, *, seed: int | None = None, env_kwargs: dict[str, Any] | None = None,
                 steps_per_iteration: int = DEFAULT_STEPS_PER_ITERATION, n_envs: int = 8,
                 policy: str | None = None, **algo_kwargs: Any):
        self.algo_class = resolve_algorithm(algo)
        self._env_argument = env
        super().__init__(env, seed=seed, env_kwargs=env_kwargs, algo=self.algo_class.__name__,
                         steps_per_iteration=steps_per_iteration, n_envs=n_envs, policy=policy,
                         algo_kwargs=algo_kwargs)

    @classmethod
    def _make_config(cls, hyperparameters: dict[str, Any]) -> SB3Config:
        return build_config(SB3Config, hyperparameters, cls.__name__)

    def _num_envs(self) -> int:
        return self.config.n_envs

    def _setup(self) -> None:
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
        from stable_baselines3.common.vec_env import DummyVecEnv

        kwargs = dict(self.config.algo_kwargs)
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
        factories = _single_env_factories(self._env_argument, self.env_kwargs, self.config.n_envs)
        self.sb3_env = DummyVecEnv(factories)
        policy = self.config.policy or (
            "MultiInputPolicy" if isinstance(self.observation_space, gym.spaces.Dict) else "MlpPolicy"
        )
        self.model = self.algo_class(policy, self.sb3_env, seed=self.seed, verbose=0, device="cpu", **kwargs)
        self._quiet_logger()

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
        with one_torch_thread():
            self.model.learn(total_timesteps=self.config.steps_per_iteration, reset_num_timesteps=False,
                             callback=collector, progress_bar=False)
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
        with one_torch_thread():
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)

    def _config(self) -> dict[str, Any]:
        config = dataclasses.asdict(self.config)
        algo_kwargs = config.pop("algo_kwargs")
        # kwargs that JSON cannot hold (classes in policy_kwargs...) live on in SB3's own file
        config.update({k: v for k, v in algo_kwargs.items() if is_jsonable(v)})
        return config

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return {}

    def _extra_files(self) -> dict[str, bytes]:
        buffer = io.BytesIO()
        self.model.save(buffer)
        return {SB3_MEMBER: buffer.getvalue()}

    def _load_state(self, arrays: dict[str, np.ndarray], files: dict[str, bytes]) -> None:
        if SB3_MEMBER not in files:
            from tl_gym.errors import IncompatibleSaveError

            raise IncompatibleSaveError(f"the file holds no {SB3_MEMBER} member")
        self.model = self.algo_class.load(io.BytesIO(files[SB3_MEMBER]), env=self.sb3_env, device="cpu")
        self._quiet_logger()


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
