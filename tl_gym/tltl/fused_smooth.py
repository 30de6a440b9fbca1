"""Smoothed robustness at position 0 and its gradient, one compiled loop per trajectory (numba).

The numpy smoother's cost at TLPS's batch size (N = 40, T = 200) is per-call overhead and its
scans (``np.logaddexp.accumulate`` is a scalar loop of ``log1p(exp)``), not arithmetic. Here one
kernel, compiled once per machine (numba's on-disk cache) for every formula, runs the
formula's plan (`tl_gym.tltl.plan`, encoded as integer arrays by `encode`) for each
trajectory: every step is a loop over the trajectory's positions, its values one row of a
scratch array that stays in cache; with the gradient, the plan then runs back to front.
A log-sum-exp of two terms keeps both softmax weights (one ``exp`` gives both), so the
backward pass of a scan is one multiplication per position, and nothing is exponentiated
or logged again. A term more than 37 below the largest (in β units) is not exponentiated:
its weight is below 2⁻⁵³, so ``1 + weight`` rounds to 1 and the value is the same; only its
own gradient (< 1e-16 of the largest) is dropped.

The rules, in β units (``z = β·ρ``, ±`INF` for ±∞), are the smoother's (`tl_gym.tltl.smooth`,
`tl_gym.tltl.operators`):

* a predicate is β times its margin; the gradient goes to the signals through its arithmetic in
  reverse mode, with the conventions of `tl_gym.tltl.expressions.evaluate_with_gradient`;
* ``&`` / ``|``: the smooth min / max of the operands (`operators.smooth_nary`); an n-ary node
  whose operands include all of another one's reads that one's value instead (log-sum-exp is
  associative: the same value and gradient, fewer exponentials);
* ``->``: ``lse(−z_φ, z_ψ)``; ``X``: one position later, −ρ_max at the last state;
* ``F`` / ``G``: a suffix log-sum-exp scan at every position (`operators.smooth_over_time`), a
  log-sum-exp over time at position 0;
* ``T`` at every position in the linear form (`operators.smooth_then_linear`);
* ``U`` / ``T`` at position 0: a prefix scan of the left operand, the smooth min with the right
  one, a log-sum-exp over time (`smooth._binary_at_zero`).

Not covered (the numpy smoother runs them): ``U``/``T`` needed at every position in the nested
form (O(T²)), a temporal left operand of ``U``/``T``, formulas reading no signal. A NaN,
infinite or too large predicate value stops the kernel and the numpy smoother answers (and
raises its error). Values and gradients equal the numpy smoother's to rounding
(``tests/test_engine_fused.py``).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tl_gym.tltl import ast as nodes
from tl_gym.tltl import fused
from tl_gym.tltl import smooth_opcodes as op
from tl_gym.tltl.expressions import postorder
from tl_gym.tltl.operators import INF, SIGN
from tl_gym.tltl.plan import Plan, cached, compile_plan

# A term more than CUT below the largest (β units) is not exponentiated: exp(-37) < 2⁻⁵³, so 1 + its weight
# is 1 and the value does not change; its own gradient (its weight times the derivative below it) is
# dropped. Below steps whose predicates are all signals against numbers or signals, that derivative is
# ±1 (times weights ≤ 1), so the error is below 1e-16 a term. Elsewhere (sqrt, log, division... may have
# any slope) the kernel exponentiates down to numpy's own floor (`tl_gym.tltl.lse`).
CUT, EXP_FLOOR = -37.0, -700.0

_BINARY = {"+": op.ADD, "-": op.SUB, "*": op.MUL, "/": op.DIV, "^": op.POW}
_CALLS = {"abs": op.ABS, "sqrt": op.SQRT, "exp": op.EXP, "log": op.LOG, "min": op.MIN, "max": op.MAX}


@dataclass(frozen=True)
class Program:
    """A formula's plan as arrays for the kernel: steps, their operands, their predicates' arithmetic."""

    names: tuple[str, ...]  # the signals, in argument order
    steps: np.ndarray  # (n_steps, 6) int64: code, first, sign (±1), start of operands, their count, weight row
    cuts: np.ndarray  # float64 per step: terms further below the largest than this are not exponentiated
    operands: np.ndarray  # int64: the operand steps of every step, concatenated
    predicates: np.ndarray  # (n_steps, 6) int64: instructions start, stop; lhs, rhs; their kinds (row, signal, number)
    code: np.ndarray  # (n_instructions, 3) int64: code, operand a (or signal), operand b
    numbers: np.ndarray  # float64 per instruction: the number of a NUM
    weights: int  # rows of softmax weights the kernel keeps


def program_for(formula: nodes.Formula, form: str) -> Program | None:
    """The formula's program for ``form`` (built once, kept on the formula), or None if not covered."""
    return cached(formula, ("fused_smooth", form), lambda: encode(compile_plan(formula, True), formula.signals,
                                                                form) or False) or None


