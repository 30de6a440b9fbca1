"""PPO on the car with the Markov view: the study behind SB3Agent's car defaults (docs/results/suite.md).

Plain stable-baselines3 (no tl_gym agent), so that each choice is visible: the reward mode
(``terminal``: no monitor view; ``dense`` or ``potential``: ``observe_monitor=True``), the
minibatch size, whether the end of the trace is a termination (``term``) or a time-limit
truncation SB3 bootstraps past (``trunc``), and reward normalisation (``nr``). PPO with
gamma 0.999, 8 envs, n_steps 1000, VecNormalize on observations; every ``chunk`` env steps
the deterministic policy runs 50 fresh episodes (seeds 10,000 + i). One JSON line per chunk.

Usage::

    python -m benchmarks.studies.ppo_car_markov TASK MODE STEPS SEED BATCH term|trunc [nr|no] [CHUNK]
    python -m benchmarks.studies.ppo_car_markov 1 dense 300000 100 64 term nr
"""

from __future__ import annotations

import json
import sys
import time

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize
from tl_gym.agents.sb3 import TraceEndIsTerminal

import tl_gym  # noqa: F401 - registers TLCarNav-v0


def main(argv: list[str]) -> None:
    task, mode, steps, seed, batch, end = int(argv[0]), argv[1], int(argv[2]), int(argv[3]), int(argv[4]), argv[5]
    norm_reward = len(argv) > 6 and argv[6] == "nr"
    chunk = int(argv[7]) if len(argv) > 7 else 50_000
    torch.set_num_threads(1)
    kwargs: dict = {"task": task}
    if mode != "terminal":
        kwargs.update(observe_monitor=True, reward_mode=mode)
    venv = VecNormalize(
        make_vec_env("TLCarNav-v0", n_envs=8, seed=seed, env_kwargs=kwargs,
                     wrapper_class=TraceEndIsTerminal if end == "term" else None),
        norm_obs=True, norm_reward=norm_reward, gamma=0.999,
    )
    model = PPO("MlpPolicy", venv, n_steps=1000, batch_size=batch, gamma=0.999, seed=seed, verbose=0, device="cpu")

    def evaluate(n: int = 50) -> tuple[float, float]:
        venv.training = False
        env = gym.make("TLCarNav-v0", **kwargs)
        robustness = []
        for i in range(n):
            obs, _ = env.reset(seed=10_000 + i)
            done = False
            while not done:
                action, _ = model.predict(venv.normalize_obs(obs[None]), deterministic=True)
                obs, _, terminated, truncated, info = env.step(action[0])
                done = terminated or truncated
            robustness.append(info["robustness"])
        venv.training = True
        return float(np.mean(np.array(robustness) > 0)), float(np.mean(robustness))

    start, done_steps = time.time(), 0
    while done_steps < steps:
        model.learn(chunk, reset_num_timesteps=False)
        done_steps += chunk
        success, rho = evaluate()
        print(json.dumps({"task": task, "mode": mode, "seed": seed, "batch": batch, "end": end,
                          "norm_reward": norm_reward, "steps": done_steps, "success": success, "rho": rho,
                          "secs": round(time.time() - start)}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
