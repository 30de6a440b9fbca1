"""`TLTLRewardWrapper`: the robustness of a TLTL formula as the reward of any Gymnasium env."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, SupportsFloat, TypeVar

import gymnasium as gym
import numpy as np

from tl_gym.checks import check_count, check_finite, check_fraction, check_positive
from tl_gym.monitor_view import MonitorView, augment, augment_space, split
from tl_gym.shaping import HierarchicalPotential, discounted_increment, satisfaction_value
from tl_gym.signals import SignalMap, SignalReader
from tl_gym.time_limits import episode_length
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.invariants import InvariantMonitor
from tl_gym.tltl.online import PrefixMonitor
from tl_gym.tltl.parser import parse

REWARDS = ("exact", "smooth")
REWARD_MODES = ("terminal", "dense", "potential")
DEFAULT_CLIP = 1e4
#: The key of the monitor features in a Dict observation (``observe_monitor=True``).
MONITOR_KEY = "monitor"
#: The info key naming the invariant an ``end_on_violation`` episode broke.
VIOLATED_KEY = "violated"


@dataclasses.dataclass(frozen=True)
class RewardSettings:
    """How a formula's robustness is paid: the reward keywords of `TLTLRewardWrapper`, checked once.

    The wrapper, the car's entry point and the batched car all build one, so that every reward
    keyword has one default and one check. Field meanings: `TLTLRewardWrapper`'s arguments.

    Raises:
        ValueError, TypeError: a bad value; the message names the keyword.
    """

    reward: str = "exact"
    beta: float = 9.0
    rho_max: float = math.inf
    reward_mode: str = "terminal"
    clip: float = DEFAULT_CLIP
    observe_monitor: bool = False
    monitor_scale: float = 1.0
    gamma: float = 1.0
    satisfaction_bonus: float = 0.0

    def __post_init__(self) -> None:
        if self.reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {self.reward!r}")
        if self.reward_mode not in REWARD_MODES:
            raise ValueError(f"reward_mode must be one of {REWARD_MODES}, got {self.reward_mode!r}")
        if self.reward_mode != "terminal" and self.reward == "smooth":
            raise ValueError(f"reward_mode={self.reward_mode!r} pays exact robustness increments; use reward='exact'")
        check_fraction("gamma", self.gamma)
        for name in ("beta", "clip", "monitor_scale"):
            object.__setattr__(self, name, check_positive(name, getattr(self, name)))
        bonus = check_positive("satisfaction_bonus", self.satisfaction_bonus, allow_zero=True)
        object.__setattr__(self, "satisfaction_bonus", bonus)
        object.__setattr__(self, "rho_max", check_positive("rho_max", self.rho_max, allow_inf=True))
        object.__setattr__(self, "gamma", float(self.gamma))
        if not isinstance(self.observe_monitor, bool):
            raise TypeError(f"observe_monitor must be True or False, got {self.observe_monitor!r}")

    def check_smoothable(self, formula: Formula) -> None:
        """Refuse a ``rho_max`` the smoothing cannot tell from ∞ in ``formula`` (`check_smoothable_rho_max`)."""
        from tl_gym.tltl.smooth import check_smoothable_rho_max  # the smoothing engine loads when smoothing is asked

        check_smoothable_rho_max(formula, self.beta, self.rho_max)

    @property
    def smooth_beta(self) -> float | None:
        """The β of the terminal reward's smoothed robustness (``reward="smooth"``), else None."""
        return self.beta if self.reward == "smooth" else None

    def prefix_paid(self, value: Any) -> Any:
        """Φ of a state in the dense mode: its clipped prefix robustness, plus the bonus once satisfied.

        The one rule the wrapper and the batched car pay by (scalars or arrays), with `terminal_paid` at the end.
        """
        return satisfaction_value(_clip(value, self.clip), self.satisfaction_bonus)

    def terminal_paid(self, info: Mapping[str, Any]) -> Any:
        """What an ended episode is worth: its clipped terminal robustness, plus the bonus when satisfied.

        The robustness is the smoothed one with ``reward="smooth"``, the bonus is for the exact one > 0
        (`terminal_info`'s keys; scalars or arrays).
        """
        rho = info.get("smooth_robustness", info["robustness"])
        return satisfaction_value(_clip(rho, self.clip), self.satisfaction_bonus, info["satisfied"])

    @classmethod
    def split(cls, kwargs: Mapping[str, Any], **defaults: Any) -> tuple[RewardSettings, dict[str, Any]]:
        """The settings among ``kwargs`` (over ``defaults``) and the keywords that are not reward settings.

        Example:
            >>> settings, rest = RewardSettings.split({"reward_mode": "dense", "horizon": 5}, monitor_scale=100.0)
            >>> settings.reward_mode, settings.monitor_scale, rest
            ('dense', 100.0, {'horizon': 5})
        """
        names = {field.name for field in dataclasses.fields(cls)}
        own = {**defaults, **{k: v for k, v in kwargs.items() if k in names}}
        return cls(**own), {k: v for k, v in kwargs.items() if k not in names}


