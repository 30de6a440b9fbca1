"""Formulas judged on one state or on a short window of states, compiled to Python functions.

The online monitor's nodes (`tl_gym.tltl.online_nodes`) judge their formulas' temporal-free and
``X``-only parts several times per env step, so those parts are compiled once, at construction:

* `compile_state_formula`: a temporal-free formula's robustness on one state, as a function of
  that state (also used by `tl_gym.shaping` and `tl_gym.tltl.invariants`);
* `compile_window_formula`: the robustness at ``window[i]`` of a formula with bounded lookahead
  (a Boolean combination of ``X``'s over temporal-free formulas; `lookahead` says how many
  states after a position decide it), ``X`` past the window's end being −ρ_max.

Each is written out as one Python expression when it is shallow enough (`tl_gym.tltl.codegen`:
fastest), else built as nested closures up to `_CLOSURE_DEPTH`, and beyond that evaluated by a
loop over the expression or by the exact evaluator on the window's states: no depth recurses.

Pure numpy and the standard library: no Gymnasium here.

Example:
    >>> from tl_gym import parse
    >>> compile_state_formula(parse("x > 2 & y < 1"), float("inf"))({"x": 3.0, "y": 0.5})
    0.5
    >>> lookahead(parse("x > 0 | X X y > 0"))
    2
    >>> compile_window_formula(parse("X x > 2"), float("inf"))([{"x": 0.0}, {"x": 5.0}], 0)
    3.0
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np

from tl_gym.errors import TraceError
from tl_gym.tltl import ast as nodes
from tl_gym.tltl import operators
from tl_gym.tltl.ast import Expr, Formula, height
from tl_gym.tltl.codegen import CodeWriter, state_formula_source, window_formula_source, writable
from tl_gym.tltl.expressions import can_be_non_finite, evaluate_expression, postorder

State = Mapping[str, float]
StateFn = Callable[[State], float]
WindowFn = Callable[[list, int], float]  # (states s_k … s_{k+d} (fewer at the trace's end), index) -> value


# --------------------------------------------------------------------------- temporal-free parts, on one state


# Closures nest as deep as the formula; beyond this depth a loop over the nodes takes over
# (no recursion at any depth, a little slower per node).
_CLOSURE_DEPTH = 64


def _compile_expr(expr: Expr) -> StateFn:
    """A function computing ``expr`` on one state with Python floats."""
    if height(expr) > _CLOSURE_DEPTH:
        return _expression_loop(expr)
    return _expression_closure(expr)


def _expression_loop(expr: Expr) -> StateFn:
    """``expr`` on one state by the array evaluator's loop over its nodes in post-order (any depth)."""
    names = tuple(dict.fromkeys(e.name for e in postorder(expr) if isinstance(e, nodes.Var)))

    def value(s: State) -> float:
        with np.errstate(all="ignore"):
            return float(evaluate_expression(expr, {n: np.float64(s[n]) for n in names}))

    return value


def _expression_closure(expr: Expr) -> StateFn:
    """A closure computing ``expr`` on one state (recursion bounded by `_CLOSURE_DEPTH`)."""
    if isinstance(expr, nodes.Var):
        name = expr.name
        return lambda s: s[name]
    if isinstance(expr, nodes.Num):
        value = expr.value
        return lambda s: value
    if isinstance(expr, nodes.Neg):
        inner = _expression_closure(expr.operand)
        return lambda s: -inner(s)
    if isinstance(expr, nodes.BinOp):
        a, b = _expression_closure(expr.left), _expression_closure(expr.right)
        ops: dict[str, StateFn] = {
            "+": lambda s: a(s) + b(s),
            "-": lambda s: a(s) - b(s),
            "*": lambda s: a(s) * b(s),
            "/": lambda s: a(s) / b(s),
            "^": lambda s: math.pow(a(s), b(s)),
        }
        return ops[expr.op]
    if isinstance(expr, nodes.Call):
        args = [_expression_closure(arg) for arg in expr.args]
        if expr.func in ("min", "max"):
            reduce_ = min if expr.func == "min" else max

            def extremum(s: State) -> float:  # NaN from any operand, as numpy's and the offline evaluators'
                values = [f(s) for f in args]  # (Python's min and max drop a NaN that is not the first)
                result = reduce_(values)
                return result if all(v == v for v in values) else math.nan

            return extremum
        fn = {"abs": abs, "sqrt": math.sqrt, "exp": math.exp, "log": math.log}[expr.func]
        only = args[0]
        return lambda s: fn(only(s))
    raise TypeError(f"no evaluation rule for expression node {type(expr).__name__}")


def _compile_predicate(node: nodes.Predicate) -> StateFn:
    """The predicate's margin on one state, with the offline evaluators' arithmetic.

    Python's floats raise where numpy's give ±inf or NaN (``log(0)``, ``1 / 0``, ``exp(1000)``, ``(-8) ^ (1/3)``);
    on such a state the margin is recomputed with numpy, so that an operand may pass through ±inf on its way to a
    finite value (``max(log(x), -20)`` at ``x = 0``) and only a margin that ends NaN or infinite raises, as offline.
    """
    lhs, rhs = _compile_expr(node.lhs), _compile_expr(node.rhs)
    op = node.op
    checked = can_be_non_finite(node.lhs) or can_be_non_finite(node.rhs)
    numpy_lhs, numpy_rhs = _expression_loop(node.lhs), _expression_loop(node.rhs)
    not_finite = f"predicate {str(node)!r} is NaN or infinite at this state"

    def numpy_margin(s: State) -> float:  # checked whatever the arithmetic (a Python int beyond a float's range)
        with np.errstate(all="ignore"):
            v = float(operators.margin(op, numpy_lhs(s), numpy_rhs(s)))
        if not math.isfinite(v):
            raise TraceError(not_finite)
        return v

    def value(s: State) -> float:
        try:
            v = operators.margin(op, lhs(s), rhs(s))
        except (ValueError, ZeroDivisionError, OverflowError, FloatingPointError):  # rare: free until raised
            return numpy_margin(s)
        if checked and not math.isfinite(v):
            raise TraceError(not_finite)
        return v

    return value


