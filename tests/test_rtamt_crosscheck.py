"""Cross-check of exact robustness against rtamt's discrete-time offline STL monitor.

rtamt (test-only dependency) evaluates ``rtamt.StlDiscreteTimeOfflineSpecification``
with `rtamt.semantics.stl.discrete_time.offline.ast_visitor`. Its semantics and ours
provably agree on the fragment drawn here, and this test compares the whole
robustness signal (every position, ``robustness_over_time``) to 1e-9:

=====================  ============================  ==========================================
ours                   rtamt text                    rtamt's value at sample i
=====================  ============================  ==========================================
``a < b``, ``a <= b``  ``(a) < (b)``, ``(a) <= (b)``  b - a   (``>``/``>=``: a - b), as ours
``!φ``                 ``not (φ)``                   -φ
``φ & ψ`` (n-ary)      ``(φ) and (ψ)`` (folded)      min; folding an n-ary min is exact
``φ | ψ`` (n-ary)      ``(φ) or (ψ)`` (folded)       max
``φ -> ψ``             ``(φ) implies (ψ)``           max(-φ, ψ)
``F φ``                ``eventually (φ)``            max over samples i … T-1
``G φ``                ``always (φ)``                min over samples i … T-1
``φ U ψ``              ``(φ) until (ψ)``             U(i) = max(ψ(i), min(φ(i), U(i+1))), U(T) = -∞
=====================  ============================  ==========================================

Unrolling rtamt's until recursion gives max over t' ≥ i of min(ψ(t'), min over
t'' in [i, t') of φ(t'')): our non-strict until. Ours judges φ on the truncated
segment s_{t''} … s_{t'-1}, which changes nothing when φ is temporal-free, so only
the *left* operand of U is drawn temporal-free (the right one may be temporal: both
judge it on the full suffix). Left out, because the semantics differ or rtamt lacks
them: ``X`` (rtamt's ``next`` is +∞ at the last sample, ours −ρ_max), ``T`` (no
rtamt counterpart), ``true``/``false`` (not in rtamt's grammar) and U with a temporal
left operand. Arithmetic is restricted to ``+ - * abs`` and non-negative literals
(negative numbers and unary minus are written ``(0 - e)``), which rtamt computes in
the same IEEE float64 operations as numpy.

At least 1,000 random formulas are checked (counted, asserted), each on a short
trace (T = 2 … 6: rtamt 0.4.10 cannot evaluate a single sample, its interpreter
fails computing the sampling period), since rtamt re-parses every formula.
"""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests import strategies as S
from tl_gym import parse
from tl_gym.tltl.ast import (
    Always,
    And,
    BinOp,
    Call,
    Eventually,
    Expr,
    Formula,
    Implies,
    Neg,
    Not,
    Num,
    Or,
    Predicate,
    Until,
    Var,
)

rtamt = pytest.importorskip("rtamt")

FORMULAS_PER_EXAMPLE = 25
EXAMPLES = 45
TEMPORAL_FREE = (Not, And, Or, Implies)


# --------------------------------------------------------------------------- our AST -> rtamt text


def rtamt_expr(e: Expr) -> str:
    if isinstance(e, Var):
        return e.name
    if isinstance(e, Num):
        return repr(e.value) if e.value >= 0 else f"(0 - {-e.value!r})"
    if isinstance(e, Neg):
        return f"(0 - {rtamt_expr(e.operand)})"
    if isinstance(e, BinOp) and e.op in "+-*":
        return f"({rtamt_expr(e.left)} {e.op} {rtamt_expr(e.right)})"
    if isinstance(e, Call) and e.func == "abs":
        return f"abs({rtamt_expr(e.args[0])})"
    raise ValueError(f"{e} is outside the shared fragment")


def rtamt_text(f: Formula) -> str:
    if isinstance(f, Predicate):
        return f"({rtamt_expr(f.lhs)} {f.op} {rtamt_expr(f.rhs)})"
    if isinstance(f, Not):
        return f"(not {rtamt_text(f.child)})"
    if isinstance(f, (And, Or)):
        word = " and " if isinstance(f, And) else " or "
        text = rtamt_text(f.operands[0])
        for operand in f.operands[1:]:
            text = f"({text}{word}{rtamt_text(operand)})"
        return text
    if isinstance(f, Implies):
        return f"({rtamt_text(f.left)} implies {rtamt_text(f.right)})"
    if isinstance(f, Eventually):
        return f"(eventually {rtamt_text(f.child)})"
    if isinstance(f, Always):
        return f"(always {rtamt_text(f.child)})"
    if isinstance(f, Until):
        return f"({rtamt_text(f.left)} until {rtamt_text(f.right)})"
    raise ValueError(f"{type(f).__name__} is outside the shared fragment")


