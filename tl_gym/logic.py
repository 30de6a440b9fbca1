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

from tl_gym.tltl import ast as nodes
from tl_gym.tltl.ast import Expr, ExprLike, Formula, as_expr

TRUE = nodes.Constant(True)
FALSE = nodes.Constant(False)


def signal(name: str) -> nodes.Var:
    """A signal of the trace, by name; compare it to build predicates (``signal("x") < 3``)."""
    return nodes.Var(name)


def signals(names: str) -> tuple[nodes.Var, ...]:
    """Several signals from a space-separated string: ``x, y = signals("x y")``."""
    return tuple(nodes.Var(n) for n in names.split())


def F(phi: Formula) -> Formula:
    """Eventually φ."""
    return nodes.Eventually(phi)


def G(phi: Formula) -> Formula:
    """Always φ."""
    return nodes.Always(phi)


def X(phi: Formula) -> Formula:
    """Next φ (−ρ_max at the last state)."""
    return nodes.Next(phi)


def U(phi: Formula, psi: Formula) -> Formula:
    """φ until ψ."""
    return nodes.Until(phi, psi)


def T(phi: Formula, psi: Formula) -> Formula:
    """φ then ψ."""
    return nodes.Then(phi, psi)


def implies(phi: Formula, psi: Formula) -> Formula:
    """φ → ψ (also written ``phi >> psi``)."""
    return nodes.Implies(phi, psi)


def all_of(*phis: Formula) -> Formula:
    """Conjunction of two or more formulas (one n-ary node)."""
    return nodes.And(phis)


def any_of(*phis: Formula) -> Formula:
    """Disjunction of two or more formulas (one n-ary node)."""
    return nodes.Or(phis)


def not_(phi: Formula) -> Formula:
    """¬φ (also written ``~phi``)."""
    return nodes.Not(phi)


def sqrt(e: ExprLike) -> Expr:
    """Square root inside a predicate."""
    return nodes.Call("sqrt", (as_expr(e),))


def exp(e: ExprLike) -> Expr:
    """Exponential inside a predicate."""
    return nodes.Call("exp", (as_expr(e),))


def log(e: ExprLike) -> Expr:
    """Natural logarithm inside a predicate."""
    return nodes.Call("log", (as_expr(e),))


def minimum(*es: ExprLike) -> Expr:
    """Exact minimum of expressions inside a predicate (``min`` in the text syntax)."""
    return nodes.Call("min", tuple(as_expr(e) for e in es))


def maximum(*es: ExprLike) -> Expr:
    """Exact maximum of expressions inside a predicate (``max`` in the text syntax)."""
    return nodes.Call("max", tuple(as_expr(e) for e in es))


__all__ = [
    "TRUE", "FALSE", "signal", "signals", "F", "G", "X", "U", "T", "implies", "all_of", "any_of",
    "not_", "sqrt", "exp", "log", "minimum", "maximum", "Formula",
]