def _setting(name: str) -> property:
    """A read-only attribute: ``self.settings.<name>``."""

    def get(self: Any) -> Any:
        return getattr(self.settings, name)

    def refuse(self: Any, value: Any) -> None:
        raise AttributeError(f"{name} is fixed when the env is built (its spec, monitors, observation bounds and "
                             f"checks are made with it): make the env again with {name}={value!r}")

    return property(get, refuse, doc=f"The reward setting ``{name}`` (`RewardSettings`), fixed at construction.")


class RewardSettingsAttributes:
    """The reward settings as attributes (``env.satisfaction_bonus``, ``env.clip``, ...), read from ``settings``.

    Read-only: what the env pays, its recorded spec, its monitors' features and bounds and the checks made
    at construction all follow the settings it was built with, so a value set later (as plain attributes
    once allowed) would pay one thing and record or observe another. Make the env again to change one.
    """

    settings: RewardSettings
    reward = _setting("reward")
    beta = _setting("beta")
    clip = _setting("clip")
    gamma = _setting("gamma")
    satisfaction_bonus = _setting("satisfaction_bonus")
    reward_mode = _setting("reward_mode")
    rho_max = _setting("rho_max")
    observe_monitor = _setting("observe_monitor")
    monitor_scale = _setting("monitor_scale")


W = TypeVar("W", bound=gym.Wrapper)


def find_wrapper(env: gym.Env, kind: type[W]) -> W | None:
    """The outermost wrapper of type ``kind`` in ``env``'s chain of wrappers; None if there is none."""
    layer: Any = env
    while isinstance(layer, gym.Wrapper):
        if isinstance(layer, kind):
            return layer
        layer = layer.env
    return None


def _clip(value: Any, bound: float) -> Any:
    """``value`` clipped to ``[-bound, bound]``: a Python float stays one (rewards are floats), arrays by numpy."""
    if isinstance(value, np.ndarray):
        return np.clip(value, -bound, bound)
    return min(max(value, -bound), bound)


