"""The TL task suite benchmark: every suite task × {TLPS, REPS, PPO, SAC}, SB3 also on the plain terminal reward.

Runs the configs of ``benchmarks/configs/suite/`` (one per task, evaluated on fresh episodes along the way), then
writes ``docs/results/suite.md`` (who solves each task, at how many env steps; a table per task) and one figure per
task: fresh-episode success and mean ρ against env steps, so progress shows where success is still 0. With
``--out`` (or ``--quick``) the records and the report go there instead, and ``docs/results`` is not touched.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure
from matplotlib.ticker import EngFormatter

from benchmarks.figures import plot_seeds, saved
from benchmarks.results import RunResult, first_text, group_runs, load_runs, median_first, notes, table
from benchmarks.runner import add_sweep_options, check_only, run_with_options, variant_of
from benchmarks.sweep_config import ConfigError, RunSpec, load_config

HERE = Path(__file__).resolve().parent
CONFIGS = HERE / "configs" / "suite"
RESULTS = HERE.parent / "docs" / "results"
#: Where the suite's run records live by default: in git (spec, history and summary of each run, a few KB), so that
#: ``--report-only`` redraws the report on any clone. (Until 2026-12-02 they lived in the git-ignored ``runs/suite``
#: and were lost with that machine.) ``--quick`` runs go to ``runs/suite-quick``.
RECORDS = HERE / "results" / "suite"
#: Record folders beside a task's own whose runs its report also shows, by config stem: runs of the task as it was
#: before a change, kept for comparison (parking's episode ended at the slot until 2026-12-03, SAC paid no
#: satisfaction bonus until 2026-12-05 and went on past a violation until later that day; docs/results/parking.md).
EARLIER_RECORDS = {"parking": ["suite-parking-terminate-on-success-session", "suite-parking-no-bonus-session",
                               "suite-parking-no-end-on-violation-session"]}
#: The report's fixed words: `write_report` writes them, `hand_notes` tells its own paragraphs from the notes by them.
PAGE_TITLE, PRODUCED_BY = "# The TL task suite", "Produced by "
NOT_RUN, NO_RUN = "Not run for this report", "No finished run for this report"
#: Success on fresh episodes that counts as "solved" (the issue's target).
SOLVED = 0.9


def config_paths(tasks: Sequence[str] = ()) -> list[Path]:
    """The suite configs, in name order; ``tasks`` picks some by file stem (``car1``, ``pendulum`` ...)."""
    return [p for p in sorted(CONFIGS.glob("*.toml")) if not tasks or p.stem in tasks]


def suite_run(task: str, label: str) -> RunSpec:
    """The run of suite task ``task`` (a config's file stem) labelled ``label``, at its first seed: a trial's base.

    Raises:
        KeyError: the task's config has no such label (the message lists its labels).
    """
    runs = load_config(CONFIGS / f"{task}.toml").runs
    for spec in runs:
        if spec.label == label:
            return spec
    raise KeyError(f"the suite config {task}.toml has no run labelled {label!r}; its labels: "
                   f"{sorted({spec.label for spec in runs})}")


def parking_sac_without_bonus() -> RunSpec:
    """The suite's parking SAC run as it was before its entry added satisfaction_bonus 10 (2026-12-05).

    The trials of docs/results/parking.md built on that run before then start from it, to stay what they ran: no
    bonus, and no end at the violation (the entry's since the thirteenth session, also 2026-12-05), both written out.
    """
    suite_sac = suite_run("parking", "SAC")
    env_kwargs = {**suite_sac.env_kwargs, "satisfaction_bonus": 0.0, "end_on_violation": False}
    return dataclasses.replace(suite_sac, env_kwargs=env_kwargs, note="")


#: Mean ρ beyond which the ρ panel of `plot_task` is drawn on a symlog axis.
SYMLOG_FROM = 10.0


def eval_points(run: RunResult, key: str = "eval_success_rate") -> tuple[np.ndarray, np.ndarray]:
    """``(env steps, values)`` of the rows where ``run`` evaluated, at its own env steps."""
    mask = ~np.isnan(run.history[key])
    return run.history["env_steps"][mask], run.history[key][mask]


def eval_curve(runs: Sequence[RunResult], key: str = "eval_success_rate") -> tuple[np.ndarray, np.ndarray]:
    """``(env steps, values)``, both ``(seeds, points)``, of the rows where the runs evaluated, cut to the shortest run.

    The env steps are each seed's own: they differ where episodes end early (TLMountainCar-v0, TLParking-v0).
    """
    points = [eval_points(run, key) for run in runs]
    length = min(len(values) for _, values in points)
    return np.stack([steps[:length] for steps, _ in points]), np.stack([values[:length] for _, values in points])


def steps_to_solve(steps: np.ndarray, values: np.ndarray) -> float | None:
    """Env steps at which one seed's fresh-episode success first reaches `SOLVED`; None if never."""
    hits = np.flatnonzero(values >= SOLVED)
    return float(steps[hits[0]]) if hits.size else None


def plot_task(name: str, runs: Sequence[RunResult], path: Path | None) -> Figure:
    """Fresh-episode success (left) and mean ρ (right) against env steps: each seed thin, the median thick.

    The ρ panel shows progress where success is still 0 on every seed (a rising mean ρ is a policy
    getting closer to the formula).
    """
    fig = Figure(figsize=(11.0, 4.2), constrained_layout=True)
    success_ax, rho_ax = fig.subplots(1, 2)
    largest_rho = 0.0
    for i, ((_, label), members) in enumerate(group_runs(runs).items()):
        color, legend = colormaps["tab10"](i % 10), f"{label} ({_seeds(len(members))})"
        steps, values = eval_curve(members)  # each seed's line at its own env steps
        if not steps.size:
            continue
        plot_seeds(success_ax, steps, values, color, legend)
        rho_steps, rho_values = eval_curve(members, "eval_mean_robustness")
        plot_seeds(rho_ax, rho_steps, rho_values, color, legend)
        largest_rho = max(largest_rho, float(np.nanmax(np.abs(rho_values), initial=0.0)))
    success_ax.axhline(SOLVED, color="0.4", lw=0.8, ls="--")
    rho_ax.axhline(0.0, color="0.4", lw=0.8, ls="--")
    success_ax.set(xlabel="env steps", ylabel="success on fresh episodes (ρ > 0)", ylim=(-0.02, 1.02))
    # early policies' ρ can be 100× the late ones': symlog, linear within ±1; a task whose ρ stays within
    # ±SYMLOG_FROM keeps a linear axis (symlog would show it as one decade with unreadable ticks)
    symlog = largest_rho > SYMLOG_FROM
    rho_ax.set(xlabel="env steps", ylabel="mean ρ on fresh episodes" + (" (symlog)" if symlog else ""))
    if symlog:
        rho_ax.set_yscale("symlog", linthresh=1.0)
    for ax in (success_ax, rho_ax):
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))  # 100k, 1.5M
    success_ax.legend(fontsize=7, loc="best")
    fig.suptitle(name)
    return saved(fig, path)


