"""Evaluation of the arithmetic inside predicates, for numpy arrays and torch tensors."""

from __future__ import annotations

import functools
import math
from functools import reduce
from typing import Any

import numpy as np

from tl_gym.tltl.ast import BinOp, Call, Expr, Neg, Num, Var
from tl_gym.tltl.trace import is_torch


def _functions(sample: Any) -> dict[str, Any]:
    if is_torch(sample):
        import torch

        return {
            "abs": torch.abs, "sqrt": torch.sqrt, "exp": torch.exp, "log": torch.log,
            "min": torch.minimum, "max": torch.maximum, "pow": torch.pow,
        }
    return {
        "abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log,
        "min": np.minimum, "max": np.maximum, "pow": np.power,
    }


def evaluate_expression(expr: Expr, signals: dict[str, Any], sample: Any) -> Any:
    """Value of ``expr`` on the ``(N, T)`` signals; ``sample`` picks the array library.

    Numbers stay Python floats so that they broadcast against the signals.
    ``min``/``max`` inside a predicate are the exact ones: they are part of the
    predicate's function f(s), not of the robustness (smoothing leaves them alone).
    """
    fns = _functions(sample)

    def ev(e: Expr) -> Any:
        if isinstance(e, Var):
            return signals[e.name]
        if isinstance(e, Num):
            return np.float64(e.value)  # numpy division: 0/0 is NaN (refused later), not ZeroDivisionError
        if isinstance(e, Neg):
            return -ev(e.operand)
        if isinstance(e, BinOp):
            a, b = ev(e.left), ev(e.right)
            if e.op == "+":
                return a + b
            if e.op == "-":
                return a - b
            if e.op == "*":
                return a * b
            if e.op == "/":
                return a / b
            if _is_square(a, b):
                return a * a  # what pow does, without its general path
            return fns["pow"](np.float64(a) if isinstance(a, float) else a, b)
        if isinstance(e, Call):
            args = [ev(a) for a in e.args]
            if e.func in ("min", "max"):
                return reduce(fns[e.func], args) if len(args) > 1 else args[0]
            arg = args[0]
            if isinstance(arg, float):
                arg = np.float64(arg)
            return fns[e.func](arg)
        raise TypeError(f"no evaluation rule for expression node {type(e).__name__}")

    return ev(expr)


GradientTerm = tuple[str, Any, float, bool]  # (signal, array, coefficient, owned): coefficient · array


