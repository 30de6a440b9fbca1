"""Evaluation of the arithmetic inside predicates, on numpy arrays.

Every function here walks the expression in post-order on an explicit stack (the order
is computed once per expression, `postorder`), so a sum of 10,000 terms or 10,000 nested
minus signs evaluates, differentiates and is bounded without Python recursion.
"""

from __future__ import annotations

import functools
import math
from functools import reduce
from typing import Any

import numpy as np

from tl_gym.tltl.ast import BinOp, Call, Expr, Neg, Num, Var, parts

_FUNCTIONS: dict[str, Any] = {
    "abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log,
    "min": np.minimum, "max": np.maximum, "pow": np.power,
}


def postorder(expr: Expr) -> tuple[Expr, ...]:
    """Every node of ``expr``, operands before their operation (one entry per occurrence).

    Computed once per expression and kept on it (expressions are immutable).
    """
    cached = expr.__dict__.get("_postorder")
    if cached is not None:
        return cached
    order: list[Expr] = []
    stack: list[tuple[Expr, bool]] = [(expr, False)]
    while stack:
        node, expanded = stack.pop()
        if expanded:
            order.append(node)
        else:
            stack.append((node, True))
            stack.extend((child, False) for child in reversed(parts(node)))
    result = tuple(order)
    object.__setattr__(expr, "_postorder", result)
    return result


def _unknown(e: Expr) -> TypeError:
    return TypeError(f"no evaluation rule for expression node {type(e).__name__}")


def evaluate_expression(expr: Expr, signals: dict[str, Any]) -> Any:
    """Value of ``expr`` on the ``(N, T)`` numpy signals.

    Numbers are numpy scalars so that they broadcast against the signals (and 0/0 is
    NaN, refused later, not ZeroDivisionError). ``min``/``max`` inside a predicate are
    the exact ones: they are part of the predicate's function f(s), not of the
    robustness (smoothing leaves them alone).
    """
    fns = _FUNCTIONS
    values: list[Any] = []  # operands awaiting their operation
    for e in postorder(expr):
        if isinstance(e, Var):
            values.append(signals[e.name])
        elif isinstance(e, Num):
            values.append(np.float64(e.value))
        elif isinstance(e, Neg):
            values[-1] = -values[-1]
        elif isinstance(e, BinOp):
            b = values.pop()
            values[-1] = _arithmetic(e.op, values[-1], b, fns)
        elif isinstance(e, Call):
            args = values[len(values) - len(e.args):]
            del values[len(values) - len(e.args):]
            values.append(_call(e.func, args, fns))
        else:
            raise _unknown(e)
    return values[0]


def _arithmetic(op: str, a: Any, b: Any, fns: dict[str, Any]) -> Any:
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if op == "/":
        return a / b
    if _is_square(a, b):
        return a * a  # what pow does, without its general path
    return fns["pow"](np.float64(a) if isinstance(a, float) else a, b)


def _call(func: str, args: list[Any], fns: dict[str, Any]) -> Any:
    if func in ("min", "max"):
        return reduce(fns[func], args) if len(args) > 1 else args[0]
    arg = args[0]
    if isinstance(arg, float):
        arg = np.float64(arg)
    return fns[func](arg)


GradientTerm = tuple[str, Any, float, bool]  # (signal, array, coefficient, owned): coefficient · array

# A node's backward rule: (grad, coef, owned) -> what to send to each operand, in order, as
# (operand's rule, grad, coef, owned); a signal's rule is its name.
_Back = Any


