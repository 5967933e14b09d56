"""Cassandra's ``.pomdp`` text format: reader and writer.

The format of Anthony Cassandra's pomdp-solve, read by APPL SARSOP, ZMDP and POMDPs.jl
(https://www.pomdp.org/code/pomdp-file-spec.html). Covered:

* preamble, in any order: ``discount: f``, ``values: reward|cost``,
  ``states|actions|observations: N`` or a list of names, ``start: p1 ... pS``,
  ``start: uniform``, ``start: <state>``, ``start include: <states>``,
  ``start exclude: <states>``;
* entries, later ones overriding earlier ones, ``*`` a wildcard for any action / state /
  observation, names or 0-based numbers::

      T: a : s : s2 p          T: a : s  <S numbers | uniform>
      T: a  <S x S numbers | uniform | identity>
      O: a : s2 : o p          O: a : s2 <O numbers | uniform>      O: a <S x O numbers | uniform>
      R: a : s : s2 : o v      R: a : s : s2 <O numbers>             R: a : s <S x O numbers>

* comments from ``#`` to the end of the line.

``read_pomdp(..., sparse=True)`` returns a :class:`~torchhrc.sparse.SparsePOMDP` (coordinate
lists) for models too large to hold densely, e.g. RockSample(7, 8) with 12545 states.
Rewards are reduced to the expected ``R[a, s] = sum_s2 T[a, s, s2] sum_o Z[a, s2, o]
R(a, s, s2, o)`` (``values: cost`` negates them). Rows of ``T``, ``Z`` and ``start`` must sum to
1 within 1e-4 (then they are renormalised exactly). Any malformed input raises
:class:`~torchhrc.errors.ParseError` with file, line, column and reason -- never another
exception. The writer emits the sparse single-entry form (only nonzeros), names where they
are valid identifiers, floats with ``repr`` precision, so ``read(write(m)) == m`` exactly.

Example:
    >>> from torchhrc.io.cassandra import read_pomdp
    >>> m = read_pomdp('''discount: 0.9
    ... values: reward
    ... states: 2
    ... actions: stay
    ... observations: 1
    ... T: stay identity
    ... O: * uniform
    ... R: * : 1 : * : * 1.0''')
    >>> m.R
    tensor([[0., 1.]], dtype=torch.float64)
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.io._atomic import atomic_write_bytes
from torchhrc.io._budget import check_budget, resolve_budget
from torchhrc.io._gc import gc_paused
from torchhrc.pomdp import POMDP
from torchhrc.sparse import MAX_DENSE_ENTRIES, SparsePOMDP, coalesce

__all__ = [
    "AUTO_DENSE_FRACTION",
    "AUTO_SPARSE_ENTRIES",
    "format_pomdp",
    "parse_pomdp",
    "read_pomdp",
    "write_pomdp",
]

#: ``read_pomdp(..., sparse="auto")`` reads a model sparsely when its dense ``T (A, S, S)`` or
#: ``Z (A, S, O)`` would have more entries than this (80 MB in float64; ``torchhrc solve``
#: with SARSOP uses it). Every problem of the SARSOP suite and its held-out sets below
#: baseball has at most 6.4 million; a 5,000-state model with 4 successors a state has 150
#: million, which were 1.2 GB and 3.6 s to read densely (0.4 s sparse).
AUTO_SPARSE_ENTRIES = 10_000_000
#: ...unless at least this fraction of ``T``'s entries are nonzero (a dense model, held as
#: coordinate lists of 4 numbers an entry, would take more memory and a slower solver path)
#: and it fits under :data:`~torchhrc.sparse.MAX_DENSE_ENTRIES`: it is then returned dense,
#: as is a model whose rewards depend on the next state or observation (which the sparse
#: form cannot hold).
AUTO_DENSE_FRACTION = 0.1

#: Peak bytes a cell of a table costs the sparse reader: its coordinate list (key, value and
#: entry, 24 bytes) and the sorting and checks of :meth:`_SparseTable.finish`. Measured: 36
#: million cells (``T: * uniform`` at 3,000 states, 4 actions) peaked 4.5 GB above the
#: process before the read, 125 bytes a cell; the model kept 32.
_SPARSE_CELL_BYTES = 128
#: Bytes of memory a character of the file takes as tokens (a str and its pointer per token;
#: RockSample(5, 5), 0.74 MB, peaked 16 MB above the process read sparsely).
_TEXT_BYTES = 16
#: Bytes of a state name the sparse reader makes up (``"12345"``: a str and its pointer).
_NAME_BYTES = 64

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
_ROW_TOL = 1e-4


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


def _read_text(source: str | os.PathLike[str]) -> tuple[str, str]:
    if isinstance(source, os.PathLike) or (
        isinstance(source, str) and source and "\n" not in source and ":" not in source
    ):
        path = os.fspath(source)
        try:
            with open(path, encoding="utf-8") as f:
                return f.read(), path
        except OSError as e:
            raise ParseError(f"cannot read file: {e.strerror}", path=path) from None
        except UnicodeDecodeError as e:
            raise ParseError(f"not UTF-8 text ({e.reason})", path=path) from None
    if not isinstance(source, str):
        raise TypeError(f"expected a path or the file's text, got {type(source).__name__}")
    return source, "<string>"


def read_pomdp(
    source: str | os.PathLike[str],
    *,
    sparse: bool | Literal["auto"] = False,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    memory_budget: float | None = None,
) -> Any:
    """Read a ``.pomdp`` file (a path, or the file's text itself).

    Args:
        source: a path (``str`` without newlines or ``:``, or ``os.PathLike``) or the text.
        sparse: return a :class:`~torchhrc.sparse.SparsePOMDP` (coordinate lists; for models
            too large to hold densely, e.g. RockSample(7, 8); rewards must then be given as
            ``R: a : s : * : * v``); ``"auto"``: sparse when the dense ``T (A, S, S)`` or
            ``Z (A, S, O)`` would exceed :data:`AUTO_SPARSE_ENTRIES` entries (1e7: 80 MB in
            float64), else dense; also dense above it when the model fits under
            :data:`~torchhrc.sparse.MAX_DENSE_ENTRIES` (2e8) and at least
            :data:`AUTO_DENSE_FRACTION` of ``T``'s entries are nonzero or its rewards depend
            on the next state or observation.
        dtype, device: of the returned tensors (a sparse model stays on the CPU).
        memory_budget: bytes the model may take while it is read (default ``None``: the
            machine's available memory, ``MemAvailable``; ``math.inf``: no limit). The
            sizes the file declares are checked against it before the tables are
            allocated: the dense ``T`` and ``O`` (8 bytes a cell) as soon as the preamble is
            read, a sparse table's cells (about 128 bytes a cell at the reader's peak) at
            each assignment that sets them, the start distribution and the rewards (``S``
            and ``A S`` floats) with them. ``sparse="auto"`` reads sparsely a model whose
            dense tables would not fit.

    Returns:
        :class:`~torchhrc.pomdp.POMDP` with the file's names (``None`` where counts were
        given), or :class:`~torchhrc.sparse.SparsePOMDP` when ``sparse``.

    Raises:
        ParseError: the file is malformed (file, line, column and reason in the message), the
            probabilities do not normalise, the model is too large to hold densely, or it
            would take more than ``memory_budget`` (the message gives the cells, the bytes and
            the budget).

    Example:
        >>> from torchhrc.io.cassandra import format_pomdp
        >>> from torchhrc.tasks.classic import tiger
        >>> read_pomdp(format_pomdp(tiger())).actions
        ('listen', 'open-left', 'open-right')
    """
    budget = resolve_budget(memory_budget)
    text, path = _read_text(source)
    return parse_pomdp(
        text, path=path, sparse=sparse, dtype=dtype, device=device, memory_budget=budget
    )


def parse_pomdp(
    text: str,
    *,
    path: str = "<string>",
    sparse: bool | Literal["auto"] = False,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    memory_budget: float | None = None,
) -> Any:
    """Parse the text of a ``.pomdp`` file (``path`` is only used in error messages); see
    :func:`read_pomdp`.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> parse_pomdp(format_pomdp(tiger())).num_states
        2
    """
    if not isinstance(text, str):
        raise TypeError(f"expected text to be a str, got {type(text).__name__}")
    budget = resolve_budget(memory_budget)
    check_budget(_TEXT_BYTES * len(text), budget, f"the tokens of {len(text)} characters of "
                 "text", path=path)  # fmt: skip
    parser = _Parser(text, path)
    try:
        with gc_paused():
            return _parse(parser, sparse=sparse, dtype=dtype, device=device, budget=budget)
    except ParseError:
        raise
    except Exception as e:  # a safety net: every failure is reported as a ParseError
        raise parser.error(f"cannot parse ({type(e).__name__}: {e})") from e


def _parse(
    p: _Parser,
    *,
    sparse: bool | Literal["auto"],
    dtype: torch.dtype,
    device: torch.device | str | None,
    budget: float,
) -> Any:
    discount: float | None = None
    sign = 1.0
    sizes: dict[str, int] = {}
    names: dict[str, tuple[str, ...] | None] = {}
    start_spec: tuple[str, object, int] | None = None
    preamble = {"discount", "values", "states", "actions", "observations", "start"}
    while p.peek() in preamble:
        key_index = p.i
        key = p.next("a preamble entry")
        if key == "start" and p.peek() in ("include", "exclude"):
            mode = p.next("include/exclude")
            p.expect_colon()
            start_spec = (mode, p.i, key_index)
            # the state list is resolved after the preamble (states must be declared)
            while p.peek() is not None and not p._at_keyword():
                p.i += 1
            continue
        p.expect_colon()
        if key == "discount":
            discount = p.number("the discount")
            if not 0.0 < discount <= 1.0:
                raise p.error(f"expected a discount in (0, 1], found {discount}", p.i - 1)
        elif key == "values":
            tok = p.next("reward or cost")
            if tok not in ("reward", "cost"):
                raise p.error(f"expected 'reward' or 'cost', found {tok!r}", p.i - 1)
            sign = 1.0 if tok == "reward" else -1.0
        elif key == "start":
            start_spec = ("value", p.i, key_index)
            while p.peek() is not None and not p._at_keyword():
                p.i += 1
        else:
            if key in sizes:
                raise p.error(f"{key} declared twice", key_index)
            sizes[key], names[key] = p.count_or_names(key)
    for key in ("states", "actions", "observations"):
        if key not in sizes:
            raise p.error(f"missing '{key}:' in the preamble")
    if discount is None:
        raise p.error("missing 'discount:' in the preamble")
    S, A, O = sizes["states"], sizes["actions"], sizes["observations"]
    # the memory budget, before anything of the model's size is allocated: the dense tables
    # (T, O, and the row bookkeeping, rewards and start), or the sparse reader's fixed part
    # (start, rewards, made-up state names); a sparse table's cells are charged as they are
    # set (_SparseTable)
    dense_cells = A * S * S + A * S * O
    tokens = _TEXT_BYTES * len(p.text)  # (held until the end of the parse)
    dense_bytes = 8 * dense_cells + 40 * A * S + 8 * S + tokens
    if dtype != torch.float64:  # the tensors are a converted copy
        dense_bytes += dense_cells * torch.empty(0, dtype=dtype).element_size()
    auto = sparse == "auto"
    if auto:
        sparse = max(A * S * S, A * S * O) > AUTO_SPARSE_ENTRIES or dense_bytes > budget
    if not sparse and (A * S * S > MAX_DENSE_ENTRIES or A * S * O > MAX_DENSE_ENTRIES):
        raise p.error(
            f"model too large to hold densely (A={A}, S={S}, O={O}: {A * S * S:.3g} entries "
            "of T); read it with sparse=True"
        )
    if not sparse:
        check_budget(dense_bytes, budget, f"the dense T (A={A}, S={S}, S) and O (A, S, O={O}), "
                     f"{dense_cells:.3g} cells, with the file's tokens,", path=p.path)  # fmt: skip
    fixed = 8 * (S + A * S) + (_NAME_BYTES * S if names["states"] is None else 0) + tokens
    if sparse:
        check_budget(fixed, budget, f"the start distribution and rewards of the sparse form "
                     f"(S={S}, A={A}: {S + A * S:.3g} floats, and the states' names), with "
                     "the file's tokens,", path=p.path)  # fmt: skip
    lookup = {k: ({n: i for i, n in enumerate(v)} if v else None) for k, v in names.items()}

    store = _SparseTable if sparse else _DenseTable
    charge = _Charge(p, budget, fixed)
    T, Z = store("T", A, S, S, charge), store("O", A, S, O, charge)
    rewards: list[tuple[object, object, object, object, object]] = []
    r_level = 0  # 0: R(a, s); 1: R(a, s, s2); 2: R(a, s, s2, o)
    la, ls, lo = lookup["actions"], lookup["states"], lookup["observations"]
    fast = _FastEntries(p, {"T": T, "O": Z}, lookup, (A, S, O))
    while p.peek() is not None:
        level = fast.run(rewards)
        if level is not None:
            r_level = max(r_level, level)
            continue
        entry = p.i
        kind = p.next("an entry")
        if kind not in ("T", "O", "R"):
            raise p.error(f"expected 'T:', 'O:' or 'R:', found {kind!r}", entry)
        p.expect_colon()
        a = p.index("action", A, la)
        if kind == "T":
            if p.peek() != ":":
                tok = p.peek()
                if tok == "uniform":
                    p.i += 1
                    T.fill(p, a, slice(None), slice(None), 1.0 / S, entry)
                elif tok == "identity":
                    p.i += 1
                    T.identity(p, a, entry)
                else:
                    matrix = p.numbers(S * S, "the T matrix").reshape(S, S)
                    T.fill(p, a, slice(None), slice(None), matrix, entry)
                continue
            p.expect_colon()
            s = p.index("state", S, ls)
            if p.peek() != ":":
                if p.peek() == "uniform":
                    p.i += 1
                    T.fill(p, a, s, slice(None), 1.0 / S, entry)
                else:
                    T.fill(p, a, s, slice(None), p.numbers(S, "the T row"), entry)
                continue
            p.expect_colon()
            s2 = p.index("state", S, ls)
            T.fill(p, a, s, s2, p.number("the probability"), entry)
        elif kind == "O":
            if p.peek() != ":":
                if p.peek() == "uniform":
                    p.i += 1
                    Z.fill(p, a, slice(None), slice(None), 1.0 / O, entry)
                else:
                    matrix = p.numbers(S * O, "the O matrix").reshape(S, O)
                    Z.fill(p, a, slice(None), slice(None), matrix, entry)
                continue
            p.expect_colon()
            s2 = p.index("state", S, ls)
            if p.peek() != ":":
                if p.peek() == "uniform":
                    p.i += 1
                    Z.fill(p, a, s2, slice(None), 1.0 / O, entry)
                else:
                    Z.fill(p, a, s2, slice(None), p.numbers(O, "the O row"), entry)
                continue
            p.expect_colon()
            o = p.index("observation", O, lo)
            Z.fill(p, a, s2, o, p.number("the probability"), entry)
        else:
            p.expect_colon()
            s = p.index("state", S, ls)
            if p.peek() != ":":
                value = p.numbers(S * O, "the R matrix").reshape(S, O)
                rewards.append((a, s, slice(None), slice(None), value))
                r_level = 2
                continue
            p.expect_colon()
            s2 = p.index("state", S, ls)
            if p.peek() != ":":
                rewards.append((a, s, s2, slice(None), p.numbers(O, "the R row")))
                r_level = 2
                continue
            p.expect_colon()
            o = p.index("observation", O, lo)
            value = p.number("the reward")
            rewards.append((a, s, s2, o, value))
            if not isinstance(o, slice):
                r_level = 2
            elif not isinstance(s2, slice):
                r_level = max(r_level, 1)

    # the start after the body: a body that sets more cells than the budget holds is refused
    # before the start's S floats are allocated
    end = p.i
    b0 = _parse_start(p, start_spec, S, lookup["states"])
    p.i = end
    T_final = T.finish(p)
    Z_final = Z.finish(p)
    if (sparse and auto and max(A * S * S, A * S * O) <= MAX_DENSE_ENTRIES
            and (r_level > 0 or T_final[1].size >= AUTO_DENSE_FRACTION * A * S * S)
            and (dense_bytes <= budget or r_level > 0)):  # fmt: skip
        check_budget(dense_bytes, budget, f"the dense T (A={A}, S={S}, S) and O (A, S, O={O}), "
                     f"{dense_cells:.3g} cells (rewards that depend on the next state or "
                     "observation need them),", path=p.path)  # fmt: skip
        T_final, Z_final = _densify(*T_final, (A, S, S)), _densify(*Z_final, (A, S, O))
        sparse = False
    if sparse:
        if r_level > 0:
            raise ParseError(
                "the sparse reader supports rewards 'R: a : s : * : * v' only (rewards here "
                "depend on the next state or observation); use read_pomdp(..., sparse=False)",
                path=p.path,
            )
        R = _expected_reward(p, rewards, 0, None, None, (A, S, O), budget) * sign
        names_or_index = {k: names[k] or tuple(str(i) for i in range(sizes[k])) for k in names}
        try:
            return SparsePOMDP(
                transitions=(torch.as_tensor(T_final[0]), torch.as_tensor(T_final[1], dtype=dtype)),
                observations_=(
                    torch.as_tensor(Z_final[0]),
                    torch.as_tensor(Z_final[1], dtype=dtype),
                ),
                R=torch.as_tensor(R, dtype=dtype),
                b0=torch.as_tensor(b0, dtype=dtype),
                discount=discount,
                states=names_or_index["states"],
                actions=names_or_index["actions"],
                observations=names_or_index["observations"],
            )
        except (ModelError, TypeError) as e:
            raise ParseError(str(e), path=p.path) from None
    R = _expected_reward(p, rewards, r_level, T_final, Z_final, (A, S, O), budget) * sign
    try:
        return POMDP(
            T=torch.as_tensor(T_final, dtype=dtype, device=device),
            Z=torch.as_tensor(Z_final, dtype=dtype, device=device),
            R=torch.as_tensor(R, dtype=dtype, device=device),
            b0=torch.as_tensor(b0, dtype=dtype, device=device),
            discount=discount,
            states=names["states"],
            actions=names["actions"],
            observations=names["observations"],
        )
    except (ModelError, TypeError) as e:
        raise ParseError(str(e), path=p.path) from None


class _Charge:
    """The cells the sparse tables of one read have set, charged against the budget: each
    assignment is checked, before its cells are allocated, for the cells of every table so
    far at :data:`_SPARSE_CELL_BYTES` each plus the reader's ``fixed`` bytes."""

    def __init__(self, p: _Parser | None, budget: float, fixed: float) -> None:
        self.p = p
        self.budget = budget
        self.fixed = fixed
        self.cells = 0

    def __call__(self, count: int, what: str, token: int) -> None:
        p = self.p
        need = self.fixed + _SPARSE_CELL_BYTES * (self.cells + count)
        if need > self.budget and p is not None:
            line, column = p.position(token)
            so_far = f" (with the {self.cells:.3g} cells before it)" if self.cells else ""
            check_budget(need, self.budget, f"{what}{so_far}; as the sparse reader's coordinate "
                         "lists they", path=p.path, line=line, column=column)  # fmt: skip
        self.cells += count


