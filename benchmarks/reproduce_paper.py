"""Reproduce the paper's Figures 2 and 3 and the ablations, and write them under ``docs/results/``.

Runs the sweeps of ``configs/paper.toml`` and ``configs/ablations.toml`` (finished runs are skipped, so an
interrupted reproduction resumes), then writes the pages and figures that docs/benchmarks.md lists from the
results on disk (``--quick``: to ``runs/results-quick``).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks import figures, results
from benchmarks.provenance import git
from benchmarks.runner import add_sweep_options, check_only, default_out_dir, run_with_options, variant_of
from benchmarks.sweep_config import ConfigError, Sweep, load_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "benchmarks" / "configs"
PAPER, ABLATIONS = CONFIGS / "paper.toml", CONFIGS / "ablations.toml"
#: The TLPS curve the Figure-2 plots and the claims are about (the paper's default β).
DEFAULT_TLPS = "TLPS β=9"


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.reproduce_paper",
                                     description="Reproduce the paper's Figures 2 and 3 and the ablations.")
    add_sweep_options(parser)
    parser.add_argument("--seeds", type=int, help="seeds per curve (overrides the config's)")
    parser.add_argument("--iterations", type=int, help="iterations per run (caps every agent's)")
    parser.add_argument("--no-run", action="store_true", help="do not run: write the pages from results on disk")
    args = parser.parse_args(argv)
    variant = variant_of(parser, args)
    for name in ("seeds", "iterations"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name} must be >= 1")
    overrides = {k: v for k, v in (("seeds", args.seeds), ("iterations", args.iterations)) if v is not None}
    docs = Path("runs/results-quick") if args.quick else Path("docs/results")
    command = "python -m benchmarks.reproduce_paper " + " ".join(sys.argv[1:] if argv is None else argv)
    failed = 0
    sweeps = {config: load_config(config, variant=variant, overrides=overrides) for config in (PAPER, ABLATIONS)}
    try:
        check_only(list(sweeps.values()), args.only)  # a pattern must match in one of the two configs
    except ConfigError as exc:
        parser.error(str(exc))
    for config, write in ((PAPER, write_paper), (ABLATIONS, write_ablations)):
        sweep = sweeps[config]
        out_dir = default_out_dir(sweep)
        if not args.no_run:
            failed += len(run_with_options(sweep, out_dir, args).failed)
        try:
            runs = results.load_runs(out_dir)
        except FileNotFoundError as error:  # --no-run before any run: one line, saying how to get the runs
            parser.error(f"{error}" + (" (or drop --no-run: this command runs them)" if args.no_run else ""))
        if not runs:
            print(f"{sweep.name}: no finished runs in {out_dir}; nothing written", file=sys.stderr)
            continue
        written = write(runs, docs, provenance(sweep, config, out_dir, command.strip(), runs))
        print(f"{sweep.name}: {len(runs)}/{len(sweep.runs)} runs finished; wrote {', '.join(map(str, written))}")
    return 1 if failed else 0


def provenance(sweep: Sweep, config: Path, out_dir: Path, command: str, runs: Sequence[results.RunResult]) -> str:
    """What produced a results page (command, config, variant, commit, machine), and its curves' seeds and budgets."""
    missing = len({run.run_id for run in sweep.runs} - {run.spec.run_id for run in runs})
    variant = sweep.name.partition("-")[2]
    versions = results.group_by(runs, lambda run: run.summary.get("code", "not recorded"))
    code = "; ".join(f"{key}: {len(members)} run(s)" for key, members in versions.items())
    rows = []
    for label, members in results.group_by(runs, lambda run: run.spec.label).items():
        spec = members[0].spec
        hyper = ", ".join(f"{k}={v}" for k, v in spec.hyperparameters.items()) or "defaults"
        env = ", ".join(f"{k}={v}" for k, v in spec.env_kwargs.items() if k != "task") or "–"
        seeds = ", ".join(str(s) for s in sorted({run.spec.seed for run in members}))
        rows.append([label, f"`{spec.agent}`", hyper, env, seeds, spec.iterations])
    reduced = (f"**Reduced grid** (config variant `{variant}`): fewer seeds and, where noted, smaller budgets than "
               "the full benchmark (`python -m benchmarks.reproduce_paper`); see the table below for what ran.\n")
    return "\n".join([
        reduced if variant else "",
        f"Produced by `{command}` from `{config.relative_to(ROOT)}` (sweep `{sweep.name}`, "
        f"results in `{out_dir}`), tl_gym at commit `{git('rev-parse', '--short', 'HEAD') or 'unknown'}`, on "
        f"{os.cpu_count()} CPU cores ({platform.machine()}, Python {platform.python_version()}), "
        f"written {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC. "
        f"Code of the runs: {code}. {len(runs)} finished runs"
        + (f"; {missing} run(s) of the grid not finished yet." if missing else "."),
        "",
        results.table(["curve", "agent", "hyperparameters", "env kwargs", "seeds", "iterations"], rows),
    ])


