"""A formula compiled once into a flat list of operations (a *plan*), run without recursion.

`compile_plan` orders a formula's distinct sub-formulas so that operands come before
their operators (a repeated sub-formula, such as the goal boxes of the car's task 2, is
one step); the evaluators run the list front to back (and back to front for gradients),
so an evaluation neither recurses nor walks the tree. Each step says whether its node
is needed at every position or, at the root and below Boolean connectives of the root,
at position 0 only (``first``). Plans are cached on the formula.

The evaluators then attach to every step the function that computes it
(`tl_gym.tltl.operators` for the plain rules); their optimisations are *rewrites*: a
step's function is replaced by a cheaper one with the same value, and `prune` drops the
steps nothing reads any more. ``rewrite=False`` keeps the plain plan, which the tests
compare with the rewritten one.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

from tl_gym.tltl import ast as nodes
from tl_gym.tltl.ast import Formula


@dataclass
class Step:
    """One operation of a plan: the value of ``node`` (at position 0 only if ``first``)."""

    node: Formula
    first: bool
    inputs: tuple[int, ...]  # indices of the steps whose values it reads, in operand order
    run: Callable[..., Any] | None = None  # set by the evaluator (the rule, or a rewrite of it)
    readers: int = 0  # how many steps read this one (the root has none)
    segments: bool = False  # U / T whose temporal left operand is judged on every truncated segment
    options: dict[str, Any] = field(default_factory=dict)  # what a rewrite told the step


@dataclass
class Plan:
    """The steps of one formula in topological order; the last one is the root."""

    steps: list[Step]

    @property
    def root(self) -> Step:
        return self.steps[-1]


def operands(node: Formula, first: bool, segments: bool = True) -> list[tuple[Formula, bool]]:
    """What a node's value at every position (or at position 0, ``first``) is computed from.

    Boolean connectives pass the position-0 request to their operands; a temporal operator
    reads its operands at every position. With ``segments``, the temporal left operand of U / T
    is not listed: it is judged on every truncated segment, by its own plan.
    """
    if isinstance(node, (nodes.Not, nodes.And, nodes.Or, nodes.Implies)):
        return [(child, first) for child in node.children]
    if isinstance(node, (nodes.Next, nodes.Eventually, nodes.Always)):
        return [(node.child, False)]
    if isinstance(node, (nodes.Until, nodes.Then)):
        if segments and node.left.is_temporal:
            return [(node.right, False)]
        return [(node.left, False), (node.right, False)]
    return []


def compile_plan(formula: Formula, first: bool, at_zero: bool = True, segments: bool = True) -> Plan:
    """The plain plan of ``formula`` (every node once, operands first), without any rewrite.

    ``first``: the root is needed at position 0 only. ``at_zero=False`` evaluates every node
    at every position even then (the evaluator takes position 0 of the root's values): the
    reference the position-0 rewrite is tested against. ``segments=False`` lists the temporal
    left operand of U / T as an ordinary operand (for rules that do not evaluate, the bracket).
    """
    index: dict[Hashable, int] = {}
    steps: list[Step] = []
    root = (formula, first and at_zero)
    stack: list[tuple[tuple[Formula, bool], bool]] = [(root, False)]
    while stack:  # post-order on an explicit stack: any depth
        key, expanded = stack.pop()
        if key in index:
            continue
        needed = operands(*key, segments)
        if not expanded:
            stack.append((key, True))
            stack.extend((k, False) for k in reversed(needed) if k not in index)
            continue
        node = key[0]
        step = Step(node, key[1], tuple(index[k] for k in needed))
        step.segments = segments and isinstance(node, (nodes.Until, nodes.Then)) and node.left.is_temporal
        for i in step.inputs:
            steps[i].readers += 1
        index[key] = len(steps)
        steps.append(step)
    return Plan(steps)


def prune(plan: Plan) -> Plan:
    """The plan without the steps that nothing reads any more (after rewrites dropped inputs)."""
    live = [False] * len(plan.steps)
    live[-1] = True
    for i in range(len(plan.steps) - 1, -1, -1):
        if live[i]:
            for j in plan.steps[i].inputs:
                live[j] = True
    renumber: dict[int, int] = {}
    kept: list[Step] = []
    for i, step in enumerate(plan.steps):
        if live[i]:
            renumber[i] = len(kept)
            step.inputs = tuple(renumber[j] for j in step.inputs)
            step.readers = 0
            kept.append(step)
    for step in kept:
        for j in step.inputs:
            kept[j].readers += 1
    return Plan(kept)


def chosen(rewrite: bool | frozenset[str], every: frozenset[str]) -> frozenset[str]:
    """The rewrites to apply: all of ``every`` (True), none (False), or the named ones."""
    if rewrite is True:
        return every
    if rewrite is False:
        return frozenset()
    unknown = set(rewrite) - every
    if unknown:
        raise ValueError(f"unknown rewrites {sorted(unknown)}; known: {sorted(every)}")
    return frozenset(rewrite)


def cached(formula: Formula, key: Hashable, build: Callable[[], Any]) -> Any:
    """``build()``, kept on the formula under ``key`` (formulas are immutable; pickling drops it)."""
    plans = formula.__dict__.get("_plans")
    if plans is None:
        plans = {}
        object.__setattr__(formula, "_plans", plans)
    out = plans.get(key)
    if out is None:
        out = plans[key] = build()
    return out
