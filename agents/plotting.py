"""Plots of training runs: learning curves and trajectory distributions.

Figures are built with `matplotlib.figure.Figure` directly (no pyplot state, any
backend), returned, and written to ``path`` when one is given. The benchmarks
reuse them to put several agents on the same axes.

- `plot_learning_curve`: mean exact robustness and success rate against the
  iteration or the env steps, one line per run (the paper's Figure 3).
- `plot_trajectories`: sampled x-y paths at selected iterations as a mean path and
  a band of ± 2 standard deviations across it, lighter for earlier iterations,
  over the task layout when a drawing function is given (the paper's Figure 2).
- `plot_signals`: the same bands for each signal over time, for envs without a plane.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

History = Sequence[Mapping[str, Any]]
#: One snapshot of sampled trajectories: ``(iteration, {signal name: (N, T+1) values})``.
Snapshot = tuple[int, Mapping[str, Any]]


def plot_learning_curve(
    runs: History | Mapping[str, History],
    path: str | Path | None = None,
    x: str = "iteration",
    title: str | None = None,
) -> Figure:
    """Mean exact robustness (top) and success rate (bottom) per iteration.

    Args:
        runs: one history (a list of rows) or ``{label: history}`` for several runs.
        path: where to save the PNG (optional).
        x: ``"iteration"`` or ``"env_steps"``.
        title: figure title.

    Example:
        >>> rows = [{"iteration": i, "env_steps": 8000 * i, "mean_robustness": i - 3.0,
        ...          "success_rate": i / 5} for i in range(1, 6)]
        >>> fig = plot_learning_curve({"REPS": rows}, x="env_steps")
        >>> [ax.get_ylabel() for ax in fig.axes]
        ['mean robustness', 'success rate']
    """
    if x not in ("iteration", "env_steps"):
        raise ValueError(f"x must be 'iteration' or 'env_steps', got {x!r}")
    if not isinstance(runs, Mapping):
        runs = {"": runs}
    fig = Figure(figsize=(7, 6), constrained_layout=True)
    top, bottom = fig.subplots(2, 1, sharex=True)
    for label, history in runs.items():
        xs = [row[x] for row in history]
        top.plot(xs, [row["mean_robustness"] for row in history], label=label or None)
        bottom.plot(xs, [row["success_rate"] for row in history], label=label or None)
    steps = {_steps_per_iteration(h) for h in runs.values()}
    if x == "iteration" and len(steps) == 1 and None not in steps:
        per = steps.pop()  # one budget per iteration: show env steps along the top as well
        top.secondary_xaxis("top", functions=(lambda i: i * per, lambda s: s / per)).set_xlabel("env steps")
    top.axhline(0.0, color="0.5", lw=0.8, ls="--")
    top.set_ylabel("mean robustness")
    bottom.set_ylabel("success rate")
    bottom.set_ylim(-0.02, 1.02)
    bottom.set_xlabel("iteration" if x == "iteration" else "env steps")
    if any(runs):
        top.legend()
    if title:
        fig.suptitle(title)
    return _saved(fig, path)


def _steps_per_iteration(history: History) -> float | None:
    """The env steps of every iteration when they are all equal, else ``None``."""
    if not history:
        return None
    steps = np.diff([0] + [row["env_steps"] for row in history]) / np.diff([0] + [row["iteration"] for row in history])
    return float(steps[0]) if np.allclose(steps, steps[0]) else None


def trajectory_band(xs: np.ndarray, ys: np.ndarray, width: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Mean path and the band of ± ``width`` standard deviations across it.

    At each time step the spread is measured along the normal of the mean path, so the
    band's width is the trajectories' spread across their direction of travel.

    Args:
        xs: sampled x coordinates, shape ``(N, T)``.
        ys: sampled y coordinates, shape ``(N, T)``.
        width: band half-width in standard deviations.

    Returns:
        ``(mean (T, 2), quads (T-1, 4, 2))``: the band as one quadrilateral per time step,
        each counter-clockwise, so that filling them as one path (nonzero winding) paints
        their union once even where a wide band folds over itself.
    """
    points = np.stack([xs, ys], axis=-1)  # (N, T, 2)
    mean = points.mean(axis=0)
    tangent = np.gradient(mean, axis=0)
    norm = np.linalg.norm(tangent, axis=1, keepdims=True)
    tangent = np.where(norm > 1e-12, tangent / np.maximum(norm, 1e-12), np.array([1.0, 0.0]))
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    spread = np.einsum("ntd,td->nt", points - mean, normal).std(axis=0)
    upper = mean + width * spread[:, None] * normal
    lower = mean - width * spread[:, None] * normal
    quads = np.stack([lower[:-1], lower[1:], upper[1:], upper[:-1]], axis=1)
    x, y = quads[..., 0], quads[..., 1]
    area = 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    quads[area < 0] = quads[area < 0, ::-1]
    return mean, quads


