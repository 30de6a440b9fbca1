"""TLPS research driver: variants × seeds on the car's two tasks, REPS alongside.

Writes, under ``docs/results/tlps_research/`` (or ``--out``):

- ``runs/<task>_<variant>_s<seed>.csv``: every history row of one run (a finished run is
  not recomputed: delete its file to rerun it);
- ``summary.csv``: one row per run: first iteration with mean exact robustness > 0 and with
  success ≥ 80 %, the best and final batch success, and the final policy's success on
  200 fresh episodes (stochastic, as it is trained, and deterministic);
- ``task<k>_success.png``, ``task<k>_robustness.png``: success rate and mean exact robustness
  vs iteration, one panel per variant (thin lines: seeds; thick: median), and
  ``task<k>_medians.png``, the medians of all variants on one pair of axes;
- ``tables.md``: the per-variant tables quoted in ``docs/tlps.md``;
- ``solver_check.csv`` (``--solver-check``): the projected solver's gain in ρ̂ against
  SLSQP's on sampled car trajectories;
- ``timing.csv`` (``--timing``): seconds per TLPS iteration on both tasks;
- ``dynamics_check.csv`` (``--dynamics-check``): how well linear dynamics fitted to a batch
  predict the response of its trajectories to changed actions.

Runs are spread over ``--workers`` processes (one torch thread each).

Variants whose name starts with ``spread_`` run on the wide start spread of issue 16
(``env_kwargs={"start_std": (15, 15, 0.3)}``: half a goal's width and 17°) instead of the
paper's (1.5, 1.5, 0.01). Every variant that does not set ``feedback`` runs open loop
(``feedback="open"``, the paper's policy and the default before issue 16), so the names
measured before the fitted feedback keep their meaning.

Usage::

    python -m benchmarks.tlps_research --tasks 1 2 --variants default reps --seeds 0 1 2
    python -m benchmarks.tlps_research --solver-check --timing
    python -m benchmarks.tlps_research --out docs/results/tlps_research/feedback --workers 1 \
        --iterations 50 --tasks 1 2 --seeds 0 1 2 3 4 \
        --variants spread_open spread_fitted spread_reps spread_reps_fitted
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

OUT = Path(__file__).resolve().parent.parent / "docs" / "results" / "tlps_research"
ITERATIONS = {1: 30, 2: 50}
EVAL_EPISODES = 200
EVAL_SEED = 1_000_000

#: name -> (agent, hyperparameters that differ from the agent's defaults). TLPS's defaults
#: are the recipe chosen from these runs (docs/tlps.md): hybrid weights with mix 1.0, no
#: exploration floor, KL bound 2, ε = 4.5, β = 9, linear smoothing.
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "default": ("TLPS", {}),
    # weightings
    "importance": ("TLPS", {"weights": "importance"}),
    "importance_floor": ("TLPS", {"weights": "importance", "exploration_floor": 0.1}),
    "paper": ("TLPS", {"weights": "paper"}),
    "hybrid_0.9": ("TLPS", {"hybrid_mix": 0.9}),
    "hybrid_0.7": ("TLPS", {"hybrid_mix": 0.7}),
    "hybrid_0.7_floor": ("TLPS", {"hybrid_mix": 0.7, "exploration_floor": 0.1}),  # the best recipe
    "hybrid_0.7_beta_30": ("TLPS", {"hybrid_mix": 0.7, "beta": 30.0}),
    "hybrid_0.7_floor_beta_30": ("TLPS", {"hybrid_mix": 0.7, "exploration_floor": 0.1, "beta": 30.0}),
    # trust region, smoothing, exploration, KL bound
    "eps_0.45": ("TLPS", {"epsilon": 0.45}),
    "eps_45": ("TLPS", {"epsilon": 45.0}),
    "eps_450": ("TLPS", {"epsilon": 450.0}),
    "beta_30": ("TLPS", {"beta": 30.0}),
    "beta_3": ("TLPS", {"beta": 3.0}),
    "floor_0.05": ("TLPS", {"exploration_floor": 0.05}),
    "floor_0.1": ("TLPS", {"exploration_floor": 0.1}),
    "kl_3": ("TLPS", {"kl_bound": 3.0}),
    "kl_1": ("TLPS", {"kl_bound": 1.0}),
    "nested": ("TLPS", {"smoothing": "nested"}),
    "slsqp": ("TLPS", {"solver": "slsqp"}),
    # the baseline, at the tuned ε = 2 and at TLPS's faster KL bound
    "reps": ("REPS", {"epsilon": 2.0}),
    "reps_3": ("REPS", {"epsilon": 3.0}),
    "reps_floor": ("REPS", {"epsilon": 2.0}),  # REPS with a 0.1 exploration floor (see _floor_callback)
    # issue 16: fitted time-varying feedback K_t (s_t ⊖ s̄_t), paper start and wide start spread
    "fitted": ("TLPS", {"feedback": "fitted"}),
    "reps_fitted": ("REPS", {"epsilon": 2.0, "feedback": "fitted"}),
    "spread_open": ("TLPS", {}),
    "spread_fitted": ("TLPS", {"feedback": "fitted"}),
    "spread_reps": ("REPS", {"epsilon": 2.0}),
    "spread_reps_fitted": ("REPS", {"epsilon": 2.0, "feedback": "fitted"}),
    # ablations of the fitted feedback (on the spread)
    "spread_fitted_xy": ("TLPS", {"feedback": "fitted", "feedback_features": [0, 1]}),
    "spread_fitted_all": ("TLPS", {"feedback": "fitted", "feedback_features": "all"}),
    "spread_fitted_no_floor": ("TLPS", {"feedback": "fitted", "exploration_floor": 0.0}),
    "spread_fitted_no_pool": ("TLPS", {"feedback": "fitted", "feedback_window": 0}),
    "spread_fitted_ridge_0.1": ("TLPS", {"feedback": "fitted", "feedback_ridge": 0.1}),
    "spread_open_floor": ("TLPS", {"exploration_floor": 0.1}),
    "spread_reps_floor": ("REPS", {"epsilon": 2.0, "exploration_floor": 0.1}),
}

#: The wide start spread of issue 16, for the ``spread_`` variants.
SPREAD = {"start_std": (15.0, 15.0, 0.3)}


def _make_agent(variant: str, task: int, seed: int) -> Any:
    from tl_gym.agents import REPS, TLPS

    kind, hyperparameters = VARIANTS[variant]
    cls = TLPS if kind == "TLPS" else REPS
    env_kwargs = {"task": task, **(SPREAD if variant.startswith("spread_") else {})}
    return cls("TLCarNav-v0", seed=seed, env_kwargs=env_kwargs, **{"feedback": "open", **hyperparameters})


def _floor_callback(agent: Any, row: dict[str, Any]) -> bool:
    """Give REPS the TLPS exploration schedule: re-floor the policy after each update."""
    from tl_gym.agents.tlps import TLPSConfig

    floor = TLPSConfig(exploration_floor=0.1).std_floor(row["iteration"])
    policy = agent.policy
    policy.cov = policy._floored(policy.cov, max(floor, policy.min_std))
    return True


def run_one(variant: str, task: int, seed: int, iterations: int, out: Path) -> Path:
    """Train one agent, evaluate it, and write its history CSV (skipped when it exists)."""
    import torch

    torch.set_num_threads(1)
    path = out / "runs" / f"task{task}_{variant}_s{seed}.csv"
    if path.exists():
        return path
    agent = _make_agent(variant, task, seed)
    agent.learn(iterations, callback=_floor_callback if variant == "reps_floor" else None)
    stochastic = agent.evaluate(EVAL_EPISODES, seed=EVAL_SEED, deterministic=False)
    deterministic = agent.evaluate(EVAL_EPISODES, seed=EVAL_SEED, deterministic=True)
    rows = [dict(row, eval_success_stochastic=stochastic["success_rate"],
                 eval_success_deterministic=deterministic["success_rate"],
                 eval_rho_stochastic=stochastic["mean_robustness"]) for row in agent.history]
    agent.close()
    _write_csv(path, rows)
    return path


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    keys: list[str] = []
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


def _read_csv(path: Path) -> list[dict[str, float]]:
    with path.open() as f:
        return [{k: float(v) if v not in ("", None) else math.nan for k, v in row.items()} for row in csv.DictReader(f)]


def summarise(out: Path) -> list[dict[str, Any]]:
    """One summary row per finished run, written to ``summary.csv``."""
    rows = []
    for path in sorted((out / "runs").glob("task*_s*.csv")):
        task_part, rest = path.stem.split("_", 1)
        variant, seed = rest.rsplit("_s", 1)
        history = _read_csv(path)
        success = np.array([r["success_rate"] for r in history])
        rho = np.array([r["mean_robustness"] for r in history])
        first = lambda mask: int(np.argmax(mask)) + 1 if mask.any() else ""  # noqa: E731
        rows.append({
            "task": int(task_part[4:]), "variant": variant, "seed": int(seed), "iterations": len(history),
            "first_rho_positive": first(rho > 0), "first_success_80": first(success >= 0.8),
            "best_success": float(success.max()), "final_success": float(success[-1]),
            "final_rho": float(rho[-1]),
            "eval_success_stochastic": history[-1]["eval_success_stochastic"],
            "eval_success_deterministic": history[-1]["eval_success_deterministic"],
            "eval_rho_stochastic": history[-1]["eval_rho_stochastic"],
            "seconds_per_iteration": history[-1]["wall_time"] / len(history),
        })
    _write_csv(out / "summary.csv", rows)
    return rows


def table(rows: list[dict[str, Any]], task: int) -> str:
    """A markdown table per variant of ``task``: per-seed first iterations, medians, final evaluations."""
    key = "first_rho_positive" if task == 1 else "first_success_80"
    label = "mean ρ > 0 at" if task == 1 else "80 % at"
    lines = [f"| variant | seeds | {label} (per seed) | median | eval success | median eval success | eval mean ρ |",
             "|---|---|---|---|---|---|---|"]
    for variant in VARIANTS:
        runs = sorted((r for r in rows if r["task"] == task and r["variant"] == variant), key=lambda r: r["seed"])
        if not runs:
            continue
        firsts = [r[key] if r[key] != "" else math.inf for r in runs]
        per_seed = ", ".join("–" if math.isinf(f) else str(f) for f in firsts)
        median = float(np.median(firsts))
        success = [r["eval_success_stochastic"] for r in runs]
        rho = [r["eval_rho_stochastic"] for r in runs]
        lines.append(
            f"| {variant} | {len(runs)} | {per_seed} | {'–' if math.isinf(median) else f'{median:g}'} | "
            f"{min(success):.1%}–{max(success):.1%} | {np.median(success):.1%} | {np.mean(rho):.2f} |"
        )
    return "\n".join(lines)


def plot(out: Path, task: int, variants: list[str]) -> None:
    """Learning curves of ``task``: ``task<k>_success.png``, ``task<k>_robustness.png``, ``task<k>_medians.png``.

    One panel per variant (seeds thin, median thick) of success rate and of mean exact
    robustness, and one overlay of all variants' medians.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {v: [_read_csv(p) for p in sorted((out / "runs").glob(f"task{task}_{v}_s*.csv"))] for v in variants}
    curves = {v: c for v, c in curves.items() if c}
    if not curves:
        return
    medians: dict[str, dict[str, np.ndarray]] = {}
    for key, name in (("success_rate", "success"), ("mean_robustness", "robustness")):
        cols = min(5, len(curves))
        rows = math.ceil(len(curves) / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), sharex=True, sharey=True,
                                 squeeze=False)
        for ax, (variant, runs) in zip(axes.flat, curves.items()):
            series = [np.array([r[key] for r in run]) for run in runs]
            for values in series:
                ax.plot(np.arange(1, len(values) + 1), values, lw=0.8, alpha=0.6)
            length = min(len(v) for v in series)
            median = np.median([v[:length] for v in series], axis=0)
            medians.setdefault(variant, {})[key] = median
            ax.plot(np.arange(1, length + 1), median, color="k", lw=2)
            ax.axhline(0.8 if key == "success_rate" else 0.0, color="gray", ls="--", lw=0.8)
            ax.set_title(f"{variant} ({len(series)} seeds)", fontsize=9)
            if key == "mean_robustness":
                ax.set_yscale("symlog", linthresh=5.0)
        for ax in axes.flat[len(curves):]:
            ax.set_visible(False)
        fig.supxlabel("iteration (40 episodes each)")
        fig.supylabel("success rate" if key == "success_rate" else "mean exact robustness")
        fig.suptitle(f"TLCarNav-v0 task {task}: thin = seeds, thick = median")
        fig.tight_layout()
        fig.savefig(out / f"task{task}_{name}.png", dpi=80)
        plt.close(fig)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for variant, median in medians.items():
        style = {"default": dict(lw=2.5, color="k"), "reps": dict(lw=2.5, color="tab:red"),
                 "fitted": dict(lw=2.5, color="tab:blue"), "reps_fitted": dict(lw=2.5, color="tab:orange"),
                 }.get(variant, dict(lw=1.0))
        for ax, key in zip(axes, ("success_rate", "mean_robustness")):
            ax.plot(np.arange(1, len(median[key]) + 1), median[key], label=variant, **style)
    axes[0].set_ylabel("median success rate")
    axes[1].set_ylabel("median mean exact robustness")
    axes[1].set_yscale("symlog", linthresh=5.0)
    for ax in axes:
        ax.set_xlabel("iteration")
    axes[1].legend(fontsize=7, ncol=2)
    fig.suptitle(f"TLCarNav-v0 task {task}: medians over seeds (black: TLPS open loop, red: REPS ε = 2;\n"
                 "blue, orange: the same with fitted feedback, TLPS's default since issue 16)")
    fig.tight_layout()
    fig.savefig(out / f"task{task}_medians.png", dpi=80)
    plt.close(fig)


