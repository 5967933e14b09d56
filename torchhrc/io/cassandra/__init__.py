"""Cassandra's ``.pomdp`` text format: reader and writer.

This package's front: :func:`read_pomdp` and :func:`parse_pomdp` (the preamble, the entries
and the choice of the dense or sparse form); the parts live in
:mod:`~torchhrc.io.cassandra.tokens` (the tokens and the parser over them),
:mod:`~torchhrc.io.cassandra.tables` (the tables the entries fill, their checks) and
:mod:`~torchhrc.io.cassandra.writer`.

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

``read_pomdp(..., sparse=True)`` returns a :class:`~torchhrc.pomdp.sparse.SparsePOMDP` (coordinate
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
from typing import Any, Literal

import numpy as np
import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.io._budget import check_budget, resolve_budget
from torchhrc.io._gc import gc_paused
from torchhrc.io.cassandra.tables import (
    _ROW_TOL,
    _Charge,
    _DenseTable,
    _densify,
    _FastEntries,
    _SparseTable,
)
from torchhrc.io.cassandra.tokens import _is_int, _is_number, _Parser
from torchhrc.io.cassandra.writer import format_pomdp, write_pomdp
from torchhrc.pomdp import POMDP
from torchhrc.pomdp.sparse import MAX_DENSE_ENTRIES, SparsePOMDP

__all__ = [
    "AUTO_DENSE_FRACTION",
    "AUTO_SPARSE_ENTRIES",
    "format_pomdp",
    "parse_pomdp",
    "read_pomdp",
    "write_pomdp",
]

#: ``read_pomdp(..., sparse="auto")`` reads a model sparsely when its dense ``T (A, S, S)`` or
#: ``Z (A, S, O)`` would have more entries than this (8 MB in float64; ``torchhrc solve``
#: with SARSOP uses it), and returns it dense after all where ``T`` is dense enough
#: (:data:`AUTO_DENSE_FRACTION`). It was 10 million until the forty-first session: the six
#: problems of the SARSOP suite and its held-out sets between 1 and 10 million entries
#: (TagAvoid and two generated Tags, RockSample(5, 5) and (6, 4) layouts, 0.1-0.6 % of ``T``
#: nonzero) then solved densely, with twice to five times APPL's memory; sparsely their gap
#: after 10 CPU-s is narrower on five and equal on one, at 1.1-1.5x APPL's memory
#: (docs/benchmarks.md, "Sparse above a million entries"). A 5,000-state model with 4
#: successors a state has 150 million, which were 1.2 GB and 3.6 s to read densely.
AUTO_SPARSE_ENTRIES = 1_000_000
#: ...unless at least this fraction of ``T``'s entries are nonzero (a dense model, held as
#: coordinate lists of 4 numbers an entry, would take more memory and a slower solver path)
#: and it fits under :data:`~torchhrc.pomdp.sparse.MAX_DENSE_ENTRIES`: it is then returned dense,
#: as is a model whose rewards depend on the next state or observation (which the sparse
#: form cannot hold).
AUTO_DENSE_FRACTION = 0.1


#: Bytes of memory a character of the file takes as tokens (a str and its pointer per token;
#: RockSample(5, 5), 0.74 MB, peaked 16 MB above the process read sparsely)...
_TEXT_BYTES = 16
#: ...of at most this many characters: the parser holds the tokens of a few pieces of lines
#: at a time (:class:`~torchhrc.io.cassandra.tokens._Parser`), not the whole file's.
_TEXT_HELD = 1 << 20


def _token_bytes(text: str) -> int:
    return _TEXT_BYTES * min(len(text), _TEXT_HELD)


#: Bytes of a state name the sparse reader makes up (``"12345"``: a str and its pointer).
_NAME_BYTES = 64


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
        sparse: return a :class:`~torchhrc.pomdp.sparse.SparsePOMDP` (coordinate lists; for models
            too large to hold densely, e.g. RockSample(7, 8); rewards must then be given as
            ``R: a : s : * : * v``); ``"auto"``: sparse when the dense ``T (A, S, S)`` or
            ``Z (A, S, O)`` would exceed :data:`AUTO_SPARSE_ENTRIES` entries (1e6: 8 MB in
            float64), else dense; also dense above it when the model fits under
            :data:`~torchhrc.pomdp.sparse.MAX_DENSE_ENTRIES` (2e8) and at least
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
        given), or :class:`~torchhrc.pomdp.sparse.SparsePOMDP` when ``sparse``.

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
    check_budget(_token_bytes(text), budget, f"the tokens of {len(text)} characters of "
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
    tokens = _token_bytes(p.text)  # (held until the end of the parse)
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


def _parse_start(
    p: _Parser, spec: tuple[str, object, int] | None, S: int, states: dict[str, int] | None
) -> np.ndarray:
    if spec is None:
        return np.full(S, 1.0 / S)
    mode, first, key_index = spec
    p.seek(first)  # type: ignore[arg-type]
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
