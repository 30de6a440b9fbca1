"""The paper's task formulas φ1 (Eq. 16) and φ2 (Eq. 19) over signals ``x, y``, with their geometry.

Every evaluator of the speed benchmark builds its formula from one `Task`: all judge TLCarNav-v0's geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

from tl_gym.envs.tasks import Goal, Obstacle, make_layout, task_formula

from tl_gym import Formula

ARENA = float(make_layout(1).arena[0])  # side of the square arena, for drawing random paths

TASKS = ("phi1", "phi2", "phi2-strict")


@dataclass(frozen=True)
class Task:
    """One benchmark formula: φ1, φ2 or strict φ2 (``key``), its goals in visiting order and the obstacle."""

    key: str
    goals: tuple[Goal, ...]
    obstacle: Obstacle
    formula: Formula  # the env's tl_gym formula for this task (compiled once, evaluated many times)

    @property
    def strict(self) -> bool:
        """Whether the no-revisit clause is Eq. 19's literal ``G(g -> X G !g)``."""
        return self.key == "phi2-strict"


def benchmark_task(key: str) -> Task:
    """The benchmark task ``key`` (one of `TASKS`, else ValueError) on the env's layout."""
    if key not in TASKS:
        raise ValueError(f"unknown task {key!r}; expected one of {', '.join(TASKS)}")
    number = 1 if key == "phi1" else 2
    layout = make_layout(number)
    return Task(key, layout.goals, layout.obstacle, task_formula(number, "strict" if key == "phi2-strict" else "leave"))