def _band_patch(quads: np.ndarray, color: Any) -> Any:
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    vertices = np.concatenate([quads, quads[:, :1]], axis=1).reshape(-1, 2)
    codes = np.tile([MplPath.MOVETO, *[MplPath.LINETO] * 3, MplPath.CLOSEPOLY], len(quads))
    return PathPatch(MplPath(vertices, codes), facecolor=color, edgecolor="none", alpha=0.3)


def plot_trajectories(
    snapshots: Sequence[Snapshot],
    path: str | Path | None = None,
    x: str = "x",
    y: str = "y",
    background: Callable[[Any], None] | None = None,
    title: str | None = None,
) -> Figure:
    """Sampled paths in the plane at selected iterations, lighter = earlier.

    Args:
        snapshots: ``(iteration, traces)`` pairs in training order; ``traces[x]`` and
            ``traces[y]`` hold ``(N, T+1)`` sampled values.
        path: where to save the PNG (optional).
        x: the signal giving the horizontal coordinate.
        y: the signal giving the vertical coordinate.
        background: draws the task layout on the axes (e.g. the car env's goals and obstacle).
        title: figure title.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> t = np.linspace(0, 1, 20)
        >>> snaps = [(i, {"x": t + rng.normal(0, 0.05, (10, 20)), "y": t ** 2 + rng.normal(0, 0.05, (10, 20))})
        ...          for i in (1, 10)]
        >>> len(plot_trajectories(snaps).axes[0].lines)
        2
    """
    fig = Figure(figsize=(8, 6), constrained_layout=True)
    ax = fig.subplots()
    if background is not None:
        background(ax)
    colors = _shades(len(snapshots))
    for (iteration, traces), color in zip(snapshots, colors):
        xs, ys = _matrix(traces, x), _matrix(traces, y)
        mean, quads = trajectory_band(xs, ys)
        ax.add_patch(_band_patch(quads, color))
        ax.plot(mean[:, 0], mean[:, 1], color=color, lw=1.5, label=f"iteration {iteration}")
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small")  # keep the layout visible
    if title:
        fig.suptitle(title)
    return _saved(fig, path)


def plot_signals(
    snapshots: Sequence[Snapshot],
    path: str | Path | None = None,
    signals: Sequence[str] | None = None,
    title: str | None = None,
) -> Figure:
    """Each signal over time at selected iterations: mean and ± 2 standard deviations, lighter = earlier.

    Args:
        snapshots: ``(iteration, traces)`` pairs in training order (``(N, T+1)`` values per signal).
        path: where to save the PNG (optional).
        signals: which signals to plot; all of the first snapshot's by default.
        title: figure title.
    """
    if not snapshots:
        raise ValueError("no snapshots to plot")
    names = list(signals) if signals is not None else list(snapshots[0][1])
    fig = Figure(figsize=(7, 2.4 * len(names) + 0.6), constrained_layout=True)
    axes = np.atleast_1d(fig.subplots(len(names), 1, sharex=True))
    colors = _shades(len(snapshots))
    for ax, name in zip(axes, names):
        for (iteration, traces), color in zip(snapshots, colors):
            values = _matrix(traces, name)
            mean, std = values.mean(axis=0), values.std(axis=0)
            steps = np.arange(values.shape[1])
            ax.fill_between(steps, mean - 2 * std, mean + 2 * std, color=color, alpha=0.3, lw=0)
            ax.plot(steps, mean, color=color, lw=1.2, label=f"iteration {iteration}")
        ax.set_ylabel(name)
    axes[-1].set_xlabel("time step")
    axes[0].legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(title)
    return _saved(fig, path)


def _matrix(traces: Mapping[str, Any], name: str) -> np.ndarray:
    """A signal's sampled values as an ``(N, T)`` array (episodes of unequal length padded with their last value)."""
    if name not in traces:
        raise KeyError(f"no signal {name!r} in the traces (have {sorted(traces)})")
    rows = [np.asarray(r, dtype=float) for r in traces[name]]
    length = max(r.shape[0] for r in rows)
    return np.stack([np.concatenate([r, np.full(length - r.shape[0], r[-1])]) for r in rows])


def _shades(n: int) -> list[Any]:
    """``n`` colours from light (early) to dark (late)."""
    cmap = colormaps["Blues"]
    return [cmap(v) for v in np.linspace(0.35, 0.95, max(n, 1))][:n]


def _saved(fig: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
    return fig