def final_success(run: RunResult) -> float:
    """The final policy's success on its last evaluation along training and the final one (``done.json``), pooled.

    Both evaluate the same final policy on fresh episodes of their own (100 each in the suite's configs); either
    alone is a sample whose noise (± 6 points at 80 % on 100) decides a verdict at the 90 % line, so the verdict
    reads both, weighted by their episodes.
    """
    steps, values = eval_points(run)
    done = run.summary.get("eval_deterministic")
    if done is None or steps[-1] != run.history["env_steps"][-1]:  # no final evaluation, or not of this policy
        return float(values[-1])
    weights = [run.spec.evaluate_episodes, done["episodes"]]
    return float(np.average([values[-1], done["success_rate"]], weights=weights))


def task_table(runs: Sequence[RunResult]) -> tuple[str, list[tuple[str, float, float | None, int, int]]]:
    """One task's markdown table and, per agent, (label, median final success, median steps to solve, solved, seeds)."""
    header = ["agent", "seeds", "budget (env steps)",
              "final success (the last and the final evaluations pooled): median (min–max)",
              "env steps to ≥ 90 %: median over all seeds (how many got there)", "final mean ρ", "note"]
    lines, rows = [], []
    for (_, label), members in group_runs(runs).items():
        # each seed's own evaluations: its last one is its final policy's, and it reached 90 % at its own env steps
        points = [eval_points(run) for run in members]
        rho = [eval_points(run, "eval_mean_robustness")[1] for run in members]
        if any(not len(values) for _, values in points) or any(not len(r) for r in rho):
            continue
        final = np.array([final_success(run) for run in members])
        solves = [steps_to_solve(steps, values) for steps, values in points]
        lines.append([label, len(members), f"{np.mean([steps[-1] for steps, _ in points]):,.0f}",
                      f"{np.median(final):.0%} ({final.min():.0%}–{final.max():.0%})", first_text(solves, ",.0f"),
                      f"{np.median([r[-1] for r in rho]):.3g}", notes(members)])
        rows.append((label, float(np.median(final)), median_first(solves), sum(s is not None for s in solves),
                     len(solves)))
    return table(header, lines), rows


