"""Which TLParking-v0 starts saved agents park from, against the start's geometry and a hand controller.

Every agent is evaluated on the same fresh episodes (episode ``i`` resets with seed ``seed + i``, as
`tl_gym.agents.evaluation.evaluate_policy` seeds them), and so is `ParkingController`. parking-v0 starts the
car at the lot's centre with a random heading and draws a random slot, so a start is two things: which slot
(its distance: the slots at the rows' ends lie farthest) and where the car faces (the bearing of the slot from
the car's heading: 0° ahead, 180° behind). The report splits success by both and says how many starts *some*
policy parks from: evidence for what success a learned policy could reach within the horizon. It also says how
each policy's failures end (`ending`: over the speed limit, crashed, at the slot too fast, out of time), read
from the episodes' traces. Prints Markdown tables; ``--figure`` draws the lot, each slot coloured by the agents'
success there.

    python -m benchmarks.parking_starts RUN_DIR [RUN_DIR ...] --episodes 100 --seed 12345 --figure out.png

A ``RUN_DIR`` is a folder with ``agent.zip`` trained on ``TLParking-v0`` as registered (the experiment runner's
run folders, ``tl-gym train``'s output); a run whose env keywords change the task (its horizon, bounds, end or
parking-v0 config) is refused, since the controller and the starts are those of the registered task. Needs
highway-env (``pip install "tl_gym[highway]"``).
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import matplotlib
import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from tl_gym.agents import Agent
from tl_gym.agents.evaluation import evaluate_policy
from tl_gym.envs.dynamics import wrap_angle
from tl_gym.envs.suite import make_parking, parking_formula

import tl_gym  # noqa: F401  (registers TLParking-v0)
from benchmarks.figures import saved
from benchmarks.results import percent, table
from benchmarks.run_one import AGENT, SPEC

ENV_ID = "TLParking-v0"
#: What a run folder records of its run: `tl-gym train`'s run file or the experiment runner's spec (the command
#: line's order of precedence, `tl_gym.cli.commands.read_run`).
RUN_FILES = ("run.json", SPEC)
#: TLParking-v0's keywords that change the task (all of `make_parking`'s but the wrapper's and rendering).
TASK_KWARGS = frozenset(name for name, p in inspect.signature(make_parking).parameters.items()
                        if p.kind is not p.VAR_KEYWORD and name != "render_mode")
#: parking-v0's observation scales: positions are divided by 100 m, velocities by 5 m/s.
POSITION_SCALE, SPEED_SCALE = 100.0, 5.0
#: Bands of the report: the slot's distance from the start (m; the lot's slots lie 14.1–29.5 m from its centre)
#: and its bearing from the car's start heading (degrees; 0: straight ahead, 180: straight behind).
DISTANCE_BANDS = (0.0, 20.0, 25.0, math.inf)
BEARING_BANDS = (0.0, 45.0, 90.0, 135.0, 180.0)
#: A slot's size in the lot (m): 4 wide across the rows (x), 8 long along them (y).
SLOT_WIDTH, SLOT_LENGTH = 4.0, 8.0
#: The registered task's horizon and bounds that `ending` reads (`check_run` refuses runs that change them): the
#: defaults of `make_parking` and `parking_formula` (``success_error`` 1.44 m is parking-v0's own success threshold
#: at its default config, which `make_parking` passes).
_TASK = {name: p.default for function in (make_parking, parking_formula)
         for name, p in inspect.signature(function).parameters.items() if p.default is not p.empty}
HORIZON, SUCCESS_ERROR, SPEED_LIMIT = int(_TASK["horizon"]), float(_TASK["success_error"]), float(_TASK["speed_limit"])
#: How an episode ends (`ending`): a success, then the four ways to fail.
ENDINGS = ("parked", "over the speed limit", "crashed", "at the slot, too fast", "out of time")


class ParkingController:
    """A hand controller for TLParking-v0: line-of-sight pursuit of the slot's centre line.

    It cruises at ``cruise`` m/s, slows to 0.6 m/s within 6 m of the slot, makes a three-point turn (reverse at
    full lock) when the line lies behind, and reverses straight for a new attempt when it overshoots the slot.
    A baseline of what a simple geometric policy parks from, not a bound on what a learned one can.

    Example (success of each of ten fresh episodes; `policy_outcomes` runs them):

        outcomes, starts = policy_outcomes(ParkingController, n_episodes=10, seed=0)
    """

    def __init__(self, cruise: float = 3.0, lookahead: float = 3.0, gain: float = 3.0) -> None:
        self.cruise, self.lookahead, self.gain, self.mode = cruise, lookahead, gain, "forward"

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The action (acceleration, steering), each in [-1, 1], for a parking-v0 observation."""
        o, g = obs["observation"], obs["desired_goal"]
        p, heading = o[:2] * POSITION_SCALE, math.atan2(o[5], o[4])
        speed = float(np.hypot(o[2], o[3]) * SPEED_SCALE)
        signed = speed * np.sign(math.cos(math.atan2(o[3], o[2]) - heading)) if speed > 1e-6 else 0.0
        goal, goal_heading = g[:2] * POSITION_SCALE, math.atan2(g[5], g[4])
        axis = np.array([math.cos(goal_heading), math.sin(goal_heading)])
        s = float((p - goal) @ axis)  # position along the slot's axis, 0 at its centre
        if s > 0.5:
            self.mode = "back"
        if self.mode == "back" and s < -5.0:
            self.mode = "forward"
        if self.mode == "back":
            steer, target = 0.0, -1.0
        else:
            d = goal + (s + self.lookahead) * axis - p
            alpha = wrap_angle(math.atan2(d[1], d[0]) - heading)
            if self.mode == "forward" and abs(alpha) > math.radians(120) and s < -3:
                self.mode = "turn"
            if self.mode == "turn" and abs(alpha) < math.radians(60):
                self.mode = "forward"
            if self.mode == "turn":
                steer, target = -math.copysign(1.0, alpha), -1.5
            else:
                steer = float(np.clip(self.gain * alpha / (math.pi / 4), -1, 1))
                distance = float(np.linalg.norm(p - goal))
                target = 0.6 if distance < 6 else min(self.cruise, 0.6 + 0.5 * (distance - 6))
        return np.array([np.clip(2.0 * (target - signed) / SPEED_SCALE, -1, 1), steer], dtype=np.float32)


