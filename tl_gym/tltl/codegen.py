"""Python source written at construction: formulas on one state, and monitor states, as flat functions.

The online monitor (`tl_gym.tltl.online`, through `tl_gym.tltl.windowed`) judges small formulas
on one state, or on a window of a few states, several times per env step. As nested closures
(one call per operator and per predicate, a list per connective) that costs several times the
arithmetic; the same formula written out as one Python expression, e.g.
``min(s['x'] - 210.0, 240.0 - s['x'])`` for ``x > 210 & x < 240``, and compiled once, does only
the arithmetic. `CodeWriter` collects such expressions and the objects they read, and compiles
them into functions. The Markov view uses it too: the monitor's nodes write their state's floats
as expressions over their own attributes (`tl_gym.tltl.online.PrefixMonitor.state_source`),
compiled into the view's encoder.

What is written out computes the same floats as the closures it replaces, in the same order
(the connectives' forms are `tl_gym.tltl.operators.connective_source`, tested against their
rules). A predicate whose arithmetic can be undefined or non-finite (``/ ^``, functions) is
not written out: the expression calls its closure, which names the predicate in its error; and
an arithmetic error anywhere in a written formula (an int signal overflowing a float) reruns it
through the closures, so that error names its predicate too.
Formulas nested deeper than `MAX_WRITTEN_DEPTH` keep their closures (CPython's parser bounds
the nesting of one expression).

Example:
    >>> from tl_gym import parse
    >>> code = CodeWriter()
    >>> source = state_formula_source(parse("x > 210 & x < 240"), 10.0, "s", code, checked=None)
    >>> source
    "min((s['x'] - 210.0), (240.0 - s['x']))"
    >>> code.scalar_function("rho", "s", source)({"x": 225.0})
    15.0
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from tl_gym.tltl import ast as nodes
from tl_gym.tltl import operators
from tl_gym.tltl.ast import Expr, Formula, height
from tl_gym.tltl.expressions import can_be_non_finite

Checked = Callable[[nodes.Predicate], Callable[[Mapping[str, float]], float]]  # a predicate's checking closure

#: Formulas whose operator depth plus the height of their deepest expression exceed this keep their
#: closures: the written expression nests about one parenthesis per level, and CPython's tokenizer
#: refuses 200 levels.
MAX_WRITTEN_DEPTH = 40


class CodeWriter:
    """Python expressions, the objects they read, and local variables, compiled into functions.

    Args:
        prefix: the names this writer makes start with (so that another writer's stay apart).
    """

    def __init__(self, prefix: str = "_m"):
        self.prefix = prefix
        self.namespace: dict[str, Any] = {}
        self.lines: list[str] = []  # statements before the returned expression: `name = expression`
        self._names: dict[int, str] = {}

    def bind(self, obj: Any) -> str:
        """The name under which the written code reads ``obj`` (one name per object)."""
        if id(obj) not in self._names:
            self._names[id(obj)] = f"{self.prefix}{len(self._names)}"
            self.namespace[self._names[id(obj)]] = obj
        return self._names[id(obj)]

    def local(self, expression: str) -> str:
        """A local variable holding ``expression``, computed once before the returned expression."""
        name = f"{self.prefix}_{len(self.lines)}"
        self.lines.append(f"{name} = {expression}")
        return name

    def function(self, name: str, arguments: str, items: list[str]) -> Callable[..., list[float]]:
        """``def name(arguments): <lines>; return [items]``, compiled in this writer's namespace."""
        return self.scalar_function(name, arguments, f"[{', '.join(items)}]")

    def scalar_function(self, name: str, arguments: str, expression: str,
                        fallback: Callable[..., Any] | None = None) -> Callable[..., Any]:
        """``def name(arguments): <lines>; return expression``, compiled in this writer's namespace.

        With ``fallback``, an arithmetic error (ValueError, ZeroDivisionError, OverflowError, FloatingPointError) in the
        expression returns ``fallback(arguments)`` instead: the closures, whose error names the culprit.
        """
        body = "".join(f"    {line}\n" for line in self.lines)
        if fallback is None:
            source = f"def {name}({arguments}):\n{body}    return {expression}\n"
        else:  # a try block costs nothing on CPython 3.11 until something is raised
            source = (f"def {name}({arguments}):\n{body}    try:\n        return {expression}\n"
                      f"    except (ValueError, ZeroDivisionError, OverflowError, FloatingPointError):\n"
                      f"        return {self.bind(fallback)}({arguments})\n")
        scope = dict(self.namespace)
        exec(compile(source, f"<tl_gym {name}>", "exec"), scope)
        return scope[name]


def writable(formula: Formula) -> bool:
    """Whether `state_formula_source` and `window_formula_source` write ``formula`` out (shallow enough)."""
    deepest_expression = max((height(p.lhs) + height(p.rhs) for p in formula.walk() if isinstance(p, nodes.Predicate)),
                             default=0)
    return formula.depth + deepest_expression <= MAX_WRITTEN_DEPTH


def state_formula_source(formula: Formula, rho_max: float, state: str, code: CodeWriter,
                         checked: Checked | None) -> str:
    """The robustness of a temporal-free ``formula`` on the state ``state`` (an expression), as an expression.

    A predicate whose arithmetic can be undefined or non-finite is called through ``checked(predicate)``,
    a function of the state that raises an error naming it (None: there is no such predicate).
    """
    if isinstance(formula, nodes.Constant):
        return code.bind(float(rho_max) if formula.value else -float(rho_max))
    if isinstance(formula, nodes.Predicate):
        if can_be_non_finite(formula.lhs) or can_be_non_finite(formula.rhs):
            if checked is None:
                raise ValueError(f"{formula} needs a checking closure (checked=None)")
            return f"{code.bind(checked(formula))}({state})"
        lhs, rhs = _expression_source(formula.lhs, state), _expression_source(formula.rhs, state)
        return operators.margin_source(formula.op, lhs, rhs)
    if isinstance(formula, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        parts = [state_formula_source(c, rho_max, state, code, checked) for c in formula.children]
        return operators.connective_source(type(formula), parts)
    raise TypeError(f"{type(formula).__name__} is temporal; state_formula_source takes temporal-free formulas")


def window_formula_source(formula: Formula, rho_max: float, code: CodeWriter, checked: Checked | None,
                          offset: int = 0) -> str:
    """The robustness at ``w[i + offset]`` of a formula with bounded lookahead, as an expression in ``w`` and ``i``.

    ``X φ`` past the window's end is −ρ_max, as in `tl_gym.tltl.windowed.compile_window_formula`.
    """
    if not formula.is_temporal:
        return state_formula_source(formula, rho_max, f"w[i + {offset}]" if offset else "w[i]", code, checked)
    if isinstance(formula, nodes.Next):
        inner = window_formula_source(formula.child, rho_max, code, checked, offset + 1)
        return f"({inner} if i + {offset + 1} < len(w) else {code.bind(-float(rho_max))})"
    if isinstance(formula, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        parts = [window_formula_source(c, rho_max, code, checked, offset) for c in formula.children]
        return operators.connective_source(type(formula), parts)
    raise TypeError(f"{type(formula).__name__} has no bounded lookahead")


def _expression_source(expr: Expr, state: str) -> str:
    """Plain arithmetic (``+ - *``, unary minus) over signals and numbers, as the closures compute it."""
    if isinstance(expr, nodes.Var):
        return f"{state}[{expr.name!r}]"
    if isinstance(expr, nodes.Num):
        return repr(expr.value)
    if isinstance(expr, nodes.Neg):
        return f"(-{_expression_source(expr.operand, state)})"
    if isinstance(expr, nodes.BinOp) and expr.op in "+-*":
        return f"({_expression_source(expr.left, state)} {expr.op} {_expression_source(expr.right, state)})"
    raise TypeError(f"{expr} is not plain arithmetic")  # can_be_non_finite screens these out