def solver_check(
    out: Path, seeds: int = 2, n: int = 8, steps: tuple[int, ...] = (5, 10, 20, 40)
) -> list[dict[str, Any]]:
    """Projected solver (several step counts) vs SLSQP on car trajectories of two policies.

    The policies: the initial one (``k_t = 0``, std 0.5) and a slow, tight one (mean speed
    action -0.85, std 0.1) whose trajectories stay in the arena, as trained ones do.
    """
    import torch
    from tl_gym.agents import TLPS
    from tl_gym.agents.sampling import rollout
    from tl_gym.agents.trust_region import improve_trajectories

    torch.set_num_threads(1)
    rows = []
    for task in (1, 2):
        for seed in range(seeds):
            agent = TLPS("TLCarNav-v0", seed=seed, n_episodes=n, env_kwargs={"task": task})
            rng = np.random.default_rng(seed)
            for label, mean, std in (("initial", 0.0, 0.5), ("slow", -0.85, 0.1)):
                feedforward = np.array([mean, 0.0]) + std * rng.standard_normal((n, agent.horizon, 2))
                batch = rollout(agent.env, feedforward, seed=seed)
                tau = np.stack([batch.traces[s] for s in agent.signal_names], axis=-1)
                for epsilon in (4.5, 45.0):
                    kwargs = dict(beta=agent.config.beta, epsilon=epsilon, form=agent.config.smoothing)
                    start = time.perf_counter()
                    slsqp = improve_trajectories(agent.formula, agent.signal_names, tau, solver="slsqp", **kwargs)
                    t_slsqp = time.perf_counter() - start
                    gain_s = slsqp.smooth_after - slsqp.smooth_before
                    for k in steps:
                        start = time.perf_counter()
                        proj = improve_trajectories(agent.formula, agent.signal_names, tau, solver="projected",
                                                    steps=k, decay=agent.config.solver_decay, **kwargs)
                        t_proj = time.perf_counter() - start
                        gain_p = proj.smooth_after - proj.smooth_before
                        rows.append({
                            "task": task, "seed": seed, "policy": label, "epsilon": epsilon, "steps": k,
                            "mean_gain_slsqp": float(gain_s.mean()), "mean_gain_projected": float(gain_p.mean()),
                            "gain_ratio": float(gain_p.mean() / gain_s.mean()),
                            "worst_trajectory_ratio": float(np.min(gain_p / np.maximum(gain_s, 1e-12))),
                            "objective_rel_gap": float(np.max((slsqp.smooth_after - proj.smooth_after)
                                                              / np.abs(slsqp.smooth_after))),
                            "seconds_slsqp_per_trajectory": t_slsqp / n, "seconds_projected_batch": t_proj,
                        })
                        print({k: round(v, 4) if isinstance(v, float) else v for k, v in rows[-1].items()}, flush=True)
            agent.close()
    _write_csv(out / "solver_check.csv", rows)
    return rows


