"""Evaluation of the arithmetic inside predicates, for numpy arrays and torch tensors."""

from __future__ import annotations

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


def evaluate_with_gradient(expr: Expr, signals: dict[str, np.ndarray]) -> tuple[Any, Any]:
    """Value of ``expr`` on numpy signals, and the map from an upstream gradient to the signals' gradients.

    The gradients come as a dict name -> array, summed over every use of the signal.

    ``min``/``max`` pass the gradient to the first operand attaining the extreme;
    ``abs`` has gradient 0 at 0 (subgradients, as torch does).
    """

    def ev(e: Expr) -> tuple[Any, Any]:
        # returns (value, backward) where backward(grad, sink) accumulates into sink
        if isinstance(e, Var):
            def back_var(grad: Any, sink: dict[str, Any]) -> None:
                sink[e.name] = grad if e.name not in sink else sink[e.name] + grad
            return signals[e.name], back_var
        if isinstance(e, Num):
            return np.float64(e.value), None
        if isinstance(e, Neg):
            value, back = ev(e.operand)
            return -value, (None if back is None else lambda g, s: back(-g, s))
        if isinstance(e, BinOp):
            (a, back_a), (b, back_b) = ev(e.left), ev(e.right)
            with np.errstate(all="ignore"):
                if e.op == "+":
                    out = a + b
                elif e.op == "-":
                    out = a - b
                elif e.op == "*":
                    out = a * b
                elif e.op == "/":
                    out = a / b
                elif _is_square(a, b):
                    out = a * a
                else:
                    out = np.power(np.float64(a) if isinstance(a, float) else a, b)

            def slopes() -> tuple[Any, Any]:
                # derivatives are computed only when a gradient is asked for
                if e.op == "+":
                    return 1.0, 1.0
                if e.op == "-":
                    return 1.0, -1.0
                if e.op == "*":
                    return b, a
                if e.op == "/":
                    return 1.0 / b, -out / b
                da = (2.0 * a if b == 2.0 else b * np.power(a, b - 1.0)) if back_a is not None else 0.0
                return da, (out * np.log(a) if back_b is not None else 0.0)

            def back_bin(grad: Any, sink: dict[str, Any]) -> None:
                with np.errstate(all="ignore"):
                    da, db = slopes()
                    if back_a is not None:
                        back_a(grad if _is_one(da) else grad * da, sink)
                    if back_b is not None:
                        back_b(grad if _is_one(db) else grad * db, sink)

            return out, (None if back_a is None and back_b is None else back_bin)
        if isinstance(e, Call):
            parts = [ev(a) for a in e.args]
            values = [p[0] for p in parts]
            pick = None
            with np.errstate(all="ignore"):
                if e.func in ("min", "max"):
                    stacked = np.stack(np.broadcast_arrays(*values))
                    pick = stacked.argmin(0) if e.func == "min" else stacked.argmax(0)
                    out = np.take_along_axis(stacked, pick[None], 0)[0]
                else:
                    x = values[0]
                    x = np.float64(x) if isinstance(x, float) else x
                    out = {"abs": np.abs, "sqrt": np.sqrt, "exp": np.exp, "log": np.log}[e.func](x)

            def call_slopes() -> list[Any]:
                if pick is not None:
                    return [(pick == i).astype(np.float64) for i in range(len(values))]
                x = values[0]
                slope = {"abs": lambda: np.sign(x), "sqrt": lambda: 0.5 / out, "exp": lambda: out,
                         "log": lambda: 1.0 / x}[e.func]()
                return [slope]

            def back_call(grad: Any, sink: dict[str, Any]) -> None:
                with np.errstate(all="ignore"):
                    for (_, back), slope in zip(parts, call_slopes()):
                        if back is not None:
                            back(grad * slope, sink)

            return out, (None if all(p[1] is None for p in parts) else back_call)
        raise TypeError(f"no evaluation rule for expression node {type(e).__name__}")

    value, back = ev(expr)

    def gradient(grad: Any) -> dict[str, Any]:
        sink: dict[str, Any] = {}
        if back is not None:
            back(grad, sink)
        return sink

    return value, gradient


def _is_square(base: Any, exponent: Any) -> bool:
    """Whether ``base ^ exponent`` is an array squared (x·x is exact: pow's result, faster)."""
    return np.ndim(base) > 0 and np.ndim(exponent) == 0 and exponent == 2.0


def _is_one(slope: Any) -> bool:
    """Whether a slope is the constant 1 (the gradient passes through unchanged; it is never mutated)."""
    return isinstance(slope, float) and slope == 1.0


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
