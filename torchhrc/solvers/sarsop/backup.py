"""SARSOP's point-based backups of tree beliefs: a new alpha vector and a new sawtooth point
where they improve the bounds (Pineau et al. 2003; Ong et al. 2010 for the MOMDP factoring).
"""

from __future__ import annotations

import numpy as np
import torch

from torchhrc.solvers.eval_cache import action_prob

__all__: list[str] = []


class _Backups:
    """Methods of the search (``_SARSOP`` of :mod:`~torchhrc.solvers.sarsop.search`) that
    back up tree nodes: one node on the numpy path, a batch on the torch path, and a sweep
    of every active node."""

    def _backup_one_np(self, x: int, node: int) -> None:
        """:meth:`backup` of one node in numpy (the sequential path of a trial)."""
        tree = self.tree
        b = tree.beliefs_np[node]
        bid = int(self.belief_id[node])
        stale = self._cache.get(bid) if self.cfg.lazy_upper else None
        call = self._one_call(x)
        A = self.A
        if call is not None:  # the whole backup in one compiled call
            out = self._backup_compiled(x, b, stale, call, vector=True)
            record, best, lo, cu, a, alpha, nl = (out.record, out.best, out.lower, out.upper,
                                                  out.action, out.vector, out.value)  # fmt: skip
        else:
            record, best, lo, cu, child_x, own = self._evaluate_np(x, b, stale)
            a = int(record[:A].argmax())
            C = best.shape[0]
            n = C // A  # the action's children (K O), in (k, o) order
            use = best[a * n : (a + 1) * n]
            p_a = action_prob(record, A, a)
            if np.count_nonzero(p_a) < n:  # some child of a is impossible
                possible = p_a > 0
                fill = self._impossible_best_np(x, b, child_x[a * n : (a + 1) * n], possible, own)
                use = np.where(possible, use, fill)
            K = C // (A * self.O)
            alpha = self.form.backup_vector_np(x, a, use.reshape(K, self.O),
                                               self.alphas.np_vectors, self.gamma)  # fmt: skip
            nl = float(alpha @ b)
        q = record[: 2 * A].tolist()  # q_low, then q_up
        q_up_list = q[A:]
        nu = max(q_up_list)
        self._cache[bid] = record
        self._child_best[bid] = best
        if nl > lo + 1e-10 * max(abs(nl), 1.0):
            n = best.shape[0] // A
            self.alphas.add_np(
                alpha, a, x, best[a * n : (a + 1) * n][action_prob(record, A, a) > 0]
            )
        if nu < cu - 1e-10 * max(abs(cu), 1.0):
            self.ub.add_np(b, x, nu)
        low, up = max(lo, nl), min(cu, nu)
        tree.lower[node], tree.upper[node] = low, up
        self.backups += 1
        top = q[a]  # q_low[a] = max Q_low
        if self.cfg.prune_nodes and min(q_up_list) < top:
            for c in tree.children_of(node):
                if q_up_list[tree.action[c]] < top:
                    tree.active[c] = False
        if self.cfg.prediction == "binning":
            self.bins.update(bid, x, b, float(self.entropy[node]), up, low)

    def backup_node(self, x: int, node: int) -> None:
        """:meth:`backup` of one tree node (a trial's path, one node at a time): the numpy
        path's step directly, without a batch of one."""
        if self._np:
            self._backup_one_np(x, node)
        else:
            self.backup(x, np.array([node]))

    def backup(self, x: int, nodes: np.ndarray) -> None:
        """Point-based backup of tree nodes sharing observed value ``x``, all at once.

        Lower bound: for the action ``a`` maximising ``Q_low(b, a)``, the alpha vector
        ``alpha(y) = R(a, x, y) + gamma sum_{x2, o, y2} Tx Ty Z(a, x2, y2, o) alpha_{x2, o}(y2)``
        with ``alpha_{x2, o}`` the best vector at ``tau(b, a, x2, o)`` (Pineau et al. 2003); it
        is added when it raises ``V_low(b)``. Upper bound: the point
        ``(b, max_a Q_up(b, a))`` is added when below the sawtooth at ``b``.
        """
        if self._np and (len(nodes) == 1 or not self.form.batch_backups):
            for node in nodes.tolist():
                self._backup_one_np(x, int(node))
            return
        tree, form = self.tree, self.form
        B = len(nodes)
        beliefs = (
            tree.beliefs[torch.from_numpy(nodes).to(self.device)]
            if B > 1
            else tree.beliefs[int(nodes[0])][None]
        )
        ev = self.evaluate(x, beliefs)
        a = ev.q_low.argmax(-1)  # (B,)
        sel = ev.best[torch.arange(B, device=self.device), a]  # (B, K, O) alpha index per child
        possible = ev.prob[torch.arange(B, device=self.device), a] > 0  # (B, K, O)
        refs = [sel[i][possible[i]].cpu().numpy() for i in range(B)]
        W = self.alphas.vectors[sel]  # (B, K, O, Y)
        z = form.observation_slice(x, a)  # (B, K, O, Y)
        alpha = form.R[a, x, :] + self.gamma * form.backproject(x, a, (z * W).sum(2))  # (B, Y)
        new_low = (alpha * beliefs).sum(-1)
        new_up = ev.q_up.amax(-1)
        cur_low, cur_up = ev.self_low, ev.self_up
        xb = self._child_x[(x, B)][-B:]
        for i, node in enumerate(nodes.tolist()):
            self._store(node, ev, i)
        if B == 1:
            lo, nl, cu, nu = cur_low.item(), new_low.item(), cur_up.item(), new_up.item()
            if nl > lo + 1e-10 * max(abs(nl), 1.0):
                self.alphas.add(alpha, a, xb, refs)
            if nu < cu - 1e-10 * max(abs(cu), 1.0):
                self.ub.add(beliefs, xb, new_up)
            tree.lower[nodes[0]], tree.upper[nodes[0]] = max(lo, nl), min(cu, nu)
            low, up = np.array([max(lo, nl)]), np.array([min(cu, nu)])
        else:
            better = new_low > cur_low + 1e-10 * new_low.abs().clamp(min=1.0)
            if better.any():
                keep = better.nonzero().squeeze(-1)
                self.alphas.add(alpha[keep], a[keep], xb[keep], [refs[i] for i in keep.tolist()])
            improve = new_up < cur_up - 1e-10 * cur_up.abs().clamp(min=1.0)
            if improve.any():
                keep = improve.nonzero().squeeze(-1)
                self.ub.add(beliefs[keep], xb[keep], new_up[keep])
            low = torch.maximum(new_low, cur_low).cpu().numpy()
            up = torch.minimum(new_up, cur_up).cpu().numpy()
            tree.lower[nodes], tree.upper[nodes] = low, up
        self.backups += B
        # sub-optimal action pruning: children reached by a with Q_up(b, a) < max Q_low(b, .)
        if self.cfg.prune_nodes:
            bad = (ev.q_up < ev.q_low.amax(-1, keepdim=True)).cpu().numpy()  # (B, A)
            for i, n in enumerate(nodes.tolist()):
                for c in tree.children_of(n):
                    if bad[i, tree.action[c]]:
                        tree.active[c] = False
        if self.cfg.prediction == "binning":
            ent = self.entropy[nodes]
            rows = beliefs.cpu().double().numpy()
            for i, (n, u, e, lo) in enumerate(
                zip(nodes.tolist(), up.tolist(), ent.tolist(), low.tolist())
            ):
                self.bins.update(int(self.belief_id[n]), x, rows[i], e, u, lo)

    def sweep(self) -> None:
        """Back up every active tree node, one batched backup per observed value."""
        tree = self.tree
        act = np.flatnonzero(tree.active[: tree.size])
        xs = tree.x[act]
        for x in np.unique(xs).tolist():
            nodes = act[xs == x]
            # deepest first within the batch order does not matter: one batched backup
            for start in range(0, nodes.size, 256):
                if self._out_of_budget():
                    return  # every backup leaves valid bounds: the rest waits (as a trial)
                self.backup(int(x), nodes[start : start + 256])