HOW_TO_READ = (
    "Columns: *final mean ρ* is the exact robustness averaged over the episodes sampled for the last update, "
    "then over seeds (± the 95% Student-t half-width); *final success* the share of those episodes with ρ > 0; "
    "*eval success* the final policy's mean action on 200 fresh episodes (deterministic); *first it.* columns "
    "give the median first iteration over all the seeds (a seed that never got there counting as later than any; "
    "*never* where the median seed did not) and how many got there; *env steps* and *wall time* "
    "(training only, one process, one torch thread) are per run, averaged over seeds. The machine was shared with "
    "other jobs, so wall times are upper bounds."
)


def _page(title: str, context: str, body: Sequence[str], images: str, intro: Sequence[str] = (),
          tail: Sequence[str] = ()) -> str:
    return "\n".join([f"# {title}", "", *intro, context, "", *body, "", HOW_TO_READ, "", images, "", *tail])


def write_paper(runs: Sequence[results.RunResult], docs: Path, context: str) -> list[Path]:
    """Write the per-task tables, the claims, Figure 3 and the Figure-2 plots; return the paths."""
    written = [docs / "fig3_learning_curves.png"]
    figures.plot_learning_curves(runs, written[0], title="Exact robustness of the sampled episodes (Figure 3)")
    for task, rows in results.summaries_by_task(runs).items():
        images = "![learning curves](fig3_learning_curves.png)"
        default = [r for r in runs if r.task == task and r.spec.label == DEFAULT_TLPS and r.spec.trajectory_iterations]
        if default:
            run = min(default, key=lambda r: r.spec.seed)
            written.append(docs / f"fig2_trajectories_task{task}.png")
            figures.plot_trajectory_distribution(
                run, written[-1], title=f"Task {task}: {DEFAULT_TLPS}, seed {run.spec.seed}, sampled paths (mean ± 2σ)")
            images += f"\n\n![trajectories]({written[-1].name})"
        written.append(docs / f"paper_task{task}.md")
        written[-1].write_text(_page(f"Task {task}: TLPS vs REPS vs stable-baselines3", context,
                                     ["## Results", "", results.markdown_table(rows)], images,
                                     tail=["## The paper's claims against these runs", "", claims(task, rows), ""]))
    return written


def write_ablations(runs: Sequence[results.RunResult], docs: Path, context: str) -> list[Path]:
    """Write the ablation tables and curves; return the paths."""
    figure = docs / "ablations_learning_curves.png"
    figures.plot_learning_curves(runs, figure, title="TLPS ablations (exact robustness of sampled episodes)")
    sections = [f"## Task {task}\n\n{results.markdown_table(rows)}"
                for task, rows in results.summaries_by_task(runs).items()]
    intro = ("Weights (`hybrid`, the default, against `importance` and the paper's literal `paper` form), the "
             "exploration schedule (a decaying floor on the policy's std, `exploration_floor`) against the default, "
             "fixed feedback gains (the paper keeps K_t fixed and learns k_t, C_t; these arms run the paper's "
             "K_t = 0, open loop, pinned with feedback=\"open\" in the config; the `heading feedback K` arm steers "
             "against the heading, steering action −1.0·θ) and task 2 "
             "with `no_revisit=\"strict\"` (Eq. 19 literally). Every TLPS arm changes one thing from the default, "
             "so compare each with the `weights=hybrid` row.")
    page = docs / "ablations.md"
    page.write_text(_page("TLPS ablations", context, sections, f"![ablation curves]({figure.name})", [intro, ""]))
    return [page, figure]