@dataclass(frozen=True)
class Start:
    """A start's geometry: the slot's centre (m), its distance, and its bearing from the car's heading (deg)."""

    slot: tuple[float, float]
    distance: float
    bearing: float


def start_of(obs: dict[str, np.ndarray]) -> Start:
    """The geometry of a reset observation: where the slot is, and how far the car must turn to face it."""
    o, g = obs["observation"], obs["desired_goal"]
    line = (g[:2] - o[:2]) * POSITION_SCALE
    bearing = abs(math.degrees(wrap_angle(math.atan2(line[1], line[0]) - math.atan2(o[5], o[4]))))
    return Start((float(g[0] * POSITION_SCALE), float(g[1] * POSITION_SCALE)), float(np.linalg.norm(line)), bearing)


class ControllerPredictor:
    """A per-episode controller as an SB3-style predictor: a fresh ``make()`` at each episode's start.

    It records the geometry of each episode's start (`start_of` of its first observation) in ``starts``, in the
    order the episodes start, so the starts come from the very episodes the successes do.
    """

    def __init__(self, make: Callable[[], Callable[[dict[str, np.ndarray]], np.ndarray]]) -> None:
        self.make, self.controllers, self.starts = make, {}, []

    def predict(self, obs: dict[str, np.ndarray], state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """Each env's action from its episode's controller."""
        actions = []
        for j, starting in enumerate(episode_start):
            mine = {key: value[j] for key, value in obs.items()}
            if starting:
                self.controllers[j] = self.make()
                self.starts.append(start_of(mine))
            actions.append(self.controllers[j](mine))
        return np.stack(actions), state


def ending(goal_error: np.ndarray, speed: np.ndarray, satisfied: bool) -> str:
    """How one episode of the registered task ended (`ENDINGS`), from its trace s_0 … s_T and its success.

    "parked" is ``satisfied`` (ρ > 0, as the formula's robustness decides it); a failure is, in this order: "over
    the speed limit" (some state at ≥ 5 m/s; with ``end_on_violation`` the episode ends there), "crashed" (the
    trace ends before the horizon: only a crash ends the task's episode otherwise; a crash on the horizon's last
    step leaves the trace whole and counts as one of the next two), "at the slot, too fast" (in the slot,
    ``goal_error < 1.44``, never slowly enough), "out of time" (never in the slot).
    """
    if satisfied:
        return "parked"
    goal_error, speed = np.asarray(goal_error, dtype=float), np.asarray(speed, dtype=float)
    if np.any(speed >= SPEED_LIMIT):
        return "over the speed limit"
    if len(goal_error) < HORIZON + 1:
        return "crashed"
    return "at the slot, too fast" if np.any(goal_error < SUCCESS_ERROR) else "out of time"


@dataclass(frozen=True)
class Outcomes:
    """One policy's episodes: success (ρ > 0) and how each ended (`ending`)."""

    wins: np.ndarray
    endings: list[str]


def outcomes_of(result: dict[str, Any]) -> Outcomes:
    """The `Outcomes` of an `evaluate_policy` result on the registered task."""
    traces, wins = result["traces"], np.asarray(result["robustness"]) > 0
    return Outcomes(wins, [ending(e, v, won) for e, v, won in zip(traces["goal_error"], traces["speed"], wins)])


def policy_outcomes(policy: Callable[[], Callable[[dict[str, np.ndarray]], np.ndarray]], n_episodes: int,
                    seed: int) -> tuple[Outcomes, list[Start]]:
    """Outcomes and start of each episode ``seed + i`` driven by ``policy()``, a fresh one per episode.

    The episodes run through `evaluate_policy`, as an agent's do, so episode ``i`` is the agent's episode ``i``.
    """
    predictor = ControllerPredictor(policy)
    with contextlib.closing(gym.make(ENV_ID)) as env:
        result = evaluate_policy(predictor, env, n_episodes=n_episodes, seed=seed)
    return outcomes_of(result), predictor.starts[:n_episodes]


def check_run(run_dir: Path) -> Path:
    """``run_dir`` if it holds an agent trained on the registered TLParking-v0; else an error naming what is off."""
    run_dir = Path(run_dir)
    run_file = next((run_dir / name for name in RUN_FILES if (run_dir / name).exists()), None)
    if run_file is None:
        raise FileNotFoundError(f"{run_dir} has no {' or '.join(RUN_FILES)}: is it a run folder of `tl-gym train` "
                                f"or of the experiment runner?")
    run = json.loads(run_file.read_text())
    if run.get("env") != ENV_ID or run.get("spec") is not None:
        raise ValueError(f"{run_file}: trained on {run.get('env')!r}" + (" with --spec" if run.get("spec") else "")
                         + f", not the registered {ENV_ID}")
    changed = sorted(TASK_KWARGS & set(run.get("env_kwargs") or {}))
    if changed:
        raise ValueError(f"{run_file}: env_kwargs {changed} change the task; the starts and the controller here are "
                         f"those of {ENV_ID} as registered")
    if not (run_dir / AGENT).exists():
        raise FileNotFoundError(f"{run_dir / AGENT} not found: the run has not finished")
    return run_dir


def agent_outcomes(run_dir: Path, n_episodes: int, seed: int) -> Outcomes:
    """Outcomes of each episode ``seed + i`` of the run's saved agent (deterministic), in its own env."""
    agent = Agent.load(check_run(run_dir) / AGENT)
    try:
        result = agent.evaluate(n_episodes=n_episodes, seed=seed, deterministic=True)
    finally:
        agent.env.close()
    return outcomes_of(result)


def band_rows(wins: dict[str, np.ndarray], values: np.ndarray, edges: Sequence[float], unit: str) -> list[list[str]]:
    """One row per band ``[lo, hi)`` of ``values`` (the last ``[lo, hi]``): its starts and each policy's success."""
    rows, last = [], len(edges) - 2
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        inside = (values >= lo) & ((values <= hi) if k == last else (values < hi))  # the last band is closed
        label = f"≥ {lo:g} {unit}" if math.isinf(hi) else f"{lo:g}–{hi:g} {unit}"
        rows.append([label, str(int(inside.sum()))]
                    + [percent(w[inside].mean() if inside.any() else None) for w in wins.values()])
    return rows


def report(agent_wins: dict[str, np.ndarray], controller_wins: np.ndarray, geometry: Sequence[Start],
           endings: dict[str, Sequence[str]] | None = None) -> str:
    """The Markdown report: success per policy, the unions, success by the start's geometry, how episodes ended.

    ``endings``: each policy's `ending` per episode, keyed as the table's columns ("agent 1", …, "controller");
    without it the report leaves out how the episodes ended.
    """
    agents = np.array(list(agent_wins.values()))
    union = agents.any(axis=0)
    everyone = union | controller_wins
    lines = [table(["policy", "success"], [[name, percent(w.mean())] for name, w in agent_wins.items()]
                   + [["hand controller (`ParkingController`)", percent(controller_wins.mean())],
                      ["some agent parks", percent(union.mean())],
                      ["some agent or the controller parks", percent(everyone.mean())]]), ""]
    wins = {**{f"agent {k + 1}": w for k, w in enumerate(agent_wins.values())}, "controller": controller_wins}
    header = ["start", "starts", *wins]
    distance = np.array([s.distance for s in geometry])
    bearing = np.array([s.bearing for s in geometry])
    lines += [table(["slot's distance", *header[1:]], band_rows(wins, distance, DISTANCE_BANDS, "m")), "",
              table(["slot's bearing", *header[1:]], band_rows(wins, bearing, BEARING_BANDS, "°")), ""]
    lines.append(f"Agents in the order given; starts no agent parks from: "
                 f"{np.flatnonzero(~union).tolist()} (episode indices), of which the controller parks "
                 f"{int((controller_wins & ~union).sum())}.")
    if endings is not None:
        lines += ["", table(["how the episode ended", *endings],
                            [[kind, *(str(sum(e == kind for e in ends)) for ends in endings.values())]
                             for kind in ENDINGS])]
    return "\n".join(lines)


def plot_lot(agent_wins: dict[str, np.ndarray], geometry: Sequence[Start], path: Path | None = None) -> Figure:
    """Each drawn slot at its place in the lot, coloured by the agents' mean success from its starts."""
    success = np.mean(list(agent_wins.values()), axis=0)
    fig = Figure(figsize=(7.5, 4.6), layout="tight")
    ax = fig.add_subplot()
    colours = matplotlib.colormaps["RdYlGn"]
    for slot in sorted({s.slot for s in geometry}):
        mine = np.array([s.slot == slot for s in geometry])
        ax.add_patch(Rectangle((slot[0] - SLOT_WIDTH / 2, slot[1] - SLOT_LENGTH / 2), SLOT_WIDTH, SLOT_LENGTH,
                               facecolor=colours(success[mine].mean()), edgecolor="black", lw=0.5))
        ax.text(slot[0], slot[1], str(int(mine.sum())), ha="center", va="center", fontsize=7)
    ax.plot(0, 0, "k^", ms=8, label="start (random heading)")
    ax.set(xlim=(-35, 35), ylim=(-21, 21), aspect="equal", xlabel="x (m)", ylabel="y (m)",
           title=f"TLParking-v0: success of {len(agent_wins)} agents by slot (number: starts)")
    fig.colorbar(ScalarMappable(cmap=colours, norm=Normalize(0, 1)), ax=ax,
                 label="success")
    ax.legend(loc="lower right", fontsize=8)
    return saved(fig, path)


def main(argv: Sequence[str] | None = None) -> int:
    """Evaluate the agents and the controller on the same starts; print the report (and draw the lot)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.parking_starts", description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders with agent.zip trained on TLParking-v0")
    parser.add_argument("--episodes", type=int, default=100, help="fresh episodes (default 100)")
    parser.add_argument("--seed", type=int, default=12345, help="reset seed of the first episode (default 12345)")
    parser.add_argument("--cruise", type=float, default=3.0, help="the hand controller's cruise speed, m/s")
    parser.add_argument("--figure", type=Path, help="draw the lot, each slot coloured by the agents' success")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if len(set(args.runs)) < len(args.runs):
        parser.error(f"a run folder is given twice: {[str(run) for run in args.runs]}")
    for run in args.runs:  # before minutes of evaluation
        check_run(run)
    agents = {str(run): agent_outcomes(run, args.episodes, args.seed) for run in args.runs}
    controller, geometry = policy_outcomes(lambda: ParkingController(cruise=args.cruise), args.episodes, args.seed)
    agent_wins = {name: outcome.wins for name, outcome in agents.items()}
    endings = {**{f"agent {k + 1}": outcome.endings for k, outcome in enumerate(agents.values())},
               "controller": controller.endings}
    print(report(agent_wins, controller.wins, geometry, endings))
    if args.figure is not None:
        plot_lot(agent_wins, geometry, args.figure)
        print(f"\nfigure: {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
