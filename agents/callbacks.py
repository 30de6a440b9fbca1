"""Callbacks: code run after every training iteration, able to stop training.

Modelled on stable-baselines3's template methods, but with an explicit payload:
`AbstractCallback.on_iteration(agent, row)` receives the agent and the history row
just appended, and returning ``False`` stops `Agent.learn`. A plain function
``f(agent, row) -> bool | None`` works too (``None`` means continue).

Example:
    >>> stop = StopOnSuccessRate(0.8)
    >>> stop.on_iteration(None, {"success_rate": 0.5}), stop.on_iteration(None, {"success_rate": 0.9})
    (True, False)
"""

from __future__ import annotations

import abc
import csv
import io
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Union

from tl_gym.checks import check_count, check_finite

from .serialization import write_atomic

#: Reset seed of the first episode of each evaluation along training (`EvalCallback`; the benchmark runner's
#: evaluations, plus the run's seed there): far above the training episodes' seeds (0, 1, …) and apart from the
#: runner's final evaluation (``FINAL_EVAL_SEED``) and the CLI's ``eval`` default (12345), so that no evaluation
#: replays an episode the agent trained on or one reported elsewhere.
ALONG_TRAINING_EVAL_SEED = 20_000_033

Row = dict[str, Any]


class AbstractCallback(abc.ABC):
    """Interface of a training callback."""

    @abc.abstractmethod
    def on_iteration(self, agent: Any, row: Row) -> bool:
        """Called after each update with the new history row; return False to stop training."""


class FunctionCallback(AbstractCallback):
    """Adapts a plain function ``f(agent, row) -> bool | None`` (``None`` continues)."""

    def __init__(self, function: Callable[[Any, Row], Any]):
        self.function = function

    def on_iteration(self, agent: Any, row: Row) -> bool:
        return self.function(agent, row) is not False


class CallbackList(AbstractCallback):
    """Runs several callbacks in order; training stops if any of them returns ``False``.

    As for a callback on its own, only ``False`` stops: a callback that returns ``None`` continues.
    """

    def __init__(self, callbacks: Sequence[CallbackLike]):
        self.callbacks = [as_callback(c) for c in callbacks]

    def on_iteration(self, agent: Any, row: Row) -> bool:
        results = [c.on_iteration(agent, row) for c in self.callbacks if c is not None]
        return all(result is not False for result in results)


class StopOnSuccessRate(AbstractCallback):
    """Stops training once an iteration's success rate reaches ``threshold``."""

    def __init__(self, threshold: float):
        if not 0 <= check_finite("threshold", threshold) <= 1:
            raise ValueError(f"threshold must be in [0, 1], got {threshold!r}")
        self.threshold = float(threshold)

    def on_iteration(self, agent: Any, row: Row) -> bool:
        return row["success_rate"] < self.threshold


class StopOnRobustness(AbstractCallback):
    """Stops training once an iteration's mean exact robustness exceeds ``threshold``."""

    def __init__(self, threshold: float = 0.0):
        self.threshold = check_finite("threshold", threshold)  # NaN would stop at once: nothing exceeds it

    def on_iteration(self, agent: Any, row: Row) -> bool:
        return row["mean_robustness"] <= self.threshold


class CheckpointCallback(AbstractCallback):
    """Saves the agent every ``every`` iterations as ``<directory>/<prefix>_<iteration>.zip``."""

    def __init__(self, every: int, directory: str | Path, prefix: str = "agent"):
        self.every = check_count("every", every)
        self.directory = Path(directory)
        self.prefix = prefix

    def on_iteration(self, agent: Any, row: Row) -> bool:
        if row["iteration"] % self.every == 0:
            self.directory.mkdir(parents=True, exist_ok=True)
            agent.save(self.directory / f"{self.prefix}_{row['iteration']}.zip")
        return True