def headline(task: str, rows: Sequence[tuple[str, float, float | None, int, int]]) -> str:
    """One README-style line: which agent solves the task (median final success ≥ 90 %), at how many steps.

    An agent listed after the first with another number of seeds says how many (``SAC (1 seed)``).
    """
    solved = [r for r in rows if r[1] >= SOLVED]  # the final success decides; the steps say when, where they can
    if not solved:
        best = max(rows, key=lambda r: r[1]) if rows else None
        tail = f"best: {best[0]} at {best[1]:.0%} (median of {_seeds(best[4])})" if best else "no runs"
        return f"| {task} | none solved it (≥ 90 % on fresh episodes) | {tail} |"
    first = min(solved, key=lambda r: math.inf if r[2] is None else r[2])
    others = "; ".join(r[0] + (f" ({_seeds(r[4])})" if r[4] != first[4] else "")
                       for r in solved if r is not first)  # labels may hold commas
    # a final success pooled with done.json's can reach 90 % where the median seed's evaluations along training
    # never did: solved at the end, at no evaluation's step
    when = "never at an evaluation along training" if first[2] is None else f"{first[2]:,.0f} env steps"
    return (f"| {task} | {first[0]} | {when} (median over {_seeds(first[4])}, {first[3]} got there)"
            + (f"; also {others}" if others else "") + " |")


def _seeds(count: int) -> str:
    return f"{count} seed{'s' if count != 1 else ''}"


def write_report(results: dict[str, tuple[str, list[RunResult], list[str]]], command: str, out: Path) -> Path:
    """``suite.md`` in ``out``: the headline, then each config's table and figure, and its planned labels not run.

    The notes written by hand into an earlier ``suite.md`` there stay (`hand_notes`): the page's own after its
    first paragraph, each task's after its table, so that redrawing the report from the records loses no word.
    """
    path = out / "suite.md"
    top_notes, section_notes = hand_notes(path.read_text()) if path.is_file() else ([], {})
    lines = [PAGE_TITLE, "",
             f"{PRODUCED_BY}`{command}` (seeds and budgets in `benchmarks/configs/suite/`); success is "
             "ρ > 0 on fresh episodes of the deterministic policy, evaluated along training; a seed's final "
             "success pools its last evaluation and the run's final one on as many other fresh episodes "
             "(`done.json`); the env steps to ≥ 90 % are a median over all the seeds, one that never got "
             "there counting as later than any. "
             "Tasks and formulas: [../tasks.md](../tasks.md). Each task's figure plots the success (left) and "
             "the mean ρ (right; symlog where it spans beyond ±10) of those evaluations against env steps: "
             "each seed as a thin line, the median over seeds (what the tables report) as the thick one.", "",
             *(line for note in top_notes for line in (*note, "")),
             "| task | solved by (median final success ≥ 90 %) | at |", "|---|---|---|"]
    sections = []
    for stem, (title, runs, planned) in results.items():
        if not runs:  # its notes stay: a report redrawn from fewer records loses no word
            lines.append(f"| {title} | not run for this report | |")
            sections += ["", f"## {title}", "", f"{NO_RUN}."]
            sections += [line for note in section_notes.get(title, []) for line in ("", *note)]
            continue
        task_markdown, rows = task_table(runs)
        lines.append(headline(title, rows))
        figure = f"suite_{stem}.png"
        plot_task(title, runs, out / figure)
        sections += ["", f"## {title}", "", task_markdown]
        done = {run.spec.label for run in runs}
        missing = [label for label in planned if label not in done]
        if missing:
            sections += ["", f"{NOT_RUN}: {'; '.join(missing)}."]
        sections += [line for note in section_notes.get(title, []) for line in ("", *note)]
        sections += ["", f"![{title}]({figure})"]
    path.write_text("\n".join(lines + sections) + "\n")
    return path


