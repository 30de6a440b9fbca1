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

FORMULAS_PER_EXAMPLE = 20
EXAMPLES = 55
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


@st.composite
def _exprs(draw, depth: int = 2) -> Expr:
    if depth == 0 or draw(st.integers(0, 2)) == 0:
        if draw(st.booleans()):
            return Var(draw(st.sampled_from(S.SIGNALS)))
        return Num(draw(st.integers(-20, 20)) / 2)
    kind = draw(st.sampled_from(("+", "-", "*", "neg", "abs")))
    a = draw(_exprs(depth - 1))
    if kind == "neg":
        return Neg(a)
    if kind == "abs":
        return Call("abs", (a,))
    return BinOp(kind, a, draw(_exprs(depth - 1)))


_predicates = S.predicates(exprs=_exprs())


@st.composite
def shared_formulas(draw, depth: int = 3) -> Formula:
    """Predicates, not, and, or, implies, F, G, and U whose left operand is temporal-free."""
    if depth == 0 or draw(st.integers(0, 4)) == 0:
        return draw(_predicates)
    op = draw(st.sampled_from((Not, And, Or, Implies, Eventually, Always, Until, Until)))
    sub = shared_formulas(depth - 1)
    if op in (Not, Eventually, Always):
        return op(draw(sub))
    if op in (And, Or):
        return op(tuple(draw(st.lists(sub, min_size=2, max_size=3))))
    if op is Until:
        left = S.formulas(max_depth=2, operators=TEMPORAL_FREE, constants=False, leaves=_predicates)
        return Until(draw(left), draw(sub))
    return Implies(draw(sub), draw(sub))


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
    @given(st.lists(shared_formulas(), min_size=FORMULAS_PER_EXAMPLE, max_size=FORMULAS_PER_EXAMPLE),
           S.traces(min_length=2, max_length=6))
    def check(formulas, trace):
        nonlocal checked
        for formula in formulas:
            expected = rtamt_robustness(formula, trace)
            got = formula.robustness_over_time(trace)
            np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9, err_msg=str(formula))
            assert parse(str(formula)) == formula
            checked += 1

    check()
    assert checked >= 1000
