"""A trial: SAC with n-step returns on TLParking-v0 (docs/results/parking.md, "gSDE, 3-step returns and ...").

SB3 2.9's n-step replay buffer refuses Dict observations, so this registers ``TLParkingFlat-v0``: TLParking-v0
with its Dict observation flattened by gymnasium's ``FlattenObservation`` (the same numbers that SB3's
``CombinedExtractor`` concatenates), gives it TLParking-v0's SAC entry of ``agents/hyperparams/sb3.yml``, and
runs the suite's protocol (50 iterations of 4,000 env steps, 100 fresh episodes every 5) in this process.

    python -m benchmarks.parking_nstep 3 runs/parking_nstep            # n = 3, tuning seed 100

A trial, not a suite entry: the id exists only while this script runs. Needs highway-env
(``pip install "tl_gym[highway]"``).
"""

from __future__ import annotations

import argparse

import gymnasium as gym
from tl_gym.agents import sb3
from tl_gym.envs.suite import make_parking

import tl_gym  # noqa: F401  (registers TLParking-v0)
from benchmarks import runner

FLAT_ID = "TLParkingFlat-v0"


def _flat_parking(**kwargs) -> gym.Env:
    return gym.wrappers.FlattenObservation(make_parking(**kwargs))


def _register_flat_parking() -> None:
    """Register the flattened id and let it look up TLParking-v0's hyperparameters."""
    gym.register(FLAT_ID, entry_point=_flat_parking)
    find = sb3.find_hyperparams

    def find_as_parking(table, env_id, env_kwargs, algo):
        return find(table, "TLParking-v0" if env_id == FLAT_ID else env_id, env_kwargs, algo)

    sb3.find_hyperparams = find_as_parking


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n_steps", type=int, help="the returns' number of steps (SB3's n_steps)")
    parser.add_argument("out", help="results folder; a rerun resumes the run's checkpoint there")
    parser.add_argument("--seed", type=int, default=100, help="the tuning seed (default 100)")
    args = parser.parse_args(argv)
    _register_flat_parking()
    sweep = runner.expand_config({
        "name": f"parking-nstep{args.n_steps}", "env": FLAT_ID, "seeds": [args.seed], "iterations": 50,
        "evaluate_episodes": 100, "evaluate_every": 5,
        "agents": [{"label": f"SAC, {args.n_steps}-step returns", "agent": "sac",
                    "hyperparameters": {"steps_per_iteration": 4000, "policy": "MlpPolicy",
                                        "n_steps": args.n_steps}}]})
    spec = sweep.runs[0]
    print(spec.run_id, flush=True)
    print(runner.execute_run(spec, f"{args.out}/{spec.run_id}", checkpoint_every=5))


if __name__ == "__main__":
    main()
