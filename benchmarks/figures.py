"""Figures of a sweep: learning curves with 95% bands (Figure 3), trajectories (Figure 2), per-seed panels.

The suite's figures draw each seed and the median instead of a band (`plot_seeds`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from benchmarks.results import RunResult, group_runs, mean_band, stack


def plot_learning_curves(runs: Sequence[RunResult], path: str | Path | None = None, title: str | None = None) -> Figure:
    """Mean exact robustness of the sampled episodes (top) and success rate per iteration, by task, with 95% bands."""
    groups = group_runs(runs)
    tasks = list(dict.fromkeys(task for task, _ in groups))
    colors = {label: colormaps["tab10"](i % 10) for i, label in enumerate(dict.fromkeys(key[1] for key in groups))}
    fig = Figure(figsize=(5.2 * len(tasks), 7), constrained_layout=True)
    axes = np.asarray(fig.subplots(2, len(tasks), sharex="col", squeeze=False))
    for (task, label), members in groups.items():
        for ax, key in zip(axes[:, tasks.index(task)], ("mean_robustness", "success_rate")):
            plot_band(ax, *stack(members, key), colors[label], f"{label} ({len(members)})", rate=key == "success_rate")
    for top, bottom, task in zip(axes[0], axes[1], tasks):
        top.axhline(0.0, color="0.4", lw=0.8, ls="--")
        top.set(title=f"task {task}" if task is not None else "", ylabel="mean exact robustness")
        bottom.set(ylabel="success rate (ρ > 0)", ylim=(-0.02, 1.02), xlabel="iteration (8,000 env steps each)")
        top.legend(fontsize="x-small", loc="lower right")
    if title:
        fig.suptitle(title)
    return saved(fig, path)


def plot_band(ax: Any, x: np.ndarray, values: np.ndarray, color: Any, label: str, rate: bool = False,
              markersize: float = 4) -> None:
    """Mean over seeds of ``values`` ``(seeds, len(x))`` against ``x``, 95% band ([0, 1] for a rate), short: markers."""
    mean, low, high = mean_band(values)
    if rate:
        low, high = np.clip(low, 0.0, 1.0), np.clip(high, 0.0, 1.0)
    ax.plot(x, mean, color=color, lw=1.5, marker="o" if len(x) <= 5 else None, markersize=markersize, label=label)
    ax.fill_between(x, low, high, color=color, alpha=0.2, lw=0)


def plot_seeds(ax: Any, x: np.ndarray, values: np.ndarray, color: Any, label: str, markersize: float = 3) -> None:
    """Each seed of ``values`` ``(seeds, points)`` as a thin line, their median as the thick one.

    ``x`` is shared ``(points,)`` or each seed's own ``(seeds, points)``; then each seed's line runs at its own
    ``x`` and the median of each point sits at the seeds' mean ``x`` there.

    For the few seeds of a suite task (5 or fewer) whose outcomes split, solved or not, a band
    around the mean covers the whole axis and hides which seed does what; the lines show it, and
    the median is what the tables report.
    """
    x = np.asarray(x, dtype=float)
    if len(values) > 1:
        ax.plot(x.T if x.ndim == 2 else x, values.T, color=color, lw=0.8, alpha=0.45)
    x = x.mean(axis=0) if x.ndim == 2 else x
    ax.plot(x, np.median(values, axis=0), color=color, lw=1.8, marker="o" if len(x) <= 5 else None,
            markersize=markersize, label=label)


def plot_trajectory_distribution(run: RunResult, path: str | Path | None = None, title: str | None = None) -> Figure:
    """The sampled x-y paths of one run at its recorded iterations, mean ± 2σ, lighter = earlier (ValueError: none)."""
    import gymnasium as gym
    from tl_gym.agents.plotting import plot_trajectories
    from tl_gym.envs.rendering import draw_layout

    traces = run.traces()
    iterations = sorted({int(key[2:].split("_", 1)[0]) for key in traces})
    if not iterations:
        raise ValueError(f"run {run.path.name} recorded no trajectories")
    snapshots = [(it, {"x": traces[f"it{it}_x"], "y": traces[f"it{it}_y"]}) for it in iterations]
    with gym.make(run.spec.env, **run.spec.env_kwargs) as env:  # built once, for its task layout
        layout = env.unwrapped.layout
    fig = plot_trajectories(snapshots, background=lambda ax: draw_layout(ax, layout), title=title)
    ax = fig.axes[0]
    # early iterations spread over the whole arena: fainter bands (the snapshots' patches), the layout again on top
    for patch in ax.patches[-len(snapshots):]:
        patch.set_alpha(0.15)
    before = len(ax.patches)
    draw_layout(ax, layout, labels=False, alpha=0.45)  # which also sets the whole arena as the limits
    for patch in ax.patches[before:]:
        patch.set_zorder(5)
    for text, it in zip(ax.get_legend().get_texts(), iterations):  # plot_trajectories' legend, one entry a snapshot
        success = float(np.mean(traces[f"it{it}_robustness"] > 0))
        text.set_text(f"iteration {it}" + (" (initial)" if it == 0 else "") + f": success {success:.0%}")
    return saved(fig, path)


def saved(fig: Figure, path: str | Path | None, dpi: int = 110) -> Figure:
    """``fig``, saved as ``path`` first when one is given."""
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi)
    return fig


def plot_seed_panels(runs: Sequence[RunResult], task: Any, out: str | Path) -> list[Path]:
    """Per-seed curves of ``task`` for the research report (docs/benchmarks.md); return the paths written."""
    groups = {label: members for (t, label), members in group_runs(runs).items() if t == task}
    paths = []
    for key, name in (("success_rate", "success"), ("mean_robustness", "robustness")):
        cols = min(5, len(groups))
        rows = -(-len(groups) // cols)
        fig = Figure(figsize=(3.2 * cols, 2.6 * rows), layout="tight")
        axes = np.asarray(fig.subplots(rows, cols, sharex=True, sharey=True, squeeze=False))
        for ax, (label, members) in zip(axes.flat, groups.items()):
            iterations, values = stack(members, key)
            for run in members:
                ax.plot(run.history["iteration"], run.history[key], lw=0.8, alpha=0.6)
            ax.plot(iterations, np.median(values, axis=0), color="k", lw=2)
            ax.axhline(0.8 if key == "success_rate" else 0.0, color="gray", ls="--", lw=0.8)
            ax.set_title(f"{label} ({len(members)} seeds)", fontsize=9)
            if key == "mean_robustness":
                ax.set_yscale("symlog", linthresh=5.0)
        for ax in axes.flat[len(groups):]:
            ax.set_visible(False)
        fig.supxlabel("iteration")
        fig.supylabel("success rate" if key == "success_rate" else "mean exact robustness")
        fig.suptitle(f"task {task}: thin = seeds, thick = median")
        paths.append(Path(out) / f"task{task}_{name}.png")
        saved(fig, paths[-1], dpi=80)
    fig = Figure(figsize=(12, 4.5), layout="tight")
    axes = fig.subplots(1, 2)
    for i, (label, members) in enumerate(groups.items()):
        for ax, key in zip(axes, ("success_rate", "mean_robustness")):
            median = np.median(stack(members, key)[1], axis=0)
            # the first four labels (the baselines, by the config's order) drawn thick
            ax.plot(np.arange(1, len(median) + 1), median, label=label, lw=2.5 if i < 4 else 1.0,
                    color=colormaps["tab10"](i % 10) if i < 4 else None)
    axes[0].set(ylabel="median success rate", xlabel="iteration")
    axes[1].set(ylabel="median mean exact robustness", xlabel="iteration")
    axes[1].set_yscale("symlog", linthresh=5.0)
    axes[1].legend(fontsize=7, ncol=2)
    fig.suptitle(f"task {task}: medians over seeds")
    paths.append(Path(out) / f"task{task}_medians.png")
    saved(fig, paths[-1], dpi=80)
    return paths
