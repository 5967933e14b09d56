"""The sparse flat form: a flat POMDP whose ``T`` is kept as its nonzeros.

For models too large for a dense ``T`` (RockSample(7, 8): 12545 states, a dense ``T`` of 2e9
entries) read as a :class:`~torchhrc.pomdp.SparsePOMDP`. The operations run on the per-action
CSR of :class:`~torchhrc.solvers.sparse_model.SparseFlatModel`; tree beliefs are stored by
their support (:class:`~torchhrc.solvers.belief_tree.SparseBeliefTree`), and the children of
one belief are formed and bounded only on the union of their supports (``Children.cols``;
RockSample(7, 8): about a thousand of 12545 states). Alpha vectors stay dense ``(S,)``.

Example:
    >>> from torchhrc.solvers.forms import as_solver_model
    >>> from torchhrc.pomdp import SparsePOMDP
    >>> from torchhrc.tasks.classic import tiger
    >>> form = as_solver_model(SparsePOMDP.from_dense(tiger()))
    >>> ch = form.children_np(0, form.b0.numpy())
    >>> ch.rows.shape, ch.cols.tolist()  # 6 possible children and b0, on states 0 and 1
    ((7, 2), [0, 1])
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from torchhrc.solvers.backup import CHUNK_ELEMENTS, BackupResult, _new_result
from torchhrc.solvers.belief_tree import BeliefTree, SparseBeliefTree
from torchhrc.solvers.clock import NEVER, Deadline
from torchhrc.solvers.forms.base import Children, FIBOperator, FlatFields, SimStep, SolverModel
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import mostly_zero, normalize_rows, sample_categorical, to_csr
from torchhrc.solvers.sparse_model import SparseFlatModel, sparse_blind_policy

__all__ = ["SparseForm"]


class SparseForm(FlatFields, SolverModel):
    """A flat model with sparse ``T`` under the solver interface (:class:`~.base.SolverModel`).

    Args:
        model: the :class:`SparseFlatModel` (in the solve's dtype).
        source: what the user passed (a ``SparsePOMDP``; default ``model``).
    """

    batch_backups = False  # a batch would hold B A O dense children

    def __init__(self, model: SparseFlatModel, source: Any = None) -> None:
        self.sparse = model
        self.source = model if source is None else source
        self._flat(model.Z, model.R, model.b0, model.discount)

    # -- torch ---------------------------------------------------------------------------------
    def predict(self, x: int, beliefs: torch.Tensor) -> torch.Tensor:
        return self.sparse.predict(beliefs).unsqueeze(2)  # (B, A, 1, S): one sparse product

    def backproject(self, x: int, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        return self.sparse.backproject(actions, values[:, 0, :])

    # -- numpy ---------------------------------------------------------------------------------
    def predict_np(self, x: int, b: np.ndarray) -> np.ndarray:
        return self.sparse.predict_np(b)[:, None, :]  # (A, 1, S)

    def predict_action_np(self, x: int, b: np.ndarray, a: int, k: int) -> np.ndarray:
        return self.sparse.predict_action_np(b, a)

    def backproject_np(self, x: int, a: int, values: np.ndarray) -> np.ndarray:
        return self.sparse.backproject_np(a, values[0])

    def children_np(self, x: int, b: np.ndarray) -> Children:
        """The children of ``b (S,)`` on ``cols``, the union of the supports of the
        predictions and of ``b`` (``K = 1``)."""
        cols, pred = self.sparse.predict_columns_np(b)  # (C,), (A, C)
        Z = self._cached("Z", 0, lambda: self.sparse.Z.numpy())  # (A, S, O)
        zc = Z[:, cols, :]  # (A, C, O)
        A, _, O = zc.shape
        prob = np.matmul(pred[:, None, :], zc)[:, 0, :]  # (A, O)
        nz = np.flatnonzero(prob)
        ia, io = np.unravel_index(nz, (A, O))
        rows = np.concatenate([pred[ia] * zc[ia, :, io], b[cols][None]])  # (m + 1, C)
        reward = b[cols] @ self.reward_np(0)[cols]  # (A,)
        zeros = np.zeros(A * O, dtype=np.int64)
        return Children(rows, np.zeros(rows.shape[0], dtype=np.int64), cols, nz,
                        prob.reshape(A, 1, O), zeros, reward)  # fmt: skip

    # -- initial bounds and beliefs ------------------------------------------------------------
    def blind_policy(self, max_iterations: int | None = None) -> AlphaVectorPolicy:
        return sparse_blind_policy(self.sparse, max_iterations=max_iterations)

    def fib_start(self, tol: float, deadline: Deadline, info: dict[str, Any],
                  ) -> tuple[torch.Tensor, FIBOperator | None]:  # fmt: skip
        """QMDP by sparse value iteration (to ``tol``, whatever ``deadline`` says),
        then :meth:`SparseFlatModel.fib_np`; deterministic moves make FIB equal QMDP."""
        alpha = torch.from_numpy(self.sparse.qmdp_np(tol))  # whatever the clock says (_iterate_fib)
        if self.sparse.deterministic:  # one successor per (a, s)
            return alpha, None
        step = self.sparse.fib_operator()  # (its pairs freed with it, after the iteration)
        return alpha, lambda a: torch.from_numpy(step(a.numpy()))

    def new_tree(self) -> BeliefTree:
        """A :class:`SparseBeliefTree` (beliefs stored by their support)."""
        return SparseBeliefTree(self.b0, self.x0)

    # -- PBVI ----------------------------------------------------------------------------------
    def upper_vectors(self, kind: str, tol: float, max_iterations: int = 100_000) -> torch.Tensor:
        if kind == "fib":
            return self.fib_vectors(tol, NEVER, max_iterations)[0]
        return torch.from_numpy(self.sparse.qmdp_np(tol))

    def self_loop_probs(self) -> torch.Tensor:
        return torch.from_numpy(self.sparse.self_loop_probs()).unsqueeze(1)  # (A, 1, S)

    def step(self, x: torch.Tensor, y: torch.Tensor, beliefs: torch.Tensor, actions: torch.Tensor,
             generator: torch.Generator) -> SimStep:  # fmt: skip
        """One sampled step from states ``y = s``: ``s2 ~ T[a, s, .]`` among the stored
        successors, ``o ~ Z[a, s2, .]``, then the Bayes update ``b2 ~ (b T_a) Z[a, ., o]``
        (the uniform belief where ``P(o) = 0``, which a sampled ``o`` never has, as
        :func:`torchhrc.pomdp.belief.update` with ``on_zero="ninf"``)."""
        sp = self.sparse
        nxt, prob = sp.successors(actions, y)  # (M, W)
        s2 = nxt.gather(1, sample_categorical(prob, generator).unsqueeze(1)).squeeze(1)
        o = sample_categorical(sp.Z[actions, s2], generator)
        if mostly_zero(beliefs):  # (m, S) CSR @ T[a] CSR per action used
            new = torch.empty(beliefs.shape, dtype=sp.dtype)
            for a in torch.unique(actions).tolist():
                rows = (actions == a).nonzero().squeeze(-1)
                pred = to_csr(beliefs[rows].to(sp.dtype)) @ sp.T_csr[a]
                new[rows] = pred.to_dense()
        else:
            new = sp.predict_actions(beliefs, actions)
        new *= sp.Z[actions, :, o]  # (M, S)
        return SimStep(torch.zeros_like(s2), s2, o, normalize_rows(new))

    def point_backup(self, policy: AlphaVectorPolicy, x: torch.Tensor,
                     beliefs: torch.Tensor) -> BackupResult:  # fmt: skip
        """The belief-side point backup (Pineau et al. 2003) on the sparse ``T``::

            best[m, a, o] = argmax_n (b_m T_a) Z[a, ., o] . alpha_n
            inner[m, a]   = sum_o Z[a, ., o] * alpha_best[m, a, o]              (S,)
            Q[m, a]       = b_m . R[a] + gamma (b_m T_a) . inner[m, a]

        and only the chosen action's vector ``R[a] + gamma T_a inner[m, a]`` is formed (one
        sparse back-projection per chunk), chunked over beliefs to bound the ``(m, A, O, S)``
        children: what is held across chunks is the ``(M, S)`` result and ``(M, A)`` Q-values,
        no ``(M, A, S)`` block (at M = 1020, S = 10^4, A = 4 that block was 326 MB, copied once
        more by a concatenation).
        """
        sp = self.sparse
        alphas = policy.alphas.to(sp.dtype)
        beliefs = beliefs.to(sp.dtype)
        A, S, O = sp.num_actions, sp.num_states, sp.num_observations
        N, M = alphas.shape[0], beliefs.shape[0]
        R, g = sp.R, self.discount
        Zt = sp.Z.transpose(-1, -2)  # (A, O, S)
        chunk = max(1, CHUNK_ELEMENTS // max(1, A * O * max(N, S)))
        result = _new_result(beliefs, A)
        for start in range(0, M, chunk):
            stop = min(start + chunk, M)
            b = beliefs[start:stop]
            pred = sp.predict(b)  # (m, A, S)
            W = pred.new_empty(stop - start, A, O, S)  # contiguous: the product below
            torch.mul(pred.unsqueeze(2), Zt.unsqueeze(0), out=W)  # needs no copy
            best = (W @ alphas.T).argmax(-1)  # (m, A, O)
            del W  # one (m, A, O, S) block at a time
            chosen = alphas[best].mul_(Zt.unsqueeze(0))  # (m, A, O, S)
            inner = chosen.sum(2)  # (m, A, S)
            del chosen
            q = result.q_values[start:stop]
            q[:] = b @ R.T + g * (pred * inner).sum(-1)  # (m, A)
            result.values[start:stop], act = q.max(-1)
            result.actions[start:stop] = act
            chosen_inner = inner[torch.arange(stop - start, device=inner.device), act]  # (m, S)
            result.alphas[start:stop] = R[act] + g * sp.backproject(act, chosen_inner)
        return result