class EvalCallback(AbstractCallback):
    """Evaluates the deterministic policy every ``every`` iterations and keeps the best one, as SB3's ``EvalCallback``.

    Each evaluation runs ``n_episodes`` fresh episodes (`Agent.evaluate`, reset seeds ``seed``,
    ``seed + 1``, …, the same every time, so that evaluations compare like with like) and is
    appended to ``evaluations`` as ``(iteration, success_rate, mean_robustness)``. When one beats
    every earlier one (success rate first, then mean robustness), the agent is saved to
    ``best_path`` (if given), as rl-baselines3-zoo keeps ``best_model.zip``: where a policy's
    success swings between evaluations (docs/results/ppo_car2.md), the best one is what to deploy,
    reported on other fresh episodes. Evaluation episodes are not counted in ``env_steps``.
    With ``log_path``, every evaluation so far is also written there as CSV (``iteration``,
    ``env_steps``, ``success_rate``, ``mean_robustness``) after each one, as SB3's
    ``EvalCallback(log_path=...)`` writes ``evaluations.npz``: a long run can be watched.
    """

    def __init__(self, every: int, n_episodes: int = 100, best_path: str | Path | None = None,
                 seed: int = ALONG_TRAINING_EVAL_SEED,
                 log_path: str | Path | None = None):
        self.every, self.n_episodes = check_count("every", every), check_count("n_episodes", n_episodes)
        self.seed = seed
        self.best_path = None if best_path is None else Path(best_path)
        self.log_path = None if log_path is None else Path(log_path)
        self._log: list[Row] = []
        self.evaluations: list[tuple[int, float, float]] = []
        self.best: tuple[int, float, float] | None = None

    def on_iteration(self, agent: Any, row: Row) -> bool:
        if row["iteration"] % self.every == 0:
            result = agent.evaluate(n_episodes=self.n_episodes, seed=self.seed)
            evaluation = (int(row["iteration"]), float(result["success_rate"]), float(result["mean_robustness"]))
            self.evaluations.append(evaluation)
            if self.log_path is not None:
                self._log.append({"iteration": evaluation[0], "env_steps": row.get("env_steps"),
                                  "success_rate": evaluation[1], "mean_robustness": evaluation[2]})
                write_history(self._log, self.log_path)
            if self.best is None or evaluation[1:] > self.best[1:]:
                self.best = evaluation
                if self.best_path is not None:
                    agent.save(self.best_path)
        return True


class HistoryCSV(AbstractCallback):
    """Writes the history rows seen so far to a CSV file after every iteration (live progress).

    The file is rewritten whole and atomically each time, so it is never half-written and its
    columns are every key seen so far, in order of first appearance.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.rows: list[Row] = []

    def on_iteration(self, agent: Any, row: Row) -> bool:
        self.rows.append(dict(row))
        write_history(self.rows, self.path)
        return True


def write_history(rows: Iterable[Row], path: str | Path) -> None:
    """Write history rows as CSV (columns in order of first appearance), atomically.

    Example:
        >>> import pathlib, tempfile
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "history.csv"
        >>> write_history([{"iteration": 1, "success_rate": 0.5}, {"iteration": 2, "extra": 3}], path)
        >>> print(path.read_text().strip())
        iteration,success_rate,extra
        1,0.5,
        2,,3
    """
    rows = list(rows)
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_atomic(path, text.getvalue().encode())


CallbackLike = Union[AbstractCallback, Callable[[Any, Row], Any], Sequence[Any], None]


def as_callback(callback: CallbackLike) -> AbstractCallback | None:
    """Normalise ``None``, a callback, a function or a list of them into one callback."""
    if callback is None or isinstance(callback, AbstractCallback):
        return callback
    if callable(callback):
        return FunctionCallback(callback)
    if isinstance(callback, Sequence):
        return CallbackList(callback)
    raise TypeError(f"callback must be an AbstractCallback, a function or a list of them, got {callback!r}")
