"""The lower bound's alpha-vector set: each vector with its action, its observed value and the
vectors it was built from, stored flat and grouped by observed value.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from torchhrc.solvers import backup_kernel
from torchhrc.solvers._memory import release_pages

__all__: list[str] = []

# floats copied at a time where the vectors are moved about (a pruning's compaction and
# regrouping): 16 MB, not a second copy of every vector (on a 20,000-state model, 1,300
# vectors are 200 MB)
_BLOCK = 1 << 21
_EMPTY = np.zeros((0, 0))


class _AlphaSet:
    """Alpha vectors ``(N, Y)`` with their action and observed value, grown geometrically.

    On CPU the vectors are also kept grouped by observed value (Ong et al. 2010: a MOMDP
    lower bound is a set of vectors over ``Y`` per ``x``): ``group(x)`` returns the ``(N_x, Y)``
    contiguous block of ``x``'s vectors and their indices in the flat storage, so bounding a
    belief at ``x`` touches only ``N_x`` vectors, not all ``N``.

    Each vector also keeps ``refs[n]``, the indices of the vectors its backup chose at the
    possible children (the plan it is the value of: ``alpha = R_a + gamma sum P Z alpha_ref``).
    :meth:`keep` keeps what a kept vector refers to, so the vectors stay the values of plans
    made of vectors in the set: the value function stays uniformly improvable
    (``V_low(b) <= max_a Q_low(b, a)`` at every belief, Pineau et al. 2003) and the greedy
    policy of the written vectors earns at least ``V_low(b0)``. The initial vectors (blind
    policies: fixed points of their own action) refer to none.

    Memory: the vectors are held twice (the flat rows, which backups gather, and the
    per-``x`` columns, which bounding scores), but never three times: a block that grows is
    refilled from the flat rows after the old one is freed, the blocks are dropped while the
    flat storage is copied into a larger one and rebuilt after, and a pruning compacts the
    rows in place a block at a time and hands the dropped rows' pages back to the OS
    (:func:`~torchhrc.solvers._memory.release_pages`).
    """

    def __init__(self, alphas: torch.Tensor, actions: torch.Tensor, observed: torch.Tensor,
                 num_observed: int = 1) -> None:  # fmt: skip
        n = alphas.shape[0]
        self.refs: list[np.ndarray] = [np.zeros(0, dtype=np.int64) for _ in range(n)]
        cap = max(64, 2 * n)
        self.num_observed = int(num_observed)
        self.vectors = alphas.new_zeros(cap, alphas.shape[1])
        self.actions = torch.zeros(cap, dtype=torch.long, device=alphas.device)
        self.observed = torch.zeros(cap, dtype=torch.long, device=alphas.device)
        self.vectors[:n], self.actions[:n], self.observed[:n] = alphas, actions, observed
        self.size = n
        self._gcol: list[np.ndarray] = []  # the per-x blocks (empty: freed, see _released)
        self._gid: list[np.ndarray] = []
        self._views()
        self._regroup()

    def _dominating(self, need: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """``(len(need),)``: for each vector of ``need``, a vector of ``kept`` of the same
        observed value that is >= it at every entry, or -1 (CPU storage; -1 elsewhere, or when
        the comparison would exceed 2e8 entries)."""
        out = np.full(need.size, -1, dtype=np.int64)
        if self.np_vectors is None or self.np_observed is None or not kept.size:
            return out
        V, obs, Y = self.np_vectors, self.np_observed, self.np_vectors.shape[1]
        probe = np.linspace(0, Y - 1, min(Y, 8)).astype(np.int64)
        for x in np.unique(obs[need]).tolist():
            rows = np.flatnonzero(obs[need] == x)
            cand = kept[obs[kept] == x]
            if not cand.size or rows.size * cand.size * Y > 2e8:
                continue
            C = V[cand]  # (c, Y)
            # a few probe entries first (a candidate dominates only if it does there; most
            # pairs fail), the full rows for the survivors; the first dominating candidate
            # wins, as an argmax over the full comparison would pick
            Cp = C[:, probe]  # (c, k)
            # (step, c, k) booleans at once: 4 MB (16 MB raised Hallway2's peak memory)
            step = max(1, (1 << 22) // (cand.size * probe.size))
            for start in range(0, rows.size, step):
                chunk = rows[start : start + step]
                Vn = V[need[chunk]]  # (n, Y)
                ii, jj = np.nonzero((Cp[None, :, :] >= Vn[:, None, probe]).all(-1))
                # the survivors' full rows in blocks of about 256k floats (2 MB), not all at
                # once (up to 2e8 floats: the peak memory of a solve)
                ok = np.empty(ii.size, dtype=bool)
                block = max(1, (1 << 18) // Y)
                for b0 in range(0, ii.size, block):
                    sl = slice(b0, b0 + block)
                    ok[sl] = (C[jj[sl]] >= Vn[ii[sl]]).all(-1)
                ii, jj = ii[ok], jj[ok]
                first, at = np.unique(ii, return_index=True)  # ii is sorted, jj rising
                out[chunk[first]] = cand[jj[at]]
        return out

    def _views(self) -> None:
        """Numpy views of the storage (CPU only; refreshed after every reallocation)."""
        cpu = self.vectors.device.type == "cpu"
        self.np_vectors = self.vectors.numpy() if cpu else None
        self.np_actions = self.actions.numpy() if cpu else None
        self.np_observed = self.observed.numpy() if cpu else None

    def _regroup(self) -> None:
        """Rebuild the per-``x`` blocks from the flat storage (CPU only)."""
        if self.np_vectors is None:
            return
        assert self.np_observed is not None
        n = self.size
        obs = self.np_observed[:n]
        order = np.argsort(obs, kind="stable")
        counts = np.bincount(obs, minlength=self.num_observed)
        ends = np.cumsum(counts)
        self._gn = counts.astype(np.int64)
        self._gcol = []
        self._gid = []
        for x in range(self.num_observed):
            ids = order[ends[x] - counts[x] : ends[x]]
            col, gid = self._columns(ids, max(4, 2 * ids.size))
            self._gcol.append(col)
            self._gid.append(gid)

    def release_groups(self) -> None:
        """Free the per-``x`` blocks (the second copy of the vectors), as before the final
        policy's copy; the next use rebuilds them from the flat storage."""
        self._gcol, self._gid = [], []

    @property
    def _released(self) -> bool:
        """Whether the per-``x`` blocks are freed (:meth:`release_groups`) and due for a
        rebuild before their next use."""
        return self.np_vectors is not None and not self._gcol

    def _columns(self, ids: np.ndarray, cap: int) -> tuple[np.ndarray, np.ndarray]:
        """A group's ``(Y, cap)`` column block and ``(cap,)`` index array holding the flat
        storage's vectors ``ids`` first, copied a block of vectors at a time (no whole
        transposed copy beside the two stores)."""
        assert self.np_vectors is not None
        Y = self.np_vectors.shape[1]
        col = np.empty((Y, cap), dtype=self.np_vectors.dtype)
        step = max(1, _BLOCK // max(Y, 1))
        for b0 in range(0, ids.size, step):
            part = ids[b0 : b0 + step]
            col[:, b0 : b0 + part.size] = self.np_vectors[part].T
        gid = np.empty(cap, dtype=np.int64)
        gid[: ids.size] = ids
        return col, gid

    def group(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """``(N_x, Y)`` the vectors of observed value ``x`` (a transposed view of
        :meth:`group_columns`) and ``(N_x,)`` their indices."""
        cols, ids = self.group_columns(x)
        return cols.T, ids

    def group_columns(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """``(Y, N_x)`` the vectors of observed value ``x`` as columns (a view of the group's
        ``(Y, capacity)`` copy: ``rows @ columns`` is a plain BLAS product, a third faster
        than ``rows @ vectors.T`` on aloha-10max's 28 x 30 x 600) and ``(N_x,)`` their
        indices in the flat storage."""
        if self._released:
            self._regroup()
        m = self._gn[x]
        return self._gcol[x][:, :m], self._gid[x][:m]

    def group_scores(self, kernel: Any, rows: np.ndarray, rows_x: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """``(B,)`` the best score of each row among its own observed value's vectors and
        ``(B,)`` that vector's index, in one compiled call over the group columns
        (:func:`~torchhrc.solvers.backup_kernel.group_scores`; ``rows`` ``(B, Y)``
        C-contiguous, or ``(1, Y)``: one belief under each ``x`` of ``rows_x``)."""
        if self._released:
            self._regroup()
        return backup_kernel.group_scores(kernel, rows, rows_x.astype(np.int64, copy=False),
                                          self._gcol, self._gid, self._gn)  # fmt: skip

    def _append_group(self, x: int, alpha: np.ndarray, index: int) -> None:
        m = self._gn[x]
        if m == self._gid[x].shape[0]:
            # a block twice as wide, filled from the flat storage after the old block is
            # freed: the same floats as a copy of the old block, without holding both blocks
            # at once (three copies of the vectors at the peak, with the flat storage)
            ids = self._gid[x][:m].copy()
            self._gcol[x] = self._gid[x] = _EMPTY
            self._gcol[x], self._gid[x] = self._columns(ids, 2 * m)
        self._gcol[x][:, m] = alpha
        self._gid[x][m] = index
        self._gn[x] = m + 1

    def add_np(self, alpha: np.ndarray, action: int, observed: int,
               refs: np.ndarray | None = None) -> None:  # fmt: skip
        """Add one vector ``alpha (Y,)`` from numpy (CPU storage only), built from the vectors
        ``refs``."""
        if self.size == self.vectors.shape[0]:
            self._reserve(self.size + 1)
        assert self.np_vectors is not None
        assert self.np_actions is not None and self.np_observed is not None
        n = self.size
        self.np_vectors[n] = alpha
        self.np_actions[n] = action
        self.np_observed[n] = observed
        self.size = n + 1
        self.refs.append(np.asarray(() if refs is None else refs, dtype=np.int64))
        if self._released:  # (rebuilt with the new vector)
            self._regroup()
        else:
            self._append_group(observed, self.np_vectors[n], n)

    def _reserve(self, need: int) -> None:
        cap = self.vectors.shape[0]
        while cap < need:
            cap *= 2
        # the per-x blocks go while the flat storage is copied and are rebuilt from the new
        # one: two copies of the vectors at the peak, not three
        grouped = self.np_vectors is not None
        if grouped:
            self.release_groups()
        for name in ("vectors", "actions", "observed"):
            old = getattr(self, name)
            # rows past ``size`` are written before they are read; empty leaves their pages
            # untouched (not resident) until then
            new = old.new_empty(cap, *old.shape[1:])
            new[: self.size] = old[: self.size]
            setattr(self, name, new)
            del old, new
        self._views()
        if grouped:
            self._regroup()

    def add(self, alphas: torch.Tensor, actions: torch.Tensor, observed: torch.Tensor,
            refs: list[np.ndarray] | None = None) -> None:  # fmt: skip
        m = alphas.shape[0]
        if refs is None:
            refs = [np.zeros(0, dtype=np.int64)] * m
        self.refs.extend(np.asarray(r, dtype=np.int64) for r in refs)
        if self.size + m > self.vectors.shape[0]:
            self._reserve(self.size + m)
        s = slice(self.size, self.size + m)
        self.vectors[s], self.actions[s], self.observed[s] = alphas, actions, observed
        self.size += m
        if self._released:  # (rebuilt with the new vectors)
            self._regroup()
        elif self.np_vectors is not None:
            assert self.np_observed is not None
            for i in range(s.start, s.stop):
                self._append_group(int(self.np_observed[i]), self.np_vectors[i], i)

    def keep(self, mask: torch.Tensor) -> np.ndarray:
        """Keep the vectors of ``mask (N,)`` and, transitively, those they refer to; a
        referred vector that a kept one of its ``x`` dominates pointwise is replaced by it in
        the references instead (the plan only gains).

        Returns ``(N,)`` the new index of each old vector (of its replacement, for a replaced
        one; -1 for a dropped one)."""
        m = mask[: self.size].cpu().numpy().copy()
        target = np.arange(self.size)  # reference i now means vector target[i]
        frontier = np.flatnonzero(m)
        while frontier.size:
            refs = [self.refs[i] for i in frontier.tolist() if self.refs[i].size]
            if not refs:
                break
            r = np.unique(np.concatenate(refs))
            need = r[~m[r] & (target[r] == r)]
            if not need.size:
                break
            sub = self._dominating(need, np.flatnonzero(m))
            target[need[sub >= 0]] = sub[sub >= 0]
            frontier = need[sub < 0]
            m[frontier] = True
        remap = np.full(self.size, -1, dtype=np.int64)
        kept = np.flatnonzero(m)
        remap[kept] = np.arange(kept.size)
        self.refs = [remap[target[self.refs[i]]] for i in kept.tolist()]
        moved = remap[target]
        idx = torch.from_numpy(kept).to(self.vectors.device)
        n = idx.numel()
        # in place, a block of rows at a time: ``kept`` rises, so a block's rows are read
        # before a later block writes over them (kept[i] >= i)
        step = max(1, _BLOCK // max(self.vectors.shape[1], 1))
        for b0 in range(0, n, step):
            part = idx[b0 : b0 + step]
            self.vectors[b0 : b0 + part.numel()] = self.vectors[part]
        self.actions[:n] = self.actions[idx]
        self.observed[:n] = self.observed[idx]
        self.size = n
        self.release_groups()  # the old per-x copy goes before the new is built
        self._regroup()
        if self.np_vectors is not None:  # the dropped vectors' pages go back to the OS
            release_pages(self.np_vectors, n * self.np_vectors.strides[0])
        return moved
