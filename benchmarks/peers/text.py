"""The peers that parse formula text: rtamt, argus and STLRom, exact robustness only.

Each library's `Syntax` says how it writes the pieces of the tasks; `specification` assembles them into one text.
Rewrites for missing operators are in docs/speed.md ("What each peer evaluates") and in `Evaluator.expressed`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from benchmarks.formulas import Task
from benchmarks.peers import Evaluator, Unsupported

Text = Callable[..., str]


@dataclass(frozen=True)
class Syntax:
    """How a library writes the pieces of the tasks; each field maps its operands (texts) to text."""

    name: str
    box: Text  # a goal ψ_g, from a `tl_gym.envs.tasks.Goal`
    distance: Text  # the obstacle distance d_o, from a `tl_gym.envs.tasks.Obstacle`
    always: Text
    phi1: Text  # (g, avoid) -> F g ∧ avoid
    sequence: Text  # (g1, g2, g3) -> g1 T (g2 T g3)
    until: Text
    always_after: Text  # X G φ
    next: Text | None  # tl_gym's strong X; None: it cannot be written
    not_: Text
    and_: Text = "({} and {})".format
    or_: Text = "({} or {})".format
    implies: Text = "{} -> {}".format
    join: str = " and "
    wrap: Text = "{}".format


def specification(task: Task, s: Syntax) -> str:
    """``task`` in the library's syntax ``s`` (ValueError: φ2's default no-revisit clause and no X).

    φ1 = ``F g ∧ G(d_o > r)``; φ2 = ``g1 T (g2 T g3)``, ``¬(g2 ∨ g3) U g1``, ``¬g3 U g2``, a no-revisit clause
    per goal and ``G(d_o > r)``.
    """
    g = [s.box(b) for b in task.goals]
    avoid = s.always(f"{s.distance(task.obstacle)} > {task.obstacle.radius:.1f}")
    if task.key == "phi1":
        return s.wrap(s.phi1(g[0], avoid))
    if s.next is None and not task.strict:
        raise ValueError(f"{s.name} cannot express X, which φ2's default no-revisit clause needs")
    clauses = [s.sequence(*g), s.until(s.not_(s.or_(g[1], g[2])), g[0]), s.until(s.not_(g[2]), g[1])]
    for gi in g:
        leaving = gi if task.strict else s.and_(gi, s.next(s.not_(gi)))  # type: ignore[misc]
        clauses.append(s.always(s.implies(leaving, s.always_after(s.not_(gi)))))
    return s.wrap(s.join.join(f"({c})" for c in [*clauses, avoid]))


def _exact(name: str, task: Task, run_one: Callable[[np.ndarray, np.ndarray], float], rewrites: str,
           d_signal: bool = True) -> list:
    """One trajectory at a time; the note says if ``d_o`` is passed as a signal and, beyond φ1, the ``rewrites``."""
    expressed = ["d_o passed as a signal (no sqrt)" if d_signal else "", "" if task.key == "phi1" else rewrites]
    return [Evaluator(name, "exact", lambda x, y: np.array([run_one(a, b) for a, b in zip(x, y)]),
                      "; ".join(filter(None, expressed))),
            Unsupported(name, "smooth+grad", "no smoothed semantics")]


def _rtamt_next(phi: str) -> str:
    return f"(not(next(not({phi}))))"  # tl_gym's strong next (−∞ at the last state) from rtamt's weak one


def _rtamt_then(phi: str, later: str) -> str:
    return f"eventually({phi} and {_rtamt_next(later)})"


RTAMT = Syntax(
    name="rtamt",
    box="((x > {0.x_low:.1f}) and (x < {0.x_high:.1f}) and (y > {0.y_low:.1f}) and (y < {0.y_high:.1f}))".format,
    distance="sqrt((x - {0.x:.1f})*(x - {0.x:.1f}) + (y - {0.y:.1f})*(y - {0.y:.1f}))".format,
    always="always({})".format, phi1="(eventually{}) and ({})".format,
    sequence=lambda g1, g2, g3: _rtamt_then(g1, _rtamt_then(g2, f"eventually{g3}")),
    until="(({}) until {})".format, always_after=lambda phi: _rtamt_next(f"always({phi})"), next=_rtamt_next,
    not_="not{}".format,
)


def rtamt_evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact φ1 and φ2 with rtamt (pure-Python offline STL monitor); T and strong X rewritten exactly (speed.md)."""
    import rtamt

    spec = rtamt.StlDiscreteTimeOfflineSpecification()
    spec.declare_var("x", "float")
    spec.declare_var("y", "float")
    spec.spec = specification(task, RTAMT)
    spec.parse()

    def run_one(x: np.ndarray, y: np.ndarray) -> float:
        return float(spec.evaluate({"time": list(range(len(x))), "x": x.tolist(), "y": y.tolist()})[0][1])

    return _exact("rtamt", task, run_one, "T as F(φ & X F ψ); X as not next not (exact)", d_signal=False)


