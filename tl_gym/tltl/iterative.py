"""Recursion without the Python stack: the driver of the parser.

A formula may nest 10,000 levels deep (``F F F … x > 1``, ``((((x > 1))))``, a sum of
10,000 terms), far beyond Python's recursion limit. Recursive procedures are therefore
written as *generators* that ``yield`` what they would have called recursively; a driver
keeps the pending calls on an explicit list. The code reads like recursion and runs in
constant Python stack depth.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any


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
