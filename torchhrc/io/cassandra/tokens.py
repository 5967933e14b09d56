"""The tokens of a Cassandra ``.pomdp`` file and the ``_Parser`` over them (made a piece
of lines at a time; names, numbers, the grammar's reserved words, errors with line and
column)."""

from __future__ import annotations

import bisect
import re

import numpy as np

from torchhrc.errors import ParseError

__all__: list[str] = []  # private parts; the public names are the package's

#: Characters of text tokenized at a time (cut after the next newline): large enough that a
#: piece costs little (a few per MB), small enough that its tokens do (about 3 MB)...
_PIECE = 1 << 18
#: ...from a first piece this small, doubling: the preamble is read again after the body (for
#: the start distribution), and its piece with it.
_FIRST_PIECE = 1 << 12
#: Tokens converted to numbers at a time by :meth:`_Parser.numbers`.
_BLOCK = 1 << 16

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
    """Recursive-descent parser over the file's tokens, made a piece of lines at a time.

    The text is cut after a newline every :data:`_PIECE` characters or so (no token and no
    comment crosses the end of a line); a piece is tokenized when the parser reaches it (by
    :func:`_split`), and the tokens before the parser's position are dropped when the next
    piece is added. So a large file is never held as a list of tokens (at 100,000 states,
    94 MB of text and 20 M tokens, that list was 1.0 GB). Token indices stay those of the
    whole file: the tables keep them for their error messages, and :meth:`position` finds a
    token's line and column, from its piece, only when an error is raised. Moving back (the
    start distribution is read after the body) tokenizes that piece again.
    """

    def __init__(self, text: str, path: str) -> None:
        self.text = text
        self.path = path
        self.i = 0  # the index, in the whole file, of the next token
        self._starts = [0]  # the first character of each piece found so far (the last: where
        self._firsts = [0]  # the next would start), and the index of its first token
        self._buf: list[str] = []  # the tokens from index self._base on
        self._base = 0
        self._piece = 0  # the piece whose tokens come next after _buf

    # -------------------------------------------------------------- the pieces

    def _tokens_of(self, k: int) -> list[str]:
        """The tokens of piece ``k`` (its end found and recorded the first time)."""
        start, text = self._starts[k], self.text
        if k + 1 < len(self._starts):
            return _split(text[start : self._starts[k + 1]])
        end = text.find("\n", start + min(_PIECE, _FIRST_PIECE << min(k, 30)))
        end = len(text) if end < 0 else end + 1
        tokens = _split(text[start:end] if start or end < len(text) else text)
        self._starts.append(end)
        self._firsts.append(self._firsts[k] + len(tokens))
        return tokens

    def _fetch(self, j: int) -> str | None:
        """Token ``j`` (``None`` past the last), keeping the tokens from ``self.i`` on; the
        piece of ``self.i`` tokenized again if it was dropped."""
        low = min(self.i, j)
        if low < self._base:  # back: start again at the piece of token `low`
            k = bisect.bisect_right(self._firsts, low) - 1
            self._buf, self._base, self._piece = self._tokens_of(k), self._firsts[k], k + 1
        while j >= self._base + len(self._buf):
            if self._starts[self._piece] >= len(self.text):
                return None
            cut = max(low - self._base, 0)
            more = self._tokens_of(self._piece)
            self._buf = self._buf[cut:] + more if self._buf else more
            self._base += cut
            self._piece += 1
        return self._buf[j - self._base]

    def window(self, count: int) -> tuple[list[str], int]:
        """The buffer and the offset in it of the next token, with the next ``count`` tokens
        in it (fewer at the end of the file); nothing consumed, nothing copied."""
        off = self.i - self._base
        if off + count > len(self._buf):
            self._fetch(self.i + count - 1)
            off = self.i - self._base
        return self._buf, off

    def ahead(self, count: int) -> list[str]:
        """The next ``count`` tokens (fewer at the end of the file), not consumed."""
        buf, off = self.window(count)
        return buf[off : off + count]

    # -------------------------------------------------------------- positions and errors

    def position(self, index: int) -> tuple[int, int]:
        """1-based (line, column) of token ``index`` (end of file past the last token)."""
        while index >= self._firsts[-1] and self._starts[-1] < len(self.text):
            self._tokens_of(len(self._starts) - 1)  # (find the pieces up to the token's)
        k = bisect.bisect_right(self._firsts, index) - 1
        text = self.text
        if k + 1 < len(self._starts):
            count = self._firsts[k]
            for m in _TOKEN.finditer(text, self._starts[k], self._starts[k + 1]):
                if not m.group(1):
                    continue
                if count == index:
                    start = m.start(1)
                    line = text.count("\n", 0, start) + 1
                    column = start - (text.rfind("\n", 0, start) + 1) + 1
                    return line, column
                count += 1
        line = text.count("\n") + 1
        return line, len(text) - (text.rfind("\n") + 1) + 1

    def error(self, reason: str, index: int | None = None) -> ParseError:
        line, column = self.position(self.i if index is None else index)
        return ParseError(reason, path=self.path, line=line, column=column)

    # -------------------------------------------------------------- token helpers

    def peek(self, k: int = 0) -> str | None:
        try:  # (never below the buffer: `i` only moves back by seek, which refills it)
            return self._buf[self.i + k - self._base]
        except IndexError:
            return self._fetch(self.i + k)

    def seek(self, index: int) -> None:
        """Move to token ``index`` (back too)."""
        self.i = index
        if index < self._base:
            self._fetch(index)

    def next(self, what: str) -> str:
        try:
            tok = self._buf[self.i - self._base]
        except IndexError:
            tok = self._fetch(self.i)  # type: ignore[assignment]
            if tok is None:
                raise self.error(f"unexpected end of file, expected {what}") from None
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
        """Read exactly ``count`` numbers (vectorised conversion, :data:`_BLOCK` at a time)."""
        if count <= _BLOCK:  # (one block: its array is the result)
            values = self._numbers(count, count, 0, what)
            self.i += count
            return values
        first = self.i
        values = np.empty(count)
        for done in range(0, count, _BLOCK):
            want = min(count - done, _BLOCK)
            values[done : done + want] = self._numbers(want, count, done, what)
            self.i += want
        self.i = first + count
        return values

    def _numbers(self, want: int, count: int, done: int, what: str) -> np.ndarray:
        """The next ``want`` numbers, not consumed: those after the first ``done`` of the
        ``count`` that ``what`` has (for the error messages)."""
        buf, off = self.window(want)
        chunk = buf[off : off + want]
        if len(chunk) < want:
            for k, tok in enumerate(chunk):
                if not _is_number(tok):
                    raise self.error(f"expected {count} numbers for {what}, found {tok!r} "
                                     f"after {done + k}", self.i + k)  # fmt: skip
            raise self.error(f"unexpected end of file: expected {count} numbers for {what}",
                             self.i - done + count)  # fmt: skip
        try:
            block = np.array(chunk, dtype=np.float64)
        except ValueError:
            k = next(k for k, tok in enumerate(chunk) if not _is_number(tok))
            raise self.error(f"expected {count} numbers for {what}, found {chunk[k]!r} "
                             f"after {done + k}", self.i + k) from None  # fmt: skip
        if not np.isfinite(block).all():
            k = int(np.flatnonzero(~np.isfinite(block))[0])
            raise self.error(f"expected finite numbers for {what}, found {chunk[k]!r}", self.i + k)
        return block

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


def _split(text: str) -> list[str]:
    """The tokens of ``text`` (those of :data:`_TOKEN`: maximal runs of characters other than
    whitespace, ':' and '#', and each ':'; comments dropped), by ``str.split``: a quarter of
    the regex's time (15 MB file: 0.16 s against 0.61 s)."""
    body = _COMMENT.sub("", text) if "#" in text else text
    return body.replace(":", " : ").split()


def _is_int(tok: str) -> bool:
    return tok.isascii() and tok.isdigit()


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True