def evaluate_with_gradient(expr: Expr, signals: dict[str, np.ndarray]) -> tuple[Any, Any]:
    """Value of ``expr`` on numpy signals, and its vector-Jacobian product.

    The second result maps ``(grad, coef, owned)`` — the upstream gradient is ``coef · grad``;
    ``owned``: nothing else holds ``grad``, so it may be overwritten — to a list of terms
    ``(signal, array, coefficient, owned)``, one per use of a signal, whose sum
    ``coefficient · array`` is the gradient wrt the signals. Scalar factors (β, the 2 of a
    square, the ½ of a square root) travel as coefficients instead of whole-array passes.

    ``min``/``max`` pass the gradient to the first operand attaining the extreme;
    ``abs`` has gradient 0 at 0 (subgradients, as torch does).
    """
    _Back = Any  # (grad, coef, owned, terms) -> None

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

    def ev(e: Expr) -> tuple[Any, _Back | None]:
        if isinstance(e, Var):
            def back_var(grad: Any, coef: float, owned: bool, terms: list[GradientTerm]) -> None:
                terms.append((e.name, grad, coef, owned))
            return signals[e.name], back_var
        if isinstance(e, Num):
            return np.float64(e.value), None
        if isinstance(e, Neg):
            value, back = ev(e.operand)
            out = np.negative(value, out=into(value, shape=np.shape(value)))
            release(out)
            if back is None:
                return out, None
            return out, lambda g, c, o, t: back(g, -c, o, t)
        if isinstance(e, BinOp):
            return binary(e)
        if isinstance(e, Call):
            return call(e)
        raise TypeError(f"no evaluation rule for expression node {type(e).__name__}")

    def binary(e: BinOp) -> tuple[Any, _Back | None]:
        (a, back_a), (b, back_b) = ev(e.left), ev(e.right)
        if back_a is None and back_b is None:
            return _apply(e.op, a, b), None
        scalar_a, scalar_b = np.ndim(a) == 0, np.ndim(b) == 0
        # what this operation's backward reads: the other factor of a product, the divisor, the base
        keep = {"*": (b if back_a else None, a if back_b else None), "/": (b,), "+": (), "-": ()}.get(e.op, (a, b))
        out = _apply(e.op, a, b, into(a, b, shape=np.broadcast_shapes(np.shape(a), np.shape(b)), keep=keep))
        if back_b is None or e.op in ("+", "-", "*"):  # a quotient's or a power's backward wrt b reads the result
            release(out)

        def back(grad: Any, coef: float, owned: bool, terms: list[GradientTerm]) -> None:
            both = back_a is not None and back_b is not None  # then the two sides share ``grad``
            if e.op in ("+", "-"):
                if back_a is not None:
                    back_a(grad, coef, owned and not both, terms)
                if back_b is not None:
                    back_b(grad, coef if e.op == "+" else -coef, owned and not both, terms)
            elif e.op == "*":
                if back_a is not None:
                    if scalar_b:
                        back_a(grad, coef * float(b), owned and not both, terms)
                    else:
                        back_a(_on_grad(np.multiply, grad, b, owned and not both), coef, True, terms)
                if back_b is not None:
                    if scalar_a:
                        back_b(grad, coef * float(a), owned, terms)
                    else:
                        back_b(_on_grad(np.multiply, grad, a, owned), coef, True, terms)
            elif e.op == "/":
                if back_b is not None:  # d(a/b)/db = −out / b
                    back_b(_on_grad(np.divide, _on_grad(np.multiply, grad, out, False), b, True), -coef, True, terms)
                if back_a is not None:
                    if scalar_b:
                        back_a(grad, coef / float(b), owned, terms)
                    else:
                        back_a(_on_grad(np.divide, grad, b, owned), coef, True, terms)
            else:  # power
                if back_b is not None:  # d(a^b)/db = out · log a
                    slope = _on_grad(np.multiply, grad, out, False)
                    back_b(_on_grad(np.multiply, slope, np.log(a), True), coef, True, terms)
                if back_a is not None:
                    if _is_square(a, b):
                        back_a(_on_grad(np.multiply, grad, a, owned), 2.0 * coef, True, terms)
                    else:
                        back_a(_on_grad(np.multiply, grad, b * np.power(a, b - 1.0), owned), coef, True, terms)

        return out, back

    def call(e: Call) -> tuple[Any, _Back | None]:
        parts = [ev(a) for a in e.args]
        values = [p[0] for p in parts]
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
        if all(p[1] is None for p in parts):
            return out, None

        def back(grad: Any, coef: float, owned: bool, terms: list[GradientTerm]) -> None:
            if e.func in ("min", "max"):
                for i, (_, back_i) in enumerate(parts):
                    if back_i is not None:
                        back_i(grad * (pick == i), coef, True, terms)
                return
            x, back_x = values[0], parts[0][1]
            if e.func == "sqrt":
                back_x(_on_grad(np.divide, grad, out, owned), 0.5 * coef, True, terms)
            elif e.func == "exp":
                back_x(_on_grad(np.multiply, grad, out, owned), coef, True, terms)
            elif e.func == "log":
                back_x(_on_grad(np.divide, grad, x, owned), coef, True, terms)
            else:  # abs
                back_x(_on_grad(np.multiply, grad, np.sign(x), owned), coef, True, terms)

        return out, back

    with np.errstate(all="ignore"):  # undefined arithmetic is the caller's to find and refuse
        value, back = ev(expr)

    def gradient(grad: Any, coef: float = 1.0, owned: bool = False) -> list[GradientTerm]:
        terms: list[GradientTerm] = []
        if back is not None:
            with np.errstate(all="ignore"):
                back(grad, coef, owned, terms)
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
    if isinstance(expr, (Var, Num)):
        return False
    if isinstance(expr, Neg):
        return can_be_non_finite(expr.operand)
    if isinstance(expr, BinOp):
        return expr.op in ("/", "^") or can_be_non_finite(expr.left) or can_be_non_finite(expr.right)
    return True


