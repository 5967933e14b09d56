"""The tokens of a Cassandra ``.pomdp`` file and the ``_Parser`` over them (one
regex scan; names, numbers, the grammar's reserved words, errors with line and column)."""

from __future__ import annotations

import re

import numpy as np

from torchhrc.errors import ParseError

__all__: list[str] = []  # private parts; the public names are the package's

_TOKEN = re.compile(r"#[^\n]*|([^\s:#]+|:)")
_COMMENT = re.compile(r"#[^\n]*")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_\-]*\Z")
_RESERVED = frozenset(
    {
        "uniform",
        "identity",
        "reset",
        "discount",
        "values",
        "states",
        "actions",
        "observations",
        "start",
        "include",
        "exclude",
        "reward",
        "cost",
        "T",
        "O",
        "R",
    }
)


class _Parser:
    """Recursive-descent parser over a token list (tokens found by one C-level regex scan)."""

    def __init__(self, text: str, path: str) -> None:
        self.text = text
        self.path = path
        # the tokens of _TOKEN (maximal runs of characters other than whitespace, ':' and '#',
        # and each ':'; comments dropped), by str.split: a quarter of the regex's time (15 MB
        # file: 0.16 s against 0.61 s)
        body = _COMMENT.sub("", text) if "#" in text else text
        self.tokens = body.replace(":", " : ").split()
        self.i = 0

    # -------------------------------------------------------------- positions and errors

    def position(self, index: int) -> tuple[int, int]:
        """1-based (line, column) of token ``index`` (end of file past the last token)."""
        count = 0
        for m in _TOKEN.finditer(self.text):
            if not m.group(1):
                continue
            if count == index:
                start = m.start(1)
                line = self.text.count("\n", 0, start) + 1
                column = start - (self.text.rfind("\n", 0, start) + 1) + 1
                return line, column
            count += 1
        line = self.text.count("\n") + 1
        return line, len(self.text) - (self.text.rfind("\n") + 1) + 1

    def error(self, reason: str, index: int | None = None) -> ParseError:
        line, column = self.position(self.i if index is None else index)
        return ParseError(reason, path=self.path, line=line, column=column)

    # -------------------------------------------------------------- token helpers

    def peek(self, k: int = 0) -> str | None:
        j = self.i + k
        return self.tokens[j] if j < len(self.tokens) else None

    def next(self, what: str) -> str:
        if self.i >= len(self.tokens):
            raise self.error(f"unexpected end of file, expected {what}")
        tok = self.tokens[self.i]
        self.i += 1
        return tok

    def expect_colon(self) -> None:
        tok = self.next("':'")
        if tok != ":":
            raise self.error(f"expected ':', found {tok!r}", self.i - 1)

    def number(self, what: str) -> float:
        tok = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise self.error(f"expected {what} (a number), found {tok!r}", self.i - 1) from None
        if not np.isfinite(value):
            raise self.error(f"expected a finite number for {what}, found {tok!r}", self.i - 1)
        return value

    def numbers(self, count: int, what: str) -> np.ndarray:
        """Read exactly ``count`` numbers (vectorised conversion)."""
        end = self.i + count
        chunk = self.tokens[self.i : end]
        if len(chunk) < count:
            for k, tok in enumerate(chunk):
                if not _is_number(tok):
                    raise self.error(
                        f"expected {count} numbers for {what}, found {tok!r} after {k}", self.i + k
                    )
            raise self.error(f"unexpected end of file: expected {count} numbers for {what}", end)
        try:
            values = np.array(chunk, dtype=np.float64)
        except ValueError:
            k = next(k for k, tok in enumerate(chunk) if not _is_number(tok))
            raise self.error(
                f"expected {count} numbers for {what}, found {chunk[k]!r} after {k}", self.i + k
            ) from None
        if not np.isfinite(values).all():
            k = int(np.flatnonzero(~np.isfinite(values))[0])
            raise self.error(f"expected finite numbers for {what}, found {chunk[k]!r}", self.i + k)
        self.i = end
        return values

    def count_or_names(self, what: str) -> tuple[int, tuple[str, ...] | None]:
        tok = self.peek()
        if tok is None:
            raise self.error(f"unexpected end of file, expected the {what}")
        if _is_int(tok):
            self.i += 1
            n = int(tok)
            if n < 1:
                raise self.error(f"expected a positive number of {what}, found {tok}", self.i - 1)
            return n, None
        names: list[str] = []
        seen: set[str] = set()  # (a list's `in` made the check quadratic: 12,545 states)
        while self.peek() is not None and not self._at_keyword():
            start = self.i
            name = self.next(what)
            if not _NAME.match(name):
                raise self.error(f"invalid name {name!r} in the list of {what}", start)
            if name in seen:
                raise self.error(f"duplicate name {name!r} in the list of {what}", start)
            seen.add(name)
            names.append(name)
        if not names:
            raise self.error(f"expected a count or a list of names for {what}")
        return len(names), tuple(names)

    def _at_keyword(self) -> bool:
        if self.peek(1) == ":":
            return True
        return (
            self.peek() == "start"
            and self.peek(1) in ("include", "exclude")
            and self.peek(2) == ":"
        )

    def index(self, kind: str, size: int, names: dict[str, int] | None, *, star: bool = True):
        """An action / state / observation: a name, a 0-based number, or ``*`` (slice)."""
        start = self.i
        tok = self.next(kind)
        if tok == "*" and star:
            return slice(None)
        if _is_int(tok):
            value = int(tok)
            if value >= size:
                raise self.error(f"{kind} {value} out of range [0, {size})", start)
            return value
        if names is not None and tok in names:
            return names[tok]
        raise self.error(f"unknown {kind} {tok!r}", start)


def _is_int(tok: str) -> bool:
    return tok.isascii() and tok.isdigit()


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True
