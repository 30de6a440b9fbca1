"""Why episodes fail a formula: the robustness of each top-level conjunct, episode by episode.

A task is usually a conjunction — reach something ``&`` never do something else — and its
robustness is the least of its conjuncts'. A success rate says how often the whole holds;
`conjunct_breakdown` says which part broke: for each conjunct, in how many episodes it was
violated (ρ ≤ 0), in how many failed episodes it was the lowest (the one the formula's ρ is
equal to), and its median ρ. ``tl-gym eval --why`` prints it for a trained agent.

Example:
    >>> import numpy as np
    >>> from tl_gym import parse
    >>> phi = parse("F(x > 2) & G(v < 1)")
    >>> traces = {"x": [np.array([0.0, 3.0]), np.array([0.0, 1.0]), np.array([0.0, 3.0])],
    ...           "v": [np.array([0.5, 0.5]), np.array([0.5, 0.5]), np.array([0.5, 2.0])]}
    >>> for row in conjunct_breakdown(phi, traces):
    ...     print(row.conjunct, row.violated, row.lowest, row.median)
    F x > 2 1 1 1.0
    G v < 1 1 1 0.5
    >>> print(format_breakdown(conjunct_breakdown(phi, traces)))
    conjunct   violated in   lowest in the 2 failures   median ρ
    F x > 2    1 of 3        1                          1
    G v < 1    1 of 3        1                          0.5
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tl_gym.tltl.ast import Formula, conjuncts


@dataclass(frozen=True)
class ConjunctStats:
    """One top-level conjunct over a set of episodes.

    Attributes:
        conjunct: the conjunct's text.
        robustness: its robustness in each episode, shape ``(n_episodes,)``.
        violated: episodes where it is ≤ 0.
        lowest: failed episodes (formula ρ ≤ 0) where it is the lowest conjunct (ties count for each).
        failures: failed episodes in all.
        median: its median robustness over the episodes (the lower middle value for an even count:
            an episode's value, defined when the robustness is ±inf, as ``X φ`` at the last state's).
    """

    conjunct: str
    robustness: np.ndarray
    violated: int
    lowest: int
    failures: int
    median: float


def conjunct_breakdown(
    formula: Formula, traces: Mapping[str, Sequence[np.ndarray]], rho_max: float = math.inf
) -> list[ConjunctStats]:
    """Each top-level conjunct's robustness over recorded episodes, and which ones broke.

    Args:
        formula: the task formula.
        traces: signal name → one array ``s_0 … s_T`` per episode (episodes may differ in length),
            as `TLTLRewardWrapper`'s ``info["trace"]`` records them.
        rho_max: the robustness of ``true``, as the wrapper's.

    Returns:
        One `ConjunctStats` per conjunct, in the formula's order.

    Raises:
        ValueError: no episodes, or signals with different numbers of episodes.
        UnknownSignalError: a signal the formula reads is missing.
    """
    counts = {len(episodes) for episodes in traces.values()}
    if len(counts) != 1 or 0 in counts:
        raise ValueError(f"traces must hold the same number (≥ 1) of episodes per signal, got {sorted(counts)}")
    n_episodes = counts.pop()
    parts = conjuncts(formula)
    values = np.array([[part.robustness({name: episodes[i] for name, episodes in traces.items()}, rho_max)
                        for i in range(n_episodes)] for part in parts], dtype=float)  # (conjuncts, episodes)
    lowest_value = values.min(axis=0)  # the formula's robustness: And is the n-ary min
    failed = lowest_value <= 0
    return [
        ConjunctStats(
            conjunct=str(part),
            robustness=row,
            violated=int(np.sum(row <= 0)),
            lowest=int(np.sum(failed & (row == lowest_value))),
            failures=int(failed.sum()),
            median=float(np.quantile(row, 0.5, method="lower")),
        )
        for part, row in zip(parts, values)
    ]


def format_breakdown(rows: Sequence[ConjunctStats]) -> str:
    """`conjunct_breakdown`'s rows as an aligned plain-text table."""
    if not rows:
        return ""
    n_episodes = len(rows[0].robustness)
    header = ["conjunct", "violated in", f"lowest in the {rows[0].failures} failures", "median ρ"]
    body = [[r.conjunct, f"{r.violated} of {n_episodes}", str(r.lowest), f"{r.median:.4g}"] for r in rows]
    widths = [max(len(line[k]) for line in [header, *body]) for k in range(len(header))]
    return "\n".join("   ".join(cell.ljust(w) for cell, w in zip(line, widths)).rstrip() for line in [header, *body])
