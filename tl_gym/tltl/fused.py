"""Exact robustness through one fused loop per formula, compiled by numba (the ``tl_gym[fast]`` extra).

The formula's plan (`tl_gym.tltl.plan`, every node at every position) becomes the body of a
loop over each trajectory's positions from the last to the first. Every temporal operator
keeps one or two running values, from the recurrences of `tl_gym.tltl.operators`:

* ``F φ``, ``G φ``: the running max / min of φ;
* ``X φ``: φ one position later (−ρ_max at the last state);
* ``φ U ψ``: U(t) = max(ψ(t), min(φ(t), U(t+1)));
* ``φ T ψ``: T(t) = max(T(t+1), min(φ(t), L(t+1))) with L(t) = max(L(t+1), ψ(t)).

So the batch is read once and no temporary array is written. Values equal the numpy plan's
(max and min are exact; predicate arithmetic is the same IEEE operations, except that ``exp``,
``log`` and powers other than squares may differ in the last bit from numpy's vectorised
ones). Formulas this does not cover fall back to the numpy plan: ``U``/``T`` with a temporal
left operand, formulas reading no signal, and very large ones (compiling would cost more than
it saves).

The generated source is written to a cache directory (``$TL_GYM_CACHE`` or
``~/.cache/tl_gym/fused``) and compiled with numba's on-disk cache, so a formula is compiled
once per machine (about a second), then loaded in milliseconds; `kernel_for` reports it.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tl_gym.tltl import ast as nodes
from tl_gym.tltl import exact
from tl_gym.tltl.ast import Formula
from tl_gym.tltl.expressions import postorder
from tl_gym.tltl.operators import SIGN
from tl_gym.tltl.plan import Plan, cached, compile_plan
from tl_gym.tltl.trace import Trace, check_rho_max, prepare

MAX_STEPS = 400  # larger formulas stay on the numpy plan
MAX_EXPRESSION_NODES = 2000


@functools.cache
def available() -> bool:
    """Whether numba can be imported (``pip install tl_gym[fast]``)."""
    return importlib.util.find_spec("numba") is not None


def wanted(backend: str) -> bool:
    """Whether a compiled kernel should be tried: "auto" when numba is installed, "numba" (warning once if not)."""
    if available():
        return True
    if backend == "numba":
        _missing()
    return False


@dataclass(frozen=True)
class Kernel:
    """A compiled kernel: ``function(top, out, *signals)`` returns -1, or where the numpy plan takes over.

    That is the trajectory of a NaN or infinite signal or predicate, or of a monotone function outside its domain.
    """

    function: Any
    names: tuple[str, ...]  # the signals, in argument order
    seconds: float  # time to compile (or load from numba's cache) in this process
    source: str


def kernel_for(formula: Formula) -> Kernel | None:
    """The formula's fused kernel (compiled on first use, kept on the formula), or None if not covered."""
    return cached(formula, ("fused",), lambda: _build(formula)) or None


AUTO_SECONDS = 0.5  # numpy time a formula must cost a process before ``backend="auto"`` compiles its kernel


@dataclass
class _Usage:
    """What ``backend="auto"`` knows of a formula: numpy seconds spent on it, whether its kernel is compiled."""

    seconds: float = 0.0
    compiled: bool | None = None  # on this machine already (numba's cache holds it); None: not looked yet


def auto_robustness(formula: Formula, trace: Trace, rho_max: float = math.inf) -> float | np.ndarray:
    """``backend="auto"``: the fused kernel once it pays, the numpy plan until then.

    The kernel is used when numba is installed and either this machine has compiled it before
    (it loads in milliseconds) or the formula has cost this process `AUTO_SECONDS` of numpy
    evaluation (compiling takes about a second, once per machine). So one-off evaluations and
    the many small formulas of a test suite never wait for a compiler, and a formula evaluated
    over and over spends at most about twice the best possible time before it runs compiled.
    """
    usage: _Usage = cached(formula, ("auto",), _Usage)
    if available() and usage.compiled is None:
        source = _kernel_source(formula)
        usage.compiled = source is not None and any(_path(source).parent.glob(
            f"__pycache__/{_path(source).stem}.kernel-*.nbi"))
    if available() and (usage.compiled or usage.seconds >= AUTO_SECONDS):
        return robustness(formula, trace, rho_max)
    start = time.perf_counter()
    out = exact.robustness(formula, trace, rho_max)
    usage.seconds += time.perf_counter() - start
    return out


