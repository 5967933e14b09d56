"""Sawtooth upper bound over a point set, per observed value (flat and MOMDP).

The sawtooth interpolation (Hauskrecht 2000; used by HSVI, Smith & Simmons 2004, and SARSOP,
Kurniawati, Hsu & Lee 2008) bounds the optimal value at any belief from the corner values
``c(y) >= V*(e_y)`` and a set of belief points ``(b_i, v_i)`` with ``v_i >= V*(b_i)``::

    V_up(b) = b . c + min(0, min_i (v_i - b_i . c) * min_{y : b_i(y) > 0} b(y) / b_i(y))

For a MOMDP (Ong et al. 2010) the bound is kept per observed value ``x``: corner values
``c: (X, Y)`` and points ``(x_i, b_i, v_i)``; a point only bounds beliefs with the same ``x``.
A flat POMDP is the case ``X = 1``. ``V_up`` is positively homogeneous (``V_up(k b) =
k V_up(b)`` for ``k >= 0``), so it can be evaluated at unnormalised beliefs, e.g.
``P(o | b, a) * tau(b, a, o)``, which is what the solvers sum.

Points are stored sparsely: the supports of all points (indices and probabilities) end to
end in one flat array, each point's found by its offset and width, so a point costs its
support and not the widest support seen (TagAvoid: most points cover a few dozen of 870
states, the widest 841). On any device :meth:`SawtoothUpperBound.value` evaluates ``B``
beliefs against ``P`` points, their supports padded to the widest ``K`` (built on demand
and kept until the points change), as one gather and one ``min`` over tensors
(``B * P * K``); on the CPU, :meth:`SawtoothUpperBound.value_np` (the
solvers' sequential path) runs a compiled loop over each ``x``'s points sorted by gain that
stops as soon as no remaining point can lower the bound
(:mod:`~torchhrc.solvers.sawtooth_kernel`), with the same result.

Example:
    >>> import torch
    >>> ub = SawtoothUpperBound(torch.tensor([[10.0, 0.0]], dtype=torch.float64))
    >>> ub.add(torch.tensor([[0.5, 0.5]], dtype=torch.float64), torch.tensor([0]),
    ...        torch.tensor([2.0], dtype=torch.float64))
    >>> ub.value(torch.tensor([[0.5, 0.5], [1.0, 0.0]], dtype=torch.float64), torch.tensor([0, 0]))
    tensor([ 2., 10.], dtype=torch.float64)
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import torch

from torchhrc._checks import all_finite
from torchhrc._host import alloc, copy_front, host_view
from torchhrc.errors import ModelError
from torchhrc.solvers import backup_kernel
from torchhrc.solvers.sawtooth_kernel import (
    sawtooth_corrections,
    support_signature,
    support_signatures,
)

__all__ = ["SawtoothUpperBound"]

# elements of the (B, P, K) ratio tensor computed at once by the tensor path :meth:`value` (4 MB
# in float64; 1 << 22 made 32 MB temporaries, each a fresh mmap and its page faults)
_CHUNK = 1 << 19
_COMPACT_ENTRIES = 1 << 18  # support entries moved at once when a pruning compacts them
_ROWS = np.arange(1024)  # row indices 0..B-1 of a query, sliced (read only)
_ROWS.flags.writeable = False
_NO_IDS, _NO_KEYS = np.empty(0, dtype=np.int64), np.empty(0)  # no key order built yet


#: At most this many dense belief entries at a time in :meth:`SawtoothUpperBound.prune`
#: (2^20 floats: 8 MB, and as much again for their product with the corners), whatever the
#: block of points it disables together. At 2^22 each pruning of the 20,000-state model's
#: points raised the resident memory by about 70 MB for its duration, the solve's peak at
#: 10 s where it fell late; the values are the same at any size (each row's own).
_DENSE_ENTRIES = 1 << 20


class SawtoothUpperBound:
    """A sawtooth upper bound with corner values and sparse points, per observed ``x``.

    Args:
        corner: ``(X, Y)`` corner values, ``corner[x, y] >= V*(x, e_y)`` (e.g. the Fast Informed
            Bound); for a flat POMDP ``(1, S)``. Its dtype and device are used throughout.
        capacity: initial number of point slots (grown geometrically).

    Raises:
        ModelError: ``corner`` is not a finite 2-D floating tensor.
    """

    def __init__(self, corner: torch.Tensor, *, capacity: int = 256) -> None:
        if not isinstance(corner, torch.Tensor) or not corner.is_floating_point():
            raise TypeError(f"expected corner to be a floating torch.Tensor, got {type(corner)}")
        if corner.dim() != 2:
            raise ModelError(
                f"expected corner to have shape (X, Y), actual shape = {tuple(corner.shape)}"
            )
        if not all_finite(corner):
            raise ModelError("corner values must be finite")
        X, Y = corner.shape
        self.num_observed, self.num_hidden = X, Y
        dev, dt = corner.device, corner.dtype
        c = host_view(corner)
        self.corner = corner.clone() if c is None else torch.from_numpy(c.copy())  # (X, Y)
        cap = max(int(capacity), 1)
        # the supports end to end: point i's are entries _off[i] to _off[i] + _w[i]
        self._fidx = alloc(cap * 4, torch.long, dev, fill=None)  # (E,) hidden values
        self._finv = alloc(cap * 4, dt, dev, fill=None)  # (E,) 1 / b_i(y) on them
        self._off = alloc(cap, torch.long, dev)  # (P,) start of a support
        self._used = 0  # entries of _fidx / _finv in use
        self._kmax = 1  # the widest support ever stored (the width of the padded rows)
        self._padded_cache: tuple[int, torch.Tensor, torch.Tensor] | None = None
        self._stamp = 0  # counts changes of the stored supports (for _padded_cache)
        self._x = alloc(cap, torch.long, dev)  # (P,) observed value of point
        self._v = alloc(cap, dt, dev)  # (P,) upper value v_i at b_i
        self._gain = alloc(cap, dt, dev)  # (P,) v_i - b_i . c (<= 0 useful)
        self._w = alloc(cap, torch.long, dev, fill=1)  # (P,) support width of point
        self._mass = alloc(cap, dt, dev, fill=1)  # (P,) sum_y b_i(y) (1 up to round-off)
        # (P,) support signature, bit y % 64 per hidden value y of the support (CPU storage;
        # the compiled loops skip a point that covers a value where the row is 0)
        self._sig = alloc(cap, torch.long, dev)
        self.size = 0
        self._alive_after_prune = 0
        self._views()
        # per observed value, the indices of its points (CPU): an evaluation at x only
        # looks at x's points (Ong et al. 2010), not at all of them
        self._members = [np.empty(4, dtype=np.int64) for _ in range(X)] if self._np else []
        self._count = np.zeros(X, dtype=np.int64)
        # per observed value, its points with a negative gain by increasing key g_i / s_i and
        # those keys (the order of the compiled loop, sawtooth_kernel); None: to be rebuilt.
        # They are views of the first entries of _sorted_room[x], arrays with room to insert
        # a new point in place
        self._sorted: list[tuple[np.ndarray, np.ndarray] | None] = [None] * X
        self._sorted_room: list[tuple[np.ndarray, np.ndarray]] = [(_NO_IDS, _NO_KEYS)] * X
        # a point stored in one compiled call (backup_kernel.add_point): float64 on the CPU
        self._add_kernel = (backup_kernel.load()
                            if self._np is not None and dt == torch.float64 else None)  # fmt: skip
        # several observed values, float64 on the CPU: queries of mixed x in one compiled
        # call (backup_kernel.group_upper) instead of one loop call per x
        usable = self._np is not None and X > 1 and dt == torch.float64
        self._group_kernel = backup_kernel.load() if usable else None

    # -- storage -----------------------------------------------------------------------------
    def _views(self) -> None:
        """Refresh the numpy views of the storage (CPU only; after every reallocation)."""
        if self.corner.device.type != "cpu":
            self._np = None
            return
        self._np = (self.corner.numpy(), self._fidx.numpy(), self._finv.numpy(), self._x.numpy(),
                    self._v.numpy(), self._gain.numpy(), self._w.numpy(), self._mass.numpy(),
                    self._off.numpy(), self._sig.numpy())  # fmt: skip

    def _add_member(self, x: int, i: int) -> None:
        if self._np is None:
            return
        arr, m = self._member_space(x)
        arr[m] = i
        self._count[x] = m + 1
        self._insert_sorted(x, i)

    def _member_space(self, x: int) -> tuple[np.ndarray, int]:
        """``x``'s member array with room for one more, and how many it holds."""
        m = int(self._count[x])
        arr = self._members[x]
        if m == arr.shape[0]:
            arr = self._members[x] = np.concatenate([arr, np.empty(m, dtype=np.int64)])
        return arr, m

    def _insert_sorted(self, x: int, i: int) -> None:
        """Put a new point ``i`` of ``x`` into ``x``'s key order (if built and it can help)."""
        cur = self._sorted[x]
        if cur is None:
            return
        gain, mass = self._np[5], self._np[7]  # type: ignore[index]
        if gain[i] >= 0:
            return
        p = cur[0].size
        ids, keys = self._sorted_space(x, p)
        k = gain[i] / mass[i]
        pos = int(keys[:p].searchsorted(k, side="right"))
        ids[pos + 1 : p + 1], keys[pos + 1 : p + 1] = ids[pos:p].copy(), keys[pos:p].copy()
        ids[pos], keys[pos] = i, k
        self._sorted[x] = (ids[: p + 1], keys[: p + 1])

    def _sorted_space(self, x: int, p: int) -> tuple[np.ndarray, np.ndarray]:
        """``x``'s key-order arrays with room for one more than their ``p`` points."""
        ids, keys = self._sorted_room[x]
        if p >= ids.shape[0]:
            new_ids, new_keys = self._new_sorted_room(x, p)
            new_ids[:p], new_keys[:p] = ids[:p], keys[:p]
            ids, keys = new_ids, new_keys
        return ids, keys

    def _new_sorted_room(self, x: int, p: int) -> tuple[np.ndarray, np.ndarray]:
        """New key-order arrays of ``x`` with room for ``p`` points and as many more (and 8)."""
        room = self._sorted_room[x] = (np.empty(2 * p + 8, dtype=np.int64), np.empty(2 * p + 8))
        return room

    def _sorted_points(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """``(P',)`` x's points with a negative gain by increasing key ``g_i / s_i``; keys."""
        cur = self._sorted[x]
        if cur is None:
            gain, mass = self._np[5], self._np[7]  # type: ignore[index]
            ids = self.members(x)
            ids = ids[gain[ids] < 0]
            key = gain[ids] / mass[ids]
            order = np.argsort(key, kind="stable")
            p = order.size
            room_ids, room_keys = self._new_sorted_room(x, p)
            room_ids[:p], room_keys[:p] = ids[order], key[order]
            cur = (room_ids[:p], room_keys[:p])
            self._sorted[x] = cur
        return cur

    def _rebuild_members(self) -> None:
        if self._np is None:
            return
        n = self.size
        px = self._np[3][:n]
        order = np.argsort(px, kind="stable")
        counts = np.bincount(px, minlength=self.num_observed)
        ends = np.cumsum(counts)
        for x in range(self.num_observed):
            ids = order[ends[x] - counts[x] : ends[x]]
            arr = np.empty(max(4, 2 * ids.size), dtype=np.int64)
            arr[: ids.size] = ids
            self._members[x] = arr
        self._count[:] = counts
        self._sorted = [None] * self.num_observed

    def members(self, x: int) -> np.ndarray:
        """``(P_x,)`` the indices of the points of observed value ``x`` (CPU storage only)."""
        return self._members[x][: self._count[x]]

    def _grow(self, need: int, entries: int) -> None:
        """Room for ``need`` points and ``entries`` support entries (capacities doubled)."""
        cap = self._off.shape[0]
        if need > cap:
            new_cap = max(cap, 1)
            while new_cap < need:
                new_cap *= 2
            for name in ("_x", "_v", "_gain", "_w", "_mass", "_off", "_sig"):
                old = getattr(self, name)
                new = alloc(new_cap, old.dtype, old.device)
                copy_front(new, old, self.size)
                setattr(self, name, new)
        ecap = self._fidx.shape[0]
        if entries > ecap:
            new_e = max(ecap, 1)
            while new_e < entries:
                new_e *= 2
            # empty, not zeros: only the entries written are touched, so the free room stays
            # pages that are not resident
            fidx = alloc(new_e, self._fidx.dtype, self._fidx.device, fill=None)
            finv = alloc(new_e, self._finv.dtype, self._finv.device, fill=None)
            copy_front(fidx, self._fidx, self._used)
            copy_front(finv, self._finv, self._used)
            self._fidx, self._finv = fidx, finv
        if need > cap or entries > ecap:
            self._views()

    def _padded(self, ids: Any) -> tuple[Any, Any]:
        """``(n, K)`` supports and ``1 / b_i(y)`` of points ``ids (n,)``, padded to the widest
        support ever stored with the index ``Y`` and ``1`` (what the tensor path gathers).

        ``ids`` a tensor: tensors of the storage's device; a numpy array (CPU storage):
        numpy arrays, from the storage's numpy views."""
        if isinstance(ids, np.ndarray):
            assert self._np is not None
            fidx, finv, wid, off = self._np[1], self._np[2], self._np[6], self._np[8]
            where, k = np.where, np.arange(self._kmax)
        else:
            fidx, finv, wid, off = self._fidx, self._finv, self._w, self._off
            where, k = torch.where, torch.arange(self._kmax, device=ids.device)
        inside = k < wid[ids][:, None]  # (n, K)
        pos = where(inside, off[ids][:, None] + k, 0)
        return where(inside, fidx[pos], self.num_hidden), where(inside, finv[pos], 1.0)

    def _padded_all(self) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`_padded` of every point, kept until the stored supports change."""
        cached = self._padded_cache
        if cached is None or cached[0] != self._stamp:
            ids = torch.arange(self.size, device=self._off.device)
            cached = (self._stamp, *self._padded(ids))
            self._padded_cache = cached
        return cached[1], cached[2]

    def _append(self, idx: Any, inv: Any) -> int:
        """Store one more point's support ``idx (w,)`` and ``1 / b(y)`` there, ``inv (w,)``,
        at the end of the flat arrays (numpy arrays on the CPU storage, tensors elsewhere);
        returns its offset. The point's other fields are the caller's."""
        w = idx.shape[0]
        start = self._used
        self._grow(self.size + 1, start + w)
        fidx, finv = (self._fidx, self._finv) if self._np is None else self._np[1:3]
        fidx[start : start + w] = idx
        finv[start : start + w] = inv
        self._used = start + w
        self._kmax = max(self._kmax, w)
        self._stamp += 1
        return start

    def _refresh_gain(self, x: int | None = None) -> None:
        """Recompute the gains after a corner change (only ``x``'s points when given).

        ``b_i . c`` is summed over each point's padded row (numpy for one ``x`` on the CPU,
        torch otherwise), as before the supports were stored end to end, so the gains are the
        same floats; a block of points at a time keeps the padded temporaries small."""
        if x is not None and self._np is not None:
            corner, v, gain = self._np[0], self._np[4], self._np[5]
            c = np.append(corner[x], 0.0)  # (Y + 1,), the pad index Y maps to 0
            ids, step = self.members(x), self._block()
            for blk in (ids[i : i + step] for i in range(0, ids.size, step)):
                idx, inv = self._padded(blk)
                gain[blk] = v[blk] - (c[idx] / inv).sum(-1)
            self._sorted[x] = None
            return
        self._sorted = [None] * self.num_observed
        c = torch.cat([self.corner, self.corner.new_zeros(self.num_observed, 1)], dim=1)
        ids = torch.arange(self.size, device=c.device)
        for blk in ids.split(self._block()):
            idx, inv = self._padded(blk)
            self._gain[blk] = self._v[blk] - (c[self._x[blk]].gather(1, idx) / inv).sum(-1)

    def _block(self) -> int:
        """Points per block of padded rows (about ``_CHUNK`` entries)."""
        return max(1, _CHUNK // self._kmax)

    @property
    def points(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The stored points as dense tensors: ``beliefs (P, Y)``, ``x (P,)``, ``values (P,)``."""
        n = self.size
        ids = torch.arange(n, device=self._off.device)
        return self._dense(ids), self._x[:n].clone(), self._v[:n].clone()

    def _entries(self, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The positions ``(E',)`` in the flat arrays of the supports of points ``ids (n,)``,
        one after the other, and their widths ``(n,)``."""
        w = self._w[ids]
        start = torch.cumsum(w, 0) - w  # (n,) where each point's entries begin in the result
        pos = torch.repeat_interleave(self._off[ids] - start, w)
        return pos + torch.arange(pos.shape[0], device=w.device), w

    def _dense(self, ids: torch.Tensor) -> torch.Tensor:
        """``(n, Y)`` the beliefs of points ``ids (n,)`` as dense rows."""
        pos, w = self._entries(ids)
        return self._rows(pos, w, self._fidx[pos], self.num_hidden)

    def _rows(self, pos: torch.Tensor, w: torch.Tensor, columns: torch.Tensor,
              width: int) -> torch.Tensor:  # fmt: skip
        """``(n, width)`` rows of the supports at ``pos`` (point ``i``'s ``w[i]`` entries one
        after the other, :meth:`_entries`), each entry in its column of ``columns``."""
        rows = torch.repeat_interleave(torch.arange(w.shape[0], device=w.device), w)
        out = self.corner.new_zeros(w.shape[0], width)
        out[rows, columns] = 1.0 / self._finv[pos]
        return out

    # -- evaluation --------------------------------------------------------------------------
    def value(self, beliefs: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The sawtooth bound at (possibly unnormalised) beliefs.

        Args:
            beliefs: ``(B, Y)`` non-negative weights over the hidden values (a belief, or a
                belief times a probability).
            x: ``(B,)`` long, the observed value of each belief (all zeros for a flat POMDP).

        Returns:
            ``(B,)`` upper bounds, ``V_up(beliefs[i])`` at observed value ``x[i]``.
        """
        base = (beliefs * self.corner[x]).sum(-1)  # (B,)
        n = self.size
        B = beliefs.shape[0]
        if n == 0 or B == 0:
            return base
        idx, inv = self._padded_all()
        px, gain = self._x[:n], self._gain[:n]
        if self.num_observed > 1:  # only the points of the queried observed values compete
            sel = torch.isin(px, x).nonzero().squeeze(-1)
            if sel.numel() == 0:
                return base
            idx, inv, px, gain = idx[sel], inv[sel], px[sel], gain[sel]
        if idx.shape[0] > 64:
            # a point only lowers the bound at b if b covers its support; test its first
            # support entry against every query (a cheap necessary condition)
            sel = (beliefs[:, idx[:, 0]] > 0).any(0).nonzero().squeeze(-1)
            if sel.numel() == 0:
                return base
            if sel.numel() < idx.shape[0]:
                idx, inv, px, gain = idx[sel], inv[sel], px[sel], gain[sel]
        P, K = idx.shape
        ext = torch.cat([beliefs, beliefs.new_full((B, 1), float("inf"))], dim=1)  # (B, Y+1)
        best = None
        step = max(1, _CHUNK // max(1, B * K))
        for start in range(0, P, step):
            stop = min(P, start + step)
            g = ext[:, idx[start:stop].reshape(-1)].view(B, stop - start, K)
            term = (g * inv[start:stop]).amin(-1) * gain[start:stop]  # (B, p), <= 0
            if self.num_observed > 1:
                term = term.masked_fill(px[start:stop] != x.unsqueeze(-1), 0.0)
            low = term.amin(-1)
            best = low if best is None else torch.minimum(best, low)
        assert best is not None
        return base + best.clamp(max=0.0)

    def loop_storage(self, xs: Iterable[int]) -> tuple[Any, ...]:
        """``(corner (X, Y), sorted, idx, inv, off, wid, gain, sig)``: what the compiled loops
        read (:func:`~torchhrc.solvers.backup_kernel.group_upper`, ``bound_children``), with
        ``sorted[x] = (order, key)`` (the points of ``x`` with a negative gain by increasing
        key) built for every ``x`` of ``xs`` and ``sig`` the points' support signatures
        (:func:`~torchhrc.solvers.sawtooth_kernel.support_signatures`); CPU storage only.

        Example:
            >>> import torch
            >>> ub = SawtoothUpperBound(torch.tensor([[1.0, 2.0]], dtype=torch.float64))
            >>> corner, points = ub.loop_storage([0])[:2]
            >>> corner.tolist(), points[0][0].shape  # no point yet
            ([[1.0, 2.0]], (0,))
        """
        assert self._np is not None
        corner, idx, inv, _, _, gain, wid, _, off, sig = self._np
        for x in xs:
            self._sorted_points(x)
        return corner, self._sorted, idx, inv, off, wid, gain, sig

    def value_np(
        self, beliefs: np.ndarray, x: np.ndarray, columns: np.ndarray | None = None
    ) -> np.ndarray:
        """:meth:`value` on numpy arrays (CPU storage only), for the sequential solver path.

        The same formula with far less per-call overhead than tensor ops at small sizes:
        each query's observed value's points are visited by increasing key in a compiled loop
        that stops as soon as no remaining point can lower the bound
        (:func:`~torchhrc.solvers.sawtooth_kernel.sawtooth_corrections`); the result is the
        exhaustive minimum, bit for bit.

        Args:
            beliefs: ``(B, Y)`` non-negative weights (the dtype of the bound's storage).
            x: ``(B,)`` int observed values.
            columns: optional ``(C,)`` sorted hidden values: ``beliefs`` is then ``(B, C)``,
                the columns ``columns`` of the full ``(B, Y)`` beliefs, which are zero
                elsewhere (the sparse flat path: a few hundred of 12545 states).

        Returns:
            ``(B,)`` upper bounds.
        """
        assert self._np is not None
        B = beliefs.shape[0]
        if self._group_kernel is not None and columns is None and self.size and B:
            out = np.empty(B)
            backup_kernel.group_upper(self._group_kernel, np.ascontiguousarray(beliefs),
                                      x.astype(np.int64, copy=False),
                                      self.loop_storage(set(x.tolist())), out)  # fmt: skip
            return out
        corner, idx, inv, _, _, gain, wid, _, off, sig = self._np
        local = None
        if columns is None:
            # (B,); one observed value: the same products without gathering B rows of corner
            base = (beliefs * (corner[0] if self.num_observed == 1 else corner[x])).sum(-1)
        else:
            if self.num_observed == 1:
                base = beliefs @ corner[0, columns]  # (B,)
            else:
                base = (beliefs * corner[x[:, None], columns[None, :]]).sum(-1)
            # hidden value -> column of ``beliefs``; C where the column is not given (b = 0)
            local = np.full(self.num_hidden, columns.size, dtype=np.int64)
            local[columns] = np.arange(columns.size)
        if self.size == 0 or B == 0:
            return base
        first = int(x[0])
        if self.num_observed == 1 or (x == first).all():  # one observed value: all rows at once
            rows = _ROWS[:B] if B <= _ROWS.size else np.arange(B)
            pts, key = self._sorted_points(first)
            return base + sawtooth_corrections(beliefs, rows, pts, idx, inv, off, wid, gain, key,
                                               local, sig)  # fmt: skip
        order = np.argsort(x, kind="stable")
        sx = x[order]
        out = np.empty(B, dtype=base.dtype)
        for rows in np.split(order, np.flatnonzero(sx[1:] != sx[:-1]) + 1):
            pts, key = self._sorted_points(int(x[rows[0]]))
            out[rows] = sawtooth_corrections(beliefs, rows, pts, idx, inv, off, wid, gain, key,
                                             local, sig)  # fmt: skip
        return base + out

    # -- updates -----------------------------------------------------------------------------
    def add(self, beliefs: torch.Tensor, x: torch.Tensor, values: torch.Tensor) -> None:
        """Add points ``(x_i, b_i, v_i)``; a one-hot belief lowers its corner value instead.

        Args:
            beliefs: ``(B, Y)`` normalised beliefs.
            x: ``(B,)`` long observed values.
            values: ``(B,)`` upper bounds ``v_i >= V*(x_i, b_i)``.
        """
        if beliefs.shape[0] == 0:
            return
        if beliefs.shape[0] == 1:
            self._add_one(beliefs[0], int(x[0]), values.reshape(-1)[:1])
            return
        support = beliefs > 0
        width = support.sum(-1)  # (B,)
        corner_rows = (width == 1).nonzero().squeeze(-1)
        if corner_rows.numel() > 0:
            ys = beliefs[corner_rows].argmax(-1)
            xs = x[corner_rows]
            cur = self.corner[xs, ys]
            self.corner[xs, ys] = torch.minimum(cur, values[corner_rows])
        rows = (width > 1).nonzero().squeeze(-1)
        if corner_rows.numel() > 0:
            self._refresh_gain()
        if rows.numel() == 0:
            return
        b, bx, bv, w = beliefs[rows], x[rows], values[rows], width[rows]
        self._kmax = Kc = max(self._kmax, int(w.max()))
        m, total = rows.numel(), int(w.sum())
        self._grow(self.size + m, self._used + total)
        # each row's support by increasing hidden value, padded to Kc (the gains are summed
        # over the padded rows, as the tensor path evaluates them)
        order = torch.argsort((~support[rows]).to(torch.int8), dim=-1, stable=True)[:, :Kc]
        keep = support[rows].gather(1, order)
        idx = torch.where(keep, order, order.new_full((), self.num_hidden))
        val = torch.where(keep, b.gather(1, order), b.new_ones(()))
        s, e = slice(self.size, self.size + m), slice(self._used, self._used + total)
        self._fidx[e], self._finv[e] = idx[keep], 1.0 / val[keep]
        self._off[s] = self._used + torch.cumsum(w, 0) - w
        self._x[s], self._v[s] = bx, bv
        c = torch.cat([self.corner, self.corner.new_zeros(self.num_observed, 1)], dim=1)
        self._gain[s] = bv - (c[bx].gather(1, idx) * val).sum(-1)
        self._w[s] = w
        self._mass[s] = b.sum(-1)
        if self._np is not None:
            starts = (torch.cumsum(w, 0) - w).numpy()
            self._sig[s] = torch.from_numpy(support_signatures(idx[keep].numpy(), starts))
        self.size += m
        self._used += total
        self._stamp += 1
        if self._np is not None:
            for i, xi in enumerate(bx.tolist()):
                self._add_member(xi, s.start + i)

    def _add_one(self, belief: torch.Tensor, x: int, value: torch.Tensor) -> None:
        """:meth:`add` for one belief ``(Y,)`` (the sequential path: fewer tensor ops)."""
        if self.corner.device.type == "cpu":
            self.add_np(belief.numpy(), x, float(value[0]))
            return
        idx = belief.nonzero().squeeze(-1)  # (w,) the support
        w = idx.numel()
        if w == 1:
            y = int(idx[0])
            if float(value[0]) < float(self.corner[x, y]):
                self.corner[x, y] = value[0]
                self._refresh_gain()
            return
        n = self.size
        val = belief[idx]
        start = self._append(idx, 1.0 / val)
        self._off[n] = start
        self._x[n] = x
        self._v[n] = value[0]
        self._gain[n] = value[0] - (self.corner[x, idx] * val).sum()
        self._w[n] = w
        self._mass[n] = val.sum()
        self.size = n + 1

    def add_np(self, belief: np.ndarray, x: int, value: float) -> None:
        """Add one point ``(x, b, v)`` from numpy (CPU storage only; the sequential path).

        Args:
            belief: ``(Y,)`` a normalised belief.
            x: its observed value.
            value: an upper bound ``v >= V*(x, b)``.
        """
        assert self._np is not None
        if self._add_kernel is not None and belief.dtype == np.float64:
            if self._add_compiled(belief, x, value):
                return
        idx = belief.nonzero()[0]  # (w,) the support (a 1-D belief: flatnonzero's array)
        w = idx.size
        corner = self._np[0]
        if w == 1:
            y = int(idx[0])
            if value < corner[x, y]:
                corner[x, y] = value
                self._refresh_gain(x)
            return
        # (one point a backup: _append's steps inline, without its calls and the array
        # wrappers' overheads; the same values stored)
        n, start = self.size, self._used
        if n >= self._off.shape[0] or start + w > self._fidx.shape[0]:
            self._grow(n + 1, start + w)
        _, fidx, finv, px, v, gain, wid, mass, off, sig = self._np
        val = belief[idx]
        fidx[start : start + w] = idx
        np.divide(1.0, val, out=finv[start : start + w])
        self._used = start + w
        if w > self._kmax:
            self._kmax = w
        self._stamp += 1
        off[n] = start
        px[n] = x
        v[n] = value
        gain[n] = value - float(corner[x, idx] @ val)
        wid[n] = w
        mass[n] = np.add.reduce(val)
        sig[n] = support_signature(idx)
        self.size = n + 1
        self._add_member(x, n)

    def _add_compiled(self, belief: np.ndarray, x: int, value: float) -> bool:
        """:meth:`add_np` in one compiled call (:func:`backup_kernel.add_point`); ``False``
        where the belief has one hidden value (the corner's case, left to the caller)."""
        n, start, Y = self.size, self._used, belief.shape[0]
        if n >= self._off.shape[0] or start + Y > self._fidx.shape[0]:
            self._grow(n + 1, start + Y)  # (room for the widest support; the rest untouched)
        members, m = self._member_space(x)
        cur = self._sorted[x]
        p = -1 if cur is None else cur[0].size
        order, key = self._sorted_room[x] if cur is None else self._sorted_space(x, p)
        _, idx, inv, px, v, gain, wid, mass, off, sig = self._np  # type: ignore[misc]
        w, pos = self._add_kernel.add_point(  # type: ignore[union-attr]
            np.ascontiguousarray(belief), self._np[0], idx, inv, px, v, gain, wid, mass, off,
            sig, members, order, key, x, float(value), n, start, m, p,
        )  # fmt: skip
        if w == 1:
            return False
        self._used = start + w
        if w > self._kmax:
            self._kmax = w
        self._stamp += 1
        self.size = n + 1
        self._count[x] = m + 1
        if pos >= 0:
            self._sorted[x] = (order[: p + 1], key[: p + 1])
        return True

    def prune(self) -> int:
        """Remove points that the other points and the corners already bound as tightly.

        A point is kept when its value is strictly below the sawtooth of the others at its
        own belief. Returns the number of points removed.
        """
        n = self.size
        if n == 0:
            return 0
        if self._np is not None:
            return self._prune_np()
        x, v = self._x[:n], self._v[:n]
        useful = self._gain[:n] < 0
        # Evaluate each point against all others, excluding itself, by masking its own gain.
        saved = self._gain[:n].clone()
        keep = useful.clone()
        block = max(1, min(n, 256))
        # the block's beliefs are evaluated some rows at a time (on the CPU on the union of
        # their supports where it is narrow, :meth:`_supports_np`; else as dense rows: 256 rows
        # of a 100,000-state model are 205 MB, and the corner product as much again, a
        # transient of a solve's peak); each belief's value is its own, so the values are the
        # same
        dense_rows = max(1, _DENSE_ENTRIES // max(1, self.num_hidden))
        for start in range(0, n, block):
            stop = min(n, start + block)
            rows = torch.arange(start, stop, device=x.device)
            # Temporarily disable the evaluated points (one at a time in each block would be
            # exact; disabling the whole block is conservative: it only keeps more points).
            self._gain[start:stop] = 0.0
            self._sorted = [None] * self.num_observed  # the key order follows the gains
            others = torch.cat([self.value(self._dense(part), x[part])
                                for part in rows.split(dense_rows)])  # fmt: skip
            self._gain[start:stop] = saved[start:stop]
            self._sorted = [None] * self.num_observed
            keep[start:stop] &= v[rows] < others - 1e-12 * others.abs().clamp(min=1.0)
        sel = keep.nonzero().squeeze(-1)
        removed = n - sel.numel()
        if removed:
            # the kept supports, moved to the front end to end in their order, a block of
            # about 2^18 entries at a time (all at once, the index arrays and gathered copies
            # of RockSample_7_8's million entries raised the solve's peak memory by 30 MB).
            # Supports lie in point order, so a block lands at or before where it is read and
            # never over a later block's entries.
            w = self._w[sel]
            start = torch.cumsum(w, 0) - w
            step = max(1, _COMPACT_ENTRIES // max(1, self._kmax))
            for i in range(0, sel.numel(), step):
                pos, _ = self._entries(sel[i : i + step])
                at = int(start[i])
                self._fidx[at : at + pos.shape[0]] = self._fidx[pos]
                self._finv[at : at + pos.shape[0]] = self._finv[pos]
            self._off[: sel.numel()] = start
            self._used = int(w.sum())
            self._stamp += 1
            self._x[: sel.numel()] = self._x[sel]
            self._v[: sel.numel()] = self._v[sel]
            self._gain[: sel.numel()] = self._gain[sel]
            self._w[: sel.numel()] = self._w[sel]
            self._mass[: sel.numel()] = self._mass[sel]
            self._sig[: sel.numel()] = self._sig[sel]
            self.size = sel.numel()
            self._rebuild_members()
        self._alive_after_prune = self.size
        return removed

    def _prune_np(self) -> int:
        """:meth:`prune` on CPU storage, through its numpy views (a small model prunes every
        few iterations, and torch's operations on these few points cost more than the
        arithmetic, besides the code pages of their first calls: torchhrc._host)."""
        assert self._np is not None
        n = self.size
        _, fidx, finv, px, pv, gain, wid, mass, off, sig = self._np
        v = pv[:n]
        saved = gain[:n].copy()
        keep = saved < 0
        block = max(1, min(n, 256))
        dense_rows = max(1, _DENSE_ENTRIES // max(1, self.num_hidden))
        for start in range(0, n, block):
            stop = min(n, start + block)
            gain[start:stop] = 0.0  # the block's own points disabled (as prune)
            self._sorted = [None] * self.num_observed
            others = np.concatenate([
                self.value_np(*self._supports_np(np.arange(a, min(stop, a + dense_rows))))
                for a in range(start, stop, dense_rows)
            ])  # fmt: skip
            gain[start:stop] = saved[start:stop]
            self._sorted = [None] * self.num_observed
            keep[start:stop] &= v[start:stop] < others - 1e-12 * np.maximum(np.abs(others), 1.0)
        sel = np.flatnonzero(keep)
        removed = n - sel.size
        if removed:
            # the kept supports moved to the front, as prune moves them
            w = wid[sel]
            start = np.cumsum(w) - w
            step = max(1, _COMPACT_ENTRIES // max(1, self._kmax))
            for i in range(0, sel.size, step):
                pos = self._entries_np(sel[i : i + step])
                at = int(start[i])
                fidx[at : at + pos.size] = fidx[pos]
                finv[at : at + pos.size] = finv[pos]
            off[: sel.size] = start
            self._used = int(w.sum())
            self._stamp += 1
            for arr in (px, pv, gain, wid, mass, sig):
                arr[: sel.size] = arr[sel]
            self.size = sel.size
            self._rebuild_members()
        self._alive_after_prune = self.size
        return removed

    def _entries_np(self, ids: np.ndarray) -> np.ndarray:
        """:meth:`_entries`' positions ``(E',)`` of the supports of points ``ids``, in numpy."""
        assert self._np is not None
        off, w = self._np[8][ids], self._np[6][ids]
        start = np.cumsum(w) - w
        return np.repeat(off - start, w) + np.arange(int(w.sum()))

    def _supports_np(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The arguments of :meth:`value_np` for the beliefs of points ``ids``: their rows
        (on the sorted union of their supports where it spans at most half of ``Y``, with
        one observed value: a flat model's beliefs, a few of 20,000 states, whose dense rows were 8
        MB a block), their observed values and the columns."""
        assert self._np is not None
        _, fidx, finv, px = self._np[:4]
        w = self._np[6][ids]
        pos = self._entries_np(ids)
        idx = fidx[pos]
        rows = np.repeat(np.arange(ids.size), w)
        cols = None
        width = self.num_hidden
        if self.num_observed == 1 and pos.size:
            union, local = np.unique(idx, return_inverse=True)
            if 2 * union.size <= self.num_hidden:
                cols, idx, width = union, local, union.size
        out = np.zeros((ids.size, width), dtype=finv.dtype)
        out[rows, idx] = 1.0 / finv[pos]
        return out, px[ids], cols