def _star(index: Any) -> str:
    return "*" if isinstance(index, slice) else str(index)


def _densify(index: np.ndarray, values: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """The dense table of a sparse table's coordinates ``index (M, 3)`` and ``values (M,)``
    (one entry a cell, rows already checked and normalised)."""
    table = np.zeros(shape)
    table[index[:, 0], index[:, 1], index[:, 2]] = values
    return table


class _DenseTable:
    """``(A, S, N)`` probabilities filled in file order, with the entry of each row's last
    assignment (for error messages)."""

    def __init__(self, name: str, A: int, S: int, N: int, charge: _Charge | None = None) -> None:
        self.name = name
        self.table = np.zeros((A, S, N))
        self.where = np.full((A, S), -1, dtype=np.int64)

    def fill(self, p: _Parser, a: Any, s: Any, j: Any, value: Any, token: int) -> None:
        self.table[a, s, j] = value
        self.where[a, s] = token

    def identity(self, p: _Parser, a: Any, token: int) -> None:
        self.fill(p, a, slice(None), slice(None), np.eye(self.table.shape[1]), token)

    def bulk(self, a, i, j, values, tokens) -> None:  # type: ignore[no-untyped-def]
        _, S, N = self.table.shape
        _, last = np.unique(((a * S + i) * N + j)[::-1], return_index=True)
        keep = len(a) - 1 - last  # the last occurrence of each cell wins
        self.table[a[keep], i[keep], j[keep]] = values[keep]
        self.where[a, i] = tokens

    def finish(self, p: _Parser) -> np.ndarray:
        _check_rows(p, self.name, self.table, self.where)
        return self.table


class _SparseTable:
    """The same as :class:`_DenseTable` in coordinate form: every assignment appends its
    cells; at the end the last write of each cell wins and zeros are dropped."""

    def __init__(self, name: str, A: int, S: int, N: int, charge: _Charge | None = None) -> None:
        self.name = name
        self.charge = _Charge(None, math.inf, 0) if charge is None else charge
        self.shape = (A, S, N)
        self.keys: list[np.ndarray] = []
        self.values: list[np.ndarray] = []
        self.tokens: list[np.ndarray] = []
        self.cells = 0  # cells of the wildcard and matrix assignments (the size limit)
        self.length = 0  # cells appended so far, all kinds
        # action -> number of cells appended before its last ``identity``: that assignment
        # sets the action's whole matrix, so every earlier cell of it is dropped at the end
        # (writing S x N zeros instead made ``T: * identity`` at RockSample(7,8)'s size 2e9
        # cells, refused as too many)
        self.cleared: dict[int, int] = {}

    def _axis(self, index: Any, size: int) -> np.ndarray:
        return np.arange(size) if isinstance(index, slice) else np.array([index])

    def fill(self, p: _Parser, a: Any, s: Any, j: Any, value: Any, token: int) -> None:
        A, S, N = self.shape
        dims = [A if isinstance(a, slice) else 1, S if isinstance(s, slice) else 1,
                N if isinstance(j, slice) else 1]  # fmt: skip
        count = math.prod(dims)
        self.charge(count, f"{self.name}: {' : '.join(_star(v) for v in (a, s, j))} sets "
                    f"{count:.3g} cells ({' x '.join(map(str, dims))})", token)  # fmt: skip
        ia, is_, ij = self._axis(a, A), self._axis(s, S), self._axis(j, N)
        self.cells += count
        if self.cells > MAX_DENSE_ENTRIES:
            raise p.error(f"too many {self.name} cells for the sparse reader", token)
        keys = ((ia[:, None, None] * S + is_[None, :, None]) * N + ij[None, None, :]).reshape(-1)
        # value: a scalar, a row (N,) for (a, s, *), or a matrix (S, N) for (a, *, *)
        array = np.asarray(value, dtype=np.float64)
        array = array.reshape((1,) * (3 - array.ndim) + array.shape)
        values = np.broadcast_to(array, (len(ia), len(is_), len(ij))).reshape(-1)
        self.keys.append(keys)
        self.values.append(np.array(values))
        self.tokens.append(np.full(count, token, dtype=np.int64))
        self.length += count

    def identity(self, p: _Parser, a: Any, token: int) -> None:
        A, S, N = self.shape
        count = S * (A if isinstance(a, slice) else 1)
        self.charge(count, f"{self.name}: {_star(a)} identity sets {count:.3g} cells", token)
        for act in self._axis(a, A):
            self.cleared[int(act)] = self.length
            self.length += S
            self.cells += S
            diagonal = (int(act) * S + np.arange(S)) * N + np.arange(S)
            self.keys.append(diagonal)
            self.values.append(np.ones(S))
            self.tokens.append(np.full(S, token, dtype=np.int64))

    def bulk(self, a, i, j, values, tokens) -> None:  # type: ignore[no-untyped-def]
        _, S, N = self.shape
        self.charge(len(a), f"{len(a)} more {self.name} entries", int(tokens[0]))
        self.keys.append((a * S + i) * N + j)
        self.values.append(values)
        self.tokens.append(np.asarray(tokens, dtype=np.int64))
        self.length += len(self.keys[-1])

    def finish(self, p: _Parser) -> tuple[np.ndarray, np.ndarray]:
        A, S, N = self.shape
        if self.keys:
            keys = np.concatenate(self.keys)
            values = np.concatenate(self.values)
            tokens = np.concatenate(self.tokens)
        else:
            keys = values = tokens = np.zeros(0, dtype=np.int64)
        if self.cleared:  # cells set before their action's last identity: overwritten
            cut = np.zeros(A, dtype=np.int64)
            cut[list(self.cleared)] = list(self.cleared.values())
            keep = np.arange(len(keys)) >= cut[keys // (S * N)]
            keys, values, tokens = keys[keep], values[keep], tokens[keep]
        uniq, last = np.unique(keys[::-1], return_index=True)
        pick = len(keys) - 1 - last
        keys, values, tokens = uniq, values[pick].astype(np.float64), tokens[pick]
        rows = keys // N
        where = np.full(A * S, -1, dtype=np.int64)
        np.maximum.at(where, rows, tokens)
        bad = (values < 0) | (values > 1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            a, s, j = keys[k] // (S * N), (keys[k] // N) % S, keys[k] % N
            raise _row_error(
                p,
                self.name,
                where[rows[k]],
                f"{self.name}[{a}, {s}, {j}] = {values[k]:.6g} is not a probability",
            )
        sums = np.bincount(rows, weights=values, minlength=A * S)
        off = np.abs(sums - 1.0)
        if (off > _ROW_TOL).any():
            r = int(np.flatnonzero(off > _ROW_TOL)[0])
            what = "is never set" if where[r] < 0 else f"sums to {sums[r]:.6g}, expected 1"
            raise _row_error(
                p, self.name, where[r], f"{self.name} row for action {r // S}, state {r % S} {what}"
            )
        drift = off[rows] > 1e-12
        values = np.where(drift, values / sums[rows], values)
        nonzero = values != 0
        keys, values = keys[nonzero], values[nonzero]
        index = np.stack([keys // (S * N), (keys // N) % S, keys % N], 1).astype(np.int64)
        return index, values


class _FastEntries:
    """Vectorised fill for runs of single entries without wildcards (the bulk of big files).

    Matches, token by token, runs of ``T: a : s : s2 p`` / ``O: a : s2 : o p`` (8 tokens) and
    ``R: a : s : * : * v`` (10 tokens) with numpy on the token array; any irregularity ends the
    run and the entry is left to the general parser (which reports errors precisely). The
    action may be ``*`` (every action: Hallway's ``O: * : s2 : o p``, 840 of its 2,880
    entries), the other indices may not. Within a run a later entry overrides an earlier one,
    as in file order.
    """

    def __init__(self, p: _Parser, stores: dict, lookup: dict, sizes: tuple) -> None:
        self.p = p
        self.tokens = np.array(p.tokens, dtype=object)
        self.stores = stores
        A, S, O = sizes
        self.num_actions = A
        self.maps = {
            "action": _index_map(lookup["actions"], A, len(p.tokens)),
            "state": _index_map(lookup["states"], S, len(p.tokens)),
            "observation": _index_map(lookup["observations"], O, len(p.tokens)),
        }
        self.maps["action"]["*"] = -1  # -1: every action
        self.window = 16

    def run(self, rewards: list) -> int | None:
        p, tk = self.p, self.tokens
        kind = p.peek()
        if kind not in ("T", "O", "R"):
            return None
        width = 10 if kind == "R" else 8
        n = min(self.window, (len(tk) - p.i) // width)
        if n < 2:
            return None
        # the first two entries in plain Python first: a file written with wildcards or
        # whole rows (Hallway: 849 entries, none in the fast form) would otherwise pay the
        # numpy block below at every entry, 70 % of its reading time
        for e in (p.i, p.i + width):
            fits = (tk[e] == kind and tk[e + 1] == ":" and tk[e + 3] == ":" and tk[e + 5] == ":"
                    and tk[e + 4] != "*")  # fmt: skip
            if kind == "R":
                fits = fits and tk[e + 6] == "*" and tk[e + 7] == ":" and tk[e + 8] == "*"
            else:
                fits = fits and tk[e + 6] != "*"
            if not fits:
                self.window = 16
                return None
        block = tk[p.i : p.i + n * width].reshape(n, width)
        ok = (block[:, 0] == kind) & (block[:, 1] == ":") & (block[:, 3] == ":")
        ok &= (block[:, 5] == ":") & (block[:, 4] != "*")
        if kind == "R":
            ok &= (block[:, 6] == "*") & (block[:, 7] == ":") & (block[:, 8] == "*")
        else:
            ok &= block[:, 6] != "*"
        count = n if ok.all() else int(np.argmin(ok))
        self.window = min(self.window * 2, 1 << 16) if count == n else 16
        if count < 2:
            return None
        block = block[:count]
        second = "observation" if kind == "O" else "state"
        try:
            a = self._indices("action", block[:, 2])
            i = self._indices("state", block[:, 4])
            j = None if kind == "R" else self._indices(second, block[:, 6])
            values = np.array(block[:, width - 1], dtype=np.float64)
        except (KeyError, ValueError):
            return None  # let the general parser report the exact token
        if not np.isfinite(values).all():
            return None
        entry = p.i + width * np.arange(count)
        if (a < 0).any():  # '*': one entry per action, in place (file order kept)
            star = a < 0
            reps = np.where(star, self.num_actions, 1)
            src = np.repeat(np.arange(count), reps)
            within = np.arange(len(src)) - (np.cumsum(reps) - reps)[src]
            a = np.where(star[src], within, a[src])
            i, values, entry = i[src], values[src], entry[src]
            j = None if j is None else j[src]
        if kind == "R":
            rewards.append((a, i, slice(None), slice(None), values))
            p.i += count * width
            return 0
        self.stores[kind].bulk(a, i, j, values, entry)
        p.i += count * width
        return -1

    def _indices(self, kind: str, column: np.ndarray) -> np.ndarray:
        mapping = self.maps[kind]
        return np.fromiter(map(mapping.__getitem__, column), dtype=np.int64, count=len(column))


def _index_map(names: dict[str, int] | None, size: int, tokens: int) -> dict[str, int]:
    """Each name and 0-based number of ``size`` items, mapped to its index; the numbers made
    only where there are fewer than the file's ``tokens`` (a larger map could not be used
    up; ``states: 200000000`` made 2e8 strings, 40 s and 6 GB), else parsed on demand."""
    mapping: dict[str, int] = {str(k): k for k in range(size)} if size <= tokens else _Numbers(size)
    if names:
        mapping.update(names)
    return mapping


class _Numbers(dict):  # type: ignore[type-arg]
    """A name map that also reads the 0-based numbers below ``size`` (on a miss)."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.size = size

    def __missing__(self, key: str) -> int:
        if _is_int(key) and int(key) < self.size:
            return int(key)
        raise KeyError(key)


def _parse_start(
    p: _Parser, spec: tuple[str, object, int] | None, S: int, states: dict[str, int] | None
) -> np.ndarray:
    if spec is None:
        return np.full(S, 1.0 / S)
    mode, first, key_index = spec
    p.i = first  # type: ignore[assignment]
    if mode in ("include", "exclude"):
        chosen = np.zeros(S, dtype=bool)
        while p.peek() is not None and not p._at_keyword():
            s = p.index("state", S, states, star=False)
            chosen[s] = True
        if mode == "exclude":
            chosen = ~chosen
        if not chosen.any():
            raise p.error(f"'start {mode}:' leaves no state", key_index)
        return chosen / chosen.sum()
    tok = p.peek()
    if tok == "uniform":
        p.i += 1
        b0 = np.full(S, 1.0 / S)
    elif tok is not None and not _is_number(tok):
        b0 = np.zeros(S)
        b0[p.index("state", S, states, star=False)] = 1.0
    elif tok is not None and _is_int(tok) and S > 1 and not _is_number(p.peek(1) or ""):
        b0 = np.zeros(S)
        b0[p.index("state", S, states, star=False)] = 1.0
    else:
        b0 = p.numbers(S, "the start distribution")
    if p.peek() is not None and not p._at_keyword():
        raise p.error(f"unexpected {p.peek()!r} after the start distribution")
    if (b0 < -1e-12).any() or abs(b0.sum() - 1.0) > _ROW_TOL:
        raise p.error(f"the start distribution sums to {b0.sum():.6g}, expected 1", key_index)
    b0 = np.clip(b0, 0.0, None)
    return b0 / b0.sum() if abs(b0.sum() - 1.0) > 1e-12 else b0


def _check_rows(p: _Parser, name: str, table: np.ndarray, where: np.ndarray) -> None:
    """Every row in [0, 1] and summing to 1 within tolerance; renormalise tiny drifts."""
    # one pass for the common case (the masks only to locate an offending entry: on a large
    # dense table, three boolean temporaries of its size cost page faults on every read)
    if table.size and (table.min() < 0 or table.max() > 1):
        a, s, k = (int(v) for v in np.argwhere((table < 0) | (table > 1))[0])
        raise _row_error(
            p,
            name,
            where[a, s],
            f"{name}[{a}, {s}, {k}] = {table[a, s, k]:.6g} is not a probability",
        )
    sums = table.sum(-1)
    off = np.abs(sums - 1.0)
    if (off > _ROW_TOL).any():
        a, s = (int(v) for v in np.argwhere(off > _ROW_TOL)[0])
        what = "is never set" if where[a, s] < 0 else f"sums to {sums[a, s]:.6g}, expected 1"
        raise _row_error(p, name, where[a, s], f"{name} row for action {a}, state {s} {what}")
    drift = off > 1e-12
    if drift.any():
        table[drift] /= sums[drift][:, None]


def _row_error(p: _Parser, name: str, token: int, reason: str) -> ParseError:
    if token < 0:
        return ParseError(reason, path=p.path)
    return p.error(reason, int(token))


def _expected_reward(p: _Parser, rewards: list, level: int, T: Any, Z: Any,
                     sizes: tuple[int, int, int], budget: float = math.inf,
                     ) -> np.ndarray:  # fmt: skip
    """Apply the R entries in file order at the needed granularity; reduce to ``(A, S)``."""
    A, S, O = sizes
    if level == 2 and A * S * S * O > MAX_DENSE_ENTRIES:
        raise ParseError(
            f"rewards depend on the observation and R(a, s, s2, o) would have {A * S * S * O:.3g} "
            "entries: too large",
            path=p.path,
        )
    if level:  # (the tables T and O are held already)
        cells = A * S * S * (O if level == 2 else 1)
        held = T.nbytes + Z.nbytes
        check_budget(held + 8 * cells, budget, f"the rewards R(a, s, s2{', o' * (level == 2)}) "
                     f"({cells:.3g} cells) with T and O", path=p.path)  # fmt: skip
    table = np.zeros((A, S) + (S,) * (level >= 1) + (O,) * (level >= 2))
    for a, s, s2, o, v in rewards:
        if isinstance(a, np.ndarray):  # a run from the fast path: R(a_i, s_i, *, *) = v_i
            _, last = np.unique((a * S + s)[::-1], return_index=True)
            keep = len(a) - 1 - last
            table[a[keep], s[keep]] = v[keep].reshape(-1, *([1] * (table.ndim - 2)))
        elif level == 0:
            table[a, s] = v
        elif level == 1:
            table[a, s, s2] = v
        else:
            table[a, s, s2, o] = v
    if level == 0:
        return table
    if level == 1:
        return (T * table).sum(-1)
    # R[a, s] = sum_s2 T[a, s, s2] sum_o Z[a, s2, o] R4[a, s, s2, o]
    return np.einsum("ast,ato,asto->as", T, Z, table)


# ----------------------------------------------------------------------------- writer


def _names_or_none(names: Sequence[str] | None) -> tuple[str, ...] | None:
    if names is None:
        return None
    names = tuple(names)
    if all(_NAME.match(n) and n not in _RESERVED for n in names) and len(set(names)) == len(names):
        return names
    return None


def _fmt(values: np.ndarray) -> list[str]:
    return [repr(float(v)) for v in values]


def format_pomdp(
    model: POMDP | SparsePOMDP, *, comment: str | None = None, names: bool = True
) -> str:
    """The ``.pomdp`` text of an unbatched model (sparse single-entry form).

    Names are written when every name of a kind is a valid identifier (letters, digits,
    ``_``, ``-``, starting with a letter, not a keyword); otherwise counts and 0-based numbers.
    Rewards are written as ``R: a : s : * : * v`` (the expected reward), exact for the reader.

    Args:
        model: a :class:`POMDP` (no batch dims) or a :class:`SparsePOMDP`.
        comment: an optional comment for the first lines.
        names: write names (when valid); ``False`` writes counts and numbers (smaller files).

    Returns:
        The file's text.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> format_pomdp(tiger()).splitlines()[1]
        'discount: 0.95'
    """
    if isinstance(model, POMDP):
        if len(model.batch_shape):
            raise ModelError(
                f"write one problem at a time: got batch shape {tuple(model.batch_shape)}"
            )
        sparse = SparsePOMDP.from_dense(model)
        state_names = _names_or_none(model.states)
        action_names = _names_or_none(model.actions)
        obs_names = _names_or_none(model.observations)
    elif isinstance(model, SparsePOMDP):
        sparse = model
        state_names = _names_or_none(model.states)
        action_names = _names_or_none(model.actions)
        obs_names = _names_or_none(model.observations)
    else:
        raise TypeError(f"expected a POMDP or SparsePOMDP, got {type(model).__name__}")
    if not names:
        state_names = action_names = obs_names = None
    A, S, O = sparse.num_actions, sparse.num_states, sparse.num_observations
    sn = state_names or tuple(str(i) for i in range(S))
    an = action_names or tuple(str(i) for i in range(A))
    on = obs_names or tuple(str(i) for i in range(O))
    lines = [f"# {line}" for line in (comment or "written by torchhrc").splitlines()]
    lines.append(f"discount: {sparse.discount!r}")
    lines.append("values: reward")
    lines.append("states: " + (" ".join(state_names) if state_names else str(S)))
    lines.append("actions: " + (" ".join(action_names) if action_names else str(A)))
    lines.append("observations: " + (" ".join(obs_names) if obs_names else str(O)))
    lines.append("start: " + " ".join(_fmt(sparse.b0.double().cpu().numpy())))
    lines.append("")
    lines.extend(_entries("T", sparse.transitions, an, sn, sn, A, S))
    lines.append("")
    lines.extend(_entries("O", sparse.observations_, an, sn, on, A, S))
    lines.append("")
    R = sparse.R.double().cpu().numpy()
    if A > 1 and (R == R[:1]).all():
        cols = np.flatnonzero(R[0])
        lines.extend(f"R: * : {sn[s]} : * : * {r}" for s, r in zip(cols, _fmt(R[0, cols])))
    else:
        rows, cols = np.nonzero(R)
        lines.extend(
            f"R: {an[a]} : {sn[s]} : * : * {r}" for a, s, r in zip(rows, cols, _fmt(R[rows, cols]))
        )
    lines.append("")
    return "\n".join(lines)


def _entries(
    kind: str,
    coo: tuple[torch.Tensor, torch.Tensor],
    an: Sequence[str],
    first: Sequence[str],
    second: Sequence[str],
    A: int,
    S: int,
) -> list[str]:
    """Single-entry lines for the nonzeros; ``*`` for the state when every row of an action
    is the same, and for the action when every action has the same entries."""
    index, prob = coo
    index = index.cpu().numpy().astype(np.int64, copy=False)
    N = len(second)
    # one line per cell, sorted by (a, s, j): repeated coordinates are summed, as the solvers
    # read a coordinate list (a file's later line would override an earlier one instead)
    cells, prob = coalesce((index[:, 0] * S + index[:, 1]) * N + index[:, 2],
                           prob.double().cpu().numpy())  # fmt: skip
    index = np.stack([cells // (S * N), (cells // N) % S, cells % N], 1)
    bounds = np.searchsorted(index[:, 0], np.arange(A + 1))
    payloads = []
    for a in range(A):
        rows = index[bounds[a] : bounds[a + 1], 1:]
        p = prob[bounds[a] : bounds[a + 1]]
        m = len(p)
        k = m // S if S else 0
        same_rows = (
            S > 1
            and k > 0
            and m == k * S
            and np.array_equal(rows[:, 0], np.repeat(np.arange(S), k))
            and np.array_equal(rows[:, 1], np.tile(rows[:k, 1], S))
            and np.array_equal(p, np.tile(p[:k], S))
        )
        payloads.append((True, rows[:k, 1], p[:k]) if same_rows else (False, rows, p))

    def lines(action: str, payload: tuple) -> list[str]:
        star, rows, p = payload
        if star:
            return [
                f"{kind}: {action} : * : {second[j]} {v}" for j, v in zip(rows.tolist(), _fmt(p))
            ]
        return [
            f"{kind}: {action} : {first[i]} : {second[j]} {v}"
            for (i, j), v in zip(rows.tolist(), _fmt(p))
        ]

    def equal(x: tuple, y: tuple) -> bool:
        return x[0] == y[0] and np.array_equal(x[1], y[1]) and np.array_equal(x[2], y[2])

    if A > 1 and all(equal(payloads[0], q) for q in payloads[1:]):
        return lines("*", payloads[0])
    out: list[str] = []
    for a in range(A):
        out.extend(lines(an[a], payloads[a]))
    return out


def write_pomdp(
    model: POMDP | SparsePOMDP,
    path: str | os.PathLike[str],
    *,
    comment: str | None = None,
    names: bool = True,
) -> Path:
    """Write ``model`` to ``path`` in ``.pomdp`` format, atomically (temp file + rename).

    Args:
        model: a :class:`POMDP` (no batch dims) or a :class:`SparsePOMDP`.
        path: the destination.
        comment: optional comment lines at the top.
        names: write names (when valid identifiers) or only counts and numbers.

    Returns:
        The path written.

    Example:
        >>> import tempfile, os
        >>> from torchhrc.tasks.classic import tiger
        >>> d = tempfile.mkdtemp()
        >>> read_pomdp(write_pomdp(tiger(), os.path.join(d, "tiger.pomdp"))).num_states
        2
    """
    text = format_pomdp(model, comment=comment, names=names)
    return atomic_write_bytes(path, text.encode("utf-8"))
