"""Speed of tl_gym's robustness against hand-written numpy and numba and peer libraries (issues 3, 10, 17).

Trajectories per second of φ1 and φ2, exact and smoothed with gradient, for tl_gym, `benchmarks.handwritten` and
every peer that imports, each checked against tl_gym's values before it is timed. The table and the targets go to
stdout and ``docs/results/speed.md``; docs/speed.md says how to run and read it.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np
from scipy.interpolate import interp1d

from benchmarks import handwritten, peers
from benchmarks.formulas import ARENA, TASKS, Task, benchmark_task
from benchmarks.peers import Evaluator, Unsupported
from benchmarks.provenance import git
from tl_gym.tltl import fused

RTOL = 1e-6  # relative tolerance of the value check (absolute below |ρ| = 1)
TL_GYM = "tl_gym"
HANDWRITTEN = "numpy (hand-written)"
FUSED, TL_GYM_NUMBA = "numba (hand-written, fused)", "tl_gym, backend='numba'"  # with the numba extra (issue 17)
SMOOTH_LINEAR = "smooth+grad, linear form"
PHI1_ALTERNATED = ((TL_GYM, "exact"), (TL_GYM, "smooth+grad"), (HANDWRITTEN, "smooth+grad"))  # (library, mode)
NESTED_MAX_LENGTH = 2_000
NESTED_TOO_LONG = "nested smoothing is O(T²) per trajectory; one at T = 20,000 ran > 14 min"
RESULTS = Path("docs/results/speed.md")


def trajectories(n: int, length: int, seed: int, tasks: Iterable[Task] = ()) -> tuple[np.ndarray, np.ndarray]:
    """``n`` seeded random smooth paths of ``length`` steps in the arena, as ``(x, y)`` of shape ``(n, length)``.

    Half are random walks of the velocity, scaled to span about half the arena; the other half run through three
    goal centres of ``tasks`` (a quarter in φ2's order) plus a smaller walk, so goals are entered, left and
    re-entered and every clause of φ2 is exercised.
    """
    rng = np.random.default_rng(seed)
    scale = ARENA * math.sqrt(3) / 2 / length**1.5
    walk = np.cumsum(np.cumsum(rng.standard_normal((2, n, length)), axis=2), axis=2) * scale
    start = rng.uniform(0, ARENA, (n, 2))
    centres = list(dict.fromkeys(b.center for t in tasks for b in t.goals)) or [(ARENA / 2, ARENA / 2)]
    routed = rng.random(n) < 0.5
    picks = rng.integers(0, len(centres), (n, 3))
    in_order = rng.random(n) < 0.25
    picks[in_order] = np.arange(3) % len(centres) + (len(centres) > 3)  # φ2's goals come after φ1's
    waypoints = np.concatenate([start[:, None, :], np.asarray(centres)[picks]], axis=1)  # (n, 4, 2)
    route = interp1d(np.arange(4), waypoints, axis=1)(np.linspace(0, 3, length))  # (n, length, 2)
    base = np.where(routed[:, None, None], route, start[:, None, :])
    noise = np.where(routed[None, :, None], 0.1, 1.0) * walk
    x, y = np.clip(np.moveaxis(base, -1, 0) + noise, 0, ARENA)
    return x, y


def tl_gym_evaluators(task: Task, beta: float) -> list[Evaluator]:
    """tl_gym's exact evaluators and its smoothed-with-gradient ones (torch float64; φ2 also in the linear form)."""
    import torch

    def exact(x: np.ndarray, y: np.ndarray, backend: str = "numpy") -> np.ndarray:
        return np.asarray(task.formula.robustness({"x": x, "y": y}, backend=backend))

    def smooth(x: np.ndarray, y: np.ndarray, form: str = "nested") -> np.ndarray:
        xt, yt = (torch.from_numpy(v).requires_grad_(True) for v in (x, y))
        values = task.formula.smooth_robustness({"x": xt, "y": yt}, beta, form=form)
        values.sum().backward()
        return values.detach().numpy()

    nested = {} if task.key == "phi1" else {"max_length": NESTED_MAX_LENGTH, "too_long": NESTED_TOO_LONG}
    out = [Evaluator(TL_GYM, "exact", exact, per_trajectory=False),
           Evaluator(TL_GYM, "smooth+grad", smooth, per_trajectory=False, **nested)]
    if task.key != "phi1":
        out.append(Evaluator(TL_GYM, SMOOTH_LINEAR, functools.partial(smooth, form="linear"), per_trajectory=False))
    if fused.available():
        out.append(Evaluator(TL_GYM_NUMBA, "exact", lambda x, y: exact(x, y, "numba"), False, compiles=True))
    return out


def handwritten_evaluators(task: Task, beta: float) -> list[Evaluator]:
    """The hand-written numpy functions of ``task``: exact, and for φ1 smoothed with its gradient."""
    out = [Evaluator(HANDWRITTEN, "exact", lambda x, y: handwritten.robustness(task, x, y), per_trajectory=False)]
    if task.key == "phi1":
        out.append(Evaluator(HANDWRITTEN, "smooth+grad", lambda x, y: handwritten.smooth_phi1(task, x, y, beta)[0],
                             per_trajectory=False))
    if fused.available():
        out.append(Evaluator(FUSED, "exact", lambda x, y: handwritten.fused(task, x, y), False, compiles=True))
    return out


@dataclass
class Row:
    """One line of the table."""

    task: str
    n: int
    length: int
    library: str
    mode: str
    per_second: float | None = None  # trajectories per second
    note: str = ""
    ratio: float | None = None  # tl_gym's throughput / this library's (same mode)


def _time(run: Callable[[], np.ndarray], repeats: int = 1, budget: float = math.inf,
          warm: bool = True) -> tuple[float, np.ndarray]:
    """Best wall time of ``run`` over ``repeats`` calls and its values; unless ``warm``, an untimed call warms up first.

    That first call is the time when it alone is too slow to repeat.
    """
    if not warm:
        first, values = _time(run)
        if first > 3 * budget:
            return first, values
    best, spent = math.inf, 0.0
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        values = run()
        elapsed = time.perf_counter() - start
        best, spent = min(best, elapsed), spent + elapsed
        if spent > 3 * budget:
            break
    return best, values


def _mismatch(values: np.ndarray, reference: np.ndarray) -> str:
    """Empty when ``values`` equal ``reference`` to `RTOL`, else what differs."""
    if values.shape != reference.shape:
        return f"returned shape {values.shape}, expected {reference.shape}"
    bad = ~(np.abs(values - reference) <= RTOL * np.maximum(1.0, np.abs(reference)))
    if not bad.any():
        return ""
    worst = float(np.nanmax(np.abs(values - reference)))
    return f"disagrees with tl_gym on {int(bad.sum())}/{bad.size} trajectories (max |Δ| = {worst:.3g})"


def measure(evaluator: Evaluator, row: Row, x: np.ndarray, y: np.ndarray, reference: np.ndarray | None,
            settings: argparse.Namespace) -> np.ndarray | None:
    """Check ``evaluator`` against ``reference``, time it as ``settings`` say, fill ``row``: its values (or None)."""
    n, length = x.shape
    if evaluator.max_length is not None and length > evaluator.max_length:
        row.note = f"skipped: T > {evaluator.max_length:,} ({evaluator.too_long})"
        return None
    k, probe = n, 0
    if evaluator.per_trajectory or n > 16:
        probe = min(n, 1 if evaluator.per_trajectory else 16)
        if evaluator.compiles:  # compile for the probe's shape first, or the estimate is the compile time
            evaluator.run(x[:probe], y[:probe])
        per_one = _time(lambda: evaluator.run(x[:probe], y[:probe]))[0] / probe
        limit = settings.budget if evaluator.per_trajectory else settings.max_seconds  # on a batch: a cap
        k = int(min(n, max(1, limit // max(per_one, 1e-9))))
    try:
        if evaluator.compiles:  # a JIT compiles on the first call of a shape: that call is not timed
            evaluator.run(x[:k], y[:k])
        seconds, values = _time(lambda: evaluator.run(x[:k], y[:k]), settings.repeats, settings.budget,
                                k == probe or evaluator.compiles)
    except Exception as exc:  # a peer crashing on valid input is a result, not a benchmark failure
        row.note = f"error: {type(exc).__name__}: {exc}"[:120]
        return None
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if reference is not None and (problem := _mismatch(values[: min(k, len(reference))], reference[:k])):
        row.note = problem
        return None
    row.per_second = k / seconds
    row.note = "; ".join(filter(None, [evaluator.expressed, f"timed on {k:,} of {n:,}" if k < n else ""]))
    return values


def run_cell(task: Task, x: np.ndarray, y: np.ndarray, evaluators: list, settings: argparse.Namespace,
             log: Callable[[str], None]) -> list[Row]:
    """All libraries on one (task, N, T) batch; tl_gym first, as every other is checked against it."""
    rows: list[Row] = []
    references: dict[str, np.ndarray] = {}  # tl_gym's values, by mode
    for ev in evaluators:
        rows.append(row := Row(task.key, *x.shape, ev.library, ev.mode))
        if isinstance(ev, Unsupported):
            row.note = f"not comparable: {ev.reason}"
        elif ev.library != TL_GYM and ev.mode not in references:
            row.note = "not checked: tl_gym did not run at this size"
        else:
            values = measure(ev, row, x, y, references.get(ev.mode), settings)
            if ev.library == TL_GYM and values is not None:
                references[ev.mode] = values
            log(_format_row(row))
    base = {r.mode: r.per_second for r in rows if r.library == TL_GYM}
    for r in rows:
        if r.per_second and base.get(r.mode):
            r.ratio = base[r.mode] / r.per_second
    return rows


def _format_row(r: Row) -> str:
    rate = "—" if r.per_second is None else f"{r.per_second:,.0f}" if r.per_second >= 100 else f"{r.per_second:,.3g}"
    ratio = "" if r.ratio is None else f"{r.ratio:,.3g}"
    return f"| {r.task} | {r.n:,} | {r.length:,} | {r.library} | {r.mode} | {rate} | {ratio} | {r.note} |"


HEADER = "| formula | N | T | library | mode | traj/s | tl_gym × | note |\n|---|---:|---:|---|---|---:|---:|---|"


def table(rows: list[Row]) -> str:
    """The results as one markdown table (``tl_gym ×``: how many times tl_gym's throughput is this row's)."""
    return "\n".join([HEADER, *(_format_row(r) for r in rows)])


def machine() -> str:
    """A one-paragraph description of this machine and the library versions."""
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as f:
        cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    versions = [f"tl_gym commit {git('rev-parse', '--short', 'HEAD') or 'unknown'}"]
    for dist in ("tl_gym", "numpy", "torch", "rtamt", "argus-temporal-logic", "stlrom", "stlcgpp", "stljax", "jax"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            versions.append(f"{dist} {metadata.version(dist)}")
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    return (f"{cpu}, {os.cpu_count()} logical cores, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}; load average at the end {load}; " + ", ".join(versions))


def interleaved(task: Task, x: np.ndarray, y: np.ndarray, beta: float, rounds: int,
                calls: Sequence[tuple[str, str]] = PHI1_ALTERNATED) -> tuple[float, ...]:
    """Best time of each (library, mode) of ``task``, the calls taking turns ``rounds`` times in one loop (speed.md)."""
    runs = {(e.library, e.mode): e.run for e in [*tl_gym_evaluators(task, beta), *handwritten_evaluators(task, beta)]}
    times = [[_time(functools.partial(runs[call], x, y))[0] for call in calls] for _ in range(rounds + 1)]
    return tuple(map(min, zip(*times[1:])))  # round 0 warms up


def _met(ok: bool) -> str:
    return "met" if ok else "not met"


def targets(rows: list[Row], alternated: tuple[float, ...] | None = None,
            linear_alternated: tuple[float, float] | None = None) -> list[str]:
    """The issues' speed targets (docs/speed.md), each with the measured numbers at T = 200 and whether it is met.

    ``alternated``: (N, exact s, smoothed s, hand-written smoothed s) of `interleaved` for φ1, if measured;
    ``linear_alternated``: (smoothed linear s, hand-written exact s) of φ2 at N = 40, `interleaved`.
    """
    n_big = max((r.n for r in rows if r.length == 200), default=0)
    rates = {(r.task, r.n, r.length, r.library, r.mode): r.per_second for r in rows}  # traj/s, None: not timed

    def rate(task: str, library: str, mode: str = "exact", n: int = n_big) -> float | None:
        return rates.get((task, n, 200, library, mode))

    lines = []
    for task in ("phi1", "phi2"):
        ours, hand, peer = rate(task, TL_GYM), rate(task, HANDWRITTEN), rate(task, "rtamt")
        smooth, hand_smooth = rate(task, TL_GYM, "smooth+grad"), rate(task, HANDWRITTEN, "smooth+grad")
        linear, stlcg = rate(task, TL_GYM, SMOOTH_LINEAR), rate(task, "stlcg++", "smooth+grad")
        if ours and hand:
            lines.append(f"- exact {task}, N = {n_big:,}, T = 200: tl_gym {n_big / ours:.3g} s, hand-written numpy "
                         f"{n_big / hand:.3g} s: **{hand / ours:.2f}×** the hand-written time (target ≤ 1.5×: "
                         f"{_met(hand / ours <= 1.5)}).")
        if ours and peer:
            lines.append(f"- exact {task}, T = 200: tl_gym {ours:,.0f} traj/s vs rtamt {peer:,.1f} traj/s: "
                         f"**{ours / peer:,.0f}×** (target ≥ 1,000×: {_met(ours / peer >= 1000)}).")
        if ours and smooth:  # two rows timed apart swing ±30 % on a shared VM: φ1's alternated timing decides
            verdict = (" (reported)" if task != "phi1" else f" (target ≤ 5×: {_met(ours / smooth <= 5)})"
                       if not alternated else " (rows timed apart; the verdict is the alternated timing below)")
            lines.append(f"- smoothed {task} with gradient, N = {n_big:,}, T = 200: {smooth:,.0f} traj/s, "
                         f"**{ours / smooth:.2f}×** the exact time{verdict}.")
        if ours and smooth and hand_smooth:
            lines.append(f"- hand-written numpy smoothed {task} with gradient: **{ours / hand_smooth:.2f}×** the exact "
                         f"time (the floor under the target); tl_gym takes {hand_smooth / smooth:.2f}× its time.")
        if task == "phi1" and alternated:
            n_alt, exact_s, smooth_s, hand_s = alternated
            lines.append(f"- the same, the calls alternated in one loop (N = {n_alt:,}, best of each): exact "
                         f"{exact_s * 1e3:.1f} ms, smoothed with gradient {smooth_s * 1e3:.1f} ms: "
                         f"**{smooth_s / exact_s:.2f}×** (target ≤ 5×: {_met(smooth_s / exact_s <= 5)}); hand-written "
                         f"smoothed with gradient {hand_s * 1e3:.1f} ms ({hand_s / exact_s:.2f}× exact).")
        if ours and linear:
            lines.append(f"- smoothed {task} with gradient, linear form (TLPS's), N = {n_big:,}, T = 200: "
                         f"{linear:,.0f} traj/s, **{ours / linear:.2f}×** the exact time (reported).")
        if smooth and stlcg:
            lines.append(f"- smoothed {task} with gradient vs stlcg++: {smooth:,.0f} vs {stlcg:,.1f} traj/s: "
                         f"**{smooth / stlcg:,.0f}×** (target ≥ 100×: {_met(smooth / stlcg >= 100)}).")
    # issue 17: (what, target throughput ratio, ours, theirs)
    checks = [(f"exact {t}, N = {n_big:,}: {TL_GYM_NUMBA} vs {FUSED}", 0.5, rate(t, TL_GYM_NUMBA), rate(t, FUSED))
              for t in ("phi1", "phi2")]
    checks += [(f"exact {t}, N = 40: {lib} vs hand-written numpy", 1.0, rate(t, lib, n=40),
                rate(t, HANDWRITTEN, n=40)) for lib in (TL_GYM, TL_GYM_NUMBA) for t in ("phi1", "phi2")]
    checks += [("smoothed phi2 (linear form) + gradient, N = 40: tl_gym vs hand-written exact numpy phi2", 0.2,
                rate("phi2", TL_GYM, SMOOTH_LINEAR, n=40), rate("phi2", HANDWRITTEN, n=40)),
               (f"smoothed phi1 + gradient, N = {n_big:,}: tl_gym vs hand-written numpy", 1.0,
                rate("phi1", TL_GYM, "smooth+grad"), rate("phi1", HANDWRITTEN, "smooth+grad"))]
    lines += [f"- {what}: throughput **{ours / theirs:.2f}×** theirs (issue 17 target ≥ {bar:g}×: "
              f"{_met(ours / theirs >= bar)})." for what, bar, ours, theirs in checks if ours and theirs]
    if linear_alternated:  # the rows are timed minutes apart; this pair in one loop decides
        ours_s, hand_s = linear_alternated
        lines.append(f"- the same, the two calls alternated in one loop (N = 40, best of each): smoothed phi2 (linear "
                     f"form) + gradient {ours_s * 1e3:.2f} ms, hand-written exact phi2 {hand_s * 1e3:.2f} ms: "
                     f"**{ours_s / hand_s:.2f}×** its time (issue 17 target ≤ 5×: {_met(ours_s / hand_s <= 5)}).")
    return lines + linearity(rows, rates)


def linearity(rows: list[Row], rates: dict[tuple[str, int, int, str, str], float | None]) -> list[str]:
    """Time per trajectory step of tl_gym across T at the largest N measured at every T (``rates``: `targets`')."""
    lines = []
    lengths, sizes = sorted({r.length for r in rows}), {r.n for r in rows}
    if len(lengths) < 2:
        return lines
    for mode in ("exact", "smooth+grad", SMOOTH_LINEAR):
        for task in sorted({r.task for r in rows}):
            common = [n for n in sizes if all(rates.get((task, n, t, TL_GYM, mode)) for t in lengths)]
            if not common:
                continue
            n = max(common)
            per_step = [1e9 / (rates[task, n, t, TL_GYM, mode] * t) for t in lengths]
            growth = per_step[-1] / per_step[0]
            # Large arrays leave the caches: the hand-written numpy pays that too, so compare growths.
            hand = [rates.get((task, n, t, HANDWRITTEN, "exact")) for t in lengths]
            hand_growth = hand[0] * lengths[0] / (hand[-1] * lengths[-1]) if mode == "exact" and all(hand) else None
            linear = growth <= 2.0 or (hand_growth is not None and growth <= 1.5 * hand_growth)
            versus = "" if hand_growth is None else f"; hand-written numpy ×{hand_growth:.2f}"
            steps = ", ".join(f"T = {t:,}: {v:.1f}" for t, v in zip(lengths, per_step))
            lines.append(f"- {mode} {task}, N = {n:,}, ns per trajectory step: {steps} (×{growth:.2f} over "
                         f"×{lengths[-1] // lengths[0]} in T{versus}: **{'linear' if linear else 'not linear'}**).")
    return lines


def write_results(rows: list[Row], path: Path, command: str, skipped: list[str], target_lines: list[str]) -> None:
    """Write the table, the `targets` lines and the machine to ``path`` (markdown)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    parts = [
        "# Robustness speed: tl_gym vs hand-written numpy and peer libraries", "",
        f"Written by `{command}` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.",
        f"Machine: {machine()}.", "",
        "`traj/s`: trajectories per second (best of a few repeats); `tl_gym ×`: tl_gym's throughput in the same",
        "mode divided by this row's (above 1: tl_gym is faster). How to read it: `docs/speed.md`.", "",
        "## Targets (issue 3)", "",
        *(target_lines or ["- (the grid run does not include the targets' sizes)"]), "",
        "## Table", "", table(rows), "",
    ]
    if skipped:
        parts += ["## Skipped sizes", "", *(f"- {s}" for s in skipped), ""]
    path.write_text("\n".join(parts))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny grid for CI (N = 1, 40; T = 200; seconds)")
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument("--n", nargs="+", type=int, default=[1, 40, 1_000, 10_000], help="batch sizes")
    parser.add_argument("--t", nargs="+", type=int, default=[200, 2_000, 20_000], help="trajectory lengths")
    parser.add_argument("--peers", nargs="*", default=list(peers.PEERS), choices=peers.PEERS)
    parser.add_argument("--beta", type=float, default=9.0, help="smoothing sharpness β (the paper's 9)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--budget", type=float, default=1.0, help="seconds per per-trajectory library and cell")
    parser.add_argument("--max-seconds", type=float, default=20.0, help="cap on one batched run (else a prefix)")
    parser.add_argument("--max-elements", type=float, default=2e7, help="skip cells with N·T above this")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (1: on a loaded 2-core "
                        "machine more threads spin-wait on every small op)")
    parser.add_argument("--alternate", type=int, default=20, metavar="ROUNDS",
                        help="also time exact and smoothed φ1 alternately, ROUNDS calls each (0: off)")
    parser.add_argument("--out", type=Path, help=f"markdown results file ('-' for none; default {RESULTS}, "
                        f"--quick: runs/results-quick/speed.md)")
    args = parser.parse_args(argv)
    args.out = args.out or (Path("runs/results-quick/speed.md") if args.quick else RESULTS)
    if args.quick:  # seconds, not minutes: the smallest sizes, one timed repeat, small budgets
        args.n, args.t, args.repeats, args.budget, args.max_seconds = [1, 40], [200], 1, 0.05, 1.0
    for name, value in (("n", min(args.n)), ("t", min(args.t)), ("beta", args.beta), ("threads", args.threads)):
        if value <= 0:
            parser.error(f"--{name} must be > 0, got {value}")
    return args


def main(argv: list[str] | None = None) -> list[Row]:
    """Run the grid, print the table and the targets, write the results file; returns the rows."""
    args = parse_args(argv)
    log = functools.partial(print, file=sys.stderr, flush=True)
    import torch

    torch.set_num_threads(args.threads)
    tasks = [benchmark_task(k) for k in args.tasks]
    rows: list[Row] = []
    skipped: list[str] = []
    log(HEADER)
    for length in sorted(args.t):
        sizes = sorted(n for n in args.n if n * length <= args.max_elements)
        skipped += [f"N = {n:,}, T = {length:,}: N·T = {n * length:.0e} > {args.max_elements:.0e} elements (memory)"
                    for n in sorted(args.n) if n * length > args.max_elements]
        if not sizes:
            continue
        x_all, y_all = trajectories(sizes[-1], length, args.seed + length, tasks)
        for task in tasks:
            evaluators = [*tl_gym_evaluators(task, args.beta), *handwritten_evaluators(task, args.beta)]
            for name in args.peers:  # every peer that imports
                try:
                    evaluators += peers.load(name)(task, args.beta)
                except ImportError as exc:
                    if length == min(args.t):  # which peers are missing: once
                        log(f"{name}: not installed ({exc.name}); skipped")
            for n in sizes:
                rows += run_cell(task, x_all[:n], y_all[:n], evaluators, args, log)
    by_key, alternated, linear_alternated = {t.key: t for t in tasks}, None, None
    if args.alternate and "phi1" in by_key and 200 in args.t:
        n_alt = max(n for n in args.n if n * 200 <= args.max_elements)
        x_alt, y_alt = trajectories(n_alt, 200, args.seed + 200, tasks)
        alternated = (n_alt, *interleaved(by_key["phi1"], x_alt, y_alt, args.beta, args.alternate))
    if args.alternate and "phi2" in by_key and 200 in args.t and 40 in args.n:
        x_40, y_40 = trajectories(40, 200, args.seed + 200, tasks)  # TLPS's call against the hand-written exact φ2
        linear_alternated = interleaved(by_key["phi2"], x_40, y_40, args.beta, 5 * args.alternate,
                                        ((TL_GYM, SMOOTH_LINEAR), (HANDWRITTEN, "exact")))
    print(table(rows))
    lines = targets(rows, alternated, linear_alternated)
    if lines:
        print("\n" + "\n".join(lines))
    for s in skipped:
        print(f"skipped {s}")
    if str(args.out) != "-":
        argv = sys.argv[1:] if argv is None else argv
        shown = [a for i, a in enumerate(argv) if a != "--out" and (i == 0 or argv[i - 1] != "--out")]
        command = " ".join(["python -m benchmarks.bench_robustness", *shown]) + f" (torch threads: {args.threads})"
        write_results(rows, args.out, command, skipped, lines)
        print(f"\nwritten to {args.out}")
    return rows


if __name__ == "__main__":
    main()