def claims(task: Any, rows: Sequence[results.GroupSummary]) -> str:
    """The paper's claims for ``task``, each set against the measured numbers (computed, not asserted)."""
    by_label = {row.label: row for row in rows}
    tlps, reps = by_label.get(DEFAULT_TLPS), by_label.get("REPS")
    key, what, paper = ("first_positive", "mean ρ > 0", 30) if task == 1 else ("first_success", "success ≥ 80%", 50)
    lines = []
    if tlps is not None:
        firsts = getattr(tlps, key)
        median, share = results.median_first(firsts), f"{sum(f is not None for f in firsts)}/{len(firsts)} seeds"
        if median is None:
            verdict = f"**not reproduced**: the median seed never reached {what} ({share})"
        else:
            verdict = (f"**agrees** ({share}, median iteration {median:g} ≤ {paper})" if median <= paper
                       else f"**slower than the paper** ({share}, median iteration {median:g} > {paper})")
        claim = ("Task 1 is satisfied (mean ρ > 0) around iteration 30 with β = 9" if task == 1
                 else "Task 2 is satisfied around iteration 50 with β = 9 (measured here: success ≥ 80%)")
        lines.append(f"- *{claim}.* {verdict}.")
    betas = sorted(((_beta(row.label), row) for row in rows if _beta(row.label) is not None), key=lambda p: p[0])
    if len(betas) > 1:
        parts = [f"β = {beta:g}: {results.first_text(getattr(row, key))}, final success {row.final_success:.0%}"
                 for beta, row in betas]
        medians = [results.median_first(getattr(row, key)) for _, row in betas]
        if any(m is None for m in medians):
            verdict = "the median seed of some β never got there"
        elif all(b <= a for a, b in zip(medians, medians[1:])) and medians[-1] <= 0.8 * medians[0]:
            verdict = "**agrees**: the medians fall as β grows"
        else:
            verdict = (f"**not reproduced here**: the medians range {min(medians):g}–{max(medians):g} "
                       "with no consistent decrease as β grows")
        lines.append(f"- *Larger β converges faster, with diminishing returns.* First iteration with {what} "
                     "(median over the seeds, a seed that never got there later than any): " + "; ".join(parts)
                     + f". {verdict}.")
    if task == 2 and tlps is not None and reps is not None:
        ahead = _ahead(tlps, reps)
        lines.append(
            f"- *TLPS is ahead of REPS on task 2.* Success ≥ 80% first reached: TLPS "
            f"{results.first_text(tlps.first_success)}, REPS {results.first_text(reps.first_success)}; final success "
            f"{tlps.final_success:.0%} vs {reps.final_success:.0%}; eval success "
            f"{results.percent(tlps.eval_success)} vs {results.percent(reps.eval_success)}. On these runs: **{ahead}**."
        )
    return "\n".join(lines) if lines else "No TLPS β = 9 curve in these results."


def _ahead(a: results.GroupSummary, b: results.GroupSummary) -> str:
    """Which of two curves is ahead on success ≥ 80%, only when the seeds leave no doubt.

    More seeds reaching it wins; with as many, every seed of one must get there before every seed of the other.
    """
    reached_a, reached_b = ([f for f in row.first_success if f is not None] for row in (a, b))
    share_a, share_b = len(reached_a) / len(a.first_success), len(reached_b) / len(b.first_success)
    if share_a != share_b:
        winner, loser = (a, b) if share_a > share_b else (b, a)
        return f"{winner.label} is ahead of {loser.label} (more seeds reached 80% success)"
    if not reached_a:
        return "neither reached 80% success"
    if max(reached_a) < min(reached_b) or max(reached_b) < min(reached_a):
        winner, loser = (a, b) if max(reached_a) < min(reached_b) else (b, a)
        return f"{winner.label} is ahead of {loser.label} (every seed reached 80% success earlier)"
    return (f"no clear difference: first iterations with success ≥ 80% overlap ({a.label} "
            f"{min(reached_a)}–{max(reached_a)}, {b.label} {min(reached_b)}–{max(reached_b)})")


def _beta(label: str) -> float | None:
    try:
        return float(label.removeprefix("TLPS β=")) if label.startswith("TLPS β=") else None
    except ValueError:
        return None


if __name__ == "__main__":
    sys.exit(main())
