"""Which TLParking-v0 starts saved agents park from, against the start's geometry and a hand controller.

Every agent is evaluated on the same fresh episodes (episode ``i`` resets with seed ``seed + i``, as
`tl_gym.agents.evaluation.evaluate_policy` seeds them), and so is `ParkingController`. The report splits
success by how far the slot is and how its axis turns from the line to it, and says how many starts
*some* policy parks from: evidence for what success a learned policy could reach within the horizon.
Prints Markdown tables; ``--figure`` draws the lot, each slot coloured by the agents' success there.

    python -m benchmarks.parking_starts RUN_DIR [RUN_DIR ...] --episodes 100 --seed 12345 --figure out.png

A ``RUN_DIR`` is a folder with ``agent.zip`` trained on ``TLParking-v0`` (the experiment runner's run
folders, ``tl-gym train``'s output). Needs highway-env (``pip install "tl_gym[highway]"``).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from tl_gym.agents import Agent

import tl_gym  # noqa: F401  (registers TLParking-v0)
from benchmarks.results import table

ENV_ID = "TLParking-v0"
#: What a run folder records of its run: the experiment runner's spec, or `tl-gym train`'s run file.
RUN_FILES = ("spec.json", "run.json")
#: parking-v0's observation scales: positions are divided by 100 m, velocities by 5 m/s.
POSITION_SCALE, SPEED_SCALE = 100.0, 5.0
#: Bands of the report: the slot's distance from the start (m) and the angle between the slot's axis and the
#: line from the start to it (degrees; 0: drive straight in, 90: turn a right angle into the slot).
DISTANCE_BANDS = (0.0, 20.0, math.inf)
AXIS_ANGLE_BANDS = (0.0, 30.0, 60.0, 90.0)


def _wrap(angle: float) -> float:
    """``angle`` in [-π, π)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


class ParkingController:
    """A hand controller for TLParking-v0: line-of-sight pursuit of the slot's centre line.

    It cruises at ``cruise`` m/s, slows to 0.6 m/s within 6 m of the slot, makes a three-point turn (reverse at
    full lock) when the line lies behind, and reverses straight for a new attempt when it overshoots the slot.
    A baseline of what a simple geometric policy parks from, not a bound on what a learned one can.

    Example (success of each of ten fresh episodes; `policy_successes` runs them):

        wins = policy_successes(ParkingController, n_episodes=10, seed=0)
    """

    def __init__(self, cruise: float = 3.0, lookahead: float = 3.0, gain: float = 3.0) -> None:
        self.cruise, self.lookahead, self.gain, self.mode = cruise, lookahead, gain, "forward"

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
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
            alpha = _wrap(math.atan2(d[1], d[0]) - heading)
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
    """A start's geometry: the slot's centre (m), its distance, and its axis's angle to the line to it (deg)."""

    slot: tuple[float, float]
    distance: float
    axis_angle: float


def start_of(obs: dict[str, np.ndarray]) -> Start:
    """The geometry of a reset observation; the axis angle folds a slot entered either way into [0°, 90°]."""
    o, g = obs["observation"], obs["desired_goal"]
    line = g[:2] * POSITION_SCALE - o[:2] * POSITION_SCALE
    angle = abs(math.degrees(_wrap(math.atan2(g[5], g[4]) - math.atan2(line[1], line[0]))))
    return Start((float(g[0] * POSITION_SCALE), float(g[1] * POSITION_SCALE)), float(np.linalg.norm(line)),
                 min(angle, 180.0 - angle))


def starts(n_episodes: int, seed: int) -> list[Start]:
    """The starts of episodes ``seed``, ``seed + 1``, … of TLParking-v0."""
    env = gym.make(ENV_ID)
    return [start_of(env.reset(seed=seed + i)[0]) for i in range(n_episodes)]


def policy_successes(policy: Callable[[], Callable[[Any], np.ndarray]], n_episodes: int, seed: int,
                     **env_kwargs: Any) -> np.ndarray:
    """Success (ρ > 0) of each episode ``seed + i`` driven by ``policy()``, a fresh controller per episode."""
    env = gym.make(ENV_ID, **env_kwargs)
    wins = np.zeros(n_episodes, dtype=bool)
    for i in range(n_episodes):
        act, (obs, _) = policy(), env.reset(seed=seed + i)
        while True:
            obs, _, terminated, truncated, info = env.step(act(obs))
            if terminated or truncated:
                wins[i] = info["satisfied"]
                break
    return wins


