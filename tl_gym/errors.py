"""Exceptions raised by tl_gym.

Every error names its culprit (the column in a formula, the missing signal, the
step holding a NaN) so that a user can fix the input without a debugger.
"""

from __future__ import annotations


class TLGymError(Exception):
    """Base class of every error tl_gym raises on purpose."""


class SpecError(TLGymError, ValueError):
    """A formula's text does not parse.

    The message quotes the text with a caret under the offending token. A text of several
    lines (a long formula in a triple-quoted string) is quoted by the offending line alone,
    with its line number, so that the caret stands under the token; tabs before the token
    are kept in the caret's indent, so that it lines up however wide a tab is shown.

    Attributes:
        text: the formula text that failed to parse.
        column: 1-based column of the offending token in its line.
        line: 1-based line of the offending token (1 for a one-line text).
    """

    def __init__(self, message: str, text: str | None = None, column: int = 0):
        self.text = text
        self.column = column
        self.line = 1
        if text is not None:
            offset = max(column - 1, 0)  # ``column`` counts from the start of the text
            start = text.rfind("\n", 0, offset) + 1  # where the offending line starts
            end = text.find("\n", start)
            shown = text[start:] if end < 0 else text[start:end]
            indent = "".join(c if c == "\t" else " " for c in shown[: offset - start])
            if "\n" in text:
                self.line, self.column = text.count("\n", 0, start) + 1, offset - start + 1
                where = f"line {self.line}, column {self.column}"
            else:
                where = f"column {column}"
            message = f"{message} ({where})\n    {shown}\n    {indent}^"
        super().__init__(message)


class UnknownSignalError(TLGymError, KeyError):
    """A formula reads a signal that the trace (or the signal mapping) does not provide."""

    def __str__(self) -> str:  # KeyError quotes its message; show it plainly instead
        return str(self.args[0]) if self.args else ""


class TraceError(TLGymError, ValueError):
    """A trace holds NaN or inf, or its arrays have inconsistent shapes."""


class IncompatibleSaveError(TLGymError, ValueError):
    """A saved agent does not match the running code or environment."""


class EpisodeError(TLGymError, RuntimeError):
    """Episodes an agent runs do not end as the task needs: not within the horizon, or without a robustness."""
