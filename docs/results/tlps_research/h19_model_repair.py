"""H19 prototype: TLPS repairing each episode's feed-forward through the car's known model.

Per iteration: sample, roll out; recover each step's additive noise from the recorded states;
a few projected gradient steps on k^i (radius `radius` in normalised action units over the
whole sequence) maximising ρ̂ of the closed-loop re-simulation with that noise (torch autograd
through the car and the smoothed robustness); weights from ρ̂ of the repaired episodes
(KL bound); refit on the repaired states and feed-forward.
"""
import math
import sys
import time

import numpy as np
import torch

from tl_gym.agents import TLPS
from tl_gym.agents.sampling import Rollouts, rollout
from tl_gym.agents.weights import adapt_alpha, kl_bound_for, softmax_weights
from tl_gym.envs.dynamics import CarParams

P = CarParams()
torch.set_num_threads(1)


def wrap(x):
    return torch.remainder(x + math.pi, 2 * math.pi) - math.pi


def simulate(s0, noise, k, gains, centre, angles):
    """Closed-loop car: a_t = k_t + K_t (s_t ⊖ c_t), clipped; returns states (N, T+1, 6)."""
    states = [s0]
    s = s0
    for t in range(k.shape[1]):
        dev = s - centre[t]
        dev = torch.where(angles, wrap(dev), dev)
        a = k[:, t] + torch.einsum("ij,nj->ni", gains[t], dev)
        a = a.clamp(-1.0, 1.0)
        v = (a[:, 0] + 1.0) * 0.5 * P.max_speed
        phi = a[:, 1] * P.max_steer
        th = s[:, 2]
        rates = torch.stack([v * torch.cos(th), v * torch.sin(th), v / P.wheelbase * torch.tan(phi)], dim=1)
        pose = s[:, :3] + P.dt * rates + noise[:, t]
        pose = torch.cat([pose[:, :2], wrap(pose[:, 2:3])], dim=1)
        s = torch.cat([pose, rates], dim=1)
        states.append(s)
    return torch.stack(states, dim=1)


def recover_noise(obs, actions):
    s, a = obs[:, :-1], np.clip(actions, -1, 1)
    v = (a[..., 0] + 1.0) * 0.5 * P.max_speed
    phi = a[..., 1] * P.max_steer
    th = s[..., 2]
    rates = np.stack([v * np.cos(th), v * np.sin(th), v / P.wheelbase * np.tan(phi)], axis=-1)
    n = obs[:, 1:, :3] - s[..., :3] - P.dt * rates
    n[..., 2] = np.mod(n[..., 2] + math.pi, 2 * math.pi) - math.pi
    return n


class ModelTLPS(TLPS):
    radius = 1.0
    steps = 5

    def _value(self, k, s0, noise, pol):
        states = simulate(s0, noise, k, self._g, self._c, self._a)
        v = self.formula.smooth_robustness({"x": states[..., 0], "y": states[..., 1]}, self.config.beta,
                                           math.inf, self.config.smoothing)
        return v, states

    def _update(self, iteration):
        cfg, pol = self.config, self.policy
        seed = int(self.rng.integers(2**31 - 1))
        ff = pol.sample_feedforward(cfg.n_episodes, self.rng)
        batch = rollout(self.env, ff, pol.feedback, seed=seed)
        assert (batch.lengths == pol.horizon).all()
        noise = torch.tensor(recover_noise(batch.observations, batch.actions))
        s0 = torch.tensor(batch.observations[:, 0])
        self._g, self._c = torch.tensor(pol.gains), torch.tensor(pol.centre)
        self._a = torch.tensor(pol.angles)
        k = torch.tensor(ff, requires_grad=True)
        value, states = self._value(k, s0, noise, pol)
        err = float(np.abs(states.detach().numpy() - batch.observations).max())
        before = value.detach().clone()
        value.sum().backward()
        grad = k.grad.clone()
        best_k, best_v = k.detach().clone(), value.detach().clone()
        step = torch.full((ff.shape[0],), self.radius, dtype=torch.float64)
        origin = k.detach()
        for _ in range(self.steps):
            norm = grad.flatten(1).norm(dim=1).clamp_min(1e-300)
            x = best_k + (step / norm)[:, None, None] * grad
            off = x - origin
            length = off.flatten(1).norm(dim=1).clamp_min(1e-300)
            x = origin + off * torch.clamp(self.radius / length, max=1.0)[:, None, None]
            x.requires_grad_(True)
            v, _ = self._value(x, s0, noise, pol)
            v.sum().backward()
            better = v.detach() > best_v
            best_k[better] = x.detach()[better]
            best_v[better] = v.detach()[better]
            grad[better] = x.grad[better]
            step = torch.where(better, step * 1.2, step * 0.5)
        with torch.no_grad():
            _, new_states = self._value(best_k, s0, noise, pol)
        new_obs = new_states.numpy()
        logits = best_v.numpy()
        alpha = adapt_alpha(logits, kl_bound_for(cfg.kl_bound, len(logits)))
        weights = softmax_weights(logits, alpha)
        repaired = Rollouts(actions=batch.actions, observations=new_obs,
                            traces={"x": new_obs[..., 0], "y": new_obs[..., 1]}, lengths=batch.lengths,
                            robustness=batch.robustness, satisfied=batch.satisfied, env_steps=batch.env_steps)
        floor = cfg.std_floor(iteration)
        refit = self._refit(repaired, best_k.numpy(), weights, floor)
        return {"env_steps": batch.env_steps, "mean_robustness": batch.mean_robustness,
                "success_rate": batch.success_rate, "smooth_robustness": float(before.mean()),
                "smooth_updated": float(best_v.mean()), "sim_error": err, **refit}


if __name__ == "__main__":
    task, seed, radius, steps = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
    iters = int(sys.argv[5]) if len(sys.argv) > 5 else 20
    ModelTLPS.radius, ModelTLPS.steps = radius, steps
    extra = {k: float(v) for k, v in (a.split("=") for a in sys.argv[6:])}
    agent = ModelTLPS("TLCarNav-v0", seed=seed, env_kwargs={"task": task}, **extra)
    t0 = time.time()
    first = None
    for i in range(iters):
        agent.learn(1)
        row = agent.history[-1]
        if first is None and row["success_rate"] >= 0.8:
            first = i + 1
        print(i + 1, f"rho {row['mean_robustness']:.2f} succ {row['success_rate']:.2f} "
              f"sm {row['smooth_robustness']:.2f}->{row['smooth_updated']:.2f} err {row['sim_error']:.1e} "
              f"t {time.time() - t0:.0f}", flush=True)
    print("FIRST80", task, seed, radius, steps, first)
