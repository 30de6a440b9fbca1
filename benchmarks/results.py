"""Aggregate a sweep's finished runs into curves with 95% bands and markdown tables (docs/benchmarks.md).

Only the runs that ``OUT/sweep.json`` lists and that have a ``done.json`` count; the seeds of one
(task, label) are one curve.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.run_one import DONE, HISTORY, TRAJECTORIES, read_history_rows
from benchmarks.sweep_config import RunSpec

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
    """The finished runs of the sweep in ``out_dir``, in config order (FileNotFoundError: no sweep.json)."""
    manifest = Path(out_dir) / "sweep.json"
    if not manifest.is_file():
        raise FileNotFoundError(f"{out_dir} holds no sweep.json: run `python -m benchmarks.runner CONFIG` first")
    specs = json.loads(manifest.read_text())["runs"]
    dirs = {run_id: Path(out_dir) / "runs" / run_id for run_id in specs}
    return [RunResult(RunSpec.from_json(specs[key]), read_history(d / HISTORY), json.loads((d / DONE).read_text()), d)
            for key, d in dirs.items() if (d / DONE).is_file()]


def read_history(path: str | Path) -> dict[str, np.ndarray]:
    """A history CSV as columns of floats (non-numeric columns are skipped)."""
    rows = read_history_rows(path)
    columns: dict[str, np.ndarray] = {}
    for key in rows[0] if rows else ():
        with contextlib.suppress(TypeError, ValueError):  # a non-numeric column
            columns[key] = np.array([float(row[key]) for row in rows])
    return columns


def group_by(items: Iterable[Any], key: Callable[[Any], Any]) -> dict[Any, list[Any]]:
    """``items`` in lists by ``key(item)``, in first-seen order."""
    groups: dict[Any, list[Any]] = {}
    for item in items:
        groups.setdefault(key(item), []).append(item)
    return groups


def group_runs(runs: Iterable[RunResult]) -> dict[tuple[Any, str], list[RunResult]]:
    """Runs keyed by (task, label), in first-seen order; each value holds the seeds of one curve."""
    return group_by(runs, lambda run: (run.task, run.spec.label))


def mean_band(values: np.ndarray, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mean, low, high)`` over seeds (axis 0 of ``values``) with a Student-t band; for one seed, the mean."""
    values = np.asarray(values, dtype=float)
    mean = values.mean(axis=0)
    n = values.shape[0]
    if n < 2:
        return mean, mean.copy(), mean.copy()
    from scipy import stats  # imported here: loading scipy.stats takes a second

    half = stats.t.ppf(0.5 + confidence / 2, n - 1) * values.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


def stack(runs: Sequence[RunResult], key: str) -> tuple[np.ndarray, np.ndarray]:
    """``(iterations, values)``: history column ``key`` of every run as ``(seeds, iterations)``, cut to the shortest."""
    length = min(len(run.history[key]) for run in runs)
    return runs[0].history["iteration"][:length], np.stack([run.history[key][:length] for run in runs])


def first_iteration(iterations: np.ndarray, values: np.ndarray, threshold: float, strict: bool = True) -> int | None:
    """First iteration whose value exceeds ``threshold`` (``>=`` when not strict); None if never."""
    index = np.flatnonzero(values > threshold if strict else values >= threshold)
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
    mean, low, _ = mean_band(robustness[:, -1:])  # the final values, as one point
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
        note=notes(runs),
    )


def median_first(firsts: Sequence[float | None]) -> float | None:
    """Median over all the seeds of when each first got there (iteration, env steps); None: the median seed never did.

    A seed that never got there (None) counts as later than any that did, so the median speaks for the seeds run,
    not for the lucky ones: with 2 of 5 seeds there, the median seed is not, and the result is None.
    """
    if not firsts:
        return None
    median = float(np.median([math.inf if f is None or math.isnan(f) else f for f in firsts]))
    return None if math.isinf(median) or math.isnan(median) else median


def first_text(firsts: Sequence[float | None], number: str = "g") -> str:
    """Median first iteration (or env steps, ...) over all the seeds (`median_first`), and how many got there."""
    median = median_first(firsts)
    reached = sum(f is not None and not math.isnan(f) for f in firsts)
    return f"never ({reached}/{len(firsts)})" if median is None else f"{median:{number}} ({reached}/{len(firsts)})"


def notes(runs: Iterable[RunResult]) -> str:
    """The runs' distinct notes, sorted, in one text."""
    return "; ".join(sorted({run.spec.note for run in runs if run.spec.note}))


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A markdown table: the header's cells, a rule, then one line per row."""
    lines = ["| " + " | ".join(map(str, cells)) + " |" for cells in [header, *rows]]
    return "\n".join([lines[0], "|" + "---|" * len(header), *lines[1:]])


def percent(value: float | None) -> str:
    """``value`` as a whole percentage, "–" when there is none (None or NaN)."""
    return "–" if value is None or math.isnan(value) else f"{value:.0%}"


def markdown_table(rows: Sequence[GroupSummary]) -> str:
    """The per-task results table (markdown), one line per agent."""
    header = ["agent", "seeds", "iterations", "final mean ρ (±95%)", "final success", "eval success",
              "first it. mean ρ > 0", "first it. success ≥ 80%", "env steps", "wall time (s)", "note"]
    lines = []
    for row in rows:
        rho, half = row.final_robustness
        final = "–" if math.isnan(rho) else f"{rho:.3g} ± {half:.2g}"  # nan: no episode ended in the iteration
        lines.append([row.label, row.seeds, row.iterations, final, percent(row.final_success),
                      percent(row.eval_success), first_text(row.first_positive), first_text(row.first_success),
                      f"{row.env_steps:,.0f}", f"{row.wall_time:.1f}", row.note])
    return table(header, lines)


def summaries_by_task(runs: Iterable[RunResult]) -> dict[Any, list[GroupSummary]]:
    """`GroupSummary` rows grouped by task, in config order."""
    rows = [summarise(task, label, members) for (task, label), members in group_runs(runs).items()]
    return group_by(rows, lambda row: row.task)


def per_seed_table(rows: Sequence[Mapping[str, Any]], task: Any) -> str:
    """Per-label markdown table of ``task``: each seed's first iteration at the target, their median, final evaluation.

    ``rows`` are `per_seed_rows`'. The target is mean ρ > 0 on task 1 and success ≥ 80 % otherwise; the median
    (`median_first`) counts a seed that never got there as later than any (shown "–" where the median seed never
    did). Evaluation columns are the stochastic policy's.
    """
    key, what = ("first_rho_positive", "mean ρ > 0 at") if task == 1 else ("first_success_80", "80 % at")
    lines = []
    for label, members in group_by((row for row in rows if row["task"] == task), lambda row: row["variant"]).items():
        members = sorted(members, key=lambda row: row["seed"])
        firsts = [row[key] for row in members]
        median = median_first(firsts)
        success = [row["eval_success_stochastic"] for row in members]
        lines.append([label, len(members), ", ".join("–" if f is None else str(f) for f in firsts),
                      "–" if median is None else f"{median:g}", f"{min(success):.1%}–{max(success):.1%}",
                      f"{np.median(success):.1%}", f"{np.mean([row['eval_rho_stochastic'] for row in members]):.2f}"])
    header = ["variant", "seeds", f"{what} (per seed)", "median", "eval success", "median eval success", "eval mean ρ"]
    return table(header, lines)


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
