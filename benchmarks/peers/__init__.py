"""Adapters that evaluate the benchmark's task formulas with peer robustness libraries (docs/speed.md).

`load` gives a peer's ``evaluators(task, beta)``, which imports the library (ImportError when it is not
installed) and returns an `Evaluator` per mode it offers (exact, smoothed with gradient) and an `Unsupported` note
per mode it cannot express. The text-parsing peers are in `benchmarks.peers.text`, the tensor ones in
`benchmarks.peers.tensor`; they live in their own virtualenv (``benchmarks/requirements-peers.txt``).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Each peer's module, by the name the benchmark's ``--peers`` takes.
PEERS = {"rtamt": "text", "argus": "text", "stlrom": "text", "stlcgpp": "tensor", "stljax": "tensor"}

@dataclass(frozen=True)
class Evaluator:
    """One way a library evaluates one task."""

    library: str
    mode: str
    run: Callable[[np.ndarray, np.ndarray], np.ndarray]  # x, y (N, T) -> ρ (N,); "smooth+grad": + the sum's backward
    expressed: str = ""  # how the library writes the formula, when not literally
    per_trajectory: bool = True  # then timed on a prefix of the batch, sized by a time budget
    max_length: int | None = None  # the longest T it takes here (too_long says why)
    too_long: str = "memory grows as T²"
    compiles: bool = False  # a JIT: its first call is not timed


@dataclass(frozen=True)
class Unsupported:
    """A task/mode a library cannot evaluate as tl_gym defines it, and why."""

    library: str
    mode: str
    reason: str


def load(name: str) -> Callable[..., list[Evaluator | Unsupported]]:
    """The ``evaluators(task, beta)`` of peer ``name`` (one of `PEERS`)."""
    if name not in PEERS:
        raise ValueError(f"unknown peer {name!r}; expected one of {', '.join(PEERS)}")
    return getattr(importlib.import_module(f"benchmarks.peers.{PEERS[name]}"), f"{name}_evaluators")
