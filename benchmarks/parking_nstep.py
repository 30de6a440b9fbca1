"""A trial: SAC with n-step returns on TLParking-v0 (docs/results/parking.md, "gSDE, 3-step returns and ...").

SB3 2.9's n-step replay buffer refuses Dict observations, so this registers ``TLParkingFlat-v0``: TLParking-v0
with its Dict observation flattened by gymnasium's ``FlattenObservation`` (the same numbers that SB3's
``CombinedExtractor`` concatenates). The run is the suite's SAC run of ``benchmarks/configs/suite/parking.toml``
(its iterations, steps per iteration and evaluations) on that id, with TLParking-v0's SAC entry of
``agents/hyperparams/sb3.yml`` passed explicitly (``hyperparams=False``: the file has no entry for the trial's id),
an ``MlpPolicy`` and SB3's ``n_steps``; it runs in this process, where the id is registered.

    python -m benchmarks.parking_nstep 3 runs/parking_nstep            # n = 3, tuning seed 100

A trial, not a suite entry: the id exists only while this script runs. Needs highway-env
(``pip install "tl_gym[highway]"``).
"""

from __future__ import annotations

import argparse
import dataclasses

import gymnasium as gym
from tl_gym.agents import sb3_settings
from tl_gym.envs.suite import make_parking

import tl_gym  # noqa: F401  (registers TLParking-v0)
from benchmarks.run_one import execute_run
from benchmarks.suite import parking_sac_without_bonus
from benchmarks.sweep_config import RunSpec

FLAT_ID = "TLParkingFlat-v0"


def _flat_parking(**kwargs) -> gym.Env:
    return gym.wrappers.FlattenObservation(make_parking(**kwargs))


def register_flat_parking() -> None:
    """Register ``TLParkingFlat-v0`` (once; a second call is a no-op)."""
    if FLAT_ID not in gym.registry:
        gym.register(FLAT_ID, entry_point=_flat_parking)


def trial_spec(n_steps: int, seed: int) -> RunSpec:
    """The suite's parking SAC run, moved to the flattened id with ``n_steps``-step returns.

    As it was when the trial ran: without the satisfaction bonus of the SAC entry since.
    """
    suite_sac = parking_sac_without_bonus()
    entry = sb3_settings.find_hyperparams(sb3_settings.load_hyperparams(), suite_sac.env, suite_sac.env_kwargs, "sac")
    entry.pop(sb3_settings.MARKOV_ENV_KWARGS, None)  # env keywords, not hyperparameters: the trial pins its own
    hyperparameters = {**entry, **suite_sac.hyperparameters, "hyperparams": False, "policy": "MlpPolicy",
                       "n_steps": n_steps}
    return dataclasses.replace(suite_sac, env=FLAT_ID, label=f"SAC, {n_steps}-step returns", seed=seed,
                               hyperparameters=hyperparameters)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n_steps", type=int, help="the returns' number of steps (SB3's n_steps)")
    parser.add_argument("out", help="results folder; a rerun resumes the run's checkpoint there")
    parser.add_argument("--seed", type=int, default=100, help="the tuning seed (default 100)")
    args = parser.parse_args(argv)
    run_flat_trial(trial_spec(args.n_steps, args.seed), args.out)


def run_flat_trial(spec: RunSpec, out: str) -> None:
    """Register the flattened id, then run ``spec`` into ``out`` (resuming its checkpoint there)."""
    register_flat_parking()
    print(spec.run_id, flush=True)
    print(execute_run(spec, f"{out}/{spec.run_id}", checkpoint_every=5))


if __name__ == "__main__":
    main()