def agent_successes(run_dir: Path, n_episodes: int, seed: int) -> np.ndarray:
    """Success of each episode ``seed + i`` of the run's saved agent (deterministic), in its own env."""
    run_dir = Path(run_dir)
    trained_on = next((json.loads((run_dir / name).read_text())["env"] for name in RUN_FILES
                       if (run_dir / name).exists()), None)
    if trained_on != ENV_ID:
        raise ValueError(f"{run_dir}: trained on {trained_on!r}, not {ENV_ID} (read from its {' or '.join(RUN_FILES)})")
    agent = Agent.load(run_dir / "agent.zip")
    return np.asarray(agent.evaluate(n_episodes=n_episodes, seed=seed, deterministic=True)["robustness"]) > 0


def band_rows(wins: dict[str, np.ndarray], values: np.ndarray, edges: Sequence[float], unit: str) -> list[list[str]]:
    """One row per band ``[lo, hi)`` of ``values``: its number of starts and each policy's success there."""
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (values >= lo) & (values < hi)
        label = f"≥ {lo:g} {unit}" if math.isinf(hi) else f"{lo:g}–{hi:g} {unit}"
        rows.append([label, str(int(inside.sum()))]
                    + [f"{w[inside].mean():.0%}" if inside.any() else "" for w in wins.values()])
    return rows


def report(agent_wins: dict[str, np.ndarray], controller_wins: np.ndarray, geometry: Sequence[Start]) -> str:
    """The Markdown report: success per policy, the unions, and success by the start's geometry."""
    agents = np.array(list(agent_wins.values()))
    union = agents.any(axis=0)
    everyone = union | controller_wins
    lines = [table(["policy", "success"], [[name, f"{w.mean():.0%}"] for name, w in agent_wins.items()]
                   + [["hand controller (`ParkingController`)", f"{controller_wins.mean():.0%}"],
                      ["some agent parks", f"{union.mean():.0%}"],
                      ["some agent or the controller parks", f"{everyone.mean():.0%}"]]), ""]
    wins = {**{f"agent {k + 1}": w for k, w in enumerate(agent_wins.values())}, "controller": controller_wins}
    header = ["start", "starts", *wins]
    distance = np.array([s.distance for s in geometry])
    angle = np.array([s.axis_angle for s in geometry])
    lines += [table(header, band_rows(wins, distance, DISTANCE_BANDS, "m")), "",
              table(header, band_rows(wins, angle, AXIS_ANGLE_BANDS, "°")), ""]
    lines.append(f"Agents in the order given; starts no agent parks from: "
                 f"{np.flatnonzero(~union).tolist()} (episode indices), of which the controller parks "
                 f"{int((controller_wins & ~union).sum())}.")
    return "\n".join(lines)


def plot_lot(agent_wins: dict[str, np.ndarray], geometry: Sequence[Start], path: Path) -> None:
    """Draw each drawn slot at its place in the lot, coloured by the agents' mean success from its starts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    success = np.mean(list(agent_wins.values()), axis=0)
    slots = sorted({s.slot for s in geometry})
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    for slot in slots:
        mine = np.array([s.slot == slot for s in geometry])
        ax.add_patch(plt.Rectangle((slot[0] - 2, slot[1] - 4), 4, 8, color=plt.cm.RdYlGn(success[mine].mean()),
                                   ec="black", lw=0.5))
        ax.text(slot[0], slot[1], str(int(mine.sum())), ha="center", va="center", fontsize=7)
    ax.plot(0, 0, "k^", ms=8, label="start (random heading)")
    ax.set(xlim=(-35, 35), ylim=(-21, 21), aspect="equal", xlabel="x (m)", ylabel="y (m)",
           title=f"TLParking-v0: success of {len(agent_wins)} agents by slot (number: starts)")
    fig.colorbar(plt.cm.ScalarMappable(cmap="RdYlGn", norm=plt.Normalize(0, 1)), ax=ax, label="success")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    geometry = starts(args.episodes, args.seed)
    agent_wins = {str(run): agent_successes(run, args.episodes, args.seed) for run in args.runs}
    controller_wins = policy_successes(lambda: ParkingController(cruise=args.cruise), args.episodes, args.seed)
    print(report(agent_wins, controller_wins, geometry))
    if args.figure is not None:
        plot_lot(agent_wins, geometry, args.figure)
        print(f"\nfigure: {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
