"""Layouts of the paper's two car tasks (Figure 1) and their TLTL formulas (Eq. 16, Eq. 19).

The formulas read the signals ``x`` and ``y`` only (observation indices 0 and 1);
the obstacle predicate is written with arithmetic, ``sqrt((x - cx)^2 + (y - cy)^2) > r``.
`task_formula` is the formula the env pays; the batched car env and the benchmarks build
theirs with it, so that every score uses the same text.

Example:
    >>> from tl_gym.envs.tasks import task_formula
    >>> print(task_formula(1))
    F (x > 240 & x < 270 & y > 240 & y < 270) & G sqrt((x - 150) ^ 2 + (y - 150) ^ 2) > 40
    >>> task_formula(2).signals
    ('x', 'y')
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from tl_gym.checks import check_floats
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.parser import parse

NO_REVISIT_MODES = ("leave", "strict")


@dataclass(frozen=True)
class Goal:
    """An axis-aligned square (or rectangle) goal region, open on every side."""

    x_low: float
    x_high: float
    y_low: float
    y_high: float

    def __post_init__(self) -> None:
        values = (self.x_low, self.x_high, self.y_low, self.y_high)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f"a goal is four finite numbers (x_low, x_high, y_low, y_high), got {values!r}")
        if not (self.x_low < self.x_high and self.y_low < self.y_high):
            raise ValueError(f"a goal needs x_low < x_high and y_low < y_high, got {values!r}")

    @property
    def center(self) -> tuple[float, float]:
        """Centre of the region."""
        return (0.5 * (self.x_low + self.x_high), 0.5 * (self.y_low + self.y_high))

    def text(self) -> str:
        """The predicate ψ_g: ``x > x_low & x < x_high & y > y_low & y < y_high``."""
        return (
            f"(x > {_num(self.x_low)} & x < {_num(self.x_high)} & "
            f"y > {_num(self.y_low)} & y < {_num(self.y_high)})"
        )


@dataclass(frozen=True)
class Obstacle:
    """A circular obstacle; the car must keep its centre farther than ``radius`` from ``(x, y)``."""

    x: float
    y: float
    radius: float

    def __post_init__(self) -> None:
        values = (self.x, self.y, self.radius)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values) or self.radius <= 0:
            raise ValueError(f"an obstacle is (x, y, radius) with finite values and radius > 0, got {values!r}")

    def text(self) -> str:
        """The predicate d_o > r_o."""
        return f"sqrt((x - {_num(self.x)})^2 + (y - {_num(self.y)})^2) > {_num(self.radius)}"


@dataclass(frozen=True)
class Layout:
    """Where the car starts, the goals it must reach (in order), the obstacle and the arena size."""

    start: tuple[float, float, float]
    goals: tuple[Goal, ...]
    obstacle: Obstacle
    arena: tuple[float, float] = (300.0, 300.0)


# Figure 1 (left): start lower-left heading at the goal, obstacle in the way, goal upper-right.
TASK1_LAYOUT = Layout(
    start=(30.0, 30.0, math.pi / 4),
    goals=(Goal(240.0, 270.0, 240.0, 270.0),),
    obstacle=Obstacle(150.0, 150.0, 40.0),
)
# Figure 1 (right): three goals visited counter-clockwise around the obstacle.
TASK2_LAYOUT = Layout(
    start=(30.0, 30.0, 0.0),
    goals=(Goal(210.0, 240.0, 45.0, 75.0), Goal(210.0, 240.0, 225.0, 255.0), Goal(60.0, 90.0, 225.0, 255.0)),
    obstacle=Obstacle(150.0, 150.0, 40.0),
)


def make_layout(
    task: int = 1,
    start: Sequence[float] | None = None,
    goals: Sequence[Sequence[float]] | None = None,
    obstacle: Sequence[float] | None = None,
    arena: Sequence[float] | None = None,
) -> Layout:
    """The default layout of ``task`` with any of its parts replaced.

    Args:
        task: 1 (one goal) or 2 (three goals in order).
        start: ``(x, y, θ)`` mean start state.
        goals: a sequence of ``(x_low, x_high, y_low, y_high)``; task 1 takes one, task 2 three.
        obstacle: ``(x, y, radius)``.
        arena: ``(width, height)``, used for drawing and documented bounds only (no walls).
    """
    check_task(task)
    base = TASK1_LAYOUT if task == 1 else TASK2_LAYOUT
    new_goals = base.goals
    if goals is not None:
        try:
            given = [] if isinstance(goals, (str, bytes)) else list(goals)
        except TypeError:
            given = []
        what = "(x_low, x_high, y_low, y_high)"
        new_goals = tuple(Goal(*check_floats(f"goals[{i}]", g, 4, f"four numbers {what}")) for i, g in enumerate(given))
        expected = 1 if task == 1 else 3
        if len(new_goals) != expected:
            raise ValueError(f"task {task} takes {expected} goal(s) {what}, got {goals!r}")
    new_start = base.start
    if start is not None:
        what = "three finite numbers (x, y, θ)"
        new_start = check_floats("start", start, 3, what)
        if not all(math.isfinite(v) for v in new_start):
            raise ValueError(f"start must be {what}, got {start!r}")
    new_arena = base.arena if arena is None else check_floats("arena", arena, 2, "(width, height) > 0")
    if not all(math.isfinite(v) and v > 0 for v in new_arena):
        raise ValueError(f"arena must be (width, height) > 0, got {arena!r}")
    return Layout(
        start=new_start,  # type: ignore[arg-type]
        goals=new_goals,
        obstacle=(base.obstacle if obstacle is None
                  else Obstacle(*check_floats("obstacle", obstacle, 3, "(x, y, radius)"))),
        arena=new_arena,  # type: ignore[arg-type]
    )


def check_task(task: object) -> None:
    """Raise ``ValueError`` unless ``task`` is 1 or 2."""
    if isinstance(task, bool) or task not in (1, 2):
        raise ValueError(f"task must be 1 or 2, got {task!r}")


def formula_text(task: int = 1, no_revisit: str = "leave", layout: Layout | None = None) -> str:
    """The task's formula as text (see `task_formula`)."""
    check_task(task)
    if no_revisit not in NO_REVISIT_MODES:
        raise ValueError(f"no_revisit must be one of {NO_REVISIT_MODES}, got {no_revisit!r}")
    layout = layout if layout is not None else make_layout(task)
    avoid = f"G({layout.obstacle.text()})"
    if task == 1:
        return f"F{layout.goals[0].text()} & {avoid}"
    g1, g2, g3 = (g.text() for g in layout.goals)
    parts = [
        f"({g1} T ({g2} T {g3}))",  # visit g1, then g2, then g3
        f"(!({g2} | {g3}) U {g1})",  # no g2 or g3 before g1
        f"(!{g3} U {g2})",  # no g3 before g2
    ]
    for g in (g1, g2, g3):
        if no_revisit == "strict":  # Eq. 19 literally: inside for one sample only
            parts.append(f"G({g} -> X G !{g})")
        else:  # once the car has left the goal, it never comes back
            parts.append(f"G(({g} & X !{g}) -> X G !{g})")
    parts.append(avoid)
    return " & ".join(parts)


