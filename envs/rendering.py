"""Drawing of the car tasks like the paper's Figure 1: goals, obstacle, car and its trace.

`draw_layout` draws a layout on any matplotlib Axes (the agents' Figure-2-style
plots use it); `render_frame` returns an RGB array through matplotlib's Agg
backend (no display needed); `HumanViewer` shows frames in a pygame window (the
``render`` extra).

Example:
    >>> from matplotlib.figure import Figure
    >>> from tl_gym.envs.tasks import TASK2_LAYOUT
    >>> ax = Figure().add_subplot()
    >>> draw_layout(ax, TASK2_LAYOUT)
    >>> len(ax.patches)  # three goals and the obstacle
    4
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from tl_gym.envs.tasks import Layout

GOAL_COLOR = "#2ca02c"
OBSTACLE_COLOR = "#2ca02c"
CAR_COLOR = "#8c564b"  # brown, as in the paper
TRACE_COLOR = "#8c564b"


def draw_layout(ax: Any, layout: Layout, *, labels: bool = True, alpha: float = 0.35) -> None:
    """Draw the arena, goals (numbered in visiting order), obstacle and start on a matplotlib Axes.

    Args:
        ax: a ``matplotlib.axes.Axes``.
        layout: the layout to draw (`tl_gym.envs.tasks.Layout`; the env's ``layout`` attribute).
        labels: write ``g``/``g1 g2 g3`` in the goals and ``o`` in the obstacle.
        alpha: fill opacity of goals and obstacle.
    """
    from matplotlib.patches import Circle, Rectangle

    for i, goal in enumerate(layout.goals):
        ax.add_patch(Rectangle(
            (goal.x_low, goal.y_low), goal.x_high - goal.x_low, goal.y_high - goal.y_low,
            facecolor=GOAL_COLOR, edgecolor=GOAL_COLOR, alpha=alpha,
        ))
        if labels:
            name = "g" if len(layout.goals) == 1 else f"g{i + 1}"
            ax.text(*goal.center, name, ha="center", va="center", fontsize=9)
    obstacle = layout.obstacle
    ax.add_patch(Circle((obstacle.x, obstacle.y), obstacle.radius, facecolor=OBSTACLE_COLOR,
                        edgecolor=OBSTACLE_COLOR, alpha=alpha))
    if labels:
        ax.text(obstacle.x, obstacle.y, "o", ha="center", va="center", fontsize=9)
    ax.plot([layout.start[0]], [layout.start[1]], marker="x", color="black", markersize=6)
    width, height = layout.arena
    ax.set_xlim(0.0, width)
    ax.set_ylim(0.0, height)
    ax.set_aspect("equal")


def draw_car(ax: Any, x: float, y: float, theta: float, length: float = 20.0, width: float = 10.0) -> None:
    """Draw the car as a brown rectangle centred on ``(x, y)`` and heading ``theta``."""
    from matplotlib.patches import Polygon

    c, s = math.cos(theta), math.sin(theta)
    corners = np.array([[length, width], [length, -width], [-length, -width], [-length, width]]) / 2.0
    rotated = corners @ np.array([[c, s], [-s, c]]) + np.array([x, y])
    ax.add_patch(Polygon(rotated, closed=True, facecolor=CAR_COLOR, edgecolor="black", linewidth=0.5))


def render_frame(
    layout: Layout,
    paths: Sequence[np.ndarray],
    poses: np.ndarray,
    size: tuple[int, int] = (480, 480),
) -> np.ndarray:
    """An RGB image of the layout, the cars' paths so far and the cars.

    Args:
        layout: the task layout.
        paths: one ``(t, 2)`` array of positions per car.
        poses: ``(k, 3)`` current ``(x, y, θ)`` of the cars to draw.
        size: ``(width, height)`` in pixels.

    Returns:
        A ``(height, width, 3)`` uint8 array.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dpi = 100
    fig = Figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.08, 0.06, 0.9, 0.9))
    draw_layout(ax, layout)
    for path in paths:
        ax.plot(path[:, 0], path[:, 1], color=TRACE_COLOR, linewidth=1.0, alpha=0.8)
    for x, y, theta in np.asarray(poses, dtype=np.float64).reshape(-1, 3):
        draw_car(ax, x, y, theta)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class HumanViewer:
    """A pygame window that shows RGB frames (``render_mode="human"``).

    Raises:
        gymnasium.error.DependencyNotInstalled: pygame is missing (``pip install "tl_gym[render]"``).
    """

    def __init__(self, size: tuple[int, int], fps: int):
        try:
            import pygame
        except ImportError as exc:
            from gymnasium.error import DependencyNotInstalled

            raise DependencyNotInstalled(
                'render_mode="human" needs pygame, which is not installed: run `pip install "tl_gym[render]"` '
                '(or use render_mode="rgb_array")'
            ) from exc
        self._pygame = pygame
        pygame.display.init()  # the display only: no audio device is needed
        self._screen = pygame.display.set_mode(size)
        pygame.display.set_caption("TLCarNav-v0")
        self._clock = pygame.time.Clock()
        self._fps = fps

    def show(self, frame: np.ndarray) -> None:
        """Blit one ``(H, W, 3)`` frame and wait for the frame rate."""
        pygame = self._pygame
        pygame.event.pump()
        surface = pygame.surfarray.make_surface(np.transpose(frame, (1, 0, 2)))
        self._screen.blit(surface, (0, 0))
        pygame.display.flip()
        self._clock.tick(self._fps)

    def close(self) -> None:
        """Close the window."""
        self._pygame.display.quit()
