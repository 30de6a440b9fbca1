"""Hypothesis strategies for TLTL formulas, arithmetic and traces.

`formulas` draws every formula node (``U``/``T`` with temporal left operands
included) up to a nesting depth, and can force a minimum depth. Arithmetic comes in
two flavours: `safe_expressions` builds only expressions that are finite on finite
signals of moderate size (so value tests are rarely discarded), `expressions` builds
anything the syntax allows (for the parser and for the undefined-arithmetic checks).
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from tl_gym.tltl import ast as nodes
from tl_gym.tltl.ast import Expr, Formula

SIGNALS = ("x", "y", "z")
# Names that look like keywords or operators but are plain identifiers.
TRICKY_NAMES = ("x", "y_1", "Fx", "G2", "Until", "nota", "andy", "trueish", "X_", "always_", "_t", "TT", "e", "E1")
COMPARISONS = ("<", "<=", ">", ">=")
BETAS = (0.1, 0.5, 1.0, 3.0, 9.0, 50.0, 1e3, 1e6)


# --------------------------------------------------------------------------- numbers


def small_numbers() -> st.SearchStrategy[float]:
    """Numbers for formulas that get evaluated: small integers (ties) and moderate floats."""
    return st.one_of(
        st.integers(-5, 5).map(float),
        st.floats(-10, 10, allow_nan=False, allow_infinity=False),
    )


def any_numbers() -> st.SearchStrategy[float]:
    """Every finite float, for printing and parsing."""
    return st.one_of(small_numbers(), st.floats(allow_nan=False, allow_infinity=False))


# --------------------------------------------------------------------------- arithmetic


@st.composite
def expressions(draw: st.DrawFn, names: tuple[str, ...] = SIGNALS, depth: int = 3,
                numbers: st.SearchStrategy[float] | None = None) -> Expr:
    """Any arithmetic expression of the syntax (it may be undefined on some states)."""
    numbers = any_numbers() if numbers is None else numbers
    if depth == 0 or draw(st.integers(0, 2)) == 0:
        if draw(st.booleans()):
            return nodes.Var(draw(st.sampled_from(names)))
        return nodes.Num(draw(numbers))
    sub = expressions(names, depth - 1, numbers)
    kind = draw(st.sampled_from(("neg", "binop", "call1", "calln")))
    if kind == "neg":
        return nodes.Neg(draw(sub))
    if kind == "binop":
        return nodes.BinOp(draw(st.sampled_from("+-*/^")), draw(sub), draw(sub))
    if kind == "call1":
        return nodes.Call(draw(st.sampled_from(("abs", "sqrt", "exp", "log"))), (draw(sub),))
    return nodes.Call(draw(st.sampled_from(("min", "max"))), tuple(draw(st.lists(sub, min_size=1, max_size=3))))


@st.composite
def safe_expressions(draw: st.DrawFn, names: tuple[str, ...] = SIGNALS, depth: int = 2) -> Expr:
    """Expressions finite on finite signals with |value| ≤ ~10 (every operator and function)."""
    if depth == 0 or draw(st.integers(0, 2)) == 0:
        if draw(st.integers(0, 2)):
            return nodes.Var(draw(st.sampled_from(names)))
        return nodes.Num(draw(small_numbers()))
    sub = safe_expressions(names, depth - 1)
    a = draw(sub)
    kind = draw(st.sampled_from(("neg", "add", "sub", "mul", "div", "pow", "abs", "sqrt", "exp", "log", "min", "max")))
    one = nodes.Num(1.0)
    if kind == "neg":
        return nodes.Neg(a)
    if kind in ("add", "sub", "mul"):
        return nodes.BinOp({"add": "+", "sub": "-", "mul": "*"}[kind], a, draw(sub))
    if kind == "div":  # a / (1 + |b|)
        return nodes.BinOp("/", a, nodes.BinOp("+", one, nodes.Call("abs", (draw(sub),))))
    if kind == "pow":  # a^2, or |a|^0.5
        if draw(st.booleans()):
            return nodes.BinOp("^", a, nodes.Num(2.0))
        return nodes.BinOp("^", nodes.Call("abs", (a,)), nodes.Num(0.5))
    if kind == "abs":
        return nodes.Call("abs", (a,))
    if kind == "sqrt":
        return nodes.Call("sqrt", (nodes.Call("abs", (a,)),))
    if kind == "exp":  # exp(min(a, 5)) stays moderate
        return nodes.Call("exp", (nodes.Call("min", (a, nodes.Num(5.0))),))
    if kind == "log":
        return nodes.Call("log", (nodes.BinOp("+", one, nodes.Call("abs", (a,))),))
    return nodes.Call(kind, (a, *draw(st.lists(sub, min_size=0, max_size=2))))


@st.composite
def smooth_expressions(draw: st.DrawFn, names: tuple[str, ...] = SIGNALS, depth: int = 2) -> Expr:
    """Differentiable expressions (no abs, min, max, sqrt), for finite-difference checks."""
    if depth == 0 or draw(st.integers(0, 2)) == 0:
        if draw(st.integers(0, 2)):
            return nodes.Var(draw(st.sampled_from(names)))
        return nodes.Num(draw(st.floats(-3, 3, allow_nan=False)))
    sub = smooth_expressions(names, depth - 1)
    a = draw(sub)
    kind = draw(st.sampled_from(("neg", "+", "-", "*", "square", "exp")))
    if kind == "neg":
        return nodes.Neg(a)
    if kind == "square":
        return nodes.BinOp("^", a, nodes.Num(2.0))
    if kind == "exp":
        return nodes.Call("exp", (nodes.BinOp("/", a, nodes.Num(4.0)),))
    return nodes.BinOp(kind, a, draw(sub))


# --------------------------------------------------------------------------- formulas

UNARY = (nodes.Not, nodes.Next, nodes.Eventually, nodes.Always)
BINARY = (nodes.Implies, nodes.Until, nodes.Then)
NARY = (nodes.And, nodes.Or)
ALL_OPERATORS = UNARY + BINARY + NARY


@st.composite
def predicates(draw: st.DrawFn, names: tuple[str, ...] = SIGNALS,
               exprs: st.SearchStrategy[Expr] | None = None) -> nodes.Predicate:
    """``lhs op rhs``; usually a signal against a number, sometimes arithmetic on both sides."""
    exprs = safe_expressions(names) if exprs is None else exprs
    op = draw(st.sampled_from(COMPARISONS))
    if draw(st.integers(0, 2)) == 0:
        return nodes.Predicate(draw(exprs), op, draw(exprs))
    return nodes.Predicate(nodes.Var(draw(st.sampled_from(names))), op, nodes.Num(draw(small_numbers())))


@st.composite
def formulas(
    draw: st.DrawFn,
    names: tuple[str, ...] = SIGNALS,
    max_depth: int = 5,
    min_depth: int = 0,
    operators: tuple[type[Formula], ...] = ALL_OPERATORS,
    constants: bool = True,
    leaves: st.SearchStrategy[Formula] | None = None,
) -> Formula:
    """A formula over ``names`` whose operator nesting lies in [min_depth, max_depth].

    ``operators`` restricts the node classes (the rtamt fragment, temporal-free left
    operands of U...); ``leaves`` replaces the default predicates and constants.
    """
    if leaves is None:
        leaves = predicates(names)
        if constants:
            leaves = st.one_of(leaves, leaves, leaves, st.builds(nodes.Constant, st.booleans()))
    if max_depth == 0 or (min_depth <= 0 and draw(st.integers(0, 3)) == 0):
        return draw(leaves)

    def sub(lo: int = min_depth - 1) -> st.SearchStrategy[Formula]:
        return formulas(names, max_depth - 1, lo, operators, constants, leaves)

    op = draw(st.sampled_from(operators))
    if op in UNARY:
        return op(draw(sub()))
    if op in NARY:
        first = draw(sub())
        rest = draw(st.lists(sub(0), min_size=1, max_size=2))
        return op((first, *rest))
    # binary: the minimum depth is carried by either side
    if draw(st.booleans()):
        return op(draw(sub()), draw(sub(0)))
    return op(draw(sub(0)), draw(sub()))


def depth(formula: Formula) -> int:
    """Operator nesting depth (a leaf has depth 0)."""
    return 0 if not formula.children else 1 + max(depth(c) for c in formula.children)


# --------------------------------------------------------------------------- traces


def _values(integers: bool) -> st.SearchStrategy[float]:
    if integers:  # ties between signals and thresholds: exercises < against <=
        return st.integers(-4, 4).map(float)
    return st.floats(-10, 10, allow_nan=False, allow_infinity=False)


@st.composite
def traces(draw: st.DrawFn, names: tuple[str, ...] = SIGNALS, min_length: int = 1, max_length: int = 7,
           batch: int | None = None, rescale: bool = True) -> dict[str, np.ndarray]:
    """A trace over ``names``: arrays ``(T,)``, or ``(N, T)`` with ``N = batch``.

    Values lie in [-10, 10]; with ``rescale`` a trace is sometimes scaled by 1e-3 or 1e4.
    """
    length = draw(st.integers(min_length, max_length))
    shape = (length,) if batch is None else (batch, length)
    integers = draw(st.booleans())
    # mostly unit scale (values near the formulas' thresholds), sometimes tiny or huge
    scale = 1.0 if integers or not rescale else draw(st.sampled_from((1.0, 1.0, 1.0, 1e-3, 1e4)))
    size = math.prod(shape)
    return {
        name: scale * np.array(draw(st.lists(_values(integers), min_size=size, max_size=size))).reshape(shape)
        for name in names
    }


@st.composite
def batched_traces(draw: st.DrawFn, names: tuple[str, ...] = SIGNALS, max_length: int = 7,
                   max_batch: int = 3, rescale: bool = True) -> dict[str, np.ndarray]:
    """A batch of 1 … ``max_batch`` trajectories of one length."""
    return draw(traces(names, max_length=max_length, batch=draw(st.integers(1, max_batch)), rescale=rescale))


def rho_maxes() -> st.SearchStrategy[float]:
    """``rho_max``: infinite (the default) or a finite positive bound."""
    return st.one_of(st.just(math.inf), st.floats(0.5, 100.0))


def betas() -> st.SearchStrategy[float]:
    """Smoothing sharpness from 0.1 to 1e6, with the usual round values over-weighted."""
    return st.one_of(st.sampled_from(BETAS), st.floats(0.1, 1e6))
