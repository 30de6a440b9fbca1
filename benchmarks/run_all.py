"""Run every benchmark script, one subprocess each: what ``make bench`` / ``make bench-quick`` call.

The scripts, in order: the engine's speed against peer libraries (``bench_robustness``),
the car env's speed (``bench_env``), the TLPS research driver (``tlps_research``, only
with ``--quick`` if it offers one) and the paper reproduction (``reproduce_paper``).
``--quick`` is passed through. A script that does not exist is reported and skipped,
not an error; a script that fails makes the exit status non-zero after the others ran.

Usage::

    python -m benchmarks.run_all            # full benchmarks (hours)
    python -m benchmarks.run_all --quick    # CI smoke run
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: (module, whether it must support --quick to run in quick mode)
SCRIPTS = (
    ("bench_robustness", False),
    ("bench_env", False),
    ("tlps_research", True),
    ("reproduce_paper", False),
)


@dataclass(frozen=True)
class Outcome:
    """One script's fate: ``status`` is ``"ok"``, ``"failed (exit N)"``, ``"missing"`` or ``"skipped: ..."``."""

    module: str
    status: str
    seconds: float = 0.0


def supports_quick(path: Path) -> bool:
    """Whether a script's source declares a ``--quick`` option."""
    return '"--quick"' in path.read_text() or "'--quick'" in path.read_text()


def run_all(quick: bool, scripts: Sequence[tuple[str, bool]] = SCRIPTS, directory: Path = HERE) -> list[Outcome]:
    """Run the scripts that exist, in order, as ``python -m benchmarks.<module> [--quick]``."""
    outcomes = []
    for module, needs_quick in scripts:
        path = directory / f"{module}.py"
        if not path.is_file():
            outcomes.append(Outcome(module, "missing"))
            continue
        quick_ok = supports_quick(path)
        if quick and needs_quick and not quick_ok:
            outcomes.append(Outcome(module, "skipped: no --quick mode"))
            continue
        command = [sys.executable, "-m", f"{directory.name}.{module}"] + (["--quick"] if quick and quick_ok else [])
        print(f"\n=== {' '.join(command[1:])}", flush=True)
        start = time.perf_counter()
        code = subprocess.call(command, cwd=directory.parent)
        seconds = time.perf_counter() - start
        outcomes.append(Outcome(module, "ok" if code == 0 else f"failed (exit {code})", seconds))
    return outcomes


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``python -m benchmarks.run_all [--quick]``."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.run_all", description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="pass --quick to every script (CI smoke run)")
    args = parser.parse_args(argv)
    outcomes = run_all(args.quick)
    print("\n=== summary")
    for outcome in outcomes:
        took = f" in {outcome.seconds:.0f} s" if outcome.seconds else ""
        print(f"{outcome.module:18s} {outcome.status}{took}")
    return 1 if any(o.status.startswith("failed") for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
