"""Aggregate a sweep's finished runs: learning curves with 95% bands, and markdown tables.

Reads ``OUT/sweep.json`` (the runs of the sweep's config) and, for each run with a
``done.json``, its ``history.csv`` and summary; runs of other configs or unfinished runs
in the same directory are ignored. Seeds of one (task, label) are one curve.

Usage::

    python -m benchmarks.results runs/sweeps/paper                # print the tables
    python -m benchmarks.results DIR --per-seed DIR               # write tables.md, summary.csv and curves

Example:
    >>> import numpy as np
    >>> mean, low, high = mean_band(np.array([[0.0, 1.0], [2.0, 3.0]]))
    >>> mean.tolist(), bool(low[0] < 1.0 < high[0])
    ([1.0, 2.0], True)
    >>> first_iteration(np.array([1, 2, 3]), np.array([-1.0, 0.5, 2.0]), 0.0)
    2
    >>> median_first([4, None, 8]), first_text([4, None, 8]), first_text([None])
    (6.0, '6 (2/3)', 'never (0/1)')
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.runner import DONE, HISTORY, TRAJECTORIES, RunSpec

#: Success threshold of the tables' "first iteration with success ≥ 80%" column.
SUCCESS_TARGET = 0.8


@dataclasses.dataclass(frozen=True)
class RunResult:
    """One finished run: its spec, history columns, summary and directory."""

    spec: RunSpec
    history: dict[str, np.ndarray]
    summary: dict[str, Any]
    path: Path

    @property
    def task(self) -> Any:
        """The env's ``task`` kwarg (None if the env has none)."""
        return self.spec.env_kwargs.get("task")

    def traces(self) -> dict[str, np.ndarray]:
        """The recorded trajectories (``it<k>_<signal>`` -> ``(episodes, T+1)``); empty if none."""
        path = self.path / TRAJECTORIES
        if not path.is_file():
            return {}
        with np.load(path) as data:
            return {key: data[key] for key in data.files}


def load_runs(out_dir: str | Path) -> list[RunResult]:
    """The finished runs of the sweep in ``out_dir``, in config order.

    Raises:
        FileNotFoundError: ``out_dir`` holds no ``sweep.json`` (no sweep ran there).
    """
    out_dir = Path(out_dir)
    manifest_path = out_dir / "sweep.json"
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{out_dir} holds no sweep.json: run `python -m benchmarks.runner CONFIG` first")
    manifest = json.loads(manifest_path.read_text())
    results = []
    for run_id, spec in manifest["runs"].items():
        run_dir = out_dir / "runs" / run_id
        if not (run_dir / DONE).is_file():
            continue
        results.append(RunResult(
            spec=RunSpec.from_json(spec),
            history=read_history(run_dir / HISTORY),
            summary=json.loads((run_dir / DONE).read_text()),
            path=run_dir,
        ))
    return results


def read_history(path: str | Path) -> dict[str, np.ndarray]:
    """A history CSV as columns of floats (non-numeric columns are skipped)."""
    with Path(path).open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    columns: dict[str, np.ndarray] = {}
    for key in rows[0] if rows else ():
        try:
            columns[key] = np.array([float(row[key]) for row in rows])
        except (TypeError, ValueError):
            continue
    return columns


def group_runs(runs: Iterable[RunResult]) -> dict[tuple[Any, str], list[RunResult]]:
    """Runs keyed by (task, label), in first-seen order; each value holds the seeds of one curve."""
    groups: dict[tuple[Any, str], list[RunResult]] = {}
    for run in runs:
        groups.setdefault((run.task, run.spec.label), []).append(run)
    return groups


