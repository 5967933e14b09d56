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

Points are stored sparsely: the support of each point (indices and probabilities, padded to
the widest point seen), so one evaluation costs ``B * P * K`` for ``B`` beliefs, ``P`` points
and supports of at most ``K`` entries, done as one gather and one ``min`` over tensors.

Example:
    >>> import torch
    >>> ub = SawtoothUpperBound(torch.tensor([[10.0, 0.0]], dtype=torch.float64))
    >>> ub.add(torch.tensor([[0.5, 0.5]], dtype=torch.float64), torch.tensor([0]),
    ...        torch.tensor([2.0], dtype=torch.float64))
    >>> ub.value(torch.tensor([[0.5, 0.5], [1.0, 0.0]], dtype=torch.float64), torch.tensor([0, 0]))
    tensor([ 2., 10.], dtype=torch.float64)
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from torchhrc.errors import ModelError

__all__ = ["SawtoothUpperBound"]

# elements of the (B, P, K) ratio tensor computed at once (4 MB in float64; 1 << 22 made 32 MB
# temporaries, each a fresh mmap and its page faults: RockSample_11_11.pomdpx, Y = 2048)
_CHUNK = 1 << 19
_DENSE_CHUNK = 1 << 16  # elements of a dense (b, Y, P_x) product (512 kB in float64)


