"""The error hierarchy of torchhrc.

Every error a user can trigger derives from :class:`TorchHRCError`. The concrete classes
also derive from the built-in exception a caller would expect, so ``except ValueError``
keeps working:

* :class:`ModelError` -- a model (tensors, probabilities, shapes) is invalid.
* :class:`ParseError` -- a file is malformed; it carries the file, line, column and reason.

Example:
    >>> from torchhrc.errors import ParseError
    >>> str(ParseError("bad token", path="m.pomdp", line=3, column=7))
    'm.pomdp:3:7: bad token'
"""

from __future__ import annotations

__all__ = ["ModelError", "ParseError", "TorchHRCError"]


class TorchHRCError(Exception):
    """Base class of every error raised by torchhrc for bad input."""


class ModelError(TorchHRCError, ValueError):
    """A model or its tensors are invalid (shape, range, normalisation)."""


class ParseError(TorchHRCError, ValueError):
    """A file could not be read; the message names the file, line, column and reason.

    Args:
        reason: what is wrong, in a few words.
        path: the file's path (or ``"<string>"``).
        line: 1-based line number, if known.
        column: 1-based column number, if known.
    """

    def __init__(
        self,
        reason: str,
        *,
        path: str | None = None,
        line: int | None = None,
        column: int | None = None,
    ) -> None:
        self.reason = reason
        self.path = path
        self.line = line
        self.column = column
        where = ":".join(
            str(part) for part in (path or "<input>", line, column) if part is not None
        )
        super().__init__(f"{where}: {reason}")