def compile_state_formula(formula: Formula, rho_max: float) -> StateFn:
    """Robustness of a temporal-free formula on one state, as a function of that state."""
    if formula.is_temporal:
        temporal_nodes = (nodes.Next, nodes.Eventually, nodes.Always, nodes.Until, nodes.Then)
        temporal = next(n for n in formula.walk() if isinstance(n, temporal_nodes))
        raise TypeError(f"{type(temporal).__name__} is temporal; compile_state_formula takes temporal-free formulas")
    if formula.depth > _CLOSURE_DEPTH:
        window = _engine_window_formula(formula, rho_max)
        return lambda s: window([s], 0)
    if writable(formula):  # one expression, 2-3x faster (docs/results/online_monitor_speed.md)
        code = CodeWriter()
        return code.scalar_function("state_formula", "s",
                                    state_formula_source(formula, rho_max, "s", code, _compile_predicate),
                                    fallback=_state_closure(formula, rho_max))
    return _state_closure(formula, rho_max)


def _engine_window_formula(formula: Formula, rho_max: float) -> WindowFn:
    """Robustness at ``window[i]`` by the exact evaluator on the window's states from ``i`` on (any depth).

    The suffix is a trace of its own, judged at its first position as the offline evaluators judge one: ``X`` past
    its end is −ρ_max, as in `compile_window_formula`; a temporal-free part is evaluated at the suffix's first state
    alone, but an ``X``'s operand at every state of the suffix, as offline (docs/engine.md: formulas deeper than
    64 levels may raise where the shallow monitors do not).
    """
    names = formula.signals

    def value(window: list, i: int) -> float:
        if not names:  # a formula of constants still needs a length
            trace = {"_": np.zeros(len(window) - i)}
        else:
            trace = {n: np.array([float(state[n]) for state in window[i:]]) for n in names}
        return float(formula.robustness(trace, rho_max, backend="numpy"))  # no kernel compiled within an env step

    return value


def _state_closure(formula: Formula, rho_max: float) -> StateFn:
    """Nested closures for a temporal-free formula (recursion bounded by `_CLOSURE_DEPTH`)."""
    if isinstance(formula, nodes.Constant):
        value = float(rho_max) if formula.value else -float(rho_max)
        return lambda s: value
    if isinstance(formula, nodes.Predicate):
        return _compile_predicate(formula)
    if isinstance(formula, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        parts = [_state_closure(c, rho_max) for c in formula.children]
        combine = operators.CONNECTIVES[type(formula)]
        return lambda s: combine([p(s) for p in parts])
    raise TypeError(f"{type(formula).__name__} is temporal; compile_state_formula takes temporal-free formulas")


# --------------------------------------------------------------------------- windowed formulas


def lookahead(formula: Formula) -> int | None:
    """How many states after position k decide ``formula`` at k, if only ``X`` occurs in it.

    0 for a temporal-free formula, the nesting depth of ``X`` for a Boolean
    combination of ``X``'s over temporal-free formulas; None when ``F G U T`` occur.
    Computed bottom-up on an explicit stack (any depth).
    """
    return lookaheads_by_node(formula)[id(formula)]


def compile_window_formula(formula: Formula, rho_max: float) -> WindowFn:
    """Robustness at ``window[i]`` of a formula with bounded lookahead (see `lookahead`).

    ``X φ`` beyond the end of the window is −ρ_max, the value of ``X`` at the last state.
    """
    if formula.depth > _CLOSURE_DEPTH:
        if lookahead(formula) is None:
            raise TypeError(f"{type(formula).__name__} has no bounded lookahead")
        return _engine_window_formula(formula, rho_max)
    if writable(formula):
        code = CodeWriter()
        return code.scalar_function("window_formula", "w, i",
                                    window_formula_source(formula, rho_max, code, _compile_predicate),
                                    fallback=_window_closure(formula, rho_max))
    return _window_closure(formula, rho_max)


def _window_closure(formula: Formula, rho_max: float) -> WindowFn:
    """Nested closures for a formula with bounded lookahead (recursion bounded by `_CLOSURE_DEPTH`)."""
    if not formula.is_temporal:
        fn = _state_closure(formula, rho_max)
        return lambda w, i: fn(w[i])
    if isinstance(formula, nodes.Next):
        inner = _window_closure(formula.child, rho_max)
        bottom = -float(rho_max)
        return lambda w, i: inner(w, i + 1) if i + 1 < len(w) else bottom
    if isinstance(formula, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        parts = [_window_closure(c, rho_max) for c in formula.children]
        combine = operators.CONNECTIVES[type(formula)]
        return lambda w, i: combine([p(w, i) for p in parts])
    raise TypeError(f"{type(formula).__name__} has no bounded lookahead")


def lookaheads_by_node(formula: Formula) -> dict[int, int | None]:
    """`lookahead` of every node, by identity, in one bottom-up pass."""
    done: dict[int, int | None] = {}
    for node in reversed(formula.walk()):  # children before parents
        if id(node) in done:
            continue
        if not node.is_temporal:
            done[id(node)] = 0
        elif isinstance(node, (nodes.Next, nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
            depths = [done[id(c)] for c in node.children]
            done[id(node)] = None if any(d is None for d in depths) else (
                max(depths) + (1 if isinstance(node, nodes.Next) else 0)  # type: ignore[type-var]
            )
        else:
            done[id(node)] = None
    return done
