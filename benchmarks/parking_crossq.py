"""A trial: CrossQ (sb3-contrib) on TLParking-v0 (docs/results/parking.md, "CrossQ").

The library's SAC on TLParking-v0 is still improving when its 200k budget runs out (docs/results/suite.md), so the
trial asks for more learning per sample: CrossQ (Bhatt et al., ICLR 2024) drops SAC's target networks and puts batch
normalisation in the critic, which its authors report learns several times faster per env step than SAC at one
gradient step per env step. sb3-contrib's CrossQ takes only an ``MlpPolicy``, so the run is on
``TLParkingFlat-v0`` (`benchmarks.parking_nstep`: TLParking-v0 under gymnasium's ``FlattenObservation``).

Everything else is the suite's parking SAC run and its ``TLParking-v0`` SAC entry of ``agents/hyperparams/sb3.yml``
(γ 0.99, learning rate 1e-3, batch 256, learning_starts 1000, VecNormalize on observations, the Markov view, the
dense reward with the entry's ``satisfaction_bonus`` 10 and ``end_on_violation``, written out here since the
flattened id has no entry), but SAC's ``tau`` (CrossQ has no target network) and the network: the actor 256 × 256
as SAC's, the critic ``--critic-width`` wide (CrossQ's default 1024; its paper 2048).

    python -m benchmarks.parking_crossq runs/parking_crossq --critic-width 512    # tuning seed 100

A trial, not a suite entry: the id exists only while this script runs. Needs highway-env and sb3-contrib
(``pip install "tl_gym[highway]" sb3-contrib``).
"""

from __future__ import annotations

import argparse
import dataclasses

from tl_gym.agents import sb3_settings

from benchmarks.parking_nstep import FLAT_ID, run_flat_trial
from benchmarks.suite import suite_run
from benchmarks.sweep_config import RunSpec

#: SAC settings CrossQ does not take.
SAC_ONLY = ("tau",)


def trial_spec(critic_width: int, seed: int) -> RunSpec:
    """The suite's parking SAC run, moved to the flattened id and to CrossQ with a ``critic_width``-wide critic."""
    suite_sac = suite_run("parking", "SAC")
    entry = sb3_settings.find_hyperparams(sb3_settings.load_hyperparams(), suite_sac.env, suite_sac.env_kwargs, "sac")
    env_kwargs = {**suite_sac.env_kwargs, **entry.pop(sb3_settings.MARKOV_ENV_KWARGS, {})}
    for name in SAC_ONLY:
        entry.pop(name, None)
    hyperparameters = {**entry, **suite_sac.hyperparameters, "hyperparams": False, "policy": "MlpPolicy",
                       "policy_kwargs": {"net_arch": {"pi": [256, 256], "qf": [critic_width, critic_width]}}}
    return dataclasses.replace(suite_sac, env=FLAT_ID, env_kwargs=env_kwargs, agent="crossq",
                               label=f"CrossQ, critic {critic_width} x {critic_width}", seed=seed,
                               hyperparameters=hyperparameters, note="")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="results folder; a rerun resumes the run's checkpoint there")
    parser.add_argument("--critic-width", type=int, default=1024, help="the critic's two layers' width (default 1024)")
    parser.add_argument("--seed", type=int, default=100, help="the tuning seed (default 100)")
    args = parser.parse_args(argv)
    run_flat_trial(trial_spec(args.critic_width, args.seed), args.out)


if __name__ == "__main__":
    main()