def robustness(formula: Formula, trace: Trace, rho_max: float = math.inf) -> float | np.ndarray:
    """Robustness at position 0 through the fused kernel; the numpy plan where it does not apply."""
    kernel = kernel_for(formula) if available() else _missing()
    if kernel is None:
        return exact.robustness(formula, trace, rho_max)
    top = check_rho_max(rho_max)
    signals = _plain_arrays(trace, kernel.names)
    if signals is None:  # lists, tensors, odd shapes, missing names: checked (and refused) as usual
        prepared = prepare(formula.signals, trace)
        signals = [np.ascontiguousarray(prepared.signals[name]) for name in kernel.names]
        batched = prepared.batched
    else:
        batched = trace[kernel.names[0]].ndim == 2
    out = np.empty(signals[0].shape[0])
    if kernel.function(top, out, *signals) >= 0:  # NaN or inf somewhere: the numpy plan answers, or names it
        return exact.robustness(formula, trace, rho_max)
    return out if batched else float(out[0])


def _plain_arrays(trace: Trace, names: tuple[str, ...]) -> list[np.ndarray] | None:
    """The signals as ``(N, T)`` C-contiguous float64 arrays when the trace holds such arrays (the fast path)."""
    try:
        arrays = [trace[name] for name in names]
    except (KeyError, TypeError):
        return None
    first = arrays[0]
    if not (isinstance(first, np.ndarray) and first.ndim in (1, 2) and first.shape[-1] > 0):
        return None
    if not all(type(a) is np.ndarray and a.dtype == np.float64 and a.shape == first.shape for a in arrays):
        return None
    return [np.ascontiguousarray(a if a.ndim == 2 else a[None, :]) for a in arrays]


_WARNED: list[bool] = []


def _missing() -> None:
    if not _WARNED:
        _WARNED.append(True)
        warnings.warn("numba is not installed (pip install tl_gym[fast]): using the numpy plan", stacklevel=3)
    return None


# --------------------------------------------------------------------------- code generation


def _kernel_source(formula: Formula) -> str | None:
    """The kernel's source (kept on the formula), or None where the numpy plan must run it."""
    def build() -> str | bool:
        plan = compile_plan(formula, True)  # steps needed at position 0 only are computed after the loop
        if not formula.signals or len(plan.steps) > MAX_STEPS or any(step.segments for step in plan.steps):
            return False
        size = sum(len(postorder(side)) for s in plan.steps if isinstance(s.node, nodes.Predicate)
                   for side in (s.node.lhs, s.node.rhs))
        if size > MAX_EXPRESSION_NODES or any(len(s.inputs) > 64 for s in plan.steps):
            return False
        return _source(plan, formula.signals)

    return cached(formula, ("fused source",), build) or None


def _build(formula: Formula) -> Kernel | bool:
    source, names = _kernel_source(formula), formula.signals
    if source is None:
        return False
    start = time.perf_counter()
    function = _compile(source)
    function(1.0, np.empty(1), *[np.zeros((1, 1))] * len(names))  # numba compiles (or loads) on the first call
    return Kernel(function, names, time.perf_counter() - start, source)


def _monotone(plan: Plan, k: int) -> tuple[Any, str, float, bool] | None:
    """``(e, f, c, grows)`` when step k is F / G at position 0 of ``f(e) ⋈ c`` (f increasing), read by it alone."""
    step = plan.steps[k]
    if not (step.first and isinstance(step.node, (nodes.Eventually, nodes.Always))):
        return None
    child = plan.steps[step.inputs[0]]
    node = child.node
    if child.readers != 1 or not isinstance(node, nodes.Predicate):
        return None
    for call, number, grows in ((node.lhs, node.rhs, SIGN[node.op] > 0), (node.rhs, node.lhs, SIGN[node.op] < 0)):
        if isinstance(call, nodes.Call) and call.func in ("sqrt", "exp", "log") and isinstance(number, nodes.Num):
            return call.args[0], call.func, number.value, grows
    return None