def timing(out: Path, iterations: int = 5) -> list[dict[str, Any]]:
    """Seconds per TLPS and REPS iteration (N = 40, T = 200) on both tasks, with the machine's load.

    Open loop on both tasks, and the fitted feedback of issue 16 on task 2.

    The nested smoothing is timed on task 2 for one iteration only (it costs seconds per solver step).
    """
    import torch
    from tl_gym.agents import REPS, TLPS

    torch.set_num_threads(1)
    rows = []
    cases = [("TLPS", 1, "linear", iterations, "open"), ("TLPS", 2, "linear", iterations, "open"),
             ("TLPS", 2, "nested", 1, "open"), ("REPS", 1, "", iterations, "open"), ("REPS", 2, "", iterations, "open"),
             ("TLPS", 2, "linear", iterations, "fitted"), ("REPS", 2, "", iterations, "fitted")]
    for kind, task, smoothing, n, feedback in cases:
        if kind == "TLPS":
            agent = TLPS("TLCarNav-v0", seed=0, env_kwargs={"task": task}, smoothing=smoothing, feedback=feedback)
        else:
            agent = REPS("TLCarNav-v0", seed=0, env_kwargs={"task": task}, feedback=feedback)
        agent.learn(1)  # warm-up
        load_before = os.getloadavg()[0]
        agent.learn(n)
        hist = agent.history[1:]
        walls = np.diff([agent.history[0]["wall_time"]] + [r["wall_time"] for r in hist])
        rows.append({
            "agent": kind, "task": task, "smoothing": smoothing, "feedback": feedback, "iterations": n,
            "seconds_per_iteration": float(np.mean(walls)), "min_seconds": float(np.min(walls)),
            "sampling": float(np.mean([r.get("time_sampling", math.nan) for r in hist])),
            "trust_region": float(np.mean([r.get("time_trust_region", math.nan) for r in hist])),
            "load_average": 0.5 * (load_before + os.getloadavg()[0]),
        })
        print(rows[-1], flush=True)
        agent.close()
    _write_csv(out / "timing.csv", rows)
    return rows


