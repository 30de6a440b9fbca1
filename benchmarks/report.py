"""The tables and the per-seed report of a sweep's results folder (docs/benchmarks.md).

``python -m benchmarks.report DIR`` prints the per-task tables of `benchmarks.results`;
``--per-seed OUT`` writes the research report (tables, ``summary.csv``, the curves of
`benchmarks.figures`). It sits above both: the aggregation does not plot, and the plots
do not write reports.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from tl_gym.agents.callbacks import write_history

from benchmarks.figures import plot_seed_panels
from benchmarks.results import RunResult, load_runs, markdown_table, per_seed_rows, per_seed_table, summaries_by_task


def write_per_seed_report(runs: Sequence[RunResult], out: str | Path) -> list[Path]:
    """Write ``tables.md`` (`per_seed_table` per task), ``summary.csv`` and the curves of `plot_seed_panels`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = per_seed_rows(runs)
    write_history(sorted(rows, key=lambda row: (row["task"], row["variant"], row["seed"])), out / "summary.csv")
    tasks = list(dict.fromkeys(run.task for run in runs))
    (out / "tables.md").write_text("\n".join(f"### Task {task}\n\n{per_seed_table(rows, task)}\n" for task in tasks))
    return [out / "tables.md", out / "summary.csv", *(path for task in tasks
                                                      for path in plot_seed_panels(runs, task, out))]


def main(argv: Sequence[str] | None = None) -> int:
    """Print the tables of a results folder; with ``--per-seed OUT`` write the per-seed report there."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.report", description="Tables of a sweep's results.")
    parser.add_argument("out_dir", help="a sweep's results folder (e.g. runs/sweeps/paper)")
    parser.add_argument("--per-seed", type=Path, metavar="OUT",
                        help="write tables.md, summary.csv and per-label curves to OUT (the research report)")
    args = parser.parse_args(argv)
    try:
        runs = load_runs(args.out_dir)
    except FileNotFoundError as error:  # a folder that is no sweep's: one line, not a traceback
        parser.error(str(error))
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
