"""The numba kernel of `tl_gym.tltl.fused_smooth`: smoothed robustness at position 0 and its gradient.

One function for every formula: it runs a program (`fused_smooth.encode`: the plan's steps, their
operands and their predicates' arithmetic as integer arrays) for each trajectory, forward and,
with ``grad``, backward. Compiled once per machine (numba's on-disk cache); imported only when
numba is installed. The rules and their derivations are in `fused_smooth`'s docstring; here,
``W`` holds for every step the weights its backward pass multiplies by.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from tl_gym.tltl.operators import INF, SMOOTH_LIMIT
from tl_gym.tltl.smooth_opcodes import (
    ABS,
    ADD,
    BINARY_AT_ZERO,
    CONST,
    DIV,
    EXP,
    IMPLIES,
    LOG,
    MAX,
    MIN,
    MUL,
    NARY,
    NEG,
    NEXT,
    NOT,
    NUM,
    POW,
    PRED,
    REDUCE,
    SQRT,
    SQUARE,
    SUB,
    SUFFIX,
    THEN_LINEAR,
    VAR,
)

HALF = SMOOTH_LIMIT  # |β·margin| from here on cannot be told from ±∞

@njit(cache=True, error_model="numpy")
def expression(code: Any, numbers: Any, start: int, stop: int, X: Any, sigs: Any, i: int, nt: int) -> None:
    """Instructions ``start … stop − 1`` at positions ``0 … nt − 1``: each one's row of ``X``."""
    for j in range(start, stop):
        op, a, b = code[j, 0], code[j, 1], code[j, 2]
        if op == NUM:  # its row is filled once per call
            continue
        x, y, out = X[a], X[b], X[j]
        if op == VAR:
            signal = sigs[a]
            for t in range(nt):
                out[t] = signal[i, t]
        elif op == NEG:
            for t in range(nt):
                out[t] = -x[t]
        elif op == ADD:
            for t in range(nt):
                out[t] = x[t] + y[t]
        elif op == SUB:
            for t in range(nt):
                out[t] = x[t] - y[t]
        elif op == MUL:
            for t in range(nt):
                out[t] = x[t] * y[t]
        elif op == DIV:
            for t in range(nt):
                out[t] = x[t] / y[t]
        elif op == SQUARE:
            for t in range(nt):
                out[t] = x[t] * x[t]
        elif op == POW:
            for t in range(nt):
                out[t] = x[t] ** y[t]
        elif op == ABS:
            for t in range(nt):
                out[t] = abs(x[t])
        elif op == SQRT:
            for t in range(nt):
                out[t] = math.sqrt(x[t]) if x[t] >= 0.0 else math.nan
        elif op == EXP:
            for t in range(nt):
                out[t] = math.exp(x[t])
        elif op == LOG:
            for t in range(nt):
                out[t] = math.log(x[t]) if x[t] > 0.0 else (-math.inf if x[t] == 0.0 else math.nan)
        elif op == MIN:  # NaN in either operand gives NaN (numpy's minimum), which the caller refuses
            for t in range(nt):
                out[t] = y[t] if y[t] < x[t] or y[t] != y[t] else x[t]
        else:  # MAX
            for t in range(nt):
                out[t] = y[t] if y[t] > x[t] or y[t] != y[t] else x[t]


@njit(cache=True, error_model="numpy")
def expression_backward(code: Any, start: int, stop: int, X: Any, D: Any, jac: Any, i: int, nt: int) -> None:
    """Reverse mode through instructions ``stop − 1 … start``: ``D`` holds the adjoints, signals' go to ``jac``."""
    for j in range(stop - 1, start - 1, -1):
        op, a, b = code[j, 0], code[j, 1], code[j, 2]
        d, x, y, out, dx, dy = D[j], X[a], X[b], X[j], D[a], D[b]
        if op == VAR:
            target = jac[a, i]
            for t in range(nt):
                target[t] += d[t]
        elif op == NEG:
            for t in range(nt):
                dx[t] -= d[t]
        elif op == ADD:
            for t in range(nt):
                dx[t] += d[t]
                dy[t] += d[t]
        elif op == SUB:
            for t in range(nt):
                dx[t] += d[t]
                dy[t] -= d[t]
        elif op == MUL:
            for t in range(nt):
                dx[t] += d[t] * y[t]
                dy[t] += d[t] * x[t]
        elif op == DIV:
            for t in range(nt):
                dx[t] += d[t] / y[t]
                dy[t] -= d[t] * out[t] / y[t]
        elif op == SQUARE:
            for t in range(nt):
                dx[t] += 2.0 * (d[t] * x[t])
        elif op == POW:
            for t in range(nt):
                dx[t] += d[t] * (y[t] * x[t] ** (y[t] - 1.0))
                dy[t] += d[t] * out[t] * math.log(x[t])
        elif op == ABS:  # times the sign (0 at 0; inf · 0 is NaN, as in numpy)
            for t in range(nt):
                dx[t] += d[t] * (1.0 if x[t] > 0.0 else (-1.0 if x[t] < 0.0 else 0.0))
        elif op == SQRT:
            for t in range(nt):
                dx[t] += 0.5 * (d[t] / out[t])
        elif op == EXP:
            for t in range(nt):
                dx[t] += d[t] * out[t]
        elif op == LOG:
            for t in range(nt):
                dx[t] += d[t] / x[t]
        elif op == MIN or op == MAX:  # to the first operand attaining the extreme (times 0 to the other)
            for t in range(nt):
                second = (y[t] < x[t] if op == MIN else y[t] > x[t]) or y[t] != y[t]
                dx[t] += d[t] * (0.0 if second else 1.0)
                dy[t] += d[t] * (1.0 if second else 0.0)


