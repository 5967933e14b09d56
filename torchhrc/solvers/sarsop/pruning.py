"""SARSOP's pruning: the alpha vectors that win at no tree belief (keeping the plans they
build and the vectors best at the active beliefs' children) and the redundant sawtooth
points, when the sets have grown enough and the time left allows.
"""

from __future__ import annotations

import numpy as np

from torchhrc._host import to_numpy
from torchhrc.solvers import backup_kernel
from torchhrc.solvers._memory import release_free_memory
from torchhrc.solvers.eval_cache import unpack

__all__: list[str] = []


class _Pruning:
    """Methods of the search (``_SARSOP`` of :mod:`~torchhrc.solvers.sarsop.search`) that
    prune its alpha set ``alphas``, its sawtooth ``ub`` and the tree's active nodes."""

    def _child_winners(self, nodes: np.ndarray) -> np.ndarray:
        """The alpha vectors best at a child of the beliefs of ``nodes`` at their last
        evaluation, if it came after the last alpha pruning, for the children a later backup
        of the belief may combine: possible ones (``P > 0``) under an action whose ``Q_up``
        reaches ``max_a Q_low`` (the others are never the backup's action again: upper bounds
        only fall, lower bounds only rise).

        APPL's SARSOP keeps, besides the vectors certified at tree beliefs, the vector best at
        each belief of its cache when the belief was created, the unexpanded children of the
        tree included, until a newer vector beats it there (``AlphaPlaneMaxMeta``,
        ``PruneAlphaPlane::updateMax``). Here a child's best vector is recorded at each
        evaluation of its parent, and the records start afresh at each pruning: a record from
        before the last pruning is mostly stale (aloha-10max after 20 CPU-s: 1,708 recorded
        vectors, 40 of them still best at a child when formed again, and the kept set grew to
        4,000 vectors by 60 s). A belief the search has not evaluated since then protects
        none of its children's vectors; the tree beliefs keep theirs (:meth:`prune`), so no
        bound at a tree belief falls, and an unexpanded child's is restored when the search
        evaluates its parent again.
        """
        parts = []
        for b in np.unique(self.belief_id[nodes]).tolist():
            best = self._child_best.get(b)
            if best is None:
                continue
            q_low, q_up, prob = unpack(self._cache[b], self.A, self.O)[:3]
            live = (q_up >= q_low.max())[:, None, None] & (prob > 0)
            parts.append(best.reshape(prob.shape)[live])
        if not parts:
            return np.zeros(0, dtype=np.int64)
        ids = np.unique(np.concatenate(parts))
        return ids[ids >= 0]  # (an entry is -1 only if its vector was dropped: never counted)

    def _affordable(self, kind: str, size: int) -> bool:
        """Whether a pruning of ``kind`` at ``size`` items ends before the deadline, judged by
        the last one's duration scaled to ``size`` (its cost grows about linearly): a pruning
        is skipped near the end rather than overrun the limit (it only bounds the sets'
        growth; the bounds stay valid without it)."""
        last = self._prune_cost.get(kind)
        if last is None:
            return True
        seconds, at = last
        return self.clock() + seconds * size / max(at, 1) < self.deadline

    def prune(self) -> None:
        pruned = self._prune_alphas()
        if self._prune_points() or pruned:
            release_free_memory()  # what the pruning freed, back to the OS (see _memory)
        if self.cfg.prune_nodes:
            self.tree.refresh_active()

    def _prune_alphas(self) -> bool:
        """Prune the alpha vectors when the set has grown enough; whether it ran."""
        cfg = self.cfg
        if not (
            cfg.prune_alphas
            and self.alphas.size > cfg.prune_growth * max(self.last_alpha_prune, 16)
            and self._affordable("alphas", self.alphas.size)
        ):
            return False
        t0 = self.clock()
        n = self.alphas.size
        act = np.flatnonzero(self.tree.active[: self.tree.size])
        # one active node per distinct belief: the tree holds a belief once per path that
        # reaches it (bridge-repair after 13 s: 12,882 active nodes, 1,844 distinct beliefs),
        # and the winners at equal beliefs are the same vectors
        _, first = np.unique(self.belief_id[act], return_index=True)
        act = act[np.sort(first)]
        # the winners at the tree beliefs, and (in keep) every vector they were built
        # from: a backup chooses child vectors at children outside the tree, and without
        # them the greedy policy cannot realise a kept vector's value (before:
        # RockSample_7_8.pomdpx, written policy 16.4 simulated against a lower bound 20.3)
        # (float64 vectors: their store for the compiled rule, which the tree takes where
        # its storage allows)
        store = None if self._vkernel is None else backup_kernel.AlphaStore(
            self._vkernel, *self.alphas.scoring_storage(), self.alphas.np_observed[:n])  # fmt: skip
        vectors, _, obs = self.alphas.in_use()
        mask = to_numpy(self.tree.keep_alphas(vectors, obs if self.X > 1 else None, act, store))
        # and the best vectors at the children of the active tree beliefs (APPL certifies
        # a vector at any belief of its cache, the unexpanded children of the tree
        # included): a backup of a tree belief combines the best vectors at its children,
        # and pruning those would lower the children's bounds, which only a search that
        # reaches each child again restores
        mask[self._child_winners(act)] = True
        self.alphas.keep(mask)
        # the next pruning protects the children of the beliefs evaluated from now on
        self._child_best = {}
        self.last_alpha_prune = self.alphas.size
        self._prune_cost["alphas"] = (self.clock() - t0, n)
        return True

    def _prune_points(self) -> bool:
        """Prune the upper-bound points when they have grown enough; whether it ran."""
        cfg = self.cfg
        n = self.ub.size
        if n <= cfg.prune_growth * max(self.last_point_prune, 64) or not self._affordable(
            "points", n
        ):
            return False
        t0 = self.clock()
        self.ub.prune()
        self.last_point_prune = self.ub.size
        self._prune_cost["points"] = (self.clock() - t0, n)
        return True