def evaluate_with_gradient(expr: Expr, signals: dict[str, np.ndarray]) -> tuple[Any, Any]:
    """Value of ``expr`` on numpy signals, and its vector-Jacobian product.

    The second result maps ``(grad, coef, owned)`` — the upstream gradient is ``coef · grad``;
    ``owned``: nothing else holds ``grad``, so it may be overwritten — to a list of terms
    ``(signal, array, coefficient, owned)``, one per use of a signal, whose sum
    ``coefficient · array`` is the gradient wrt the signals. Scalar factors (β, the 2 of a
    square, the ½ of a square root) travel as coefficients instead of whole-array passes.

    ``min``/``max`` pass the gradient to the first operand attaining the extreme;
    ``abs`` has gradient 0 at 0 (subgradients, as torch does).

    Both passes run on explicit stacks: the forward pass in post-order, the backward pass
    from the root down, each operation's operands in the order its rule lists them.
    """
    # Intermediate arrays that nothing reads again, by id (held here, so an id is never reused while
    # listed): the operation that consumes one may write its result into it.
    spare: dict[int, np.ndarray] = {}

    def release(value: Any) -> None:
        if isinstance(value, np.ndarray):
            spare[id(value)] = value

    def into(*operands: Any, shape: tuple[int, ...], keep: tuple[Any, ...] = ()) -> Any:
        """A spare operand of the result's shape to write the result into (None: a new array)."""
        for operand in operands:
            if (id(operand) in spare and operand.shape == shape and operand.dtype == np.float64
                    and not any(operand is k for k in keep)):
                return spare.pop(id(operand))
        return None

    def negation(value: Any, back: _Back | None) -> tuple[Any, _Back | None]:
        out = np.negative(value, out=into(value, shape=np.shape(value)))
        release(out)
        if back is None:
            return out, None
        return out, lambda g, c, o: [(back, g, -c, o)]

    def binary(e: BinOp, a: Any, back_a: _Back | None, b: Any, back_b: _Back | None) -> tuple[Any, _Back | None]:
        if back_a is None and back_b is None:
            return _apply(e.op, a, b), None
        scalar_a, scalar_b = np.ndim(a) == 0, np.ndim(b) == 0
        # what this operation's backward reads: the other factor of a product, the divisor, the base
        keep = {"*": (b if back_a else None, a if back_b else None), "/": (b,), "+": (), "-": ()}.get(e.op, (a, b))
        out = _apply(e.op, a, b, into(a, b, shape=np.broadcast_shapes(np.shape(a), np.shape(b)), keep=keep))
        if back_b is None or e.op in ("+", "-", "*"):  # a quotient's or a power's backward wrt b reads the result
            release(out)

        def back(grad: Any, coef: float, owned: bool) -> list[Any]:
            both = back_a is not None and back_b is not None  # then the two sides share ``grad``
            sends: list[Any] = []
            if e.op in ("+", "-"):
                if back_a is not None:
                    sends.append((back_a, grad, coef, owned and not both))
                if back_b is not None:
                    sends.append((back_b, grad, coef if e.op == "+" else -coef, owned and not both))
            elif e.op == "*":
                if back_a is not None:
                    if scalar_b:
                        sends.append((back_a, grad, coef * float(b), owned and not both))
                    else:
                        sends.append((back_a, _on_grad(np.multiply, grad, b, owned and not both), coef, True))
                if back_b is not None:
                    if scalar_a:
                        sends.append((back_b, grad, coef * float(a), owned))
                    else:
                        sends.append((back_b, _on_grad(np.multiply, grad, a, owned), coef, True))
            elif e.op == "/":
                if back_b is not None:  # d(a/b)/db = −out / b
                    slope = _on_grad(np.divide, _on_grad(np.multiply, grad, out, False), b, True)
                    sends.append((back_b, slope, -coef, True))
                if back_a is not None:
                    if scalar_b:
                        sends.append((back_a, grad, coef / float(b), owned))
                    else:
                        sends.append((back_a, _on_grad(np.divide, grad, b, owned), coef, True))
            else:  # power
                if back_b is not None:  # d(a^b)/db = out · log a
                    slope = _on_grad(np.multiply, grad, out, False)
                    sends.append((back_b, _on_grad(np.multiply, slope, np.log(a), True), coef, True))
                if back_a is not None:
                    if _is_square(a, b):
                        sends.append((back_a, _on_grad(np.multiply, grad, a, owned), 2.0 * coef, True))
                    else:
                        sends.append((back_a, _on_grad(np.multiply, grad, b * np.power(a, b - 1.0), owned), coef, True))
            return sends

        return out, back

    def call(e: Call, values: list[Any], backs: list[_Back | None]) -> tuple[Any, _Back | None]:
        if e.func in ("min", "max"):
            stacked = np.stack(np.broadcast_arrays(*values))
            pick = stacked.argmin(0) if e.func == "min" else stacked.argmax(0)
            out = np.take_along_axis(stacked, pick[None], 0)[0]
        else:
            x = values[0]
            x = np.float64(x) if isinstance(x, float) else x
            reads_out = e.func in ("sqrt", "exp")  # their backward reads the result, the others the argument
            target = into(x, shape=np.shape(x)) if reads_out else None
            out = {"abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log}[e.func](x, out=target)
        if e.func in ("min", "max") or not reads_out:
            release(out)
        if all(b is None for b in backs):
            return out, None

        def back(grad: Any, coef: float, owned: bool) -> list[Any]:
            if e.func in ("min", "max"):
                return [(b_i, grad * (pick == i), coef, True) for i, b_i in enumerate(backs) if b_i is not None]
            x, back_x = values[0], backs[0]
            if e.func == "sqrt":
                return [(back_x, _on_grad(np.divide, grad, out, owned), 0.5 * coef, True)]
            if e.func == "exp":
                return [(back_x, _on_grad(np.multiply, grad, out, owned), coef, True)]
            if e.func == "log":
                return [(back_x, _on_grad(np.divide, grad, x, owned), coef, True)]
            return [(back_x, _on_grad(np.multiply, grad, np.sign(x), owned), coef, True)]  # abs

        return out, back

    values: list[Any] = []  # operands awaiting their operation, and their backward rules
    backs: list[_Back | None] = []
    with np.errstate(all="ignore"):  # undefined arithmetic is the caller's to find and refuse
        for e in postorder(expr):
            if isinstance(e, Var):
                values.append(signals[e.name])
                backs.append(e.name)
            elif isinstance(e, Num):
                values.append(np.float64(e.value))
                backs.append(None)
            elif isinstance(e, Neg):
                values[-1], backs[-1] = negation(values[-1], backs[-1])
            elif isinstance(e, BinOp):
                b, back_b = values.pop(), backs.pop()
                values[-1], backs[-1] = binary(e, values[-1], backs[-1], b, back_b)
            elif isinstance(e, Call):
                k = len(values) - len(e.args)
                value, back = call(e, values[k:], backs[k:])
                del values[k:], backs[k:]
                values.append(value)
                backs.append(back)
            else:
                raise _unknown(e)
    value, root = values[0], backs[0]

    def gradient(grad: Any, coef: float = 1.0, owned: bool = False) -> list[GradientTerm]:
        terms: list[GradientTerm] = []
        pending = [] if root is None else [(root, grad, coef, owned)]
        with np.errstate(all="ignore"):
            while pending:
                back, g, c, o = pending.pop()
                if isinstance(back, str):  # a signal
                    terms.append((back, g, c, o))
                else:  # its operands, first listed first (each one's whole sub-tree before the next)
                    pending.extend(reversed(back(g, c, o)))
        return terms

    return value, gradient


def _apply(op: str, a: Any, b: Any, out: np.ndarray | None = None) -> Any:
    """``a op b`` for numpy operands (numbers stay numpy scalars: 0/0 is NaN, not an exception)."""
    if op == "+":
        return np.add(a, b, out=out)
    if op == "-":
        return np.subtract(a, b, out=out)
    if op == "*":
        return np.multiply(a, b, out=out)
    if op == "/":
        return np.divide(a, b, out=out)
    if _is_square(a, b):
        return np.multiply(a, a, out=out)
    return np.power(np.float64(a) if isinstance(a, float) else a, b, out=out)


def _is_square(base: Any, exponent: Any) -> bool:
    """Whether ``base ^ exponent`` is an array squared (x·x is exact: pow's result, faster)."""
    return np.ndim(base) > 0 and np.ndim(exponent) == 0 and exponent == 2.0


def _on_grad(ufunc: np.ufunc, grad: Any, other: Any, owned: bool) -> Any:
    """``ufunc(grad, other)`` (a product or quotient), in place when ``grad`` is owned and has the result's shape."""
    if owned and np.shape(grad) == np.broadcast_shapes(np.shape(grad), np.shape(other)):
        return ufunc(grad, other, out=grad)
    return ufunc(grad, other)


def can_be_non_finite(expr: Expr) -> bool:
    """Whether finite signals can obviously give a non-finite value (division, power, functions).

    Sums and products can still overflow; evaluators that must refuse non-finite values
    check the values themselves.
    """
    plain = (Var, Num, Neg, BinOp)
    return any(not isinstance(e, plain) or (isinstance(e, BinOp) and e.op in ("/", "^")) for e in postorder(expr))


def value_range(expr: Expr, magnitudes: dict[str, float]) -> tuple[float, float] | None:
    """An interval holding every value of ``expr`` when each signal s has |s| ≤ ``magnitudes[s]``.

    None when the arithmetic may be undefined or overflow there (a division by an interval
    holding 0, the log or square root of one reaching below 0, a general power, a bound
    beyond 1e300). Evaluators use it to skip the NaN and range checks of a predicate whose
    values are known to be finite, e.g. ``sqrt((x - 150)^2 + (y - 150)^2)`` on finite signals.
    """
    with np.errstate(all="ignore"):
        out = _interval(expr, magnitudes)
    if out is None or not (-1e300 < out[0] <= out[1] < 1e300):
        return None
    return out


Interval = tuple[float, float]


def _interval(expr: Expr, magnitudes: dict[str, float]) -> Interval | None:
    """Interval arithmetic over ``expr`` in post-order (None: unknown, maybe undefined)."""
    stack: list[Interval | None] = []
    for e in postorder(expr):
        if isinstance(e, Var):
            m = magnitudes[e.name]
            stack.append((-m, m))
        elif isinstance(e, Num):
            stack.append((e.value, e.value))
        elif isinstance(e, Neg):
            inner = stack[-1]
            stack[-1] = None if inner is None else (-inner[1], -inner[0])
        elif isinstance(e, BinOp):
            b = stack.pop()
            a = stack[-1]
            stack[-1] = None if a is None or b is None else _binary_interval(e.op, a, b)
        elif isinstance(e, Call):
            k = len(stack) - len(e.args)
            args = stack[k:]
            del stack[k:]
            stack.append(None if any(a is None for a in args) else _call_interval(e.func, args))  # type: ignore[arg-type]
        else:
            return None
    return stack[0]


def _binary_interval(op: str, a: Interval, b: Interval) -> Interval | None:
    if op == "+":
        return a[0] + b[0], a[1] + b[1]
    if op == "-":
        return a[0] - b[1], a[1] - b[0]
    if op == "*":
        corners = [x * y for x in a for y in b]
        return min(corners), max(corners)
    if op == "/":
        if b[0] <= 0.0 <= b[1]:
            return None
        corners = [x / y for x in a for y in b]
        return min(corners), max(corners)
    if b == (2.0, 2.0):  # a square
        top = max(a[0] * a[0], a[1] * a[1])
        return (0.0 if a[0] <= 0.0 <= a[1] else min(a[0] * a[0], a[1] * a[1])), top
    return None


def _call_interval(func: str, args: list[Interval]) -> Interval | None:
    if func in ("min", "max"):
        pick = min if func == "min" else max
        return pick(a[0] for a in args), pick(a[1] for a in args)
    (low, high), = args
    if func == "abs":
        return (0.0 if low <= 0.0 <= high else min(abs(low), abs(high))), max(abs(low), abs(high))
    if func == "sqrt":
        return None if low < 0.0 else (math.sqrt(low), math.sqrt(high))
    if func == "log":
        return None if low <= 0.0 else (math.log(low), math.log(high))
    if func == "exp":
        return None if high > 690.0 else (math.exp(low), math.exp(high))
    return None


@functools.lru_cache(maxsize=4096)
def margin_bound(lhs: Expr, rhs: Expr, magnitudes: tuple[tuple[str, float], ...]) -> float:
    """A bound on |lhs − rhs| from the signals' magnitudes (``(name, max |value|)`` pairs); inf if unknown.

    Cached: a formula's predicates are bounded once per batch, not once per group of trajectories.
    """
    sides = [value_range(side, dict(magnitudes)) for side in (lhs, rhs)]
    if any(side is None for side in sides):
        return math.inf
    return sum(max(abs(low), abs(high)) for low, high in sides)  # type: ignore[misc]