def mean_band(values: np.ndarray, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over seeds (axis 0) with a Student-t confidence band; the band is the mean for one seed.

    Args:
        values: ``(seeds, iterations)``.
        confidence: coverage of the band.

    Returns:
        ``(mean, low, high)``, each ``(iterations,)``.
    """
    values = np.asarray(values, dtype=float)
    mean = values.mean(axis=0)
    n = values.shape[0]
    if n < 2:
        return mean, mean.copy(), mean.copy()
    from scipy import stats  # imported here: loading scipy.stats takes a second

    half = stats.t.ppf(0.5 + confidence / 2, n - 1) * values.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


def stack(runs: Sequence[RunResult], key: str) -> tuple[np.ndarray, np.ndarray]:
    """History column ``key`` of every run as ``(seeds, iterations)``, cut to the shortest run.

    Returns:
        ``(iterations, values)``.
    """
    length = min(len(run.history[key]) for run in runs)
    values = np.stack([run.history[key][:length] for run in runs])
    return runs[0].history["iteration"][:length], values


def first_iteration(iterations: np.ndarray, values: np.ndarray, threshold: float, strict: bool = True) -> int | None:
    """First iteration whose value exceeds ``threshold`` (``>=`` when not strict); None if never."""
    hits = values > threshold if strict else values >= threshold
    index = np.flatnonzero(hits)
    return int(iterations[index[0]]) if index.size else None


@dataclasses.dataclass(frozen=True)
class GroupSummary:
    """One table row: the seeds of one (task, label)."""

    task: Any
    label: str
    seeds: int
    iterations: int
    final_robustness: tuple[float, float]  # mean, 95% half-width
    final_success: float
    eval_success: float | None
    first_positive: list[int | None]
    first_success: list[int | None]
    env_steps: float
    wall_time: float
    note: str


def summarise(task: Any, label: str, runs: Sequence[RunResult]) -> GroupSummary:
    """Aggregate the seeds of one curve into a `GroupSummary`."""
    iterations, robustness = stack(runs, "mean_robustness")
    _, success = stack(runs, "success_rate")
    final = robustness[:, -1]
    mean, low, _ = mean_band(final[:, None])
    evals = [run.summary.get("eval_deterministic", {}).get("success_rate") for run in runs]
    return GroupSummary(
        task=task, label=label, seeds=len(runs), iterations=int(iterations[-1]),
        final_robustness=(float(mean[0]), float(mean[0] - low[0])),
        final_success=float(success[:, -1].mean()),
        eval_success=None if None in evals else float(np.mean(evals)),
        first_positive=[first_iteration(iterations, row, 0.0) for row in robustness],
        first_success=[first_iteration(iterations, row, SUCCESS_TARGET, strict=False) for row in success],
        env_steps=float(np.mean([run.summary["env_steps"] for run in runs])),
        wall_time=float(np.mean([run.summary["train_wall_time"] for run in runs])),
        note="; ".join(sorted({run.spec.note for run in runs if run.spec.note})),
    )


def median_first(firsts: Sequence[float | None]) -> float | None:
    """Median over the seeds that got there of when they first did (iteration, env steps); None: no seed did."""
    reached = [f for f in firsts if f is not None]
    return float(np.median(reached)) if reached else None


def first_text(firsts: Sequence[int | None]) -> str:
    """Median first iteration over the seeds that got there, and how many did."""
    median = median_first(firsts)
    reached = sum(f is not None for f in firsts)
    return f"never (0/{len(firsts)})" if median is None else f"{median:g} ({reached}/{len(firsts)})"


def markdown_table(rows: Sequence[GroupSummary]) -> str:
    """The per-task results table (markdown), one line per agent."""
    header = ("| agent | seeds | iterations | final mean ρ (±95%) | final success | eval success "
              "| first it. mean ρ > 0 | first it. success ≥ 80% | env steps | wall time (s) | note |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for row in rows:
        rho, half = row.final_robustness
        evaluation = "–" if row.eval_success is None else f"{row.eval_success:.0%}"
        final = "–" if math.isnan(rho) else f"{rho:.3g} ± {half:.2g}"  # nan: no episode ended in the iteration
        success = "–" if math.isnan(row.final_success) else f"{row.final_success:.0%}"
        lines.append(
            f"| {row.label} | {row.seeds} | {row.iterations} | {final} | {success} "
            f"| {evaluation} | {first_text(row.first_positive)} | {first_text(row.first_success)} "
            f"| {row.env_steps:,.0f} | {row.wall_time:.1f} | {row.note} |"
        )
    return "\n".join(lines)


def summaries_by_task(runs: Iterable[RunResult]) -> dict[Any, list[GroupSummary]]:
    """`GroupSummary` rows grouped by task, in config order."""
    tables: dict[Any, list[GroupSummary]] = {}
    for (task, label), members in group_runs(runs).items():
        tables.setdefault(task, []).append(summarise(task, label, members))
    return tables


def per_seed_table(rows: Sequence[Mapping[str, Any]], task: Any) -> str:
    """Per-label markdown table of ``task``: each seed's first iteration at the target, their median, final evaluation.

    ``rows`` are `per_seed_rows`'. The target is mean ρ > 0 on task 1 and success ≥ 80 % otherwise; the median
    counts a seed that never got there as infinite (shown "–"). Evaluation columns are the stochastic policy's.
    """
    key, what = ("first_rho_positive", "mean ρ > 0 at") if task == 1 else ("first_success_80", "80 % at")
    lines = [f"| variant | seeds | {what} (per seed) | median | eval success | median eval success | eval mean ρ |",
             "|---|---|---|---|---|---|---|"]
    labels: dict[str, list[Mapping[str, Any]]] = {}
    for row in rows:
        if row["task"] == task:
            labels.setdefault(row["variant"], []).append(row)
    for label, members in labels.items():
        members = sorted(members, key=lambda row: row["seed"])
        firsts = [row[key] for row in members]
        median = float(np.median([math.inf if f is None else f for f in firsts]))
        success = [row["eval_success_stochastic"] for row in members]
        lines.append(f"| {label} | {len(members)} | {', '.join('–' if f is None else str(f) for f in firsts)} | "
                     f"{'–' if math.isinf(median) else f'{median:g}'} | {min(success):.1%}–{max(success):.1%} | "
                     f"{np.median(success):.1%} | {np.mean([row['eval_rho_stochastic'] for row in members]):.2f} |")
    return "\n".join(lines)


def per_seed_rows(runs: Sequence[RunResult]) -> list[dict[str, Any]]:
    """One ``summary.csv`` row per run: first iterations at the targets, best and final batch, final evaluation."""
    rows = []
    for run in runs:
        iterations, success, rho = (run.history[k] for k in ("iteration", "success_rate", "mean_robustness"))
        stochastic, deterministic = run.summary["eval_stochastic"], run.summary["eval_deterministic"]
        rows.append({
            "task": run.task, "variant": run.spec.label, "seed": run.spec.seed, "iterations": len(success),
            "first_rho_positive": first_iteration(iterations, rho, 0.0),
            "first_success_80": first_iteration(iterations, success, SUCCESS_TARGET, strict=False),
            "best_success": float(success.max()), "final_success": float(success[-1]), "final_rho": float(rho[-1]),
            "eval_success_stochastic": stochastic["success_rate"],
            "eval_success_deterministic": deterministic["success_rate"],
            "eval_rho_stochastic": stochastic["mean_robustness"],
            "seconds_per_iteration": float(run.history["wall_time"][-1]) / len(success),
        })
    return rows


def write_per_seed_report(runs: Sequence[RunResult], out: str | Path) -> list[Path]:
    """Write ``tables.md`` (`per_seed_table` per task), ``summary.csv`` and the curves of `figures.plot_seed_panels`."""
    from tl_gym.agents.callbacks import write_history

    from benchmarks import figures

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = per_seed_rows(runs)
    write_history(sorted(rows, key=lambda row: (row["task"], row["variant"], row["seed"])), out / "summary.csv")
    tasks = list(dict.fromkeys(run.task for run in runs))
    (out / "tables.md").write_text("\n".join(f"### Task {task}\n\n{per_seed_table(rows, task)}\n" for task in tasks))
    return [out / "tables.md", out / "summary.csv", *(path for task in tasks
                                                      for path in figures.plot_seed_panels(runs, task, out))]


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables of a results folder; with ``--per-seed OUT`` write the per-seed report there."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.results", description="Tables of a sweep's results.")
    parser.add_argument("out_dir", help="a sweep's results folder (e.g. runs/sweeps/paper)")
    parser.add_argument("--per-seed", type=Path, metavar="OUT",
                        help="write tables.md, summary.csv and per-label curves to OUT (the research report)")
    args = parser.parse_args(argv)
    runs = load_runs(args.out_dir)
    if not runs:
        print(f"no finished runs in {args.out_dir}")
        return 1
    if args.per_seed:
        print("wrote " + ", ".join(map(str, write_per_seed_report(runs, args.per_seed))))
        return 0
    for task, rows in summaries_by_task(runs).items():
        print(f"\n## task {task}\n\n{markdown_table(rows)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