def rtamt_robustness(formula: Formula, trace: dict[str, np.ndarray]) -> list[float]:
    spec = rtamt.StlDiscreteTimeOfflineSpecification()
    for name in S.SIGNALS:
        spec.declare_var(name, "float")
    spec.spec = rtamt_text(formula)
    spec.parse()
    length = len(trace["x"])
    dataset = {"time": list(range(length)), **{k: [float(v) for v in trace[k]] for k in S.SIGNALS}}
    return [value for _, value in spec.evaluate(dataset)]


# --------------------------------------------------------------------------- the fragment
# Formulas come from a seeded `random.Random` (hypothesis draws the seed and the trace):
# drawing 1,000 formulas through hypothesis costs several times rtamt's own parsing.
# A failure prints the formula; the reference tests cover the same operators with shrinking.


def random_expr(rng: random.Random, depth: int = 2) -> Expr:
    if depth == 0 or rng.random() < 0.35:
        return Var(rng.choice(S.SIGNALS)) if rng.random() < 0.5 else Num(rng.randint(-20, 20) / 2)
    kind = rng.choice(("+", "-", "*", "neg", "abs"))
    a = random_expr(rng, depth - 1)
    if kind == "neg":
        return Neg(a)
    if kind == "abs":
        return Call("abs", (a,))
    return BinOp(kind, a, random_expr(rng, depth - 1))


def random_predicate(rng: random.Random) -> Predicate:
    op = rng.choice(S.COMPARISONS)
    if rng.random() < 0.3:
        return Predicate(random_expr(rng), op, random_expr(rng))
    return Predicate(Var(rng.choice(S.SIGNALS)), op, Num(rng.randint(-8, 8) / 2))


def random_formula(rng: random.Random, depth: int = 4, temporal: bool = True) -> Formula:
    """Predicates, not, and, or, implies, F, G, and U whose left operand is temporal-free."""
    if depth == 0 or rng.random() < 0.2:
        return random_predicate(rng)
    ops = (Not, And, Or, Implies, Eventually, Always, Until, Until) if temporal else TEMPORAL_FREE
    op = rng.choice(ops)
    if op in (Not, Eventually, Always):
        return op(random_formula(rng, depth - 1, temporal))
    if op in (And, Or):
        return op(tuple(random_formula(rng, depth - 1, temporal) for _ in range(rng.randint(2, 3))))
    if op is Until:
        return Until(random_formula(rng, min(depth - 1, 2), temporal=False), random_formula(rng, depth - 1))
    return Implies(random_formula(rng, depth - 1, temporal), random_formula(rng, depth - 1, temporal))


# --------------------------------------------------------------------------- tests


def test_translation_of_the_paper_example():
    formula = parse("F(s > 5 & s < 10)".replace("s", "x"))
    assert rtamt_text(formula) == "(eventually ((x > 5.0) and (x < 10.0)))"
    assert rtamt_robustness(formula, {"x": np.array([11.0, 6.0, 7.0]), "y": np.zeros(3), "z": np.zeros(3)}) == [
        2.0, 2.0, 2.0,
    ]


def test_until_is_non_strict_in_both():
    formula = parse("x > 0 U y > 0")
    trace = {"x": np.array([-1.0, 2.0, 3.0]), "y": np.array([5.0, -1.0, -2.0]), "z": np.zeros(3)}
    # ψ holds at once: ψ(0) = 5, whatever φ(0) is (a strict until would need φ first)
    assert rtamt_robustness(formula, trace)[0] == 5.0 == formula.robustness(trace)


def test_exact_robustness_matches_rtamt():
    checked = 0

    @settings(max_examples=EXAMPLES)
    @given(st.integers(0, 2**32 - 1), S.traces(min_length=2, max_length=6))
    def check(seed, trace):
        nonlocal checked
        rng = random.Random(seed)
        for _ in range(FORMULAS_PER_EXAMPLE):
            formula = random_formula(rng)
            expected = rtamt_robustness(formula, trace)
            got = formula.robustness_over_time(trace)
            np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9, err_msg=str(formula))
            assert parse(str(formula)) == formula
            checked += 1

    check()
    assert checked >= 1000