def _pair_minima(
    r: np.ndarray,
    p: np.ndarray,
    wp: np.ndarray,
    gain: np.ndarray,
    B: int,
    ratios: Callable[[np.ndarray, np.ndarray, int], np.ndarray],
) -> np.ndarray:
    """``(B,)`` sawtooth corrections ``min(0, min_i gain_i * min_y b(y) / b_i(y))`` per query.

    Args:
        r: ``(M,)`` sorted query index of each candidate (query, point) pair.
        p: ``(M,)`` point index of each pair; wp: ``(M,)`` its support width.
        gain: ``(P,)`` the points' gains; B: number of queries.
        ratios: ``ratios(rr (m,), pp (m,), Kb) -> (m, Kb)`` the ratios ``b(y) / b_i(y)`` on
            the first ``Kb`` support entries of each pair's point (``inf`` past its width).

    Pairs are bucketed by point width, so narrow points are not padded to the widest.
    """
    M = r.size
    K = int(wp.max())
    term = np.empty(M, dtype=gain.dtype)
    edges = (0, 16, 64, 256, K) if K > 64 else (0, K)
    for lo, hi in itertools.pairwise(edges):
        ids = np.flatnonzero((wp > lo) & (wp <= hi)) if len(edges) > 2 else np.arange(M)
        if ids.size == 0:
            continue
        Kb = int(wp[ids].max())
        step = max(1, _CHUNK // Kb)
        for start in range(0, ids.size, step):
            sub = ids[start : start + step]
            pp = np.take(p, sub)
            g = ratios(np.take(r, sub), pp, Kb)
            # the min over a short last axis is slow in numpy: reduce (Kb, m) over axis 0
            t = np.ascontiguousarray(g.T).min(0)
            t *= np.take(gain, pp)
            term[sub] = t
    starts = np.flatnonzero(np.concatenate([[True], r[1:] != r[:-1]]))
    best = np.zeros(B, dtype=gain.dtype)
    best[r[starts]] = np.minimum(np.minimum.reduceat(term, starts), 0.0)
    return best


_DENSE_HIDDEN = 256  # MOMDPs with at most this many hidden values keep dense per-x point tables
# flat POMDPs with at most this many states switch to a dense point table once the points are
# wide (mean support width >= states / _WIDE): a per-pair gather of nearly whole rows costs
# several times a contiguous (B, Y, P) product (Hallway2: 88 of 92 states, 12 -> 2.5 ms)
_DENSE_FLAT = 2048
_WIDE = 4
_Q_MAX = 1e250  # dense 1 / b_i(y) clipped here (a smaller ratio only raises the bound)
# dense tables of at least _PROBE_MIN_Y states and _PROBE_MIN_P points bound each point's term
# from its largest states first (_PROBES of them, Y // _PROBE_SHARE from _WIDE_PROBE_Y states) and
# evaluate exactly only the pairs that can win. RockSample_7_8.pomdpx (Y = 256): 44% of the
# pairs survive the bound of 4 probes, 23% of 16 (sawtooth time -15%); a probe is a gather,
# several times a dense entry's cost: random_S100 (Y = 100) lost 10% with 6 probes, 2x with 16
_PROBES = 4
_PROBE_SHARE = 16
_WIDE_PROBE_Y = 128
_PROBE_MIN_Y = 16
_PROBE_MIN_P = 32


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
        if not torch.isfinite(corner).all():
            raise ModelError("corner values must be finite")
        self.corner = corner.clone()  # (X, Y)
        X, Y = corner.shape
        self.num_observed, self.num_hidden = X, Y
        dev, dt = corner.device, corner.dtype
        cap = max(int(capacity), 1)
        self._idx = torch.full((cap, 1), Y, dtype=torch.long, device=dev)  # (P, K) support, Y = pad
        self._inv = torch.ones(cap, 1, dtype=dt, device=dev)  # (P, K) 1 / b_i(y) on the support
        self._x = torch.zeros(cap, dtype=torch.long, device=dev)  # (P,) observed value of point
        self._v = torch.zeros(cap, dtype=dt, device=dev)  # (P,) upper value v_i at b_i
        self._gain = torch.zeros(cap, dtype=dt, device=dev)  # (P,) v_i - b_i . c (<= 0 useful)
        self._w = torch.ones(cap, dtype=torch.long, device=dev)  # (P,) support width of point
        self.size = 0
        self._alive_after_prune = 0
        self._views()
        # per observed value, the indices of its points (CPU): an evaluation at x only
        # looks at x's points (Ong et al. 2010), not at all of them
        self._members = [np.empty(4, dtype=np.int64) for _ in range(X)] if self._np else []
        self._count = np.zeros(X, dtype=np.int64)
        # MOMDP with a narrow hidden factor: each x's points also as a dense (Y, P_x) table of
        # 1 / b_i(y) (inf off the support), so an evaluation is a few contiguous array ops
        self._dense = self._np is not None and X > 1 and Y <= _DENSE_HIDDEN
        self._width_sum = 0  # sum of the stored points' support widths (flat dense switch)
        self._probed: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # see _probes
        dt = corner.numpy().dtype if self._dense else None
        self._q = [np.empty((Y, 4), dtype=dt) for _ in range(X)] if self._dense else []  # (Y, cap)

    # -- storage -----------------------------------------------------------------------------
    def _views(self) -> None:
        """Refresh the numpy views of the storage (CPU only; after every reallocation)."""
        if self.corner.device.type != "cpu":
            self._np = None
            return
        self._np = (self.corner.numpy(), self._idx.numpy(), self._inv.numpy(), self._x.numpy(),
                    self._v.numpy(), self._gain.numpy(), self._w.numpy())  # fmt: skip

    def _add_member(self, x: int, i: int) -> None:
        if self._np is None:
            return
        m = self._count[x]
        arr = self._members[x]
        if m == arr.shape[0]:
            arr = np.concatenate([arr, np.empty(m, dtype=np.int64)])
            self._members[x] = arr
            if self._dense:
                self._q[x] = np.concatenate([self._q[x], np.empty_like(self._q[x])], axis=1)
        arr[m] = i
        self._count[x] = m + 1
        self._width_sum += int(self._np[6][i])
        if self._dense:
            self._q[x][:, m] = self._dense_row(i)

    def _dense_row(self, i: int) -> np.ndarray:
        """``(Y,)`` point ``i``'s ``1 / b_i(y)`` on its support, ``inf`` elsewhere."""
        assert self._np is not None
        _, idx, inv, _, _, _, wid = self._np
        w = int(wid[i])
        row = np.full(self.num_hidden, np.inf, dtype=inv.dtype)
        row[idx[i, :w]] = np.minimum(inv[i, :w], _Q_MAX)
        return row

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
            if self._dense:
                _, idx, inv = self._np[:3]
                rows = np.full((ids.size, self.num_hidden + 1), np.inf, dtype=inv.dtype)
                # pads land in column Y
                np.put_along_axis(rows, idx[ids], np.minimum(inv[ids], _Q_MAX), axis=1)
                q = np.empty((self.num_hidden, arr.shape[0]), dtype=inv.dtype)
                q[:, : ids.size] = rows[:, :-1].T
                self._q[x] = q
        self._count[:] = counts
        self._width_sum = int(self._np[6][:n].sum())
        self._probed = {}

    def _use_dense_flat(self) -> bool:
        """Whether a flat bound evaluates through a dense ``(Y, P)`` table (built on first use).

        Once the stored points' mean support width reaches ``Y / _WIDE`` (e.g. Hallway2, whose
        beliefs cover nearly every state), the dense table is built and kept up to date.
        """
        if self._dense:
            return True
        Y = self.num_hidden
        if self.num_observed > 1 or Y > _DENSE_FLAT or self._np is None or self.size == 0:
            return False
        if self._width_sum * _WIDE < Y * self.size:
            return False
        self._dense = True
        arr = self._members[0]
        self._q = [np.empty((Y, arr.shape[0]), dtype=self._np[2].dtype)]
        self._rebuild_members()
        return True

    def members(self, x: int) -> np.ndarray:
        """``(P_x,)`` the indices of the points of observed value ``x`` (CPU storage only)."""
        return self._members[x][: self._count[x]]

    def _grow(self, need: int, width: int) -> None:
        cap, K = self._idx.shape
        if need > cap or width > K:
            new_cap = max(cap, 1)
            while new_cap < need:
                new_cap *= 2
            new_k = max(K, width)
            # empty, not full: a point's row is written whole when it is added, so only the
            # stored rows are filled and the free slots stay untouched pages (not resident;
            # RockSample_7_8.pomdpx: 2 x 16 MB at 8,192 slots of 256 entries)
            idx = self._idx.new_empty(new_cap, new_k)
            inv = self._inv.new_empty(new_cap, new_k)
            idx[: self.size, :K] = self._idx[: self.size]
            inv[: self.size, :K] = self._inv[: self.size]
            idx[: self.size, K:] = self.num_hidden
            inv[: self.size, K:] = 1.0
            self._idx, self._inv = idx, inv
            if new_cap > cap:
                for name in ("_x", "_v", "_gain", "_w"):
                    old = getattr(self, name)
                    new = old.new_zeros(new_cap)
                    new[: self.size] = old[: self.size]
                    setattr(self, name, new)
            self._views()

    def _refresh_gain(self, x: int | None = None) -> None:
        """Recompute the gains after a corner change (only ``x``'s points when given)."""
        if x is not None and self._np is not None:
            corner, idx, inv, _, v, gain, _ = self._np
            ids = self.members(x)
            if ids.size:
                c = np.append(corner[x], 0.0)  # (Y + 1,), the pad index Y maps to 0
                gain[ids] = v[ids] - (c[idx[ids]] / inv[ids]).sum(-1)
            return
        n = self.size
        c = torch.cat([self.corner, self.corner.new_zeros(self.num_observed, 1)], dim=1)
        cx = c[self._x[:n]]  # (P, Y+1)
        self._gain[:n] = self._v[:n] - (cx.gather(1, self._idx[:n]) / self._inv[:n]).sum(-1)

    @property
    def points(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The stored points as dense tensors: ``beliefs (P, Y)``, ``x (P,)``, ``values (P,)``."""
        n = self.size
        dense = self.corner.new_zeros(n, self.num_hidden + 1)
        dense.scatter_(1, self._idx[:n], 1.0 / self._inv[:n])
        return dense[:, :-1], self._x[:n].clone(), self._v[:n].clone()

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
        idx, inv, px, gain = self._idx[:n], self._inv[:n], self._x[:n], self._gain[:n]
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

    def value_np(
        self, beliefs: np.ndarray, x: np.ndarray, columns: np.ndarray | None = None
    ) -> np.ndarray:
        """:meth:`value` on numpy arrays (CPU storage only), for the sequential solver path.

        The same formula with far less per-call overhead than tensor ops at small sizes, and
        a stronger point filter: a point can lower the bound at ``b`` only if ``b`` covers
        its whole support and its gain is negative, so points whose support is not covered
        by the union of the queries' supports are skipped before the gather.

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
        corner, idx, inv, px, _, gain, wid = self._np
        if columns is not None:
            return self._value_columns_np(beliefs, x, columns)
        base = (beliefs * corner[x]).sum(-1)  # (B,)
        n = self.size
        B = beliefs.shape[0]
        if n == 0 or B == 0:
            return base
        if self._use_dense_flat():
            return base + self._dense_min(beliefs, x)
        pos = beliefs > 0  # (B, Y)
        wr = pos.sum(-1)  # (B,) support widths of the queries
        # a point (width w_i) can lower the bound at b only if b covers its support, so
        # |supp b| >= w_i, b(first) > 0 and b(last) > 0 for its first and last support entries
        several = False
        if self.num_observed > 1:  # only the points of the queried observed values
            first = int(x[0])
            several = not bool((x == first).all())
            if several:
                sel = np.concatenate([self.members(int(u)) for u in np.unique(x)])
            else:
                sel = self.members(first)
            sel = sel[(gain[sel] < 0) & (wid[sel] <= wr.max())]
        else:
            sel = np.flatnonzero((gain[:n] < 0) & (wid[:n] <= wr.max()))
        if sel.size == 0:
            return base
        ws = np.take(wid, sel)
        # np.take: several times cheaper than fancy indexing at these sizes
        Kc = idx.shape[1]
        first = np.take(pos, np.take(idx, sel * Kc), axis=1)  # (B, P') b covers first entry
        last = np.take(pos, np.take(idx, sel * Kc + ws - 1), axis=1)
        pair = first & last & (ws[None, :] <= wr[:, None])
        if several:
            pair &= px[sel][None, :] == x[:, None]
        r, j = np.nonzero(pair)  # candidate (query, point) pairs, r sorted
        if r.size == 0:
            return base
        p = np.take(sel, j)
        wp = np.take(ws, j)
        Y1 = beliefs.shape[1] + 1
        ext = np.concatenate([beliefs, np.full((B, 1), np.inf, dtype=beliefs.dtype)], axis=1)

        def ratios(rr: np.ndarray, pp: np.ndarray, Kb: int) -> np.ndarray:
            if 2 * Kb >= Kc:  # whole rows: np.take (several times cheaper)
                flat = np.take(idx, pp, axis=0)[:, :Kb]  # (m, Kb) fresh copy
                w = np.take(inv, pp, axis=0)[:, :Kb]
            else:  # narrow bucket of wide storage: gather only Kb columns
                flat, w = idx[pp, :Kb], inv[pp, :Kb]
            flat += (rr * Y1)[:, None]  # index into ext.ravel()
            g = np.take(ext, flat)  # (m, Kb) b(y) on each point's support (inf: padding)
            g *= w
            return g

        best = _pair_minima(r, p, wp, gain, B, ratios)
        return base + best

    def _value_columns_np(
        self, beliefs: np.ndarray, x: np.ndarray, columns: np.ndarray
    ) -> np.ndarray:
        """:meth:`value_np` of beliefs given on the columns ``columns`` only (zero elsewhere).

        A point lowers the bound at ``b`` only if ``b`` covers its support, so only points
        whose support lies inside ``columns`` are gathered, through a global-to-local map.
        """
        assert self._np is not None
        corner, idx, inv, px, _, gain, wid = self._np
        B, C = beliefs.shape
        if self.num_observed == 1:
            base = beliefs @ corner[0, columns]  # (B,)
        else:
            base = (beliefs * corner[x[:, None], columns[None, :]]).sum(-1)
        n = self.size
        if n == 0 or B == 0:
            return base
        # global -> local column: outside ``columns`` -> C (b = 0), padding Y -> C + 1 (+inf)
        local = np.full(self.num_hidden + 1, C, dtype=np.int64)
        local[self.num_hidden] = C + 1
        local[columns] = np.arange(C)
        pos = np.concatenate([beliefs > 0, np.zeros((B, 1), dtype=bool)], axis=1)  # (B, C+1)
        wr = pos.sum(-1)
        cand = (gain[:n] < 0) & (wid[:n] <= wr.max())
        if self.num_observed > 1:
            cand &= np.isin(px[:n], x)
        sel = np.flatnonzero(cand)
        if sel.size == 0:
            return base
        ws = wid[sel]
        first, last = local[idx[sel, 0]], local[idx[sel, ws - 1]]
        inside = (first < C) & (last < C)  # support ends inside the columns
        sel, ws, first, last = sel[inside], ws[inside], first[inside], last[inside]
        if sel.size == 0:
            return base
        pair = pos[:, first] & pos[:, last] & (ws[None, :] <= wr[:, None])
        if self.num_observed > 1:
            pair &= px[sel][None, :] == x[:, None]
        r, j = np.nonzero(pair)
        if r.size == 0:
            return base
        p = sel[j]
        wp = ws[j]
        pad = np.zeros((B, 2), dtype=beliefs.dtype)
        pad[:, 1] = np.inf
        ext = np.concatenate([beliefs, pad], axis=1)  # (B, C + 2)

        def ratios(rr: np.ndarray, pp: np.ndarray, Kb: int) -> np.ndarray:
            return ext[rr[:, None], local[idx[pp, :Kb]]] * inv[pp, :Kb]  # (m, Kb)

        best = _pair_minima(r, p, wp, gain, B, ratios)
        return base + best

    def _dense_min(self, beliefs: np.ndarray, x: np.ndarray) -> np.ndarray:
        """``(B,)`` ``min(0, min_i gain_i * min_{y in supp b_i} b(y) / b_i(y))`` per query.

        From the dense per-``x`` tables ``q_i(y) = 1 / b_i(y)`` (``inf`` off the support):
        the zeros of ``b`` are replaced by the smallest positive float, so ``b(y) q_i(y)`` is
        ``inf`` off the support (never the minimum) and on the support ``b(y) / b_i(y)``, or a
        ratio below ``1e-290`` where ``b(y) = 0`` (the point then moves the bound by less than
        that, as it should not move it at all).
        """
        gain = self._np[5]  # type: ignore[index]
        out = np.zeros(beliefs.shape[0], dtype=beliefs.dtype)
        b_all = np.where(beliefs > 0, beliefs, np.finfo(beliefs.dtype).tiny)
        first = int(x[0])
        if (x == first).all():
            parts: Any = ((first, slice(None)),)
        else:
            order = np.argsort(x, kind="stable")
            sx = x[order]
            edges = [0, *(np.flatnonzero(sx[1:] != sx[:-1]) + 1).tolist(), sx.size]
            parts = (
                (int(sx[lo]), order[lo:hi]) for lo, hi in itertools.pairwise(edges)
            )  # (observed value, rows) per group
        Y = self.num_hidden
        for xv, sel in parts:
            m = int(self._count[xv])
            if m == 0:
                continue
            q = self._q[xv][:, :m]  # (Y, P_x)
            g = gain[self._members[xv][:m]]  # (P_x,)
            b = b_all[sel]  # (B_x, Y)
            if Y >= _PROBE_MIN_Y and m >= _PROBE_MIN_P:
                low = self._pruned_min(xv, b, q, g)
                if low is not None:
                    out[sel] = low
                    continue
            # (step, Y, P_x) products sized to stay in cache: 2x faster than one big temporary
            step = max(1, _DENSE_CHUNK // max(1, m * Y))
            for start in range(0, b.shape[0], step):
                ratio = (b[start : start + step, :, None] * q[None]).min(1)  # (b, P_x)
                low = (ratio * g).min(-1)
                if isinstance(sel, slice):
                    out[start : start + step] = low
                else:
                    out[sel[start : start + step]] = low
        return np.minimum(out, 0.0)

    def _probes(self, xv: int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(k, P_x)`` each point's ``k`` largest-probability states and their ``1 / b_i``.

        Kept per observed value and extended to points added since the last call (the table
        only grows between prunes; a prune rebuilds it and resets the probes).
        """
        m = q.shape[1]
        Y = q.shape[0]
        k = min(max(_PROBES, Y // _PROBE_SHARE) if Y >= _WIDE_PROBE_Y else _PROBES, Y)
        done = self._probed.get(xv)
        start = 0 if done is None else done[0].shape[1]
        if done is not None and start == m:
            return done
        fresh = np.argpartition(q[:, start:m], k - 1, axis=0)[:k]  # (k, new) smallest 1/b_i
        vals = np.take_along_axis(q[:, start:m], fresh, axis=0)
        if done is not None and start:
            fresh = np.concatenate([done[0], fresh], axis=1)
            vals = np.concatenate([done[1], vals], axis=1)
        self._probed[xv] = (fresh, vals)
        return fresh, vals

    def _pruned_min(
        self, xv: int, b: np.ndarray, q: np.ndarray, g: np.ndarray
    ) -> np.ndarray | None:
        """``(B,)`` ``min_i g_i min_y b(y) q_i(y)`` by bounding before computing.

        For each point, ``r_i = min_{y in probes_i} b(y) q_i(y) >= min_y b(y) q_i(y)`` (a
        minimum over fewer states), so with ``g_i < 0`` the point's term is at least
        ``g_i r_i``. The point with the lowest ``g_i r_i`` is evaluated exactly for each query;
        then only the (query, point) pairs with ``g_i r_i`` below that are (Hallway2: a few per
        cent of the pairs); when many pairs survive, the dense product over the points with a
        surviving pair (RockSample_7_8.pomdpx: a third of the points). Exact: every term is
        the same product, and the minimum is taken over a set holding the smallest, so the
        result equals the dense minimum bit for bit. Returns ``None`` when nearly every point
        survives (the dense product over all of them is then cheaper).
        """
        B, Y = b.shape
        m = q.shape[1]
        probe, qp = self._probes(xv, q)  # (k, m)
        r = (b[:, probe] * qp[None]).min(1)  # (B, m) >= the true ratios
        bound = r * g  # (B, m) <= the true terms where g < 0
        j0 = bound.argmin(-1)  # (B,) most promising point per query
        best = (b * q[:, j0].T).min(-1) * g[j0]  # (B,) exact term of that point
        best = np.minimum(best, 0.0)
        cand = bound < best[:, None]
        cand[np.arange(B), j0] = False
        rr, jj = np.nonzero(cand)
        if rr.size * 3 > B * m:
            cols = np.flatnonzero(cand.any(0))  # the points with a surviving pair
            if cols.size * 4 > m * 3:
                return None
            qc, gc = q[:, cols], g[cols]  # (Y, c), (c,)
            step = max(1, _DENSE_CHUNK // max(1, cols.size * Y))
            for start in range(0, B, step):
                ratio = (b[start : start + step, :, None] * qc[None]).min(1)  # (b, c)
                low = (ratio * gc).min(-1)
                best[start : start + step] = np.minimum(best[start : start + step], low)
            return best
        step = max(1, _DENSE_CHUNK // Y)
        for start in range(0, rr.size, step):
            ri, ji = rr[start : start + step], jj[start : start + step]
            terms = (b[ri] * q[:, ji].T).min(-1) * g[ji]
            np.minimum.at(best, ri, terms)
        return best

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
        b, bx, bv = beliefs[rows], x[rows], values[rows]
        K = int(width[rows].max())
        m = rows.numel()
        self._grow(self.size + m, K)
        Kc = self._idx.shape[1]
        order = torch.argsort((~support[rows]).to(torch.int8), dim=-1, stable=True)[:, :Kc]
        keep = support[rows].gather(1, order)
        idx = torch.where(keep, order, order.new_full((), self.num_hidden))
        val = torch.where(keep, b.gather(1, order), b.new_ones(()))
        s = slice(self.size, self.size + m)
        self._idx[s], self._inv[s], self._x[s], self._v[s] = idx, 1.0 / val, bx, bv
        c = torch.cat([self.corner, self.corner.new_zeros(self.num_observed, 1)], dim=1)
        self._gain[s] = bv - (c[bx].gather(1, idx) * val).sum(-1)
        self._w[s] = width[rows]
        self.size += m
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
        self._grow(self.size + 1, w)
        n = self.size
        val = belief[idx]
        self._idx[n, :w] = idx
        self._idx[n, w:] = self.num_hidden
        self._inv[n, :w] = 1.0 / val
        self._inv[n, w:] = 1.0
        self._x[n] = x
        self._v[n] = value[0]
        self._gain[n] = value[0] - (self.corner[x, idx] * val).sum()
        self._w[n] = w
        self.size = n + 1

    def add_np(self, belief: np.ndarray, x: int, value: float) -> None:
        """Add one point ``(x, b, v)`` from numpy (CPU storage only; the sequential path).

        Args:
            belief: ``(Y,)`` a normalised belief.
            x: its observed value.
            value: an upper bound ``v >= V*(x, b)``.
        """
        idx = np.flatnonzero(belief)  # (w,) the support
        w = idx.size
        assert self._np is not None
        corner = self._np[0]
        if w == 1:
            y = int(idx[0])
            if value < corner[x, y]:
                corner[x, y] = value
                self._refresh_gain(x)
            return
        self._grow(self.size + 1, w)
        n = self.size
        val = belief[idx]
        _, I, inv, px, v, gain, wid = self._np
        I[n, :w] = idx
        I[n, w:] = self.num_hidden
        inv[n, :w] = 1.0 / val
        inv[n, w:] = 1.0
        px[n] = x
        v[n] = value
        gain[n] = value - float(corner[x, idx] @ val)
        wid[n] = w
        self.size = n + 1
        self._add_member(x, n)

    def prune(self) -> int:
        """Remove points that the other points and the corners already bound as tightly.

        A point is kept when its value is strictly below the sawtooth of the others at its
        own belief. Returns the number of points removed.
        """
        n = self.size
        if n == 0:
            return 0
        beliefs, x, v = self.points
        useful = self._gain[:n] < 0
        # Evaluate each point against all others, excluding itself, by masking its own gain.
        saved = self._gain[:n].clone()
        keep = useful.clone()
        block = max(1, min(n, 256))
        for start in range(0, n, block):
            stop = min(n, start + block)
            rows = torch.arange(start, stop, device=x.device)
            # Temporarily disable the evaluated points (one at a time in each block would be
            # exact; disabling the whole block is conservative: it only keeps more points).
            self._gain[start:stop] = 0.0
            if self._np is not None:
                others = torch.from_numpy(self.value_np(beliefs[rows].numpy(), x[rows].numpy()))
            else:
                others = self.value(beliefs[rows], x[rows])
            self._gain[start:stop] = saved[start:stop]
            keep[start:stop] &= v[rows] < others - 1e-12 * others.abs().clamp(min=1.0)
        sel = keep.nonzero().squeeze(-1)
        removed = n - sel.numel()
        if removed:
            self._idx[: sel.numel()] = self._idx[sel]
            self._inv[: sel.numel()] = self._inv[sel]
            self._x[: sel.numel()] = self._x[sel]
            self._v[: sel.numel()] = self._v[sel]
            self._gain[: sel.numel()] = self._gain[sel]
            self._w[: sel.numel()] = self._w[sel]
            self.size = sel.numel()
            self._rebuild_members()
        self._alive_after_prune = self.size
        return removed
