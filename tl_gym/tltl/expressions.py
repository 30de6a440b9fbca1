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
            return e.value
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


def can_be_non_finite(expr: Expr) -> bool:
    """Whether finite signals can give a non-finite value (division, power, functions)."""
    if isinstance(expr, (Var, Num)):
        return False
    if isinstance(expr, Neg):
        return can_be_non_finite(expr.operand)
    if isinstance(expr, BinOp):
        return expr.op in ("/", "^") or can_be_non_finite(expr.left) or can_be_non_finite(expr.right)
    return True
