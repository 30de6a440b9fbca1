"""Python builders for TLTL formulas: the same `Formula` objects `parse` returns.

Example:
    >>> from tl_gym.logic import F, G, signal
    >>> x, y = signal("x"), signal("y")
    >>> phi = F((x > 5) & (x < 10)) & G(abs(y) < 1)
    >>> print(phi)
    F (x > 5 & x < 10) & G abs(y) < 1
    >>> from tl_gym import parse
    >>> parse(str(phi)) == phi
    True
"""

from __future__ import annotations

from tl_gym.tltl.ast import (
    Always,
    And,
    Call,
    Constant,
    Eventually,
    Expr,
    ExprLike,
    Formula,
    Implies,
    Next,
    Not,
    Or,
    Then,
    Until,
    Var,
    as_expr,
)

TRUE = Constant(True)
FALSE = Constant(False)


def signal(name: str) -> Var:
    """A signal of the trace, by name; compare it to build predicates (``signal("x") < 3``)."""
    return Var(name)


def signals(names: str) -> tuple[Var, ...]:
    """Several signals from a space-separated string: ``x, y = signals("x y")``."""
    return tuple(Var(n) for n in names.split())


def F(phi: Formula) -> Formula:
    """Eventually φ."""
    return Eventually(phi)


def G(phi: Formula) -> Formula:
    """Always φ."""
    return Always(phi)


def X(phi: Formula) -> Formula:
    """Next φ (−ρ_max at the last state)."""
    return Next(phi)


def U(phi: Formula, psi: Formula) -> Formula:
    """φ until ψ."""
    return Until(phi, psi)


def T(phi: Formula, psi: Formula) -> Formula:
    """φ then ψ."""
    return Then(phi, psi)


def implies(phi: Formula, psi: Formula) -> Formula:
    """φ → ψ (also written ``phi >> psi``)."""
    return Implies(phi, psi)


def all_of(*phis: Formula) -> Formula:
    """Conjunction of two or more formulas (one n-ary node)."""
    return And(phis)


def any_of(*phis: Formula) -> Formula:
    """Disjunction of two or more formulas (one n-ary node)."""
    return Or(phis)


def not_(phi: Formula) -> Formula:
    """¬φ (also written ``~phi``)."""
    return Not(phi)


def sqrt(e: ExprLike) -> Expr:
    """Square root inside a predicate."""
    return Call("sqrt", (as_expr(e),))


def exp(e: ExprLike) -> Expr:
    """Exponential inside a predicate."""
    return Call("exp", (as_expr(e),))


def log(e: ExprLike) -> Expr:
    """Natural logarithm inside a predicate."""
    return Call("log", (as_expr(e),))


def minimum(*es: ExprLike) -> Expr:
    """Exact minimum of expressions inside a predicate (``min`` in the text syntax)."""
    return Call("min", tuple(as_expr(e) for e in es))


def maximum(*es: ExprLike) -> Expr:
    """Exact maximum of expressions inside a predicate (``max`` in the text syntax)."""
    return Call("max", tuple(as_expr(e) for e in es))


__all__ = [
    "TRUE", "FALSE", "signal", "signals", "F", "G", "X", "U", "T", "implies", "all_of", "any_of",
    "not_", "sqrt", "exp", "log", "minimum", "maximum", "Formula",
]
