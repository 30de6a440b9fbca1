"""Recursion without the Python stack: the drivers the parser and the evaluators share.

A formula may nest 10,000 levels deep (``F F F … x > 1``, ``((((x > 1))))``, a sum of
10,000 terms), far beyond Python's recursion limit. Recursive procedures are therefore
written as *generators* that ``yield`` what they would have called recursively; a driver
keeps the pending calls on an explicit list. The code reads like recursion and runs in
constant Python stack depth.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from types import GeneratorType
from typing import Any, TypeVar

Key = TypeVar("Key")


def drive(root: Generator[Any, Any, Any]) -> Any:
    """Run a generator whose yields are sub-generators ("recursive calls"); return its result.

    Each yielded generator is run to completion and its return value sent back to the
    yielder. An exception raised by a sub-generator is thrown into its caller (so a
    caller's ``try``/``except`` works as with plain recursion).
    """
    stack = [root]
    sent: Any = None
    error: BaseException | None = None
    while True:
        gen = stack[-1]
        try:
            if error is None:
                request = gen.send(sent)
            else:
                request, error = gen.throw(error), None
        except StopIteration as stop:
            stack.pop()
            if not stack:
                return stop.value
            sent = stop.value
            continue
        except BaseException as exc:  # noqa: BLE001 - re-raised into the caller's generator
            stack.pop()
            if not stack:
                raise
            error = exc
            continue
        stack.append(request)
        sent = None


def resolve(
    root: Key,
    cache: dict[Key, Any],
    start: Callable[[Key], Any],
    finish: Callable[[Key, Any], Any],
) -> Any:
    """Evaluate ``root`` by rules that ``yield`` the keys of the values they need.

    ``start(key)`` runs a node's rule: a plain result for a leaf, or a generator that
    yields child keys, receives their values and returns its result. ``finish(key,
    result)`` stores a result and returns the node's value; a key whose value is in
    ``cache`` is not evaluated again. Children complete before their parents, in the
    order plain recursion would complete them, with no Python recursion.
    """
    result = start(root)
    if type(result) is not GeneratorType:
        return finish(root, result)
    stack: list[tuple[Key, Any]] = [(root, result)]
    sent: Any = None
    while True:
        key, gen = stack[-1]
        try:
            request = gen.send(sent)
        except StopIteration as stop:
            stack.pop()
            sent = finish(key, stop.value)
            if not stack:
                return sent
            continue
        sent = cache.get(request)
        if sent is None:
            result = start(request)
            if type(result) is GeneratorType:
                stack.append((request, result))
            else:
                sent = finish(request, result)