def task_formula(
    task: int = 1,
    no_revisit: str = "leave",
    *,
    start: Sequence[float] | None = None,
    goals: Sequence[Sequence[float]] | None = None,
    obstacle: Sequence[float] | None = None,
    arena: Sequence[float] | None = None,
) -> Formula:
    """The formula TLCarNav-v0 pays for ``task`` on the given (default) layout.

    Task 1 (Eq. 16): ``F ψ_g & G(d_o > r_o)``. Task 2 (Eq. 19): ``(ψ1 T (ψ2 T ψ3))
    & (!(ψ2 | ψ3) U ψ1) & (!ψ3 U ψ2) & ⋀_i no-revisit_i & G(d_o > r_o)``, where
    no-revisit_i is ``G((ψi & X !ψi) -> X G !ψi)`` (``no_revisit="leave"``, the default:
    once left, never come back) or Eq. 19's ``G(ψi -> X G !ψi)`` (``"strict"``: inside
    for one sample only, and not at the last one).

    Args:
        task: 1 or 2.
        no_revisit: ``"leave"`` or ``"strict"`` (checked for both tasks; task 1's formula has no such clause).
        start: mean start ``(x, y, θ)`` (see `make_layout`).
        goals: ``(x_low, x_high, y_low, y_high)`` per goal.
        obstacle: ``(x, y, radius)``.
        arena: ``(width, height)``.
    """
    layout = make_layout(task, start=start, goals=goals, obstacle=obstacle, arena=arena)
    return parse(formula_text(task, no_revisit, layout))


def _num(value: float) -> str:
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)