def _relative_error(predicted: np.ndarray, real: np.ndarray) -> float:
    return float(np.linalg.norm(predicted - real) / np.linalg.norm(real))


def dynamics_check(out: Path, seeds: int = 2, scale: float = 0.02) -> list[dict[str, Any]]:
    """How well time-varying linear dynamics fitted to a batch predict its response (issue 16, deliverable 2).

    Guided policy search maps improved trajectories back to actions through dynamics
    ``δs_{t+1} ≈ A_t δs_t + B_t δa_t`` regressed on the batch (deviations from the mean
    state, per step or pooled over ±5 steps). This fits them to 40 car episodes of three
    policies (the initial one at std 0.5 and at std 0.1, and a fitted-feedback policy after
    3 updates, closed loop ``A_t + B_t K_t``), perturbs every episode's feed-forward actions by
    ``N(0, scale²)`` with the same env noise, and compares the predicted change of the x, y
    trace with the real one: relative error over the whole trace and at steps 1, 5 and 50.
    """
    import torch
    from tl_gym.agents import TLPS
    from tl_gym.agents.feedback import deviation, weighted_centre, window_mean
    from tl_gym.agents.sampling import rollout

    torch.set_num_threads(1)

    def fit(states: np.ndarray, actions: np.ndarray, angles: np.ndarray, window: int) -> tuple[np.ndarray, ...]:
        n, horizon, act_dim = actions.shape
        centre = weighted_centre(states, np.full((n, horizon + 1), 1.0 / n), angles)
        dev = deviation(states, centre[None], angles)
        x = np.concatenate([dev[:, :-1], actions - actions.mean(axis=0)], axis=2)
        xx = window_mean(np.einsum("ntf,ntg->tfg", x, x) / n, window)
        xy = window_mean(np.einsum("ntf,ntd->tfd", x, dev[:, 1:]) / n, window)
        # standardised per step (a σ shared by all steps lets the ridge erase the tight early states)
        scale = np.sqrt(np.diagonal(xx, axis1=1, axis2=2))
        scale = np.where(scale > 1e-12, scale, 1.0)
        normal = xx / scale[:, :, None] / scale[:, None, :] + 1e-6 * np.eye(x.shape[2])
        coef = np.linalg.solve(normal, xy / scale[:, :, None]) / scale[:, :, None]
        coef = np.swapaxes(coef, 1, 2)
        dim = states.shape[2]
        return coef[:, :, :dim], coef[:, :, dim:]

    rows = []
    for task in (1, 2):
        for seed in range(seeds):
            for label, feedback, iterations, std in (("initial", "open", 0, 0.5), ("tight", "open", 0, 0.1),
                                                     ("fitted_3", "fitted", 3, None)):
                agent = TLPS("TLCarNav-v0", seed=seed, env_kwargs={"task": task}, feedback=feedback).learn(iterations)
                policy = agent.policy
                if std is not None:
                    policy.cov[:] = np.eye(policy.act_dim) * std**2
                rng = np.random.default_rng(seed)
                feedforward = policy.sample_feedforward(40, rng)
                batch = rollout(agent.env, feedforward, policy.feedback, seed=seed)
                delta_k = scale * rng.standard_normal(feedforward.shape)
                moved = rollout(agent.env, feedforward + delta_k, policy.feedback, seed=seed)
                real = np.stack([moved.traces[s] - batch.traces[s] for s in agent.signal_names], axis=-1)
                for window in (0, 5):
                    a, b = fit(batch.observations, batch.actions, policy.angles, window)
                    closed = a + np.einsum("tda,tae->tde", b, policy.gains)
                    ds = np.zeros((40, policy.obs_dim))
                    predicted = np.zeros_like(real)
                    for t in range(agent.horizon):
                        ds = np.einsum("de,ne->nd", closed[t], ds) + np.einsum("da,na->nd", b[t], delta_k[:, t])
                        predicted[:, t + 1] = ds[:, :2]  # the car's signals x, y are components 0, 1
                    rows.append({"task": task, "seed": seed, "policy": label, "window": window,
                                 "saturated": float(np.mean(np.abs(batch.actions) >= 1)),
                                 **{f"rel_error_{name}": _relative_error(predicted[:, sl], real[:, sl])
                                    for name, sl in (("trace", slice(1, None)), ("t1", 1), ("t5", 5), ("t50", 50))}})
                    print({k: round(v, 3) if isinstance(v, float) else v for k, v in rows[-1].items()}, flush=True)
                agent.close()
    _write_csv(out / "dynamics_check.csv", rows)
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--variants", nargs="+", default=["default", "reps"], choices=list(VARIANTS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--iterations", type=int, default=None, help="default: 30 (task 1), 50 (task 2)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--solver-check", action="store_true")
    parser.add_argument("--timing", action="store_true")
    parser.add_argument("--dynamics-check", action="store_true")
    parser.add_argument("--no-runs", action="store_true", help="only the checks, summary and plots")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.timing:
        timing(args.out)
    if args.solver_check:
        solver_check(args.out)
    if args.dynamics_check:
        dynamics_check(args.out)
    if not args.no_runs:
        jobs = [(v, t, s, args.iterations or ITERATIONS[t], args.out)
                for t in args.tasks for v in args.variants for s in args.seeds]
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            for path in pool.map(run_one, *zip(*jobs)):
                print("done", path.name, flush=True)
    rows = summarise(args.out)
    tables = []
    for task in (1, 2):
        plot(args.out, task, [v for v in VARIANTS if any(r["variant"] == v and r["task"] == task for r in rows)])
        tables.append(f"### Task {task}\n\n{table(rows, task)}\n")
    (args.out / "tables.md").write_text("\n".join(tables))
    print("\n".join(tables))


if __name__ == "__main__":
    main()