ARGUS = Syntax(
    name="argus", box="(x > {0.x_low:.1f} && x < {0.x_high:.1f} && y > {0.y_low:.1f} && y < {0.y_high:.1f})".format,
    distance=lambda circle: "d", always="G({})".format, phi1="F{} && {}".format,
    sequence=lambda g1, g2, g3: f"F({g1} && F[1,]F({g2} && F[1,]{g3}))",
    until="(({}) U {})".format, always_after="G[1,]({})".format, next=None, not_="!{}".format,
    and_="({} && {})".format, or_="({} || {})".format, join=" && ",
)


def argus_evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact φ1 and φ2-strict with argus (Rust core; piecewise-constant signals); its rewrites: docs/speed.md."""
    import argus

    if task.key == "phi2":
        reason = "X fails and bounded F[a,b] acts as F[a,] in argus 0.1.4: X !g cannot be written"
        return [Unsupported("argus", "exact", reason), Unsupported("argus", "smooth+grad", "no smoothed semantics")]
    expr = argus.parse_expr(specification(task, ARGUS))

    def signal(times: list[float], values: np.ndarray) -> argus.FloatSignal:
        return argus.FloatSignal.from_samples(list(zip(times, values.tolist())), interpolation_method="constant")

    def run_one(x: np.ndarray, y: np.ndarray) -> float:
        times = [float(t) for t in range(len(x))]
        d = np.hypot(x - task.obstacle.x, y - task.obstacle.y)
        trace = argus.Trace({"x": signal(times, x), "y": signal(times, y), "d": signal(times, d)})
        return float(argus.eval_robust_semantics(expr, trace, interpolation_method="constant").at(0.0))

    return _exact("argus", task, run_one, "X G as G[1,], T as F(φ & F[1,] ψ) (its X is broken)")


def stlrom_syntax(h: int) -> Syntax:
    """STLRom's syntax for trajectories of ``h`` samples (+1 duplicate): the horizon ``h`` is in every operator."""
    return Syntax(
        name="stlrom", box="(x[t] > {0.x_low:.1f} and x[t] < {0.x_high:.1f} and y[t] > {0.y_low:.1f} "
                           "and y[t] < {0.y_high:.1f})".format,
        distance=lambda circle: "d[t]", always=f"alw_[0, {h}] ({{}})".format, phi1=f"ev_[0, {h}] {{}} and {{}}".format,
        sequence=lambda g1, g2, g3: f"ev_[0, {h}] ({g1} and ev_[1, {h}] (ev_[0, {h}] ({g2} and ev_[1, {h}] {g3})))",
        until=f"({{}}) until_[0, {h}] {{}}".format, always_after=f"alw_[1, {h}] ({{}})".format,
        next="ev_[1, 1.5] ({})".format, not_="not {}".format, implies="{} => {}".format,
        wrap="signal x, y, d\nphi := {}\n".format,
    )


def stlrom_evaluators(task: Task, beta: float) -> list[Evaluator | Unsupported]:
    """Exact φ1 and an attempt at φ2 with STLRom (C++ online monitor); its dense-time rewrites: docs/speed.md."""
    import stlrom

    @lru_cache(maxsize=4)
    def driver(length: int) -> Any:
        d = stlrom.STLDriver()
        d.parse_string(specification(task, stlrom_syntax(length)))
        d.set_interpol("PREVIOUS")  # with a duplicate last sample at T: its ev_, alw_, until_ are tl_gym's F, G, U
        return d

    def run_one(x: np.ndarray, y: np.ndarray) -> float:
        monitor = driver(len(x)).get_monitor("phi")  # a fresh monitor holds no samples
        d = np.hypot(x - task.obstacle.x, y - task.obstacle.y)
        samples = np.column_stack([np.arange(len(x) + 1.0), *(np.append(v, v[-1]) for v in (x, y, d))])
        for sample in samples.tolist():
            monitor.add_sample(sample)
        return float(monitor.eval_rob(0.0))

    return _exact("stlrom", task, run_one, "X as ev_[1,1.5], T as ev(φ and ev_[1,T] ψ) (no next)")
