"""Where a result came from: the code's version and commit, for run records and results pages.

`code_version` stamps each run's ``done.json`` (`benchmarks.run_one`); `git` gives the commit that the
benchmark pages print (`benchmarks.bench_robustness`, `benchmarks.reproduce_paper`). Both answer without git
or outside a checkout (the version alone, or None).
"""

from __future__ import annotations

import subprocess
from pathlib import Path


def code_version() -> str:
    """The tl_gym version and, in a git checkout, the commit (``+dirty`` if library code is modified)."""
    import tl_gym

    root = Path(tl_gym.__file__).resolve().parents[1]
    commit = git("rev-parse", "--short", "HEAD", cwd=root)
    if commit is None:
        return tl_gym.__version__
    dirty = git("status", "--porcelain", "--", "tl_gym", "agents", "envs", cwd=root)
    return f"{tl_gym.__version__} ({commit}{'+dirty' if dirty else ''})"


def git(*args: str, cwd: str | Path | None = None) -> str | None:
    """The output of ``git ARGS`` (stripped), or None outside a checkout or without git."""
    try:
        return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