@njit(cache=True, error_model="numpy")
def lse2(a: float, b: float, cut: float) -> tuple[float, float, float]:
    """``log(exp(a) + exp(b))`` and the two softmax weights, the larger term factored out (numpy's way)."""
    big = a - b > 0.0
    m = a if big else b
    d = (b - a) if big else (a - b)  # ≤ 0
    if d < cut:
        return m, (1.0 if big else 0.0), (0.0 if big else 1.0)
    e = math.exp(d)
    q = 1.0 / (1.0 + e)
    eq = e * q
    return m + math.log(1.0 + e), (q if big else eq), (eq if big else q)


@njit(cache=True, error_model="numpy")
def add_term(m: float, s: float, value: float, y: float, cut: float) -> tuple[float, float, float, float, float]:
    """One step of a scan ``value = log Σ exp(terms)``, kept as ``m`` (the largest term) and ``s = Σ exp(term − m)``.

    Returns the new ``m, s, value`` and the weights of ``y`` and of the previous sum in the new one. Only
    ``m`` and ``s`` go from one step to the next (a max and a multiply-add): the ``exp`` and ``log`` of a
    step do not wait for the previous step's, as they would in ``value = lse2(value, y)``.
    """
    if y > m:
        d = m - y
        r = s * math.exp(d) if d > cut else 0.0  # the previous sum, rescaled to the new largest term
        m, e = y, 1.0
    else:
        d = y - m
        if d < cut:  # y does not change 1 + its weight: nothing changes
            return m, s, value, 0.0, 1.0
        r, e = s, math.exp(d)
    s = r + e
    q = 1.0 / s
    return m, s, (m if s == 1.0 else m + math.log(s)), e * q, r * q


@njit(cache=True, error_model="numpy")
def weight(d: float, cut: float) -> float:
    """``exp(d)`` for d ≤ 0, and exactly 0 where it would not change a sum that contains 1."""
    if d == 0.0:
        return 1.0
    return math.exp(d) if d > cut else 0.0


