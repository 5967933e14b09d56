"""The bounds at beliefs and at all their children, one expansion at a time: one product
against the alpha vectors and one sawtooth evaluation cover every child ``(a, x2, o)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch

from torchhrc.solvers import backup_kernel
from torchhrc.solvers.eval_cache import pack, upper_part
from torchhrc.solvers.upper_bound import _ROWS

__all__: list[str] = []

#: with one observed value, the one-call backup (its lower bounds a loop over each child's
#: support) is used while the alpha vectors times their width stay below this; above it the
#: separate steps score the children by one BLAS product, faster there (measured on
#: Hallway, a 7 x 7 maze and random 20- and 30-state models: the two paths break even at
#: 5,000-7,000; docs/benchmarks.md, "One compiled call per backup"). A MOMDP's children are
#: scored by the same loop either way.
ONE_CALL_FLAT_MAX = 6_000


@dataclass
class _Evaluation:
    """Bounds at ``B`` beliefs of one observed value and at all their children."""

    xs: torch.Tensor  # (K,) reachable next observed values
    J: torch.Tensor  # (B, A, K, O, Y) unnormalised children
    prob: torch.Tensor  # (B, A, K, O) P(x2, o | x, b, a)
    low: torch.Tensor  # (B, A, K, O) P * V_low(child)
    best: torch.Tensor  # (B, A, K, O) index of the best alpha vector at each child
    up: torch.Tensor  # (B, A, K, O) P * V_up(child)
    q_low: torch.Tensor  # (B, A)
    q_up: torch.Tensor  # (B, A)
    self_low: torch.Tensor  # (B,) V_low(b) under the current alpha vectors
    self_up: torch.Tensor  # (B,) V_up(b) under the current sawtooth


class _OneCall(NamedTuple):
    """What a backup at one observed value ``x`` hands the compiled call beside the belief."""

    tables: tuple[np.ndarray, ...]  # the form's tables at x (SolverModel.compiled_tables)
    xs: list[int]  # x and the x2 it reaches: the sawtooth groups the call reads
    scratch: tuple[np.ndarray, ...]  # backup_kernel.new_scratch of its (children, width)


class _Bounds:
    """Methods of the search (``_SARSOP`` of :mod:`~torchhrc.solvers.sarsop.search`) that
    bound beliefs and their children with its alpha set ``alphas``, its sawtooth ``ub`` and
    its model ``form``, on the batched torch path or the one-belief numpy path, and cache
    the evaluations."""

    def lower_value(
        self, beliefs: torch.Tensor, x: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(B,)`` max alpha . b over the vectors of each ``x``, and the argmax index."""
        n = self.alphas.size
        # (the batched torch path, GPU-sized sets: vectors held narrower, by alpha_dtype, are
        # widened whole here; the CPU's numpy paths score them in place)
        scores = beliefs @ self.alphas.vectors[:n].T.to(beliefs.dtype)  # (B, N)
        if self.X > 1:
            scores = scores.masked_fill(x.unsqueeze(-1) != self.alphas.observed[:n], -torch.inf)
        return scores.max(-1)

    def evaluate(self, x: int, beliefs: torch.Tensor) -> _Evaluation:
        """Expand ``B`` beliefs of observed value ``x``; bound them and all their children.

        One expansion, one matrix product against the alpha vectors and one sawtooth
        evaluation cover the ``B * A * K * O`` children and the ``B`` beliefs themselves.
        """
        xs, J = self.form.expand(x, beliefs)  # (B, A, K, O, Y)
        B, A, K, O, Y = J.shape
        C = B * A * K * O
        key = (x, B)
        cx = self._child_x.get(key)
        if cx is None:
            cx = torch.cat([xs.view(1, 1, K, 1).expand(B, A, K, O).reshape(-1),
                            xs.new_full((B,), x)])  # fmt: skip
            self._child_x[key] = cx
        prob = J.sum(-1)  # (B, A, K, O)
        nz = prob.reshape(-1).nonzero().squeeze(-1)
        shape = (B, A, K, O)
        if nz.numel() * 4 < C * 3:
            # most children are impossible (deterministic moves, observations tied to the
            # state): bound only the possible ones; the others weigh 0 (the bounds are
            # homogeneous) and take the best vector of their x2 at the parent belief
            # (:meth:`_impossible_best`)
            rows = torch.cat([J.reshape(C, Y)[nz], beliefs])
            rows_x = torch.cat([cx[nz], cx[C:]])
            low_r, best_r = self.lower_value(rows, rows_x)
            up_r = self.ub.value(rows, rows_x)
            m = nz.numel()
            low_c = J.new_zeros(C).index_copy_(0, nz, low_r[:m]).view(shape)
            up_c = J.new_zeros(C).index_copy_(0, nz, up_r[:m]).view(shape)
            best_c = self._impossible_best(beliefs, xs, shape).index_copy_(0, nz, best_r[:m])
            best_c = best_c.view(shape)
            self_low, self_up = low_r[m:], up_r[m:]
        else:
            flat = torch.cat([J.reshape(C, Y), beliefs])  # (C + B, Y)
            low, best = self.lower_value(flat, cx)
            up = self.ub.value(flat, cx)
            best_c = torch.where(prob.reshape(-1) > 0, best[:C],
                                 self._impossible_best(beliefs, xs, shape)).view(shape)  # fmt: skip
            low_c, up_c = low[:C].view(shape), up[:C].view(shape)
            self_low, self_up = low[C:], up[C:]
        reward = self.form.reward(x, beliefs)  # (B, A)
        q_low = reward + self.gamma * low_c.sum((-1, -2))
        q_up = reward + self.gamma * up_c.sum((-1, -2))
        return _Evaluation(xs, J, prob, low_c, best_c, up_c, q_low, q_up, self_low, self_up)

    def _impossible_best(self, beliefs: torch.Tensor, xs: torch.Tensor,
                         shape: tuple[int, int, int, int]) -> torch.Tensor:  # fmt: skip
        """``(B * A * K * O,)`` the best vector of each child's ``x2`` at its parent belief.

        What a backup uses at an impossible child (:meth:`_impossible_best_np`).
        """
        B, _, K, _ = shape
        rows = beliefs.unsqueeze(1).expand(B, K, beliefs.shape[-1]).reshape(B * K, -1)
        _, ids = self.lower_value(rows, xs.repeat(B))  # (B * K,)
        return ids.view(B, 1, K, 1).expand(shape).contiguous().view(-1)

    # -- numpy path (CPU, one belief) -------------------------------------------------------
    def _lower_np(self, rows: np.ndarray, rows_x: np.ndarray, cols: np.ndarray | None = None,
                  ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """``(B,)`` max alpha . b over the vectors of each ``x`` and the argmax (numpy).

        Only the vectors of the rows' own observed values are scored (``alphas.group(x)``,
        ``N_x * Y`` per row instead of ``N * Y``); ties go to the lowest index, as a scan of
        the whole set would. Rows given on the columns ``cols`` only (children of a sparse
        belief, :class:`~torchhrc.solvers.forms.base.Children`) are scored against those
        columns of the vectors only.
        """
        alphas = self.alphas
        if self.X == 1:
            V, ids = alphas.group(0)  # (N, Y) a view of the storage, (N,) 0..N-1
            if cols is None and rows.shape[1] >= 64:
                sup = np.flatnonzero(rows.any(0))
                if sup.size * 2 <= rows.shape[1]:  # sparse beliefs: only their support matters
                    rows, cols = rows[:, sup], sup
            if cols is None:
                return self._best(rows @ V.T, ids)
            return alphas.best_on_columns(self._vkernel, rows, cols)  # (ids: 0..N-1)
        if self._vkernel is not None:  # each row against its own x's, compiled
            rows = np.ascontiguousarray(rows)
            return alphas.group_scores(self._vkernel, rows, rows_x, cols)
        first = rows_x[0]
        if (rows_x == first).all():
            V, ids = alphas.group(int(first))
            return self._best(rows @ (V.T if cols is None else V[:, cols].T), ids)
        # one product against the vectors of all the rows' observed values, masked to each
        # row's own: fewer array ops than one product per observed value
        xs = np.unique(rows_x)
        blocks = [alphas.group(int(u)) for u in xs]
        V = np.concatenate([v for v, _ in blocks])  # (sum N_x, Y)
        ids = np.concatenate([i for _, i in blocks])
        label = np.repeat(xs, [i.size for _, i in blocks])  # (sum N_x,) observed value
        scores = rows @ (V.T if cols is None else V[:, cols].T)  # (B, sum N_x)
        scores[rows_x[:, None] != label[None, :]] = -np.inf
        return self._best(scores, ids)

    @staticmethod
    def _best(scores: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(B,)`` the row maxima of ``scores (B, N)`` and ``ids`` of the argmax."""
        j = scores.argmax(-1)  # one pass; the maximum is the score there
        B = scores.shape[0]
        return scores[_ROWS[:B] if B <= _ROWS.size else np.arange(B), j], ids[j]

    def _upper_np(
        self,
        value: Any,
        nz: np.ndarray,
        reward: np.ndarray,
        C: int,
        stale: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Upper bounds of a belief's possible children ``nz`` (of ``C``, ``C / A`` per
        action, in action order), ``Q_up``, ``V_up``.

        ``value(ids)`` bounds rows ``ids`` of the children (row ``nz.size`` is ``b`` itself).
        Without ``stale`` every child is bounded. With ``stale`` (the node's cached record of
        an earlier evaluation, :func:`~torchhrc.solvers.eval_cache.pack`) only the children of the
        action with the highest ``Q_up`` are re-bounded, repeatedly, until the best action is
        one just refreshed (APPL's ``getNewUBValueUseCache``): every earlier sawtooth value is
        still an upper bound, so stale ``Q_up`` of the other actions stay valid, and a backup
        bounds one or two actions' children instead of all ``A``.
        """
        m, A = nz.size, reward.shape[0]
        if stale is None:
            up_r = value(np.arange(m + 1))
            up = np.zeros(C, dtype=reward.dtype)
            up[nz] = up_r[:m]
            q_up = reward + self.gamma * up.reshape(A, -1).sum(-1)
            return up, q_up, float(up_r[m])
        q_up, up = (v.copy() for v in upper_part(stale, A))
        # plain floats and lists: the loop runs over A values one to three times per
        # backup, where each numpy call costs more than the arithmetic (aloha: 9 actions)
        q = q_up.tolist()
        fresh = [False] * A
        top = None  # the highest Q_up of a refreshed action
        every = m == C  # every child possible (dense models): action a's rows are a block
        if every:
            blocks = self._action_rows(A, C)
        else:  # action a: rows ends[a] to ends[a + 1] of nz
            ends = np.searchsorted(nz // (C // A), np.arange(A + 1)).tolist()
        cu = None
        while True:
            # refresh the best stale action while it beats every fresh one (ties within
            # 1e-12 relative, resolved to the lowest index, so that round-off in the cached
            # values does not change which children are bounded)
            if top is None:
                cand = range(A)
            else:
                over = top + 1e-12 * max(1.0, abs(top))
                cand = [i for i in range(A) if not fresh[i] and q[i] > over]
                if not cand:
                    break
            best = max(q[i] for i in cand)
            floor = best - 1e-12 * max(1.0, abs(best))
            a = next(i for i in cand if q[i] >= floor)
            if every:
                sel, with_b = blocks[a]
                ids = sel if cu is not None else with_b
            else:
                sel = np.arange(ends[a], ends[a + 1])
                ids = sel if cu is not None else np.append(sel, m)
            vals = value(ids)
            if cu is None:
                cu, vals = float(vals[-1]), vals[:-1]
            if every:
                up[sel] = vals
            else:
                up.reshape(A, -1)[a] = 0.0
                up[nz[sel]] = vals
            q_up[a] = reward[a] + self.gamma * up.reshape(A, -1)[a].sum()
            q[a] = float(q_up[a])
            fresh[a] = True
            top = q[a] if top is None else max(top, q[a])
        assert cu is not None
        return up, q_up, cu

    def _action_rows(self, A: int, C: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """When all ``C`` children of a belief are possible (``C / A`` per action): per action
        ``a``, its rows ``(C / A,)`` and the same with the belief's own row ``C`` appended
        (built once per ``(A, C)``)."""
        key = (A, C)
        rows = self._rows_cache.get(key)
        if rows is None:
            n = C // A
            rows = [(np.arange(a * n, (a + 1) * n), np.append(np.arange(a * n, (a + 1) * n), C))
                    for a in range(A)]  # fmt: skip
            self._rows_cache[key] = rows
        return rows

    def _evaluate_np(
        self, x: int, b: np.ndarray, stale: np.ndarray | None = None
    ) -> tuple[Any, ...]:
        """:meth:`evaluate` for one belief ``b (Y,)`` in numpy.

        The form gives the possible children (:meth:`SolverModel.children_np`, on the columns
        they live on); they and ``b`` are bounded by one product against the alpha vectors
        and one sawtooth evaluation. Returns the evaluation's record (``q_low (A,)``,
        ``q_up (A,)``, ``prob``, ``low``, ``up`` ``(A, K, O)`` as :class:`_Evaluation`, in
        :func:`~torchhrc.solvers.eval_cache.pack`'s layout), ``best (A * K * O,)``,
        ``V_low(b)``, ``V_up(b)``, the children's observed values ``child_x (A * K * O,)`` and
        the best vector at ``b`` itself. ``best`` holds the possible children's vectors only
        (0 elsewhere): a backup fills the impossible children of the one action it takes
        (:meth:`_impossible_best_np`); the sampling and the pruning read possible ones only.
        ``stale``: the node's cached record, see :meth:`_upper_np`.
        """
        call = self._one_call(x)
        if call is not None:  # the whole evaluation in one compiled call
            out = self._backup_compiled(x, b, stale, call, vector=False)
            return out.record, out.best, out.lower, out.upper, out.child_x, out.own
        ch = self.form.children_np(x, b)
        A, K, O = ch.prob.shape
        low_r, best_r = self._lower_np(ch.rows, ch.rows_x, ch.cols)
        m = ch.nz.size
        if self._kernel is not None and ch.cols is None and ch.rows.flags.c_contiguous:
            # float64 on the CPU, the children on all columns: the rest in one compiled call
            xs = (0,) if self.X == 1 else set(ch.rows_x.tolist())
            low, best, q_low, up, q_up, cu = backup_kernel.bound_children(
                self._kernel, ch.rows, ch.rows_x.astype(np.int64, copy=False), ch.nz, low_r,
                best_r, ch.reward, self.gamma,
                None if stale is None else upper_part(stale, A),
                self.ub.loop_storage(xs), A * K * O,
            )  # fmt: skip
            lo, own = float(low_r[m]), int(best_r[m])
            return pack(q_low, q_up, ch.prob, low, up), best, lo, cu, ch.child_x, own
        if m == A * K * O:  # every child possible: the rows are the children in order
            low, best = low_r[:m], best_r[:m].copy()
        else:
            low = np.zeros(A * K * O, dtype=b.dtype)
            low[ch.nz] = low_r[:m]
            best = np.zeros(A * K * O, dtype=np.int64)
            best[ch.nz] = best_r[:m]
        q_low = ch.reward + self.gamma * low.reshape(A, K * O).sum(-1)
        rows, rows_x, cols = ch.rows, ch.rows_x, ch.cols
        up, q_up, cu = self._upper_np(
            lambda ids: self.ub.value_np(rows[ids], rows_x[ids], cols),
            ch.nz, ch.reward, A * K * O, stale,
        )  # fmt: skip
        return (pack(q_low, q_up, ch.prob, low, up), best, float(low_r[m]), cu, ch.child_x,
                int(best_r[m]))  # fmt: skip

    def _one_call(self, x: int) -> _OneCall | None:
        """What :func:`~torchhrc.solvers.backup_kernel.backup_one` needs at ``x`` beyond the
        belief (built once per ``x``), or ``None``: the vectors are not float64 (or the
        extension is off), the form has no tables for it
        (:meth:`~torchhrc.solvers.forms.base.SolverModel.compiled_tables`), or a flat model's
        vectors times their width exceed :data:`ONE_CALL_FLAT_MAX`."""
        if self._vkernel is None:
            return None
        if self.X == 1 and self.alphas.size * self.Y > ONE_CALL_FLAT_MAX:
            return None  # many wide vectors: a BLAS product scores the children faster
        found = self._one_calls.get(x, False)
        if found is False:
            tables = self.form.compiled_tables(x)
            found = None
            if tables is not None:
                shape = (tables[2].shape[0] * tables[2].shape[1] * tables[2].shape[2], self.Y)
                scratch = self._scratch.get(shape)  # one per shape, shared by the x that have it
                if scratch is None:
                    scratch = self._scratch[shape] = backup_kernel.new_scratch(*shape)
                found = _OneCall(tables, sorted({x, *self.form.reach_np(x).tolist()}), scratch)
            self._one_calls[x] = found
        return found

    def _backup_compiled(self, x: int, b: np.ndarray, stale: np.ndarray | None,
                         call: _OneCall, vector: bool) -> backup_kernel.Backup:  # fmt: skip
        """:meth:`_evaluate_np` and, with ``vector``, the new alpha
        vector of :meth:`_backup_one_np`, in one compiled call
        (:func:`~torchhrc.solvers.backup_kernel.backup_one`)."""
        return backup_kernel.backup_one(
            self._vkernel, b, x, call.tables, self.alphas.scoring_storage(),
            self.ub.loop_storage(call.xs), stale, self.gamma, vector, call.scratch,
        )  # fmt: skip

    def _impossible_best_np(self, x: int, b: np.ndarray, child_x: np.ndarray, possible: np.ndarray,
                            own: int | None = None) -> np.ndarray:  # fmt: skip
        """``(C,)`` the vector a backup of ``b`` uses at each impossible child (``P = 0``;
        ``possible (C,)`` bool marks the others).

        An impossible child weighs 0 in ``V_low(b)``, but its vector still shapes the new
        alpha vector away from ``b``'s support, i.e. its value at the other beliefs of the
        same ``x``. As APPL's ``BackupAlphaPlaneMOMDP::getNewAlphaPlaneQ`` (a ``NULL`` edge
        takes ``getBestAlphaPlane`` of the belief ``b`` under ``x2``), it is the best vector
        of its ``x2`` at ``b`` itself, not an arbitrary vector of ``x2`` (formerly the last
        one added: on RockSample_7_8 as a MOMDP its new vectors then generalised poorly to
        the beliefs the search had not backed up). Possible children's entries are left to
        the caller. ``own``: the best vector at ``b`` under ``x`` when the caller has it (an
        evaluation scores ``b`` itself), used for the children that stay at ``x``: with one
        observed value, every child.
        """
        if own is not None and self.X == 1:
            return np.full(child_x.shape[0], own, dtype=np.int64)
        best = np.zeros(child_x.shape[0], dtype=np.int64)
        imp = ~possible
        cx = child_x[imp]
        # the distinct x2 of the impossible children, a few among many, as a plain sorted
        # list: np.unique(return_inverse=True) cost 26 us a backup on RockSample(8,4) as a
        # MOMDP, a quarter of the backup, for one or two values
        distinct = sorted(set(cx.tolist()))
        if not distinct:
            return best
        if own is not None and distinct == [x]:  # a flat model: always
            best[imp] = own
            return best
        # b itself under each distinct x2
        ux = np.array(distinct, dtype=np.int64)
        if self._vkernel is not None:  # one compiled call
            ids = self.alphas.group_scores(self._vkernel, b.reshape(1, -1), ux)[1]
        else:
            ids = self._lower_np(np.broadcast_to(b, (ux.size, b.shape[0])), ux)[1]
        best[imp] = ids[0] if ux.size == 1 else ids[np.searchsorted(ux, cx)]
        return best

    def _root_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R,)`` the lower and upper bound at each root."""
        xs, b, _ = self.form.roots
        if self._np:
            rows = b.numpy()
            return self._lower_np(rows, xs)[0], self.ub.value_np(rows, xs)
        x = torch.from_numpy(xs).to(b.device)
        lo = self.lower_value(b, x)[0].cpu().double().numpy()
        return lo, self.ub.value(b, x).cpu().double().numpy()

    def _store(self, node: int, ev: _Evaluation, i: int) -> np.ndarray:
        """Cache a node's action and child bounds (row ``i`` of ``ev``) for the sampling, as
        one record (:func:`~torchhrc.solvers.eval_cache.pack`); returns it.

        As in APPL, sampling reads the bounds of a node's last backup; they stay valid bounds
        (upper bounds only decrease and lower bounds only increase afterwards).
        """
        record = pack(*(t[i].cpu().numpy() for t in (ev.q_low, ev.q_up, ev.prob, ev.low, ev.up)))
        self._cache[int(self.belief_id[node])] = record
        self._child_best[int(self.belief_id[node])] = ev.best[i].reshape(-1).cpu().numpy()
        return record
