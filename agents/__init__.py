"""Agents behind one interface: TLPS, REPS and stable-baselines3 adapters.

Every agent takes an env id, an `Env` or a `VectorEnv` whose reward is a TLTL
formula's robustness (`tl_gym.TLTLRewardWrapper`), samples episodes batched, and
offers `learn`, `predict`, `evaluate`, `save` and `load` (see `Agent`).
`TLPS` and `SB3Agent` are imported lazily: the first needs torch, the second
stable-baselines3.
"""

from __future__ import annotations

import importlib
from typing import Any

from .base import Agent
from .callbacks import (
    AbstractCallback,
    CallbackList,
    CheckpointCallback,
    EvalCallback,
    HistoryCSV,
    StopOnRobustness,
    StopOnSuccessRate,
)
from .evaluation import evaluate_policy
from .policy import LinearGaussianPolicy
from .reps import REPS, REPSConfig

_LAZY = {"TLPS": "tl_gym.agents.tlps", "TLPSConfig": "tl_gym.agents.tlps", "SB3Agent": "tl_gym.agents.sb3"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "AbstractCallback", "Agent", "CallbackList", "CheckpointCallback", "EvalCallback", "HistoryCSV",
    "LinearGaussianPolicy", "REPS", "REPSConfig", "SB3Agent", "StopOnRobustness", "StopOnSuccessRate", "TLPS",
    "TLPSConfig", "evaluate_policy",
]