@njit(cache=True, error_model="numpy")
def kernel(steps: Any, cuts: Any, operands: Any, predicates: Any, code: Any, numbers: Any, n_weights: int, beta: float,
           top: float, grad: bool, z: Any, jac: Any, sigs: Any) -> int:
    """Smoothed values at position 0 into ``z`` (β units) and, with ``grad``, their gradients into ``jac``.

    Returns -1, or the first trajectory with a predicate value that is NaN, infinite or too large to smooth.
    """
    _, n, T = sigs.shape
    K = steps.shape[0]
    V = np.empty((K, T))  # every step's values (a step needed at position 0 only: column 0)
    G = np.zeros((K, T))  # their gradients
    W = np.empty((n_weights, T))  # what the backward pass multiplies by
    X = np.empty((max(code.shape[0], 1), T))  # predicates' arithmetic
    D = np.zeros((max(code.shape[0], 1), T))
    S = np.empty(T)
    Q = np.empty(K)  # 1 / softmax total of the reductions over time (F / G, U / T at position 0)
    for j in range(code.shape[0]):
        if code[j, 0] == NUM:
            X[j] = numbers[j]
    for i in range(n):
        # ---------------------------------------------------------------- forward
        for k in range(K):
            op, first, sign, o, m, w = steps[k, 0], steps[k, 1], steps[k, 2], steps[k, 3], steps[k, 4], steps[k, 5]
            nt, cut = (1 if first else T), cuts[k]
            out = V[k]
            if op == CONST:
                out[:nt] = sign * top
            elif op == PRED:
                start, stop, lhs, rhs, lk, rk = predicates[k]
                expression(code, numbers, start, stop, X, sigs, i, nt)
                # each side: a row of X (kind 0), a signal (1) or a number (2); the margin is sign · (lhs − rhs)
                a = sigs[lhs, i] if lk == 1 else X[lhs]  # a number's row is filled once per call
                b = sigs[rhs, i] if rk == 1 else X[rhs]
                high, low = (a, b) if sign > 0 else (b, a)
                for t in range(nt):
                    out[t] = beta * (high[t] - low[t])
                    if not abs(out[t]) < HALF:
                        return i
            elif op == NOT:
                c = V[operands[o]]
                for t in range(nt):
                    out[t] = -c[t]
            elif op == NARY and m == 2:  # two operands: one pass (W[w], W[w + 1]: their weights)
                a, b = V[operands[o]], V[operands[o + 1]]
                for t in range(nt):
                    out[t], W[w, t], W[w + 1, t] = lse2(sign * a[t], sign * b[t], cut)
                    out[t] *= sign
            elif op == NARY:  # out holds the extreme, S the softmax total, W[w + r] operand r's weight
                out[:nt] = V[operands[o], :nt]
                for r in range(1, m):
                    c = V[operands[o + r]]
                    if sign > 0:
                        for t in range(nt):
                            out[t] = c[t] if c[t] > out[t] else out[t]
                    else:
                        for t in range(nt):
                            out[t] = c[t] if c[t] < out[t] else out[t]
                S[:nt] = 0.0
                for r in range(m):
                    c, e = V[operands[o + r]], W[w + r]
                    for t in range(nt):
                        e[t] = weight(sign * (c[t] - out[t]), cut)
                        S[t] += e[t]
                for t in range(nt):  # most totals are 1: the other operands are more than 37 away
                    if S[t] != 1.0:
                        out[t] += sign * math.log(S[t])
                        q = 1.0 / S[t]
                        for r in range(m):
                            W[w + r, t] *= q
            elif op == IMPLIES:
                a, b = V[operands[o]], V[operands[o + 1]]
                for t in range(nt):
                    out[t], W[w, t], W[w + 1, t] = lse2(-a[t], b[t], cut)
            elif op == NEXT:
                c = V[operands[o]]
                if first:
                    out[0] = c[1] if T > 1 else -top
                else:
                    out[: T - 1] = c[1:]
                    out[T - 1] = -top
            elif op == SUFFIX:  # F / G at every position: W[w] weighs the new term, W[w + 1] the running one
                c = V[operands[o]]
                m_, s_, acc = sign * c[T - 1], 1.0, sign * c[T - 1]
                out[T - 1] = sign * acc
                W[w, T - 1], W[w + 1, T - 1] = 1.0, 0.0
                for t in range(T - 2, -1, -1):
                    m_, s_, acc, W[w, t], W[w + 1, t] = add_term(m_, s_, acc, sign * c[t], cut)
                    out[t] = sign * acc
            elif op == REDUCE:  # F / G at position 0: W[w] holds the softmax weights over time
                c, e = V[operands[o]], W[w]
                p = c[0]
                for t in range(1, T):
                    p = (c[t] if c[t] > p else p) if sign > 0 else (c[t] if c[t] < p else p)
                total = 0.0
                for t in range(T):
                    e[t] = weight(sign * (c[t] - p), cut)
                    total += e[t]
                out[0] = p if total == 1.0 else p + sign * math.log(total)
                Q[k] = 1.0 / total  # the weights are e / total: divided in the backward pass
            elif op == THEN_LINEAR:  # weights: ψ's suffix (new, running), φ and later in the smooth min, outer
                a, b = V[operands[o]], V[operands[o + 1]]
                later = -INF  # lse of ψ over t' > t: none at the last position
                acc, lm, ls, am, as_ = 0.0, 0.0, 0.0, 0.0, 0.0  # the two scans' (largest term, scaled sum)
                for t in range(T - 1, -1, -1):
                    m_, W[w + 2, t], W[w + 3, t] = lse2(-a[t], -later, cut)
                    if t == T - 1:
                        acc, am, as_ = -m_, -m_, 1.0
                        W[w + 4, t], W[w + 5, t] = 1.0, 0.0
                        later, lm, ls = b[t], b[t], 1.0
                        W[w, t], W[w + 1, t] = 1.0, 0.0
                    else:
                        am, as_, acc, W[w + 4, t], W[w + 5, t] = add_term(am, as_, acc, -m_, cut)
                        lm, ls, later, W[w, t], W[w + 1, t] = add_term(lm, ls, later, b[t], cut)
                    out[t] = acc
            else:  # BINARY_AT_ZERO: weights: prefix (new, running), ψ and inner in the smooth min, outer
                a, b, e = V[operands[o]], V[operands[o + 1]], W[w + 4]
                prefix, pm, ps = 0.0, 0.0, 0.0
                p = -INF
                for t in range(T):
                    inner = -sign * INF if t == 0 else sign * prefix  # the empty inner reduction first
                    m_, W[w + 2, t], W[w + 3, t] = lse2(-b[t], -inner, cut)
                    e[t] = -m_
                    p = -m_ if -m_ > p else p
                    if t == 0:
                        prefix, pm, ps = sign * a[t], sign * a[t], 1.0
                        W[w, t], W[w + 1, t] = 1.0, 0.0
                    else:
                        pm, ps, prefix, W[w, t], W[w + 1, t] = add_term(pm, ps, prefix, sign * a[t], cut)
                total = 0.0
                for t in range(T):
                    e[t] = weight(e[t] - p, cut)
                    total += e[t]
                out[0] = p if total == 1.0 else p + math.log(total)
                Q[k] = 1.0 / total
        root = V[K - 1, 0]
        z[i] = root
        if not grad:
            continue
        # ---------------------------------------------------------------- backward
        G[:, :] = 0.0
        jac[:, i, :] = 0.0
        G[K - 1, 0] = 1.0 if abs(root) < HALF else 0.0  # ±∞ results have zero gradient
        for k in range(K - 1, -1, -1):
            op, first, sign, o, m, w = steps[k, 0], steps[k, 1], steps[k, 2], steps[k, 3], steps[k, 4], steps[k, 5]
            nt = 1 if first else T
            g = G[k]
            if op == PRED:  # the gradient of the margin (ρ units: β · 1/β)
                start, stop, lhs, rhs, lk, rk = predicates[k]
                D[start:stop, :nt] = 0.0
                for side, kind, slope in ((lhs, lk, sign), (rhs, rk, -sign)):
                    if kind == 0:
                        d = D[side]
                        for t in range(nt):
                            d[t] += slope * g[t]
                    elif kind == 1:
                        target = jac[side, i]
                        for t in range(nt):
                            target[t] += slope * g[t]
                if lk == 0 or rk == 0:
                    expression_backward(code, start, stop, X, D, jac, i, nt)
            elif op == NOT:
                c = G[operands[o]]
                for t in range(nt):
                    c[t] -= g[t]
            elif op == NARY:
                for r in range(m):
                    c, e = G[operands[o + r]], W[w + r]
                    for t in range(nt):
                        c[t] += g[t] * e[t]
            elif op == IMPLIES:
                a, b, ea, eb = G[operands[o]], G[operands[o + 1]], W[w], W[w + 1]
                for t in range(nt):
                    a[t] -= g[t] * ea[t]
                    b[t] += g[t] * eb[t]
            elif op == NEXT:
                c = G[operands[o]]
                if first:
                    if T > 1:
                        c[1] += g[0]
                else:
                    for t in range(T - 1):
                        c[t + 1] += g[t]
            elif op == SUFFIX:  # g_child[t] = w_new[t] · A[t], A[t] = A[t−1] · w_running[t−1] + g[t]
                c, new, running = G[operands[o]], W[w], W[w + 1]
                acc = 0.0
                for t in range(T):
                    if t > 0:
                        acc *= running[t - 1]
                    acc += g[t]
                    c[t] += new[t] * acc
            elif op == REDUCE:
                c, e, h = G[operands[o]], W[w], g[0] * Q[k]
                for t in range(T):
                    c[t] += h * e[t]
            elif op == THEN_LINEAR:
                a, b = G[operands[o]], G[operands[o + 1]]
                outer, right, g_later = 0.0, 0.0, 0.0
                for t in range(T):
                    if t > 0:
                        outer *= W[w + 5, t - 1]
                        right *= W[w + 1, t - 1]
                    outer += g[t]
                    g_inner = W[w + 4, t] * outer
                    a[t] += g_inner * W[w + 2, t]
                    right += g_later  # ψ's suffix at t is `later` at t − 1
                    b[t] += W[w, t] * right
                    g_later = g_inner * W[w + 3, t]
            elif op == BINARY_AT_ZERO:  # the prefix's gradient: wz[t] · B[t], B[t] = B[t+1] · wr[t+1] + g_prefix[t]
                a, b, h = G[operands[o]], G[operands[o + 1]], g[0] * Q[k]
                back, g_inner = 0.0, 0.0
                for t in range(T - 1, -1, -1):
                    if t < T - 1:
                        back = back * W[w + 1, t + 1] + g_inner
                    a[t] += W[w, t] * back  # sign · sign = 1
                    g_term = h * W[w + 4, t]
                    b[t] += g_term * W[w + 2, t]
                    g_inner = g_term * W[w + 3, t]
    return -1