#: Paragraphs of ``suite.md`` that `write_report` writes itself (a task's first table is its own too).
_GENERATED = (PAGE_TITLE, PRODUCED_BY + "`", NOT_RUN, NO_RUN, "![")


def hand_notes(text: str) -> tuple[list[list[str]], dict[str, list[list[str]]]]:
    r"""The paragraphs of a ``suite.md`` that `write_report` did not generate: the page's own, and each task's by title.

    A paragraph is a block of lines between blank ones. Generated are the title, the "Produced by" paragraph, the
    first table of the page and of each task, the "Not run" line and the figure; every other paragraph is a note.

    Example:
        >>> page = ["# The TL task suite", "Produced by `x`.", "A note.", "| a |", "## T", "| b |", "Why.", "![T](t)"]
        >>> hand_notes("\n\n".join(page))
        ([['A note.']], {'T': [['Why.']]})
    """
    top: list[list[str]] = []
    sections: dict[str, list[list[str]]] = {}
    notes, table_seen = top, False
    for block in (b.strip("\n").split("\n") for b in text.split("\n\n") if b.strip()):
        if block[0].startswith("## "):
            notes, table_seen = sections.setdefault(block[0][3:].strip(), []), False
            block = block[1:]
            if not block:
                continue
        if all(line.startswith("|") for line in block) and not table_seen:
            table_seen = True
        elif not block[0].startswith(_GENERATED):
            notes.append(block)
    return top, sections


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.suite", description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", nargs="*", default=[], choices=[p.stem for p in config_paths()],
                        help="config stems to run (default: all); the report covers every task from its records")
    parser.add_argument("--out", default=None,
                        help=f"run records, and the report when given (default: {RECORDS.relative_to(HERE.parent)}, "
                             "kept in git, whose report is docs/results/suite.md; --quick: "
                             "runs/suite-quick)")
    parser.add_argument("--report-only", action="store_true", help="only redraw the report from finished runs")
    add_sweep_options(parser)
    args = parser.parse_args(argv)
    variant = variant_of(parser, args)
    records_in_git = args.out is None and not args.quick  # only these records' report is docs/results/suite.md
    if args.out is None:
        args.out = "runs/suite-quick" if args.quick else str(RECORDS)
    results: dict[str, tuple[str, list[RunResult], list[str]]] = {}
    failed = 0
    chosen = set(config_paths(args.tasks))
    sweeps = {path: load_config(path, variant=variant) for path in config_paths()}
    if not args.report_only:
        try:
            check_only([sweeps[path] for path in sorted(chosen)], args.only)  # matching in one task is enough
        except ConfigError as exc:
            parser.error(str(exc))
    for path in config_paths():  # the report covers every task, from its records; --tasks chooses what runs
        sweep = sweeps[path]
        out_dir = Path(args.out) / sweep.name
        if not args.report_only and path in chosen:
            failed += len(run_with_options(sweep, out_dir, args).failed)
        runs = load_runs(out_dir) if (out_dir / "sweep.json").is_file() else []
        runs += [run for name in EARLIER_RECORDS.get(path.stem, []) if (Path(args.out) / name / "sweep.json").is_file()
                 for run in load_runs(Path(args.out) / name)]
        planned = list(dict.fromkeys(run.label for run in sweep.runs))
        results[path.stem] = (sweep.description or path.stem, runs, planned)  # a task without runs says so
    command = "python -m benchmarks.suite" + (f" --variant {variant}" if variant and not args.quick else "")
    target = RESULTS if records_in_git else Path(args.out)
    target.mkdir(parents=True, exist_ok=True)
    print(f"wrote {write_report(results, command, target)}")  # every config has its section
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