AUTO_SECONDS = 1.0  # numpy smoothing time a process spends before backend="auto" loads the kernel (1-4 s)
_SPENT = [0.0]  # numpy smoothing time of this process under "auto"


def or_numpy(backend: str, formula: nodes.Formula, signals: dict[str, np.ndarray], beta: float, rho_max: float,
             form: str, jacobian: bool, numpy: Callable[[], Any]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """`at_position_zero` when it applies and pays, else ``numpy()`` (the numpy smoother's answer).

    "numba" uses the kernel whenever numba is installed (warning once if not). "auto" does so once the
    kernel is loaded in this process, or once the process has spent `AUTO_SECONDS` smoothing with numpy:
    loading the kernel costs 1-4 s per process (compiling it, once per machine, about a minute on this
    2-core machine), so one-off calls never wait for it and a training run loads it within seconds.
    """
    if fused.wanted(backend) and (backend == "numba" or _SPENT[0] >= AUTO_SECONDS or _KERNEL_MODULE in sys.modules):
        top = min(beta * rho_max, INF) if math.isfinite(rho_max) else INF
        out = at_position_zero(formula, signals, beta, top, form, jacobian)
        if out is not None:
            return out
    start = time.perf_counter()
    result = numpy()
    if backend == "auto":
        _SPENT[0] += time.perf_counter() - start
    return result


def at_position_zero(formula: nodes.Formula, signals: dict[str, np.ndarray], beta: float, top: float, form: str,
                     jacobian: bool) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """Smoothed values at position 0 (β units, ``(1, N)``) and, with ``jacobian``, each one's gradient.

    ``signals`` are ``(N, T)``; ``top`` is ρ_max in β units. The gradient is in ρ units, wrt each
    value's own trajectory (``(N, T)`` per signal), zero where the value is ±∞. None when the kernel
    does not cover the formula or meets a value it must not handle: the numpy smoother then answers.
    """
    program = program_for(formula, form)
    if program is None:
        return None
    # one (signals, N, T) array: one compiled signature whatever the number of signals (a copy if several)
    arrays = [np.asarray(signals[name], dtype=np.float64) for name in program.names]
    stacked = np.ascontiguousarray(arrays[0][None] if len(arrays) == 1 else np.stack(arrays))
    _, n, length = stacked.shape
    z = np.empty(n)
    jac = np.empty((len(arrays), n, length) if jacobian else (len(arrays), 0, 0))
    if _kernel()(program.steps, program.cuts, program.operands, program.predicates, program.code, program.numbers,
                 program.weights, float(beta), float(top), jacobian, z, jac, stacked) >= 0:
        return None
    return z[None], ({name: jac[c] for c, name in enumerate(program.names)} if jacobian else {})


# --------------------------------------------------------------------------- encoding a plan


def encode(plan: Plan, names: tuple[str, ...], form: str) -> Program | None:
    """The arrays the kernel runs; None if a step is not covered (see the module's docstring)."""
    if not names:
        return None
    steps: list[list[int]] = []
    operands: list[int] = []
    predicates: list[list[int]] = []
    code: list[list[int]] = []
    numbers: list[float] = []
    weights = 0
    nary: list[tuple[int, type, tuple[int, ...]]] = []  # (step, type, operands) of the n-ary steps so far
    linear: list[bool] = []  # every predicate below the step is a signal against a number or a signal
    for k, step in enumerate(plan.steps):
        node, ins = step.node, list(step.inputs)
        sign, size, expression = 1, 0, [0, 0, 0, 0, 0, 0]
        if step.segments or (isinstance(node, nodes.Until) and not step.first) or (
                isinstance(node, nodes.Then) and not step.first and form != "linear"):
            return None
        if isinstance(node, nodes.Constant):
            kind, sign = op.CONST, 1 if node.value else -1
        elif isinstance(node, nodes.Predicate):
            kind, sign = op.PRED, int(SIGN[node.op])
            start = len(code)  # a signal or a number is read directly (kind 1 or 2), arithmetic from its row (0)
            sides = [(1, names.index(side.name)) if isinstance(side, nodes.Var) else
                     (0, _expression(side, names, code, numbers)) if not isinstance(side, nodes.Num) else (2, -1)
                     for side in (node.lhs, node.rhs)]
            stop = len(code)
            for m, (side_kind, _) in enumerate(sides):
                if side_kind == 2:
                    code.append([op.NUM, 0, 0])
                    numbers.append((node.lhs, node.rhs)[m].value)  # type: ignore[attr-defined]
                    sides[m] = (2, len(code) - 1)
            expression = [start, stop, sides[0][1], sides[1][1], sides[0][0], sides[1][0]]
        elif isinstance(node, nodes.Not):
            kind = op.NOT
        elif isinstance(node, (nodes.And, nodes.Or)):
            kind, sign = op.NARY, -1 if isinstance(node, nodes.And) else 1
            ins = _reuse(ins, type(node), nary, step.first, plan)
            nary.append((k, type(node), tuple(step.inputs)))
            size = len(ins)
        elif isinstance(node, nodes.Implies):
            kind, size = op.IMPLIES, 2
        elif isinstance(node, nodes.Next):
            kind = op.NEXT
        elif isinstance(node, (nodes.Eventually, nodes.Always)):
            kind, sign = (op.REDUCE if step.first else op.SUFFIX), (1 if isinstance(node, nodes.Eventually) else -1)
            size = 1 if step.first else 2
        elif isinstance(node, nodes.Then) and not step.first:
            kind, size = op.THEN_LINEAR, 6
        elif isinstance(node, (nodes.Until, nodes.Then)):
            kind, sign, size = op.BINARY_AT_ZERO, (-1 if isinstance(node, nodes.Until) else 1), 5
        else:
            return None
        linear.append(all(linear[j] for j in step.inputs) and (kind != op.PRED or 0 not in expression[4:]))
        steps.append([kind, int(step.first), sign, len(operands), len(ins), weights])
        operands += ins
        predicates.append(expression)
        weights += size
    cuts = np.array([CUT if flag else EXP_FLOOR for flag in linear])
    return Program(names, np.array(steps, dtype=np.int64), cuts, np.array(operands + [0], dtype=np.int64),
                   np.array(predicates, dtype=np.int64), np.array(code + [[0, 0, 0]], dtype=np.int64),
                   np.array(numbers + [0.0]), max(weights, 1))


def _reuse(ins: list[int], kind: type, nary: list[tuple[int, type, tuple[int, ...]]], first: bool,
           plan: Plan) -> list[int]:
    """The operands of an n-ary step, with those of the largest earlier one of its kind replaced by it.

    Log-sum-exp is associative, so ``smin(a, b, c, d, e) = smin(smin(a, b, c, d), e)``: the goal box
    of the car's task 2 is smoothed once, not again in each clause that repeats its four predicates.
    The earlier step must be known where this one is (at every position, or this one at position 0 only).
    """
    best: tuple[int, tuple[int, ...]] | None = None
    for j, other_kind, others in nary:
        if other_kind is not kind or len(others) >= len(ins) or (plan.steps[j].first and not first):
            continue
        rest = list(ins)
        try:
            for o in others:
                rest.remove(o)
        except ValueError:
            continue
        if best is None or len(others) > len(best[1]):
            best = (j, tuple(rest))
    return ins if best is None else [best[0], *best[1]]


def _expression(expr: nodes.Expr, names: tuple[str, ...], code: list[list[int]], numbers: list[float]) -> int:
    """Append the instructions of ``expr`` (post-order, n-ary min/max as binary chains); return its root's."""
    stack: list[int] = []
    for e in postorder(expr):
        if isinstance(e, nodes.Var):
            row = [op.VAR, names.index(e.name), 0]
        elif isinstance(e, nodes.Num):
            row = [op.NUM, 0, 0]
        elif isinstance(e, nodes.Neg):
            row = [op.NEG, stack.pop(), 0]
        elif isinstance(e, nodes.BinOp):
            b, a = stack.pop(), stack.pop()
            square = e.op == "^" and isinstance(e.right, nodes.Num) and e.right.value == 2.0
            row = [op.SQUARE if square else _BINARY[e.op], a, b]
        elif isinstance(e, nodes.Call):
            args = stack[len(stack) - len(e.args):]
            del stack[len(stack) - len(e.args):]
            if e.func in ("min", "max"):  # min(a, b, c) = min(min(a, b), c): the first attaining it gets the gradient
                for arg in args[1:]:
                    code.append([_CALLS[e.func], args[0], arg])
                    numbers.append(0.0)
                    args[0] = len(code) - 1
                stack.append(args[0])
                continue
            row = [_CALLS[e.func], args[0], 0]
        else:
            raise TypeError(f"no fused rule for expression node {type(e).__name__}")
        code.append(row)
        numbers.append(e.value if isinstance(e, nodes.Num) else 0.0)
        stack.append(len(code) - 1)
    return stack[0]


_KERNEL_MODULE = "tl_gym.tltl.smooth_kernel"


def _kernel() -> Any:
    """The compiled kernel (`tl_gym.tltl.smooth_kernel`: numba compiles it once per machine, then loads it)."""
    from tl_gym.tltl.smooth_kernel import kernel

    return kernel