def value_range(expr: Expr, magnitudes: dict[str, float]) -> tuple[float, float] | None:
    """An interval holding every value of ``expr`` when each signal s has |s| ≤ ``magnitudes[s]``.

    None when the arithmetic may be undefined or overflow there (a division by an interval
    holding 0, the log or square root of one reaching below 0, a general power, a bound
    beyond 1e300). Evaluators use it to skip the NaN and range checks of a predicate whose
    values are known to be finite, e.g. ``sqrt((x - 150)^2 + (y - 150)^2)`` on finite signals.
    """
    def rng(e: Expr) -> tuple[float, float] | None:
        if isinstance(e, Var):
            m = magnitudes[e.name]
            return -m, m
        if isinstance(e, Num):
            return e.value, e.value
        if isinstance(e, Neg):
            inner = rng(e.operand)
            return None if inner is None else (-inner[1], -inner[0])
        if isinstance(e, BinOp):
            a, b = rng(e.left), rng(e.right)
            if a is None or b is None:
                return None
            if e.op == "+":
                return a[0] + b[0], a[1] + b[1]
            if e.op == "-":
                return a[0] - b[1], a[1] - b[0]
            if e.op == "*":
                corners = [x * y for x in a for y in b]
                return min(corners), max(corners)
            if e.op == "/":
                if b[0] <= 0.0 <= b[1]:
                    return None
                corners = [x / y for x in a for y in b]
                return min(corners), max(corners)
            if b == (2.0, 2.0):  # a square
                top = max(a[0] * a[0], a[1] * a[1])
                return (0.0 if a[0] <= 0.0 <= a[1] else min(a[0] * a[0], a[1] * a[1])), top
            return None
        if isinstance(e, Call):
            args = [rng(a) for a in e.args]
            if any(a is None for a in args):
                return None
            if e.func in ("min", "max"):
                pick = min if e.func == "min" else max
                return pick(a[0] for a in args), pick(a[1] for a in args)  # type: ignore[index]
            (low, high), = args  # type: ignore[misc]
            if e.func == "abs":
                return (0.0 if low <= 0.0 <= high else min(abs(low), abs(high))), max(abs(low), abs(high))
            if e.func == "sqrt":
                return None if low < 0.0 else (math.sqrt(low), math.sqrt(high))
            if e.func == "log":
                return None if low <= 0.0 else (math.log(low), math.log(high))
            if e.func == "exp":
                return None if high > 690.0 else (math.exp(low), math.exp(high))
        return None

    with np.errstate(all="ignore"):
        out = rng(expr)
    if out is None or not (-1e300 < out[0] <= out[1] < 1e300):
        return None
    return out


@functools.lru_cache(maxsize=4096)
def margin_bound(lhs: Expr, rhs: Expr, magnitudes: tuple[tuple[str, float], ...]) -> float:
    """A bound on |lhs − rhs| from the signals' magnitudes (``(name, max |value|)`` pairs); inf if unknown.

    Cached: a formula's predicates are bounded once per batch, not once per group of trajectories.
    """
    sides = [value_range(side, dict(magnitudes)) for side in (lhs, rhs)]
    if any(side is None for side in sides):
        return math.inf
    return sum(max(abs(low), abs(high)) for low, high in sides)  # type: ignore[misc]