def _source(plan: Plan, names: tuple[str, ...]) -> str:
    """The kernel's Python source: one loop over trajectories, one backwards over positions.

    Steps needed at every position run in the loop; the temporal operators needed at position 0 only
    keep their running value in the loop and read it after, where the Boolean connectives above them
    run. F / G at position 0 of a monotone predicate ``f(e) ⋈ c`` track the extremes of e and apply f
    to them after the loop (as the numpy plan does; outside f's domain the numpy plan takes over).
    """
    args = [f"s{k}" for k in range(len(names))]
    column = {name: f"a{k}" for k, name in enumerate(names)}
    init: list[str] = []
    body: list[str] = []
    for k in range(len(names)):
        body.append(f"a{k} = s{k}[i, t]")
    checked = [f"a{k}" for k in range(len(names))]  # summed once per position: one loop-carried addition
    after: list[str] = []
    skip = {plan.steps[k].inputs[0] for k in range(len(plan.steps)) if _monotone(plan, k)}
    for k, step in enumerate(plan.steps):
        node, v = step.node, [f"v{j}" for j in step.inputs]
        code = after if step.first else body
        if k in skip:
            continue
        monotone = _monotone(plan, k)
        if monotone is not None:
            expr, func, number, grows = monotone
            inner = _expression(expr, column, body, k, "m")
            checked.append(inner)
            largest = grows == isinstance(node, nodes.Eventually)
            # the extreme used, and the ends that may leave f's domain: the low end for sqrt and log
            # (the high end is then finite), the high end for exp (it may overflow)
            ends = {"hi" if largest else "lo", "lo" if func in ("sqrt", "log") else "hi"}
            for end in sorted(ends):
                init.append(f"{end}{k} = {'-INF' if end == 'hi' else 'INF'}")
                body.append(f"{end}{k} = {'max' if end == 'hi' else 'min'}({end}{k}, {inner})")
                after += [f"f{end}{k} = np.{func}({end}{k})", f"if not (f{end}{k} - f{end}{k} == 0.0):", "    return i"]
            extreme = f"fhi{k}" if largest else f"flo{k}"
            after.append(f"v{k} = {extreme} - {number!r}" if grows else f"v{k} = {number!r} - {extreme}")
        elif isinstance(node, nodes.Constant):
            code.append(f"v{k} = {'top' if node.value else '-top'}")
        elif isinstance(node, nodes.Predicate):
            if step.first:
                code += [f"a{j} = s{j}[i, 0]" for j in range(len(names))]
            lhs, rhs = _expression(node.lhs, column, code, k, "l"), _expression(node.rhs, column, code, k, "r")
            code.append(f"v{k} = {lhs} - {rhs}" if SIGN[node.op] > 0 else f"v{k} = {rhs} - {lhs}")
            if step.first:
                code.append(f"check += v{k}")
            else:
                checked.append(f"v{k}")
        elif isinstance(node, nodes.Not):
            code.append(f"v{k} = -{v[0]}")
        elif isinstance(node, (nodes.And, nodes.Or)):
            code.append(f"v{k} = {'min' if isinstance(node, nodes.And) else 'max'}({', '.join(v)})")
        elif isinstance(node, nodes.Implies):
            code.append(f"v{k} = max(-{v[0]}, {v[1]})")
        else:  # temporal: a running value updated in the loop, read in the loop or after it
            if isinstance(node, nodes.Next):
                init.append(f"n{k} = -top")
                body += [f"x{k} = n{k}", f"n{k} = {v[0]}"]
            elif isinstance(node, (nodes.Eventually, nodes.Always)):
                pick, empty = ("max", "-INF") if isinstance(node, nodes.Eventually) else ("min", "INF")
                init.append(f"x{k} = {empty}")
                body.append(f"x{k} = {pick}(x{k}, {v[0]})")
            elif isinstance(node, nodes.Until):
                init.append(f"x{k} = -INF")
                body.append(f"x{k} = max({v[1]}, min({v[0]}, x{k}))")
            elif isinstance(node, nodes.Then):
                init += [f"x{k} = -INF", f"l{k} = -INF"]
                body += [f"x{k} = max(x{k}, min({v[0]}, l{k}))", f"l{k} = max(l{k}, {v[1]})"]
            else:
                raise TypeError(f"no fused rule for formula node {type(node).__name__}")
            code.append(f"v{k} = x{k}")
    body.append(f"check += {_balanced_sum(checked)}")
    # time is scanned backwards for the recurrences (X, U, T, F and G at every position); forwards when it is
    # only reduced (the hardware reads forwards a little faster)
    recurrences = (nodes.Next, nodes.Until, nodes.Then)
    connectives = (nodes.Not, nodes.And, nodes.Or, nodes.Implies)
    backwards = any(not step.first or isinstance(step.node, recurrences) for step in plan.steps
                    if step.node.is_temporal and not isinstance(step.node, connectives))
    lines = [
        "import numpy as np",
        "from numba import njit",
        "INF = np.inf",
        "",
        "",
        "@njit(cache=True, fastmath=False, error_model='numpy')",
        f"def kernel(top, out, {', '.join(args)}):",
        "    n, length = s0.shape",
        "    for i in range(n):",
        "        check = 0.0",  # every signal and predicate value is added: NaN or ±inf anywhere makes it so
        *(f"        {line}" for line in init),
        f"        for t in {'range(length - 1, -1, -1)' if backwards else 'range(length)'}:",
        *(f"            {line}" for line in body),
        *(f"        {line}" for line in after),
        "        if not (check - check == 0.0):",  # (or a sum that overflowed: the numpy plan decides)
        "            return i",
        f"        out[i] = v{len(plan.steps) - 1}",
        "    return -1",
        "",
    ]
    return "\n".join(lines)