class TLTLRewardWrapper(RewardSettingsAttributes, gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Pays the robustness of a TLTL formula over the episode's trajectory as reward.

    The wrapper records one value per signal the formula reads, from the reset
    observation s_0 and from every observation after it. On the step that ends the
    episode (terminated or truncated) it pays the robustness of the recorded trace
    s_0 … s_T: the exact value by default, the log-sum-exp smoothed one with
    ``reward="smooth"`` (sharpness ``beta``). Every other step pays 0. With
    ``reward_mode="dense"`` each step instead pays the change of the robustness of
    the prefix s_0 … s_t, so that the rewards of an episode add up to its (clipped)
    terminal robustness; formulas in the incremental fragment of
    `tl_gym.tltl.online` (both car tasks among them) cost O(1) per step, the
    others O(t) (the prefix is re-evaluated). ``reward_mode="potential"`` adds to the dense
    increments the hierarchical potential-based shaping of `tl_gym.shaping`.
    ``env_reward_weight`` adds the env's own reward, weighted.

    ``observe_monitor=True`` appends the online monitor's state to the observation (the
    Markov view, `tl_gym.monitor_view`), so that the dense reward of a step is a function of
    the observations around it; `dense_reward` recomputes it from them.

    On the terminal step ``info`` gets ``"robustness"`` (exact, unclipped),
    ``"satisfied"`` (ρ > 0) and the same as ``"is_success"`` (which SB3's ``success_rate`` logs read; an
    env's own ``"is_success"`` of that step moves to ``"env_is_success"``),
    ``"trace"`` (a read-only mapping signal name -> float64 array s_0 … s_T)
    and, with ``reward="smooth"``, ``"smooth_robustness"``; with ``end_on_violation=True``, an episode
    ended by a broken invariant also gets ``"violated"`` (the invariant, as text). Rewards are Python
    floats of robustness values clipped to ``[-clip, clip]``, so an infinite robustness (``true`` with
    ``rho_max=inf``, ``X φ`` at the last state) never reaches an agent (a NaN can, on the steps before
    a predicate whose arithmetic overflows raises `TraceError` at the episode's end: docs/wrapper.md). Each
    ``reset`` starts a new trace, so the wrapper works across the autoreset of
    Gymnasium's vector envs and of stable-baselines3's VecEnvs.

    Signals: ``signals`` maps each name to an observation index (Box; a tuple for
    a multi-dimensional Box), a key (Dict observation whose entry holds one number),
    a ``(key, index...)`` tuple (an element of a Box inside a Dict), or a callable
    of ``(obs)`` or ``(obs, info)``; or it is one callable of ``(obs, info)`` returning
    a mapping of all signals. Names the formula does not read are allowed.

    Example:
        >>> import gymnasium as gym
        >>> from tl_gym import TLTLRewardWrapper
        >>> env = TLTLRewardWrapper(gym.make("Pendulum-v1", max_episode_steps=50),
        ...                         "F(cos_th > 0.95)", signals={"cos_th": 0})
        >>> _ = env.reset(seed=0)
        >>> push = np.array([2.0], dtype=np.float32)
        >>> _, reward, *_ = env.step(push)
        >>> reward
        0.0
        >>> for _ in range(49):
        ...     _, reward, terminated, truncated, info = env.step(push)
        >>> truncated, round(reward, 4), info["satisfied"], len(info["trace"]["cos_th"])
        (True, 0.0498, True, 51)

    Change logs:
        * v0.1.0 - Initially added.
        * v0.1.0 - ``observe_monitor``, ``monitor_scale``, ``horizon``; ``reward_mode="potential"`` and ``gamma``.
        * v0.1.0 - ``gamma`` also discounts the dense mode's potential (``γ ρ_{t+1} − ρ_t``); 1 is unchanged.
        * v0.1.0 - ``end_on_violation``: end the episode at the first state that breaks a safety invariant.
        * v0.1.0 - ``satisfaction_bonus``: pay ``clip(ρ) + bonus · [ρ > 0]`` (every reward mode).
    """

    def __init__(
        self,
        env: gym.Env,
        spec: str | Formula,
        signals: SignalMap,
        reward: str = "exact",
        beta: float = 9.0,
        rho_max: float = math.inf,
        reward_mode: str = "terminal",
        env_reward_weight: float = 0.0,
        clip: float = DEFAULT_CLIP,
        observe_monitor: bool = False,
        monitor_scale: float = 1.0,
        horizon: int | None = None,
        gamma: float = 1.0,
        end_on_violation: bool = False,
        satisfaction_bonus: float = 0.0,
    ):
        """Check every argument, then wrap ``env``.

        Args:
            env: the env to wrap.
            spec: the formula, as text or a `Formula`.
            signals: where each signal comes from (see the class docstring).
            reward: ``"exact"`` robustness or ``"smooth"`` (log-sum-exp with ``beta``).
            beta: smoothing sharpness, > 0; used with ``reward="smooth"``.
            rho_max: the robustness of ``true`` (and minus that of ``X φ`` at the last state).
            reward_mode: ``"terminal"`` (one reward at the end), ``"dense"`` (increments of
                the prefix robustness; exact robustness only) or ``"potential"`` (the dense
                increments plus ``γ Φ(s') − Φ(s)`` of the hierarchical potential of
                `tl_gym.shaping`, Φ(s_T) = 0 at the last state; use it with ``observe_monitor``).
            env_reward_weight: weight of the wrapped env's own reward, added every step.
            clip: every robustness paid (terminal or prefix) is clipped to ``[-clip, clip]``. The
                default 1e4 leaves every finite robustness of TLCarNav-v0 untouched (its
                positions stay within a few thousand units) and keeps infinite robustness
                values out of float32 buffers; lower it for agents sensitive to reward scale.
            observe_monitor: append the online monitor's state to the observation (the Markov
                view, `tl_gym.monitor_view`): a 1-D Box becomes a longer float64 Box, a Dict gets
                the key ``"monitor"``. The formula must be in the incremental fragment.
            monitor_scale: robustness values and remembered signals in the monitor features are
                divided by it (> 0); the size of a typical robustness keeps them of order one.
            horizon: the episode length ``T`` for the monitor's ``t / T`` feature; None reads it
                from the env (`tl_gym.time_limits.episode_length`: the least of its time limits, its
                spec's ``max_episode_steps`` and a ``horizon`` attribute) and leaves the feature out when
                none is stated.
            gamma: the agent's discount γ, in (0, 1]. The dense and potential modes pay
                ``γ Φ(s') − Φ(s)`` (Φ: the prefix robustness, plus the hierarchical potential),
                so that with the agent's own γ its optimal policies are the terminal reward's
                (`tl_gym.shaping.discounted_increment`). At 1, the plain prefix increments.
            end_on_violation: end the episode (``terminated``) at the first state that breaks a safety
                invariant, a top-level conjunct ``G ψ`` with ψ temporal-free (`tl_gym.tltl.invariants`):
                from there no continuation can satisfy the formula, so success is what it would have
                been, while the return stops there: a violation forfeits what the rest of the episode
                could still earn. ``info["violated"]`` names the invariant. The robustness paid and
                reported is that of the shorter trace.
            satisfaction_bonus: ``B`` >= 0. Every mode pays ``clip(ρ) + B · [ρ > 0]`` in place of the
                robustness (`tl_gym.shaping.satisfaction_value`): at the end in terminal mode (``[ρ > 0]``
                from the exact ρ also with ``reward="smooth"``), and as the potential of the dense
                increments, so a step that makes the prefix satisfied pays ``B`` more and one that
                breaks it ``B`` less. A near miss then earns ``B`` less than a success instead of a
                sliver less; ``info`` keeps the exact ρ. 0 (the default) pays the robustness itself.

        Raises:
            SpecError: ``spec`` does not parse.
            UnknownSignalError: the formula reads a name ``signals`` does not map.
            ValueError, TypeError: a bad option, or a signal the observation space cannot address;
                ``end_on_violation`` for a formula without a safety invariant.
        """
        formula = _as_formula(spec)
        settings = RewardSettings(reward=reward, beta=beta, rho_max=rho_max, reward_mode=reward_mode, clip=clip,
                                  observe_monitor=observe_monitor, monitor_scale=monitor_scale, gamma=gamma,
                                  satisfaction_bonus=satisfaction_bonus)
        check_finite("env_reward_weight", env_reward_weight)
        check_count("horizon", horizon, allow_none=True)  # checked with the view or without: it goes into the spec
        if settings.reward == "smooth":  # at construction, not at the first episode's end
            settings.check_smoothable(formula)
        if not isinstance(env, gym.Env):
            raise TypeError(f"env must be a gymnasium.Env, got {type(env).__name__}")
        if not isinstance(end_on_violation, bool):
            raise TypeError(f"end_on_violation must be True or False, got {end_on_violation!r}")
        invariants = InvariantMonitor(formula, settings.rho_max) if end_on_violation else None
        reader = SignalReader(formula.signals, signals, env.observation_space)
        view = None
        length = episode_length(env)
        if observe_monitor:
            horizon = length if horizon is None else horizon
            view = MonitorView(PrefixMonitor(formula, rho_max), monitor_scale, clip, horizon,
                               reader.bounds(env.observation_space))
            observation_space = augment_space(env.observation_space, view, MONITOR_KEY)

        gym.utils.RecordConstructorArgs.__init__(
            self, spec=str(formula), signals=signals, reward=reward, beta=beta, rho_max=rho_max,
            reward_mode=reward_mode, env_reward_weight=env_reward_weight, clip=clip,
            observe_monitor=observe_monitor, monitor_scale=monitor_scale, horizon=horizon, gamma=gamma,
            end_on_violation=end_on_violation, satisfaction_bonus=satisfaction_bonus,
        )
        gym.Wrapper.__init__(self, env)
        if view is not None:
            self.observation_space = observation_space
        if env.has_wrapper_attr("compute_reward"):  # a goal env's reward of one transition is not this one's
            self.compute_reward = refuse_goal_reward
        self.formula = formula
        #: the episode length the wrapped env states (`tl_gym.time_limits.episode_length`; None: none), which the
        #: agents compare with a time limit outside the wrapper (`tl_gym.agents.horizon.check_time_limits`)
        self.episode_length = length
        self.settings = settings
        self._over_a_tl_wrapper = find_wrapper(env, TLTLRewardWrapper) is not None  # its is_success: another formula's
        self.env_reward_weight = float(env_reward_weight)
        self._reader = reader
        self.monitor_view = view
        if view is not None:
            self._monitor: PrefixMonitor | None = view.monitor
        else:
            self._monitor = PrefixMonitor(formula, self.rho_max) if reward_mode != "terminal" else None
        self._potential = (
            HierarchicalPotential(formula, self.rho_max, monitor_scale) if reward_mode == "potential" else None
        )
        self.end_on_violation = end_on_violation
        self._invariants = invariants
        self._broken: Formula | None = None  # the invariant the recorded trace breaks
        self._monitors_read_states = any(m is not None for m in (self._monitor, self._potential, invariants))
        self._phi = 0.0  # Φ of the state the last step reached
        self._rows: list[list[float]] = []
        self._paid = 0.0  # Φ: the clipped prefix robustness (+ bonus) of the state the last step reached (0 at reset)
        self._done = True

    # Gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset the env and start a new trace at its observation s_0 (with the monitor's features appended).

        Raises:
            TraceError: a signal of s_0 is NaN or infinite (naming it).
            TypeError, ValueError, UnknownSignalError: a signal callable returns no real number, or the one
                callable no value for a signal the formula reads (checked at the first reset, naming the signal).
        """
        obs, info = self.env.reset(seed=seed, options=options)
        row = self._reader.first(obs, info)
        self._rows = [row]
        self._paid = 0.0
        self._done = False
        state = self._state(row)
        if self._invariants is not None:  # a broken s_0 ends the first step: reset cannot end an episode
            self._broken = self._invariants.broken(state)
        if self._potential is not None:
            self._potential.reset()
            self._phi = self._potential.update(state)
        if self.monitor_view is not None:
            self.monitor_view.update(state, 0)
            return augment(obs, self.monitor_view.features(0), MONITOR_KEY), info
        if self._monitor is not None:
            self._monitor.reset()
            self._monitor.update(state)
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env, record the state and pay the reward of the mode.

        The step that ends the episode pays the terminal value and its ``info`` holds `terminal_info`'s keys.

        Raises:
            RuntimeError: the episode is over, or was never started: `reset` first.
            TraceError: a signal is NaN or infinite (naming it and the step), or, on the last step, a predicate's
                arithmetic is undefined on the trace.
        """
        if self._done:
            raise RuntimeError("the episode is over (or never started): call reset() before step()")
        obs, env_reward, terminated, truncated, info = self.env.step(action)
        row = self._reader.read(obs, info, len(self._rows))
        self._rows.append(row)
        state = self._state(row)
        reward = 0.0
        value = None
        if self.monitor_view is not None:
            t = len(self._rows) - 1
            value = self.monitor_view.update(state, t)
            obs = augment(obs, self.monitor_view.features(t), MONITOR_KEY)
        if self._invariants is not None:
            if self._broken is None:
                self._broken = self._invariants.broken(state)
            if self._broken is not None:  # a termination even on the env's own last step: nothing follows
                terminated = True
                info[VIOLATED_KEY] = str(self._broken)
        if terminated or truncated:
            self._done = True
            reward = self._terminal_reward(info)
        elif self.reward_mode != "terminal":
            if value is None:
                value = self._monitor.update(state)  # type: ignore[union-attr]
            reward, self._paid = discounted_increment(self.settings.prefix_paid(value), self._paid, self.gamma)
        if self._potential is not None:  # γ Φ(s') − Φ(s), with Φ(s_T) = 0 at the last state
            phi = 0.0 if self._done else self._potential.update(state)
            shaping, self._phi = discounted_increment(phi, self._phi, self.gamma)
            reward += shaping
        if self.env_reward_weight:
            reward += self.env_reward_weight * float(env_reward)
        return obs, reward, terminated, truncated, info

    def _state(self, row: list[float]) -> dict[str, float]:
        """One recorded state's signals by name, for the monitors: built once a step (empty when none reads it)."""
        return dict(zip(self._reader.names, row)) if self._monitors_read_states else {}

    # Recorded trace -------------------------------------------------------------------------
    @property
    def trace(self) -> dict[str, np.ndarray]:
        """Signals recorded since the last reset: name -> read-only float64 array s_0 … s_t."""
        return {name: _read_only_view(values) for name, values in self._trace_arrays().items()}

    def _trace_arrays(self) -> dict[str, np.ndarray]:
        table = np.array(self._rows, dtype=np.float64).reshape(len(self._rows), len(self._reader.names))
        return {name: table[:, i].copy() for i, name in enumerate(self._reader.names)}

    def _terminal_reward(self, info: dict[str, Any]) -> float:
        trace = self._trace_arrays()
        if not trace:  # a formula that reads no signal still needs the trace's length
            trace = {"_": np.zeros(len(self._rows))}
        # the env's own (parking-v0's: in the slot now), kept beside the formula's; an inner TL wrapper that ended
        # its episode on this step has kept it already, and its is_success is its formula's
        inner_ended = self._over_a_tl_wrapper and "satisfied" in info
        if "is_success" in info and ENV_IS_SUCCESS not in info and not inner_ended:
            info[ENV_IS_SUCCESS] = info["is_success"]
        info.update(terminal_info(self.formula, trace, self.rho_max, self.settings.smooth_beta))
        if not self._reader.names:
            info["trace"] = Trace({})
        return self.settings.terminal_paid(info) - self._paid

    # The Markov view ----------------------------------------------------------------------
    def monitor_features(self, obs: Any) -> np.ndarray:
        """The monitor features of an observation of this wrapper (``observe_monitor=True``).

        Raises:
            ValueError: the wrapper has no view, or ``obs`` is not one of its observations (a raw one, say).
        """
        view = self.monitor_view
        if view is None:
            raise ValueError("the wrapper was made without observe_monitor=True: its observations hold no monitor")
        space = self.observation_space
        if isinstance(space, gym.spaces.Dict):
            fits = isinstance(obs, Mapping) and MONITOR_KEY in obs
        else:
            fits = not isinstance(obs, Mapping) and np.shape(obs)[-1:] == space.shape
        if not fits:
            def layout(x: Any) -> str:
                return f"keys {sorted(x)}" if isinstance(x, Mapping) else f"shape {np.shape(x)}"

            expected = layout(space.spaces) if isinstance(space, gym.spaces.Dict) else f"shape {space.shape}"
            raise ValueError(f"not an observation of this wrapper: {layout(obs)}, where its observations have "
                             f"{expected} (the env's observation with the monitor's state appended)")
        return split(obs, view, MONITOR_KEY)

    def dense_reward(self, obs_before: Any, obs_after: Any, last: bool = False) -> float:
        """The ``reward_mode="dense"`` reward of a step, recomputed from its two observations alone.

        A pure function of the augmented observations (``observe_monitor=True``) and, for γ < 1,
        of whether the step ended the episode (``last``: terminated or truncated, which an agent
        sees): with the monitor's state in the observation, the dense reward is Markov. It equals
        what `step` pays in dense mode (env reward excluded), up to the rounding of ``monitor_scale``.
        """
        before, after = self.monitor_features(obs_before), self.monitor_features(obs_after)
        return self.monitor_view.dense_reward(before, after,  # type: ignore[union-attr]
                                              gamma=1.0 if last else self.gamma, bonus=self.satisfaction_bonus)


#: Keys `terminal_info` writes into the info of an episode's last step.
TERMINAL_KEYS = ("robustness", "satisfied", "is_success", "trace", "smooth_robustness")
#: Where the wrapper keeps an env's own ``is_success`` of the last step, whose key the formula's takes.
ENV_IS_SUCCESS = "env_is_success"
#: Every key the wrapper adds to an info: the terminal ones, the env's own success and ``end_on_violation``'s.
WRAPPER_KEYS = (*TERMINAL_KEYS, ENV_IS_SUCCESS, VIOLATED_KEY)


def env_info(info: Mapping[str, Any]) -> dict[str, Any]:
    """A step's info as the env below the wrapper gave it: the wrapper's keys removed, its ``is_success`` back.

    Example:
        >>> env_info({"robustness": 1.0, "satisfied": True, "is_success": True, "env_is_success": False, "t": 3})
        {'t': 3, 'is_success': False}
    """
    out = {k: v for k, v in info.items() if k not in WRAPPER_KEYS}
    if ENV_IS_SUCCESS in info:
        out["is_success"] = info[ENV_IS_SUCCESS]
    return out


def terminal_info(formula: Formula, trace: Mapping[str, np.ndarray], rho_max: float,
                  smooth_beta: float | None = None) -> dict[str, Any]:
    """The terminal ``info`` of finished episodes: the one place its contract is written.

    Keys: ``"robustness"`` (exact ρ), ``"satisfied"`` (ρ > 0), ``"is_success"`` (the same, under the key
    stable-baselines3 reads for its ``success_rate`` logs), ``"trace"`` (a `Trace`) and, when
    ``smooth_beta`` is given, ``"smooth_robustness"``. A trace of 1-D arrays is one episode (floats
    and one `Trace`); a trace of ``(N, T+1)`` arrays is N episodes of one length (arrays, and an
    object array of one `Trace` per episode, the layout Gymnasium's vector envs give).

    Example:
        >>> from tl_gym import parse
        >>> info = terminal_info(parse("F(x > 1)"), {"x": np.array([0.0, 3.0])}, rho_max=1e4)
        >>> info["robustness"], info["satisfied"], info["trace"]["x"].tolist()
        (2.0, True, [0.0, 3.0])
    """
    rho = formula.robustness(trace, rho_max)
    batched = np.ndim(rho) > 0
    satisfied = rho > 0
    info: dict[str, Any] = {"robustness": rho if batched else float(rho), "satisfied": satisfied,
                            "is_success": satisfied.copy() if batched else satisfied}
    # read-only mappings, not dicts: vector envs keep one per env (episodes of different lengths
    # may end on one step; a dict would be batched into one array of one length)
    if batched:
        info["trace"] = np.empty(len(rho), dtype=object)
        for i in range(len(rho)):
            info["trace"][i] = Trace({name: values[i] for name, values in trace.items()})
    else:
        info["trace"] = Trace(trace)
    if smooth_beta is not None:
        value = formula.smooth_robustness(trace, smooth_beta, rho_max)
        info["smooth_robustness"] = np.asarray(value, dtype=np.float64) if batched else float(value)
    return info


class Trace(Mapping):
    """A recorded trace: a read-only mapping signal name -> float64 array s_0 … s_T.

    Not a dict on purpose: a Gymnasium vector env batches a dict in ``info`` into one array per
    key, which fails when episodes of different lengths end on one step; a mapping is kept whole,
    one per env (``info["trace"][i]``, with the mask ``info["_trace"]``).

    Example:
        >>> trace = Trace({"x": np.array([0.0, 1.0])})
        >>> list(trace), trace["x"].tolist(), trace
        (['x'], [0.0, 1.0], Trace({'x': array([0., 1.])}))
    """

    def __init__(self, arrays: Mapping[str, np.ndarray]):
        self._arrays = {name: _read_only_view(values) for name, values in arrays.items()}

    def __getitem__(self, name: str) -> np.ndarray:
        return self._arrays[name]

    def __iter__(self) -> Any:
        return iter(self._arrays)

    def __len__(self) -> int:
        return len(self._arrays)

    def __repr__(self) -> str:
        return f"Trace({self._arrays!r})"

    def __reduce__(self) -> tuple[type, tuple[dict[str, np.ndarray]]]:
        """Rebuilt through ``__init__`` by pickle and deepcopy (SB3 deep-copies its infos), so read-only."""
        return type(self), (self._arrays,)


def _read_only_view(values: np.ndarray) -> np.ndarray:
    """A view of ``values`` that cannot be written (the array itself keeps its flags)."""
    view = np.asarray(values).view()
    view.flags.writeable = False
    return view


# --------------------------------------------------------------------------- argument checks


def _as_formula(spec: Any) -> Formula:
    if isinstance(spec, Formula):
        return spec
    if isinstance(spec, str):
        return parse(spec)
    raise TypeError(f"spec must be formula text or a Formula, got {type(spec).__name__}")


def refuse_goal_reward(achieved_goal: Any, desired_goal: Any, info: Any) -> float:
    """What `TLTLRewardWrapper` answers for a goal env's ``compute_reward``: it cannot.

    A goal env (highway-env's parking) states its reward of one transition as
    ``compute_reward(achieved_goal, desired_goal, info)``, which SB3's ``HerReplayBuffer`` calls to relabel
    transitions. The wrapper's reward is the robustness of the whole episode, which no single transition
    determines, so the env's own function would pay relabelled transitions another reward than the one trained
    on; the wrapper shadows it with this error.

    Raises:
        NotImplementedError: always, saying what relabels TL episodes instead.
    """
    raise NotImplementedError(
        "a TLTLRewardWrapper's reward is the robustness of the whole episode, not a function of one transition's "
        "(achieved_goal, desired_goal, info): SB3's HerReplayBuffer cannot relabel it. Relabel whole episodes "
        "with SB3Agent(..., her_goals=k) (tl_gym.relabel)"
    )
