"""Exceptions raised by tl_gym.

Every error names its culprit (the column in a formula, the missing signal, the
step holding a NaN) so that a user can fix the input without a debugger.
"""

from __future__ import annotations


class TLGymError(Exception):
    """Base class of every error tl_gym raises on purpose."""


class SpecError(TLGymError, ValueError):
    """A formula's text does not parse.

    The message quotes the text with a caret under the offending token.

    Attributes:
        text: the formula text that failed to parse.
        column: 1-based column of the offending token.
    """

    def __init__(self, message: str, text: str | None = None, column: int = 0):
        self.text = text
        self.column = column
        if text is not None:
            caret = " " * max(column - 1, 0) + "^"
            message = f"{message} (column {column})\n    {text}\n    {caret}"
        super().__init__(message)


class UnknownSignalError(TLGymError, KeyError):
    """A formula reads a signal that the trace (or the signal mapping) does not provide."""

    def __str__(self) -> str:  # KeyError quotes its message; show it plainly instead
        return str(self.args[0]) if self.args else ""


class TraceError(TLGymError, ValueError):
    """A trace holds NaN or inf, or its arrays have inconsistent shapes."""


class IncompatibleSaveError(TLGymError, ValueError):
    """A saved agent does not match the running code or environment."""
