"""A trial: SAC on TLParking-v0 with the hand controller's episodes in its replay buffer (docs/results/parking.md).

Before its first iteration, the suite's parking SAC run (``benchmarks/configs/suite/parking.toml``, seed 100 by
default) drives its own training env (the Markov view, VecNormalize on observations) with `ParkingController` for
``--demo-steps`` env steps and adds every transition to SAC's replay buffer as SB3's own collection would: the
original (unnormalised) observations, the TL reward, the time-limit flag. The replay buffer (a million
transitions) keeps them for the whole run. ``--pretrain-steps`` then takes that many SAC gradient steps on the
demonstrations alone, before any of the agent's own steps. The demonstrations' env steps are not in the agent's
step count: a run's env steps are the agent's plus ``--demo-steps``.

    python -m benchmarks.parking_demos runs/parking_demos --demo-steps 20000
    python -m benchmarks.parking_demos runs/parking_demos --demo-steps 20000 --pretrain-steps 20000

A trial, not a suite entry. Needs highway-env (``pip install "tl_gym[highway]"``).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
from tl_gym.agents.sb3 import SB3Agent, one_torch_thread

from benchmarks.parking_starts import ParkingController
from benchmarks.run_one import execute_run
from benchmarks.suite import parking_sac_without_bonus
from benchmarks.sweep_config import RunSpec


def add_demonstrations(agent: SB3Agent, n_steps: int,
                       make_controller: Callable[[], Callable[[dict[str, np.ndarray]], np.ndarray]] = ParkingController,
                       ) -> dict[str, float]:
    """Drive ``agent``'s training env with a fresh ``make_controller()`` per episode for ``n_steps`` env steps.

    Each transition goes into the agent's replay buffer the way SB3's ``_store_transition`` puts it there, so
    SAC samples (and normalises) the demonstrations like its own steps. VecNormalize's observation statistics
    see the demonstrations too. Returns the finished episodes' count and success rate (``info["satisfied"]``).
    """
    model = agent.model
    env = model.get_env()  # the VecEnv SAC steps: VecNormalize over the TL-wrapped envs
    normalizer = agent.vec_normalize
    raw = lambda obs: normalizer.get_original_obs() if normalizer is not None else obs  # noqa: E731
    obs = env.reset()
    controllers = [make_controller() for _ in range(env.num_envs)]
    successes: list[bool] = []
    for _ in range(-(-n_steps // env.num_envs)):
        original = raw(obs)
        actions = np.stack([controller({key: value[j] for key, value in original.items()})
                            for j, controller in enumerate(controllers)])
        obs, rewards, dones, infos = env.step(actions)
        next_original = copy.deepcopy(raw(obs))
        if normalizer is not None:
            rewards = normalizer.get_original_reward()
        for j, done in enumerate(dones):
            if not done:
                continue
            final = infos[j]["terminal_observation"]
            final = normalizer.unnormalize_obs(final) if normalizer is not None else final
            for key in next_original:
                next_original[key][j] = final[key]
            controllers[j] = make_controller()
            successes.append(bool(infos[j].get("satisfied", False)))
        model.replay_buffer.add(original, next_original, actions, rewards, dones, infos)
    return {"episodes": len(successes), "success_rate": float(np.mean(successes)) if successes else float("nan")}


def pretrain(agent: SB3Agent, gradient_steps: int) -> None:
    """``gradient_steps`` of the algorithm's own update on what the replay buffer holds (the demonstrations)."""
    if gradient_steps > 0:
        with one_torch_thread():
            agent.model.train(gradient_steps=gradient_steps, batch_size=agent.model.batch_size)


def trial_spec(demo_steps: int, pretrain_steps: int, seed: int) -> RunSpec:
    """The suite's parking SAC run, labelled with the trial's demonstrations and pre-training.

    As it was when the trial ran: without the satisfaction bonus of the SAC entry since.
    """
    label = f"SAC, {demo_steps} controller steps in the replay buffer, {pretrain_steps} pre-training steps"
    return dataclasses.replace(parking_sac_without_bonus(), label=label, seed=seed)


def preparation(demo_steps: int, pretrain_steps: int) -> Callable[[Any], None]:
    """What `execute_run` does to the new agent: demonstrations, then pre-training."""
    def prepare(agent: SB3Agent) -> None:
        print("demonstrations:", add_demonstrations(agent, demo_steps), flush=True)
        pretrain(agent, pretrain_steps)
    return prepare


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="results folder; a rerun resumes the run's checkpoint there")
    parser.add_argument("--demo-steps", type=int, default=20_000, help="controller env steps (default 20000)")
    parser.add_argument("--pretrain-steps", type=int, default=0, help="gradient steps on them first (default 0)")
    parser.add_argument("--seed", type=int, default=100, help="the tuning seed (default 100)")
    args = parser.parse_args(argv)
    spec = trial_spec(args.demo_steps, args.pretrain_steps, args.seed)
    print(spec.run_id, flush=True)
    print(execute_run(spec, f"{args.out}/{spec.run_id}", checkpoint_every=5,
                      prepare=preparation(args.demo_steps, args.pretrain_steps)))


if __name__ == "__main__":
    main()
