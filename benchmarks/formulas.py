"""The paper's task formulas φ1 (Eq. 16) and φ2 (Eq. 19) over signals ``x, y``, with their geometry.

Every evaluator of the speed benchmark (tl_gym, the hand-written numpy functions,
each peer library) builds its formula from one `Task`, so all of them judge the
same goals and obstacle. The layout is the car arena's: a 300 × 300 square,
30 × 30 goals, an obstacle of radius 40 in the middle.

Example:
    >>> task = task_formula("phi1")
    >>> task.formula.signals
    ('x', 'y')
    >>> import numpy as np
    >>> x, y = np.array([10.0, 250.0]), np.array([10.0, 250.0])  # ends inside the goal
    >>> float(task.formula.robustness({"x": x, "y": y}))
    10.0
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from tl_gym import Formula, parse

ARENA = 300.0  # side of the square arena
GOAL = 30.0  # side of a square goal
OBSTACLE_RADIUS = 40.0

TASKS = ("phi1", "phi2", "phi2-strict")


@dataclass(frozen=True)
class Box:
    """An open square goal ``x_low < x < x_high``, ``y_low < y < y_high``."""

    x_low: float
    x_high: float
    y_low: float
    y_high: float

    def text(self) -> str:
        """The goal predicate ψ_g in tl_gym syntax (Eq. 16's conjunction of four)."""
        return f"x > {self.x_low:g} & x < {self.x_high:g} & y > {self.y_low:g} & y < {self.y_high:g}"


@dataclass(frozen=True)
class Circle:
    """A circular obstacle; its predicate is ``d_o > r_o`` with ``d_o`` the distance to the centre."""

    cx: float
    cy: float
    r: float

    def text(self) -> str:
        """The obstacle predicate ``d_o > r_o`` in tl_gym syntax."""
        return f"sqrt((x - {self.cx:g})^2 + (y - {self.cy:g})^2) > {self.r:g}"


def _square(x: float, y: float) -> Box:
    return Box(x, x + GOAL, y, y + GOAL)


@dataclass(frozen=True)
class Task:
    """One benchmark formula: φ1, φ2 (default no-revisit) or φ2 with the paper's strict no-revisit.

    Attributes:
        key: ``"phi1"``, ``"phi2"`` or ``"phi2-strict"``.
        goals: the goal (φ1) or the three goals in visiting order (φ2).
        obstacle: the obstacle to avoid at every step.
    """

    key: str
    goals: tuple[Box, ...]
    obstacle: Circle

    @property
    def strict(self) -> bool:
        """Whether the no-revisit clause is Eq. 19's literal ``G(g -> X G !g)``."""
        return self.key == "phi2-strict"

    @cached_property
    def text(self) -> str:
        """The formula in tl_gym syntax."""
        avoid = f"G({self.obstacle.text()})"
        g = [f"({b.text()})" for b in self.goals]
        if self.key == "phi1":
            return f"F{g[0]} & {avoid}"
        order = f"({g[0]} T {g[1]} T {g[2]})"
        not_before_first = f"(!({g[1]} | {g[2]}) U {g[0]})"
        not_before_second = f"(!{g[2]} U {g[1]})"
        if self.strict:  # Eq. 19 literally: once in g, never again (not even the next step)
            revisit = [f"G({gi} -> X G !{gi})" for gi in g]
        else:  # leaving g (inside now, outside next) means never coming back
            revisit = [f"G(({gi} & X !{gi}) -> X G !{gi})" for gi in g]
        return " & ".join([order, not_before_first, not_before_second, *revisit, avoid])

    @cached_property
    def formula(self) -> Formula:
        """The parsed tl_gym formula (compiled once, evaluated many times)."""
        return parse(self.text)


def task_formula(key: str) -> Task:
    """The benchmark task ``key`` (one of `TASKS`) on the shared arena layout.

    Raises:
        ValueError: ``key`` is not one of `TASKS`.
    """
    if key not in TASKS:
        raise ValueError(f"unknown task {key!r}; expected one of {', '.join(TASKS)}")
    obstacle = Circle(ARENA / 2, ARENA / 2, OBSTACLE_RADIUS)
    if key == "phi1":
        return Task(key, (_square(240.0, 240.0),), obstacle)
    return Task(key, (_square(45.0, 225.0), _square(225.0, 225.0), _square(225.0, 45.0)), obstacle)
