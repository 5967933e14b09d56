"""The lower bound's alpha-vector set: each vector with its action, its observed value and the
vectors it was built from, stored once as rows, with the indices of each observed value's.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np
import torch

from torchhrc._host import alloc, copy_front, host_view, to_numpy
from torchhrc.solvers import backup_kernel
from torchhrc.solvers._memory import release_pages
from torchhrc.solvers.pruning import prune_dominated

__all__: list[str] = []

# floats copied at a time where the vectors are moved about (a growth's copy, a pruning's
# compaction): 16 MB, not a second copy of every vector (on a 20,000-state model, 1,300
# vectors are 200 MB)
_BLOCK = 1 << 21
# how many calls of :meth:`_AlphaSet.best_on_columns` it remembers, and at most how many
# bytes of their rows (16 MB)
_SCORED = 64
_SCORED_BYTES = 1 << 24


def round_down(values: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """``values`` in ``dtype``, each entry rounded toward minus infinity where ``dtype`` is
    the narrower, so that a stored alpha vector is never above the one computed (a vector below
    a plan's value is a lower bound too).

    Example:
        >>> v = torch.tensor([0.1, -0.1, 0.5], dtype=torch.float64)
        >>> low = round_down(v, torch.float32)
        >>> bool((low.double() <= v).all()), low.dtype, low[2].item()
        (True, torch.float32, 0.5)
    """
    out = values.to(dtype)
    if dtype == values.dtype or torch.finfo(dtype).bits >= torch.finfo(values.dtype).bits:
        return out
    up = out.to(values.dtype) > values
    return torch.where(up, torch.nextafter(out, torch.full_like(out, -torch.inf)), out)


def round_down_np(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """:func:`round_down` of a numpy array (into ``dtype``; ``values`` itself where it is of
    ``dtype``: the store copies it)."""
    if values.dtype == dtype:
        return values
    out = values.astype(dtype)
    if out.dtype.itemsize >= values.dtype.itemsize:
        return out
    up = out > values
    out[up] = np.nextafter(out[up], out.dtype.type(-np.inf))
    return out


def _copy(t: torch.Tensor) -> torch.Tensor:
    """A copy of ``t`` (by numpy on the CPU: torchhrc._host)."""
    v = host_view(t)
    return t.clone() if v is None else torch.from_numpy(v.copy())


class _AlphaSet:
    """Alpha vectors ``(N, Y)`` with their action and observed value, grown geometrically.

    The vectors are held once, as rows (``vectors``, ``(capacity, Y)``): a backup reads the
    few rows it combines whole, and bounding a belief reads every vector of its observed value
    along the belief's support only. On CPU the indices of each observed value's vectors are
    kept too (Ong et al. 2010: a MOMDP lower bound is a set of vectors over ``Y`` per ``x``):
    ``group(x)`` gives ``x``'s vectors and their indices, so bounding a belief at ``x`` touches
    only ``N_x`` vectors, not all ``N``; the compiled scoring
    (:func:`~torchhrc.solvers.backup_kernel.group_scores`) reads the rows through those
    indices.

    Each vector also keeps ``refs[n]``, the indices of the vectors its backup chose at the
    possible children (the plan it is the value of: ``alpha = R_a + gamma sum P Z alpha_ref``).
    :meth:`keep` keeps what a kept vector refers to, so the vectors stay the values of plans
    made of vectors in the set: the value function stays uniformly improvable
    (``V_low(b) <= max_a Q_low(b, a)`` at every belief, Pineau et al. 2003) and the greedy
    policy of the written vectors earns at least ``V_low(b0)``. The initial vectors (blind
    policies: fixed points of their own action) refer to none.

    The storage's ``dtype`` may be narrower than the vectors computed (``SARSOPConfig``'s
    ``alpha_dtype``: float32 under a float64 solve); each vector is then stored rounded down
    (:func:`round_down`), so it stays a lower bound, and the compiled kernels that read rows
    (float64 only) give way to their numpy paths.

    Memory: one copy of the vectors, also while the storage grows (on CPU the rows are copied
    into the larger storage from the last, a block at a time, and each copied block's old
    pages go back to the OS at once) and while a pruning compacts the rows in place (the
    dropped rows' pages go back too, :func:`~torchhrc.solvers._memory.release_pages`).
    Before, a second copy as per-``x`` column blocks served the scoring: on a 20,000-state
    model 335 MB at 2,092 vectors (docs/benchmarks.md).

    Example:
        >>> import torch
        >>> s = _AlphaSet(torch.eye(2, dtype=torch.float64), torch.tensor([0, 1]),
        ...               torch.tensor([0, 1]), num_observed=2)
        >>> s.add_np(np.array([0.5, 0.5]), 1, 0)
        >>> s.group(0)[1].tolist(), s.size
        ([0, 2], 3)
    """

    def __init__(self, alphas: torch.Tensor, actions: torch.Tensor, observed: torch.Tensor,
                 num_observed: int = 1, dtype: torch.dtype | None = None) -> None:  # fmt: skip
        n = alphas.shape[0]
        self.refs: list[np.ndarray] = [np.zeros(0, dtype=np.int64) for _ in range(n)]
        cap = max(64, 2 * n)
        self.num_observed = int(num_observed)
        dev = alphas.device
        self.vectors = alloc((cap, alphas.shape[1]), dtype or alphas.dtype, dev)
        self.actions, self.observed = alloc(cap, torch.long, dev), alloc(cap, torch.long, dev)
        self._views()
        given = host_view(alphas), host_view(actions), host_view(observed)
        if self.np_vectors is not None and all(g is not None for g in given):
            assert self.np_actions is not None and self.np_observed is not None
            self.np_vectors[:n] = round_down_np(given[0], self.np_vectors.dtype)
            self.np_actions[:n], self.np_observed[:n] = given[1], given[2]
        else:
            self.vectors[:n] = round_down(alphas, self.vectors.dtype)
            self.actions[:n], self.observed[:n] = actions, observed
        self.size = n
        self._gid: list[np.ndarray] = []  # per x: the indices of its vectors (CPU only)
        self._gn = np.zeros(self.num_observed, dtype=np.int64)  # how many of each in use
        # the last calls of :meth:`best_on_columns`, by their columns: their rows, how many
        # vectors were scored, the maxima and their indices
        self._scored: OrderedDict[bytes, tuple[np.ndarray, int, np.ndarray, np.ndarray]] = (
            OrderedDict())  # fmt: skip
        self._scored_bytes = 0
        self._lent = False  # whether :meth:`lend` handed out views of the storage
        # the entries :meth:`_dominating` compares first (up to 8, spread over the width)
        Y = alphas.shape[1]
        self._probe = (
            np.linspace(0, Y - 1, min(Y, 8)).astype(np.int64) if Y else np.zeros(0, np.int64)
        )
        self._views()
        self._regroup()

    def undominated(self) -> np.ndarray:
        """``(N,)`` bool: the vectors that no other of their observed value dominates
        pointwise (:func:`~torchhrc.solvers.pruning.prune_dominated`'s rule; compiled,
        :func:`~torchhrc.solvers.backup_kernel.dominated`, on float64 CPU storage)."""
        n = self.size
        kernel = backup_kernel.load() if self.np_vectors is not None else None
        if kernel is not None and self.np_vectors.dtype == np.float64:
            assert self.np_observed is not None
            groups = None if self.num_observed == 1 else self.np_observed[:n]
            return backup_kernel.dominated(kernel, self.np_vectors, np.arange(n), groups)
        return prune_dominated(self.vectors[:n], self.observed[:n]).cpu().numpy()

    def _dominating(self, need: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """``(len(need),)``: for each vector of ``need``, a vector of ``kept`` of the same
        observed value that is >= it at every entry, or -1 (CPU storage; -1 elsewhere, or when
        the comparison would exceed 2e8 entries)."""
        out = np.full(need.size, -1, dtype=np.int64)
        if self.np_vectors is None or self.np_observed is None or not kept.size:
            return out
        V, obs, Y = self.np_vectors, self.np_observed, self.np_vectors.shape[1]
        probe = self._probe
        # (one observed value: every vector is in the one group; the per-x selections below
        # cost a call of a small model's pruning a tenth of its time)
        groups = [None] if self.num_observed == 1 else np.unique(obs[need]).tolist()
        for x in groups:
            rows = np.arange(need.size) if x is None else np.flatnonzero(obs[need] == x)
            cand = kept if x is None else kept[obs[kept] == x]
            if not cand.size or rows.size * cand.size * Y > 2e8:
                continue
            # a few probe entries first (a candidate dominates only if it does there; most
            # pairs fail), the full rows for the survivors; the first dominating candidate
            # wins, as an argmax over the full comparison would pick. The candidates' rows
            # are read where needed, never copied all at once (V[cand] was a transient copy
            # of every kept vector: 480 MB of a 20,000-state solve's peak, docs/benchmarks.md)
            Cp = V[np.ix_(cand, probe)]  # (c, k)
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
                    ok[sl] = (V[cand[jj[sl]]] >= Vn[ii[sl]]).all(-1)
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
        """Rebuild the per-``x`` index lists from the flat storage (CPU only)."""
        if self.np_vectors is None:
            return
        assert self.np_observed is not None
        obs = self.np_observed[: self.size]
        order = np.argsort(obs, kind="stable")
        counts = np.bincount(obs, minlength=self.num_observed)
        ends = np.cumsum(counts)
        self._gn = counts.astype(np.int64)
        self._gid = []
        for x in range(self.num_observed):
            gid = np.empty(max(4, 2 * int(counts[x])), dtype=np.int64)
            gid[: counts[x]] = order[ends[x] - counts[x] : ends[x]]
            self._gid.append(gid)

    def forget_scores(self) -> None:
        """Forget the remembered maxima (:meth:`best_on_columns`): after the vectors moved
        (a pruning), and before the final policy (their rows' memory)."""
        self._scored.clear()
        self._scored_bytes = 0

    def lend(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(N, Y)`` the vectors, ``(N,)`` their actions and observed values: views of the
        storage, not copies (the final policy's: a copy would be a second copy of every
        vector at the end of the solve). The set stays usable: adding writes past the views,
        and a pruning, which moves rows, first moves the set to storage of its own."""
        self._lent = True
        return self.in_use()

    def in_use(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The first :attr:`size` rows of the storage, as :meth:`lend` gives them (views; on
        the CPU made from the numpy views, torchhrc._host), without lending them: valid until
        the set next changes."""
        n = self.size
        if self.np_vectors is None:
            return self.vectors[:n], self.actions[:n], self.observed[:n]
        assert self.np_actions is not None and self.np_observed is not None
        return (torch.from_numpy(self.np_vectors[:n]), torch.from_numpy(self.np_actions[:n]),
                torch.from_numpy(self.np_observed[:n]))  # fmt: skip

    def group(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """``(N_x, Y)`` the vectors of observed value ``x`` and ``(N_x,)`` their indices in
        the flat storage, ascending (with one observed value a view of the storage; else a
        gathered copy, for the numpy path)."""
        assert self.np_vectors is not None
        ids = self._gid[x][: self._gn[x]]
        if self.num_observed == 1:
            return self.np_vectors[: ids.size], ids
        return self.np_vectors[ids], ids

    def best_on_columns(self, kernel: Any, rows: np.ndarray, cols: np.ndarray,
                        ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """``(B,)`` ``max_n rows . vectors[n, cols]`` over every vector and ``(B,)`` the first
        argmax, for rows ``(B, c)`` given on the columns ``cols (c,)`` (one observed value:
        the children of a sparse belief, on the union of their supports).

        The product is ``rows @ vectors[:N, cols].T``, the operand gathered from the rows
        (compiled where ``kernel`` is given,
        :func:`~torchhrc.solvers.backup_kernel.gather_columns`): the same BLAS product, the
        same floats, as from the former column copy. Gathering a column of every row costs a
        cache miss an entry (on a 20,000-state model at 2,000 vectors, 2 ms for a belief's 86
        columns, against 0.1 ms from a column store), but most calls score the same rows as
        one of the last few dozen calls (a trial expands a belief, then backs it up) with a
        few vectors added since: the maxima of the last ``_SCORED`` calls are kept, with
        their rows, and only the vectors added since are scored (ties stay with the lower
        index, as one argmax over all); a pruning empties them.
        """
        assert self.np_vectors is not None
        n, V, B = self.size, self.np_vectors, rows.shape[0]
        key = cols.tobytes()
        hit = self._scored.pop(key, None)
        if (hit is not None and hit[1] <= n and hit[0].shape == rows.shape
                and np.array_equal(hit[0], rows)):  # fmt: skip
            kept, m, val, arg = hit
            if m < n:
                scores = rows @ self._gather(kernel, V[m:n], cols)  # (B, n - m)
                j = scores.argmax(-1)
                new = scores[np.arange(B), j]
                better = new > val
                val, arg = np.where(better, new, val), np.where(better, j + m, arg)
        else:
            kept = np.array(rows, copy=True)
            scores = rows @ self._gather(kernel, V[:n], cols)  # (B, n)
            arg = scores.argmax(-1)
            val = scores[np.arange(B), arg]
        if hit is not None:
            self._scored_bytes -= hit[0].nbytes
        self._scored[key] = (kept, n, val, arg)
        self._scored_bytes += kept.nbytes
        while len(self._scored) > 1 and (len(self._scored) > _SCORED
                                         or self._scored_bytes > _SCORED_BYTES):  # fmt: skip
            self._scored_bytes -= self._scored.popitem(last=False)[1][0].nbytes
        return val.copy(), arg.copy()

    @staticmethod
    def _gather(kernel: Any, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """``(c, len(rows))`` ``rows[:, cols].T`` (``rows`` C-contiguous; compiled for
        float64 rows)."""
        if kernel is None or rows.dtype != np.float64:
            return np.ascontiguousarray(rows.T[cols])
        return backup_kernel.gather_columns(kernel, rows, rows.shape[0], cols)

    def group_scores(self, kernel: Any, rows: np.ndarray, rows_x: np.ndarray,
                     cols: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """``(B,)`` the best score of each row among its own observed value's vectors and
        ``(B,)`` that vector's index, in one compiled call over the rows of the storage
        (:func:`~torchhrc.solvers.backup_kernel.group_scores`; ``rows`` ``(B, Y)``
        C-contiguous, or ``(1, Y)``: one belief under each ``x`` of ``rows_x``; or ``(B, c)``
        on the columns ``cols``)."""
        assert self.np_vectors is not None
        V, gid, gn = self.scoring_storage()
        return backup_kernel.group_scores(kernel, rows, rows_x.astype(np.int64, copy=False), V,
                                          gid, gn, cols)  # fmt: skip

    def scoring_storage(self) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
        """``(vectors (cap, Y), gid, gn)``: the rows and, per observed value, the indices of
        its vectors and how many are in use, as the compiled scoring reads them
        (:func:`~torchhrc.solvers.backup_kernel.group_scores`, ``backup_one``)."""
        assert self.np_vectors is not None
        return self.np_vectors, self._gid, self._gn

    def _append_group(self, x: int, index: int) -> None:
        m = self._gn[x]
        if m == self._gid[x].shape[0]:
            grown = np.empty(2 * m, dtype=np.int64)
            grown[:m] = self._gid[x]
            self._gid[x] = grown
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
        self.np_vectors[n] = round_down_np(alpha, self.np_vectors.dtype)
        self.np_actions[n] = action
        self.np_observed[n] = observed
        self.size = n + 1
        self.refs.append(np.asarray(() if refs is None else refs, dtype=np.int64))
        self._append_group(observed, n)

    def _reserve(self, need: int) -> None:
        cap = self.vectors.shape[0]
        while cap < need:
            cap *= 2
        for name in ("vectors", "actions", "observed"):
            old = getattr(self, name)
            # rows past ``size`` are written before they are read; empty leaves their pages
            # untouched (not resident) until then
            new = alloc((cap, *old.shape[1:]), old.dtype, old.device, fill=None)
            if name == "vectors" and self.np_vectors is not None:
                # from the last rows to the first, a block at a time, each block's old pages
                # handed back once copied: one copy of the vectors at the peak, not two
                step = max(1, _BLOCK // max(old.shape[1], 1))
                for b1 in range(self.size, 0, -step):
                    b0 = max(0, b1 - step)
                    new.numpy()[b0:b1] = self.np_vectors[b0:b1]
                    release_pages(self.np_vectors, b0 * self.np_vectors.strides[0])
                self.np_vectors = None  # (a view of the old storage)
            else:
                copy_front(new, old, self.size)
            setattr(self, name, new)
            del old, new
        self._views()

    def add(self, alphas: torch.Tensor, actions: torch.Tensor, observed: torch.Tensor,
            refs: list[np.ndarray] | None = None) -> None:  # fmt: skip
        m = alphas.shape[0]
        if refs is None:
            refs = [np.zeros(0, dtype=np.int64)] * m
        self.refs.extend(np.asarray(r, dtype=np.int64) for r in refs)
        if self.size + m > self.vectors.shape[0]:
            self._reserve(self.size + m)
        s = slice(self.size, self.size + m)
        self.vectors[s] = round_down(alphas, self.vectors.dtype)
        self.actions[s], self.observed[s] = actions, observed
        self.size += m
        if self.np_vectors is not None:
            assert self.np_observed is not None
            for i in range(s.start, s.stop):
                self._append_group(int(self.np_observed[i]), i)

    def keep(self, mask: torch.Tensor | np.ndarray) -> np.ndarray:
        """Keep the vectors of ``mask (N,)`` and, transitively, those they refer to; a
        referred vector that a kept one of its ``x`` dominates pointwise is replaced by it in
        the references instead (the plan only gains).

        Returns ``(N,)`` the new index of each old vector (of its replacement, for a replaced
        one; -1 for a dropped one)."""
        m = np.array(mask if isinstance(mask, np.ndarray) else to_numpy(mask))[: self.size]
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
        if self._lent:  # the lent views keep the old rows: the set moves to a copy
            self.vectors, self.actions, self.observed = (
                _copy(self.vectors), _copy(self.actions), _copy(self.observed))  # fmt: skip
            self._lent = False
            self._views()
        n = kept.size
        # in place, a block of rows at a time: ``kept`` rises, so a block's rows are read
        # before a later block writes over them (kept[i] >= i); on the CPU through the numpy
        # views (the same copies without torch's calls: a small model prunes every iteration)
        step = max(1, _BLOCK // max(self.vectors.shape[1], 1))
        if self.np_vectors is not None:
            vectors, actions, observed, idx = (self.np_vectors, self.np_actions,
                                               self.np_observed, kept)  # fmt: skip
        else:
            vectors, actions, observed = self.vectors, self.actions, self.observed
            idx = torch.from_numpy(kept).to(self.vectors.device)
        for b0 in range(0, n, step):
            part = idx[b0 : b0 + step]
            vectors[b0 : b0 + len(part)] = vectors[part]
        actions[:n] = actions[idx]
        observed[:n] = observed[idx]
        self.size = n
        self.forget_scores()  # (the vectors moved)
        self._regroup()
        if self.np_vectors is not None:  # the dropped vectors' pages go back to the OS
            release_pages(self.np_vectors, n * self.np_vectors.strides[0])
        return moved
