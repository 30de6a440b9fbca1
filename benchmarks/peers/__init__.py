"""Adapters that evaluate the benchmark's task formulas with peer robustness libraries.

`load` gives each peer's adapter: its ``NAME`` and ``evaluators(task, beta)``, which
imports the library (raising ImportError when it is not installed) and returns the
`Evaluator` objects it can offer for that task: exact robustness, and smoothed
robustness with its gradient where the library has one. A peer that cannot
express a formula returns an `Unsupported` that says why, so the benchmark's
table can show it. The libraries that parse formula text (rtamt, argus, STLRom)
are in `benchmarks.peers.text`, the tensor ones (stlcg++, stljax) in
`benchmarks.peers.tensor`. The peers are installed in their own virtualenv
(``benchmarks/requirements-peers.txt``), never in the project's.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

#: The peers, by the name the benchmark's ``--peers`` takes.
PEER_MODULES = ("rtamt", "argus", "stlrom", "stlcgpp", "stljax")
_HOMES = {"rtamt": "text", "argus": "text", "stlrom": "text", "stlcgpp": "tensor", "stljax": "tensor"}

Batch = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Evaluator:
    """One way a library evaluates one task.

    Attributes:
        library: the library's name as the table prints it.
        mode: ``"exact"`` or ``"smooth+grad"`` (smoothed value and the gradient of its sum).
        run: maps ``(x, y)`` signals of shape ``(N, T)`` to the ``(N,)`` robustness values; in
            ``smooth+grad`` mode it also runs the backward pass.
        expressed: the formula the library evaluates, when not literally the task's, and why.
        per_trajectory: the library's cost is per trajectory (a loop, or a vmap in chunks), so
            the benchmark times it on a prefix of the batch sized by a time budget; throughput
            per trajectory is what is compared.
        max_length: the longest T the library can take here, or None.
        too_long: why longer trajectories are skipped.
        compiles: the first call on a new batch shape compiles (JIT), so the benchmark
            always makes one untimed call on the timed batch first, however slow.
    """

    library: str
    mode: str
    run: Batch
    expressed: str = ""
    per_trajectory: bool = True
    max_length: int | None = None
    too_long: str = "memory grows as T²"
    compiles: bool = False


@dataclass(frozen=True)
class Unsupported:
    """A task/mode a library cannot evaluate as tl_gym defines it, and why."""

    library: str
    mode: str
    reason: str


class Peer(NamedTuple):
    """A peer's adapter: the name the table prints and ``evaluators(task, beta)``."""

    NAME: str
    evaluators: Callable[..., list[Evaluator | Unsupported]]


def load(name: str) -> Peer:
    """The adapter of peer ``name`` (one of `PEER_MODULES`)."""
    if name not in PEER_MODULES:
        raise ValueError(f"unknown peer {name!r}; expected one of {', '.join(PEER_MODULES)}")
    module = importlib.import_module(f"benchmarks.peers.{_HOMES[name]}")
    return Peer(module.NAMES[name], getattr(module, f"{name}_evaluators"))


def per_trajectory(run_one: Callable[[np.ndarray, np.ndarray], float]) -> Batch:
    """Lift a one-trajectory evaluation ``(x[T], y[T]) -> float`` to a batch ``(N, T) -> (N,)``."""

    def run(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.array([run_one(xi, yi) for xi, yi in zip(x, y)], dtype=np.float64)

    return run
