"""The tables a Cassandra ``.pomdp`` read fills: dense ``(A, S, N)`` probabilities
(``_DenseTable``), coordinate lists for the sparse form (``_SparseTable``,
``_FastEntries``, with the budget's ``_Charge``), the name maps and the row checks."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from torchhrc.errors import ParseError
from torchhrc.io._budget import check_budget
from torchhrc.io.cassandra.tokens import _is_int, _Parser
from torchhrc.pomdp.sparse import MAX_DENSE_ENTRIES

__all__: list[str] = []  # private parts; the public names are the package's

#: Peak bytes a cell of a table costs the sparse reader: its coordinate list (key, value and
#: entry, 24 bytes) and the sorting and checks of :meth:`_SparseTable.finish`. Measured: 36
#: million cells (``T: * uniform`` at 3,000 states, 4 actions) peaked 4.5 GB above the
#: process before the read, 125 bytes a cell; the model kept 32.
_SPARSE_CELL_BYTES = 128
_ROW_TOL = 1e-4
#: Most entries :class:`_FastEntries` reads at once (as tokens: 40,000 and about 3 MB; the
#: block's arrays cost little beside the entries' own, and the parser's pieces hold as many).
_WINDOW = 1 << 12


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
        # action -> the token of its last whole matrix of zeros: such a matrix appends no
        # cells, but its rows count as set (see fill)
        self.zeroed: dict[int, int] = {}

    def _axis(self, index: Any, size: int) -> np.ndarray:
        return np.arange(size) if isinstance(index, slice) else np.array([index])

    def fill(self, p: _Parser, a: Any, s: Any, j: Any, value: Any, token: int) -> None:
        A, S, N = self.shape
        dims = [A if isinstance(a, slice) else 1, S if isinstance(s, slice) else 1,
                N if isinstance(j, slice) else 1]  # fmt: skip
        count = math.prod(dims)
        self.charge(count, f"{self.name}: {' : '.join(_star(v) for v in (a, s, j))} sets "
                    f"{count:.3g} cells ({' x '.join(map(str, dims))})", token)  # fmt: skip
        if isinstance(s, slice) and isinstance(j, slice) and np.ndim(value) == 0 \
                and float(value) == 0.0:  # fmt: skip
            # a whole matrix of zeros (``T: * : * : * 0.0``, the first line of APPL's
            # TagAvoid): no cells, which the end drops anyway; every earlier cell of its
            # actions is overwritten, as by ``identity``. Appending them took TagAvoid's
            # read (408 kB) to a 238 MB peak: 3.8 M cells of 24 bytes, joined and sorted.
            # (The budget is still charged as for the cells: a refusal does not depend on
            # how the file writes its zeros)
            for act in self._axis(a, A).tolist():
                self.cleared[act], self.zeroed[act] = self.length, token
            return
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
        if self.keys:  # (each list let go once it is joined: the read's peak is here)
            keys = np.concatenate(self.keys)
            self.keys = []
            values = np.concatenate(self.values)
            self.values = []
            tokens = np.concatenate(self.tokens)
            self.tokens = []
        else:
            keys = values = tokens = np.zeros(0, dtype=np.int64)
        if self.cleared:  # cells set before their action's last identity: overwritten
            cut = np.zeros(A, dtype=np.int64)
            cut[list(self.cleared)] = list(self.cleared.values())
            keep = np.arange(len(keys)) >= cut[keys // (S * N)]
            keys, values, tokens = keys[keep], values[keep], tokens[keep]
        uniq, last = np.unique(keys[::-1], return_index=True)
        del keys
        pick = len(values) - 1 - last
        del last
        keys, values, tokens = uniq, values[pick].astype(np.float64, copy=False), tokens[pick]
        del uniq, pick
        rows = keys // N
        where = np.full(A * S, -1, dtype=np.int64)  # the last assignment to each row
        for act, token in self.zeroed.items():
            where[act * S : (act + 1) * S] = token
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
        del tokens, where, bad
        drift = off[rows] > 1e-12
        if drift.any():
            values = np.where(drift, values / sums[rows], values)
        del rows, drift
        nonzero = values != 0
        if not nonzero.all():
            keys, values = keys[nonzero], values[nonzero]
        del nonzero
        # (A, S, N) coordinates written in place: no temporaries of their size
        index = np.empty((len(keys), 3), dtype=np.int64)
        np.floor_divide(keys, S * N, out=index[:, 0])
        np.floor_divide(keys, N, out=index[:, 1])
        np.remainder(index[:, 1], S, out=index[:, 1])
        np.remainder(keys, N, out=index[:, 2])
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
        self.stores = stores
        A, S, O = sizes
        self.num_actions = A
        tokens = len(p.text) // 2  # (about the most tokens the text can hold)
        self.maps = {
            "action": _index_map(lookup["actions"], A, tokens),
            "state": _index_map(lookup["states"], S, tokens),
            "observation": _index_map(lookup["observations"], O, tokens),
        }
        self.maps["action"]["*"] = -1  # -1: every action
        self.window = 16

    def run(self, rewards: list) -> int | None:
        p = self.p
        kind = p.peek()
        if kind not in ("T", "O", "R"):
            return None
        width = 10 if kind == "R" else 8
        # the first two entries in plain Python first: a file written with wildcards or
        # whole rows (Hallway: 849 entries, none in the fast form) would otherwise pay the
        # numpy block below at every entry, 70 % of its reading time
        tk, at = p.window(2 * width)
        if len(tk) - at < 2 * width:
            return None
        for e in (at, at + width):
            fits = (tk[e] == kind and tk[e + 1] == ":" and tk[e + 3] == ":" and tk[e + 5] == ":"
                    and tk[e + 4] != "*")  # fmt: skip
            if kind == "R":
                fits = fits and tk[e + 6] == "*" and tk[e + 7] == ":" and tk[e + 8] == "*"
            else:
                fits = fits and tk[e + 6] != "*"
            if not fits:
                self.window = 16
                return None
        # the block of the next `window` entries (held as tokens only while it is read)
        tk, at = p.window(self.window * width)
        n = min(len(tk) - at, self.window * width) // width
        block = np.array(tk[at : at + n * width], dtype=object).reshape(n, width)
        ok = (block[:, 0] == kind) & (block[:, 1] == ":") & (block[:, 3] == ":")
        ok &= (block[:, 5] == ":") & (block[:, 4] != "*")
        if kind == "R":
            ok &= (block[:, 6] == "*") & (block[:, 7] == ":") & (block[:, 8] == "*")
        else:
            ok &= block[:, 6] != "*"
        count = n if ok.all() else int(np.argmin(ok))
        self.window = min(self.window * 2, _WINDOW) if count == n else 16
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
