"""SARSOP's trials: the path a trial samples from the root (the paper's "SamplePoints") and
the tree nodes it adds, each with its entropy and the id of its distinct belief.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import torch

from torchhrc.solvers.eval_cache import unpack

__all__: list[str] = []


class _Trials:
    """Methods of the search (``_SARSOP`` of :mod:`~torchhrc.solvers.sarsop.search`) that
    sample a trial and grow the belief tree ``tree`` along it."""

    @staticmethod
    def _entropy(beliefs: np.ndarray) -> np.ndarray:
        """``(B,)`` the entropy of each row of ``beliefs (B, Y)`` (0 log 0 = 0)."""
        p = np.where(beliefs > 0, beliefs, 1.0)
        return -(p * np.log(p)).sum(-1)

    def sample(self, eps: float) -> list[int]:
        tree, g, cfg = self.tree, self.gamma, self.cfg
        node, t = 0, 0
        L = float(tree.lower[0])
        U = L + eps
        if self.n_roots > 1:
            # a random first x: the roots are the outcomes of a step without reward or
            # discount, taken with probability ``w``; the trial enters the root of largest
            # weighted gap (the observation choice below) with the targets of that step
            R, w = self.n_roots, self.root_w
            lo, up = tree.lower[:R], tree.upper[:R]
            total = float(w @ lo)
            node = int(np.argmax(w * (up - lo)))
            L = float(lo[node])  # (total - sum of the others' w lo) / w[node]
            U = float(up[node]) + (total + eps - float(w @ up)) / float(w[node])
        path = [node]
        bid = int(self.belief_id[node])
        seen = {bid}
        forward = self._forward = set()
        binning = cfg.prediction == "binning"
        # (the step's loop reads these once: attribute chains and numpy scalars cost more
        # than the arithmetic on a small model; the same values as before)
        cache, form, numpy_path, reach = self._cache, self.form, self._np, self._reach
        A, O = self.A, self.O
        step = None if self._kernel is None else self._kernel.trial_step
        draw_ties = cfg.tie_break == "random"
        scale = 1.0  # g ** (-t)
        # the lower bound at the start has stalled: draw each child among the near-largest
        explore = self.explore_after is not None and self._stall >= self.explore_after
        self.explored += explore
        while t < self.max_depth and not self._out_of_budget():
            lo, up = float(tree.lower[node]), float(tree.upper[node])
            v_hat = self.bins.predict(bid, up, lo) if binning else up
            if up - lo <= 0.5 * eps * scale:
                # APPL's final precision: the gap here is within half the trial's target
                # error, whatever the predictor says (SampleBP::sample, ``finalExcess``);
                # it ends a trial that a cycle's backups keep raising (shuttle: 238 steps)
                break
            if v_hat <= L and up <= max(U, lo + eps * scale):
                break
            x = int(tree.x[node])
            record = cache.get(bid)
            if record is None:
                if numpy_path:
                    record, best = self._evaluate_np(x, tree.beliefs_np[node])[:2]
                    cache[bid] = record
                    self._child_best[bid] = best
                else:
                    ev = self.evaluate(x, tree.beliefs[node].unsqueeze(0))
                    record = self._store(node, ev, 0)
            scale_next = g ** (-(t + 1))
            target = eps * scale_next
            ties = 0
            if step is not None and not explore:
                # the action and the child in one compiled call (the same choice as below);
                # equal actions drawn among (tie_break="random") go the Python way, as does a
                # record the call cannot read (float32: the torch path's)
                try:
                    q_low_max, a, ties, k, o, p, low_c, up_c = step(record, A, O, target)
                except TypeError:
                    step = None
            if step is None or explore or (ties > 1 and draw_ties):
                q_low, q_up, prob_all, low_all, up_all = unpack(record, A, O)
                q_low_max = max(q_low.tolist())
                a = self._argmax_tie(q_up)
                prob, up_a, low_a = prob_all[a], up_all[a], low_all[a]  # (K, O) each
                if explore:
                    k, o, p = self._child_draw(prob, up_a, low_a, target)
                else:
                    k, o, p = self._child_choice(prob, up_a, low_a, target)
                low_c, up_c = float(low_a[k, o]), float(up_a[k, o])
            if p <= 0:
                break
            L1 = max(L, q_low_max)
            U1 = max(U, q_low_max + eps * scale)
            L = (L1 - float(record[a]) + g * low_c) / (g * p)  # record[a]: Q_low(a)
            U = (U1 - float(record[A + a]) + g * up_c) / (g * p)  # Q_up(a)
            reach_x = reach.get(x)
            if reach_x is None:  # (x's reachable x2 as plain ints, once per x)
                reach_x = reach[x] = (form.reach_np(x) if numpy_path else form.reach[x]).tolist()
            x2 = reach_x[k]
            child = tree.child(node, a, x2, o)
            if child < 0:
                if numpy_path:
                    row = form.child_np(x, tree.beliefs_np[node], a, k, o) / p
                    child = self._add_node(row, x2, node, a, o)
                else:
                    _, J = form.expand(x, tree.beliefs[node].unsqueeze(0))
                    child = self._add_node(J[0, a, k, o] / p, x2, node, a, o)
                tree.lower[child] = low_c / p
                tree.upper[child] = up_c / p
            node = child
            t += 1
            scale = scale_next
            path.append(node)
            bid = int(self.belief_id[node])
            if cfg.forward_backups and bid in seen:
                # the trial reached a belief it already passed (a cycle of the model): back
                # it up now, as APPL backs up every node a trial reaches, so that the descent
                # itself propagates values around the cycle
                self.backup_node(x2, node)
                forward.add(node)
            seen.add(bid)
        return path

    @staticmethod
    def _excess(prob: np.ndarray, up: np.ndarray, low: np.ndarray, target: float) -> np.ndarray:
        """``(K * O,)`` each child's excess gap ``(up - low) - target * P``, ``-inf`` where
        the child is impossible (``P = 0``)."""
        return np.where(prob > 0, (up - low) - target * prob, -np.inf).reshape(-1)

    @staticmethod
    def _child_choice(prob: np.ndarray, up: np.ndarray, low: np.ndarray,
                      target: float) -> tuple[int, int, float]:  # fmt: skip
        """The child ``(k, o)`` of largest excess gap ``(up - low) - target * P`` among the
        possible ones (``P > 0``; the first of equal ones; ``(0, 0)`` if none), and its ``P``.

        On plain lists where the action has a few children (numpy's calls cost more than
        the arithmetic there); the same floats either way.
        """
        K, O = prob.shape
        if K * O > 64:
            j = int(_Trials._excess(prob, up, low, target).argmax())
            k, o = divmod(j, O)
            return k, o, float(prob[k, o])
        ps, us, ls = prob.ravel().tolist(), up.ravel().tolist(), low.ravel().tolist()
        best, j = -math.inf, 0
        for i, p in enumerate(ps):
            if p > 0:
                e = (us[i] - ls[i]) - target * p
                if e > best:
                    best, j = e, i
        return j // O, j % O, ps[j]

    def _child_draw(self, prob: np.ndarray, up: np.ndarray, low: np.ndarray,
                    target: float) -> tuple[int, int, float]:  # fmt: skip
        """A child ``(k, o)`` drawn uniformly (by the search's seeded generator) among the
        possible ones whose excess gap is at least ``cfg.explore_within`` times the largest,
        and its ``P``; where the largest excess is not above 0, the first of largest excess,
        as :meth:`_child_choice` (the trial's end condition reads it there)."""
        excess = self._excess(prob, up, low, target)
        j = int(excess.argmax())
        top = float(excess[j])
        if top > 0.0:
            near = np.flatnonzero(excess >= self.cfg.explore_within * top)
            if near.size > 1:
                j = int(near[self.rng.integers(near.size)])
        O = prob.shape[1]
        return j // O, j % O, float(prob.reshape(-1)[j])

    def _add_node(self, belief: torch.Tensor | np.ndarray, x: int, parent: int, action: int,
                  obs: int) -> int:  # fmt: skip
        """Add a tree node (``belief`` a numpy row on the numpy path) with its entropy and the
        id of its distinct belief."""
        node = self.tree.add(belief, x, parent, action, obs)
        if node >= self.entropy.shape[0]:
            grown = np.zeros(2 * self.entropy.shape[0])
            grown[: self.entropy.shape[0]] = self.entropy
            self.entropy = grown
            ids = np.zeros(2 * self.belief_id.shape[0], dtype=np.int64)
            ids[: self.belief_id.shape[0]] = self.belief_id
            self.belief_id = ids
        if isinstance(belief, np.ndarray):
            nz = belief.nonzero()[0]  # the support (a belief has no negative entry)
            p = belief[nz]
            self.entropy[node] = -float(np.add.reduce(p * np.log(p)))
            self.belief_id[node] = self._belief_key(x, belief, nz, p)
        else:
            row = belief.cpu().numpy()
            self.entropy[node] = float(self._entropy(row[None].astype(np.float64))[0])
            self.belief_id[node] = self._belief_key(x, row)
        return node

    def _belief_key(self, x: int, row: np.ndarray, nz: np.ndarray | None = None,
                    values: np.ndarray | None = None) -> int:  # fmt: skip
        """The id of the distinct belief ``(x, row)`` (support and values to 12 digits).

        Keyed by a 128-bit digest of ``x``, the support and the rounded values rather than their
        bytes (RockSample_7_8.pomdpx: 4 kB a belief, 16 MB after 10 s), with the same ids
        unless two of the beliefs collide (probability about ``n^2 / 2^129``).
        """
        if nz is None:
            nz = np.flatnonzero(row)  # (the caller's, when it has the support and its values)
        if values is None:
            values = row[nz]
        digest = hashlib.blake2b(int(x).to_bytes(8, "little", signed=True), digest_size=16)
        digest.update(nz.tobytes())  # (x's 8 bytes, then two parts of one length: unambiguous)
        digest.update(values.round(12).tobytes())
        return self._belief_ids.setdefault(digest.digest(), len(self._belief_ids))

    def _argmax_tie(self, q: np.ndarray) -> int:
        """The action of highest ``q`` (ties within 1e-12 relative: the first, or one drawn
        by the seeded generator); on a plain list, as ``q`` has a few entries."""
        values = q.tolist()
        top = max(values)
        floor = top - 1e-12 * max(1.0, abs(top))
        ties = [i for i, v in enumerate(values) if v >= floor]
        if len(ties) == 1 or self.cfg.tie_break == "first":
            return ties[0]
        return ties[int(self.rng.integers(len(ties)))]