def _balanced_sum(terms: list[str]) -> str:
    """``terms`` summed as a balanced tree: one loop-carried addition per position, the rest in parallel.

    (A left-to-right sum is a chain of as many dependent additions, which bounded φ1's loop.)
    """
    while len(terms) > 1:
        terms = [f"({a} + {b})" for a, b in zip(terms[::2], terms[1::2])] + terms[len(terms) - len(terms) % 2:]
    return terms[0]


_FUNCTIONS = {"abs": "abs", "sqrt": "np.sqrt", "exp": "np.exp", "log": "np.log", "min": "np.minimum",
              "max": "np.maximum"}


def _expression(expr: Any, column: dict[str, str], body: list[str], step: int, side: str) -> str:
    """Append the lines computing ``expr`` (one temporary per operation, no nesting); return its name."""
    stack: list[str] = []
    for k, e in enumerate(postorder(expr)):
        if isinstance(e, nodes.Var):
            stack.append(column[e.name])
            continue
        if isinstance(e, nodes.Num):
            stack.append(repr(float(e.value)) if math.isfinite(e.value) else ("INF" if e.value > 0 else "-INF"))
            continue
        name = f"e{step}{side}{k}"
        if isinstance(e, nodes.Neg):
            body.append(f"{name} = -{stack.pop()}")
        elif isinstance(e, nodes.BinOp):
            b, a = stack.pop(), stack.pop()
            if e.op == "^":
                # the base in parentheses: a negative literal, "-2.0 ** 4.0", is -(2.0 ** 4.0) in Python
                code = f"{a} * {a}" if isinstance(e.right, nodes.Num) and e.right.value == 2.0 else f"({a}) ** {b}"
            else:
                code = f"{a} {e.op} {b}"
            body.append(f"{name} = {code}")
        elif isinstance(e, nodes.Call):
            args = stack[len(stack) - len(e.args):]
            del stack[len(stack) - len(e.args):]
            code = args[0]
            for arg in args[1:]:
                code = f"{_FUNCTIONS[e.func]}({code}, {arg})"
            body.append(f"{name} = {code if e.func in ('min', 'max') else f'{_FUNCTIONS[e.func]}({code})'}")
        else:
            raise TypeError(f"no fused rule for expression node {type(e).__name__}")
        stack.append(name)
    return stack[0]


def _path(source: str) -> Path:
    """Where the kernel's source is written (numba's cache of its machine code goes beside it)."""
    digest = hashlib.sha256(source.encode()).hexdigest()[:20]
    return Path(os.environ.get("TL_GYM_CACHE", Path.home() / ".cache" / "tl_gym")) / "fused" / f"kernel_{digest}.py"


def _compile(source: str) -> Any:
    """Write the source to the cache directory and import it (numba caches the machine code beside it)."""
    path = _path(source)
    directory, digest = path.parent, path.stem.removeprefix("kernel_")
    try:
        directory.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            temporary = path.with_suffix(f".{os.getpid()}.tmp")
            temporary.write_text(source)
            temporary.replace(path)
        name = f"tl_gym_fused_{digest}"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        sys.modules[name] = module  # numba's cache finds the kernel's module by name
        spec.loader.exec_module(module)  # type: ignore[union-attr]
    except OSError:  # no writable cache: compile in memory (every process compiles again)
        namespace: dict[str, Any] = {}
        exec(compile(source.replace("cache=True", "cache=False"), "<tl_gym fused kernel>", "exec"), namespace)
        return namespace["kernel"]
    return module.kernel
