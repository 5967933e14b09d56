"""The sparse MOMDP form: a :class:`~torchhrc.pomdp.SparseMOMDP` solved as a MOMDP.

Beliefs are ``(x, b_y)`` (Ong et al. 2010) as in :mod:`~torchhrc.solvers.forms.momdp`, but
the joint transition ``P(x2, y2 | x, y, a) = Tx Ty`` is held as its nonzeros, never as the
dense ``Ty (A, X, Y, X, Y)`` (APPL's RockSample(7, 8): 2.1e9 entries, of which 166400 are
nonzero). For every observed value ``x`` reached by the search the form keeps, built on first
use, the reachable next observed values ``reach[x] (K,)`` and the successors of every
``(a, y)`` row padded to the widest row ``W`` (ELL format)::

    cols[x][a, y, w] = k * Y + y2,   vals[x][a, y, w] = P(x2_k, y2 | x, y, a)

so the prediction of paper Eq. 3 is one scatter-add and the back-projection of a backup one
gather, each costing ``A Y W`` (``W = 1`` for RockSample) instead of ``A K Y^2``::

    predict[a, k, y2]  = sum_y b[y] P(x2_k, y2 | x, y, a)
    backproject[y]     = sum_{k, y2} P(x2_k, y2 | x, y, a) values[k, y2]

The bounds run on the nonzeros sorted by row ``(a, x, y)``: the blind policies (Hauskrecht
2000; exact by LU up to :data:`~torchhrc.solvers._factored.SPARSE_DIRECT_SOLVE_SIZE` states,
iterated above),
QMDP by value iteration (Littman et al. 1995), and the Fast Informed Bound step summed per
``(a, x, y, x2)`` group (skipped when every group has one ``y2``: then FIB equals QMDP). The
blind and QMDP iterations run on one action of each kind
(:meth:`SparseMOMDPForm.distinct_actions`: actions with the same rewards and transitions
have the same vectors) and take a deterministic move of ``x`` that keeps ``y`` as row copies.

Example:
    >>> from torchhrc.solvers.forms import as_solver_model
    >>> from torchhrc.pomdp import SparseMOMDP
    >>> from torchhrc.tasks.classic import rock_sample
    >>> form = as_solver_model(SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp")))
    >>> xs, J = form.expand(form.x0, form.b0.unsqueeze(0))
    >>> J.shape[-1], form.factored, type(form).__name__
    (16, True, 'SparseMOMDPForm')
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from torchhrc._host import as_host, to_numpy
from torchhrc.errors import ModelError
from torchhrc.pomdp import SparseMOMDP
from torchhrc.pomdp.sparse import coalesce
from torchhrc.solvers._factored import SPARSE_DIRECT_SOLVE_SIZE
from torchhrc.solvers.backup import (
    CHUNK_ELEMENTS,
    BackupResult,
    _new_result,
    _padded_vectors,
    _select_into,
)
from torchhrc.solvers.clock import NEVER, Deadline
from torchhrc.solvers.forms.base import FIBOperator, PerObserved, SimStep, SolverModel, field
from torchhrc.solvers.forms.momdp import MOMDPForm
from torchhrc.solvers.forms.sparse import SparseForm
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import sample_categorical
from torchhrc.solvers.sparse_model import (
    SparseFlatModel,
    blind_iteration_np,
    default_blind_iterations,
    qmdp_iteration_np,
    self_loop_probs,
)

__all__ = ["ActionRows", "SparseMOMDPForm"]


class SparseMOMDPForm(SolverModel):
    """A :class:`~torchhrc.pomdp.SparseMOMDP` under the solver interface.

    Attributes:
        Z: ``(A, X, Y, O)``; R: ``(A, X, Y)`` in the solve's dtype.
        row, col, prob: the nonzeros sorted by ``(a, x, y, x2, y2)``: row ``(a X + x) Y + y``,
            column ``x2 Y + y2`` and probability (duplicates summed), numpy.
        slices: per ``x`` (built on first use) ``(reach (K,), cols (A, Y, W), vals (A, Y, W),
            z (A, K, O, Y))`` in torch; ``reach`` is its first field.

    Args:
        model: the sparse MOMDP.
        dtype: the solve's floating dtype (default the model's ``R.dtype``).
    """

    def __init__(self, model: SparseMOMDP, dtype: torch.dtype | None = None) -> None:
        self.source = model
        dt = dtype or model.R.dtype
        self.dtype = dt
        A, X, Y, O = model.num_actions, model.num_observed, model.num_hidden, model.num_observations
        self.num_actions, self.num_observed, self.num_hidden, self.num_observations = A, X, Y, O
        self.discount = float(model.discount)
        self.Z, self.R = as_host(model.Z, dt), as_host(model.R, dt)
        self.x0, self.b0 = int(model.x0), as_host(model.b0, dt)
        self._start_from(model.initial)
        self.factored = True
        self.state_shape, self.state_doc = (X, Y), "(X, Y)"
        index, prob = model.transitions
        idx = to_numpy(index).astype(np.int64, copy=False)
        row = (idx[:, 0] * X + idx[:, 1]) * Y + idx[:, 2]
        col = idx[:, 3] * Y + idx[:, 4]
        key = row * (X * Y) + col
        vals = to_numpy(prob).astype(np.float64, copy=False)
        if key.size and bool((key[1:] > key[:-1]).all()):
            # already sorted without duplicates (read_pomdpx's order): no sort, no divisions
            vals = vals + 0.0  # as the sum below: -0.0 becomes 0.0
            act = idx[:, 0].copy()
        else:
            uniq, vals = coalesce(key, vals)
            row, col = uniq // (X * Y), uniq % (X * Y)
            act = row // (X * Y)
        keep = vals != 0
        if not keep.all():
            row, col, vals, act = row[keep], col[keep], vals[keep], act[keep]
        self.row, self.col = row, col
        self.prob = vals.astype(self.R.numpy().dtype)
        self.nnz = int(row.size)
        self._act = act
        self._x = row // Y % X
        self._y = row % Y
        # one entry per (a, x, y, x2) group: FIB equals QMDP
        group = self.row * X + self.col // Y
        self._group_starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
        self._group_row = self.row[self._group_starts]
        self._one_per_group = self._group_starts.size == self.nnz
        # the nonzeros of each action: a slice (sorted by row, action first)
        self._act_ptr = np.searchsorted(self._act, np.arange(A + 1))
        # the nonzeros of each x, for the per-x slices
        order = np.argsort(self._x, kind="stable")
        self._by_x = order
        self._x_ptr = np.searchsorted(self._x[order], np.arange(X + 1))
        self.slices = PerObserved(X, self._slices)
        self.reach = field(self.slices, 0)

    def _slices(self, x: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        A, Y = self.num_actions, self.num_hidden
        e = self._by_x[self._x_ptr[x] : self._x_ptr[x + 1]]  # sorted by (a, y, x2, y2)
        x2, y2 = self.col[e] // Y, self.col[e] % Y
        reach = np.unique(x2)
        k = np.searchsorted(reach, x2)
        r = self._act[e] * Y + self._y[e]  # (a, y) row, ascending
        counts = np.bincount(r, minlength=A * Y)
        W = max(int(counts.max()) if e.size else 1, 1)
        slot = np.arange(e.size) - (np.cumsum(counts) - counts)[r]
        cols = np.zeros((A * Y, W), dtype=np.int64)
        vals = np.zeros((A * Y, W), dtype=self.prob.dtype)
        cols[r, slot] = k * Y + y2
        vals[r, slot] = self.prob[e]
        reach = reach.astype(np.int64)
        z = np.ascontiguousarray(to_numpy(self.Z)[:, reach].transpose(0, 1, 3, 2))  # (A, K, O, Y)
        return (torch.from_numpy(reach), torch.from_numpy(cols.reshape(A, Y, W)),
                torch.from_numpy(vals.reshape(A, Y, W)), torch.from_numpy(z))  # fmt: skip

    def _ell(self, x: int) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.slices[x]
        return s[1], s[2]

    def _ell_np(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        return self._cached("ell_np", x, lambda: tuple(t.numpy() for t in self._ell(x)))

    # -- torch ---------------------------------------------------------------------------------
    def observation(self, x: int) -> torch.Tensor:
        return self.slices[x][3]

    def predict(self, x: int, beliefs: torch.Tensor) -> torch.Tensor:
        cols, vals = self._ell(x)
        A, Y, _ = cols.shape
        K = self.reach[x].numel()
        target = self._cached(
            "target", x, lambda: (cols + (torch.arange(A) * K * Y).view(A, 1, 1)).reshape(-1)
        )
        w = beliefs.to(self.dtype)[:, None, :, None] * vals  # (B, A, Y, W)
        B = beliefs.shape[0]
        out = w.new_zeros(B, A * K * Y).index_add_(1, target, w.reshape(B, -1))
        return out.view(B, A, K, Y)

    def backproject(self, x: int, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        cols, vals = self._ell(x)
        c, v = cols[actions], vals[actions]  # (B, Y, W)
        B, Y, W = c.shape
        g = values.reshape(B, -1).gather(1, c.reshape(B, -1)).view(B, Y, W)
        return (v * g).sum(-1)

    # -- numpy ---------------------------------------------------------------------------------
    def predict_np(self, x: int, b: np.ndarray) -> np.ndarray:
        cols, vals = self._ell_np(x)
        A, Y, _ = cols.shape
        K = self.reach_np(x).size
        target = self._cached("target_np", x, lambda: self.predict_target(x))
        w = b[None, :, None] * vals
        out = np.bincount(target, weights=w.reshape(-1), minlength=A * K * Y)
        return out.astype(b.dtype, copy=False).reshape(A, K, Y)

    def predict_target(self, x: int) -> np.ndarray:
        """``(A Y W,)`` the flat ``(a, k, y2)`` cell of every padded successor of ``x``."""
        cols, _ = self._ell_np(x)
        A, Y, _ = cols.shape
        K = self.reach_np(x).size
        return (cols + (np.arange(A) * K * Y)[:, None, None]).reshape(-1)

    def predict_action_np(self, x: int, b: np.ndarray, a: int, k: int) -> np.ndarray:
        cols, vals = self._ell_np(x)
        Y = cols.shape[1]
        c = cols[a]
        mine = (c >= k * Y) & (c < (k + 1) * Y)
        w = (b[:, None] * vals[a])[mine]
        return np.bincount(c[mine] - k * Y, weights=w, minlength=Y).astype(b.dtype, copy=False)

    def backproject_np(self, x: int, a: int, values: np.ndarray) -> np.ndarray:
        cols, vals = self._ell_np(x)
        return (vals[a] * values.reshape(-1)[cols[a]]).sum(-1)

    # -- initial bounds ----------------------------------------------------------------------
    def expect_np(self, V: np.ndarray) -> np.ndarray:
        """``(A, X, Y)`` ``sum_{x2, y2} P(x2, y2 | x, y, a) V[x2, y2]`` for ``V (X, Y)``, or
        per action ``V (A, X, Y)`` (``ActionRows`` of every action)."""
        rows = self._cached("rows", 0, lambda: ActionRows(self, np.arange(self.num_actions)))
        return rows.expect(V)

    def distinct_actions(self) -> tuple[ActionRows, np.ndarray]:
        """The actions with distinct rewards and transitions, and where each action's are.

        Returns:
            ``rows``, the ``ActionRows`` of one action of each kind (``rows.acts``,
            those whose rows are copies first), and ``inverse (A,)``, the position in
            ``rows.acts`` of the action with the same ``R[a]`` and ``P(. | ., a)`` as ``a``.
            Such actions (RockSample's checks, which differ only in what they observe) have
            the same QMDP and blind vectors: the MDP bounds iterate on ``rows.acts`` alone
            (RockSample(11, 11): 6 of 16 actions).

        Example:
            >>> from torchhrc.solvers.forms import as_solver_model
            >>> from torchhrc.pomdp import SparseMOMDP
            >>> from torchhrc.tasks.classic import rock_sample
            >>> form = as_solver_model(SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp")))
            >>> rows, inverse = form.distinct_actions()  # 4 moves, sample (4), 4 checks
            >>> rows.acts.tolist(), inverse.tolist()
            ([0, 1, 2, 3, 5, 4], [0, 1, 2, 3, 5, 4, 4, 4, 4])
        """
        return self._cached("distinct", 0, self._distinct_actions)

    def _distinct_actions(self) -> tuple[ActionRows, np.ndarray]:
        A, XY = self.num_actions, self.num_observed * self.num_hidden
        R, ptr = self.R.numpy(), self._act_ptr

        def nonzeros(a: int) -> tuple[np.ndarray, ...]:
            lo, hi = ptr[a], ptr[a + 1]
            return self.row[lo:hi] - a * XY, self.col[lo:hi], self.prob[lo:hi]

        reps: list[int] = []
        kind = np.empty(A, dtype=np.int64)
        for a in range(A):
            kind[a] = len(reps)
            for k, b in enumerate(reps):
                if ptr[a + 1] - ptr[a] == ptr[b + 1] - ptr[b] and np.array_equal(R[a], R[b]):
                    if all(map(np.array_equal, nonzeros(a), nonzeros(b))):
                        kind[a] = k
                        break
            if kind[a] == len(reps):
                reps.append(a)
        rows = ActionRows(self, np.array(reps, dtype=np.int64), copies_first=True)
        position = np.empty(len(reps), dtype=np.int64)
        position[np.searchsorted(reps, rows.acts)] = np.arange(len(reps))
        return rows, position[kind]

    def blind_vectors(self, tol: float = 1e-8, max_iterations: int = 100_000) -> torch.Tensor:
        """``(A, X, Y)`` blind-policy vectors ``alpha_a = R_a + gamma P_a alpha_a``
        (Hauskrecht 2000): exact by LU up to ``SPARSE_DIRECT_SOLVE_SIZE`` states, else
        iterated from ``min R / (1 - gamma)`` with ``max(new, old)`` (every iterate a lower
        bound), each state's self-loop solved exactly (:func:`blind_iteration_np`), as
        :func:`~torchhrc.solvers.sparse_model.sparse_blind_vectors`."""
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        g = self.discount
        if g >= 1.0:
            raise ModelError(f"the blind lower bound needs discount < 1, got {g}")
        S = X * Y
        R = self.R.numpy()
        if S <= SPARSE_DIRECT_SOLVE_SIZE:
            P = np.zeros((A, S, S), dtype=R.dtype)
            a = self._act
            np.add.at(P, (a, self.row - a * S, self.col), self.prob)
            rhs = R.reshape(A, S, 1)
            out = np.linalg.solve(np.eye(S)[None] - g * P, rhs)
            return torch.from_numpy(out.reshape(A, X, Y).astype(R.dtype, copy=False))
        rows, inverse = self.distinct_actions()  # identical actions: identical vectors
        loops = self_loop_probs(self.row, self.col, self.prob, A, S).reshape(A, X, Y)
        alpha = blind_iteration_np(R[rows.acts], g, rows.expect, tol, max_iterations,
                                   self_prob=loops[rows.acts])  # fmt: skip
        return torch.from_numpy(alpha[inverse])

    def blind_policy(self, max_iterations: int | None = None) -> AlphaVectorPolicy:
        if max_iterations is None:
            S = self.num_observed * self.num_hidden
            max_iterations = default_blind_iterations(S, self.discount)
        vectors = self.blind_vectors(max_iterations=max_iterations)
        # one vector per kind of action (the first of each: identical actions have identical
        # vectors, and of equal vectors pruning keeps the first anyway); RockSample(11, 11):
        # 732 vectors instead of 1952, the same value function and the same pruned set
        kinds = np.sort(self.distinct_actions()[0].acts)
        X, U = self.num_observed, kinds.size
        alphas = to_numpy(vectors)[kinds].transpose(1, 0, 2).reshape(X * U, self.num_hidden)
        return AlphaVectorPolicy(
            alphas=torch.from_numpy(alphas),
            actions=torch.from_numpy(np.tile(kinds.astype(np.int64), X)),
            observed=torch.from_numpy(np.repeat(np.arange(X, dtype=np.int64), U)),
        )

    def qmdp_np(self, tol: float = 1e-8, deadline: Deadline = NEVER) -> np.ndarray:
        """``(A, X, Y)`` QMDP vectors (:func:`qmdp_iteration_np` on the
        :meth:`distinct_actions`: the same as on all of them, identical actions giving
        identical vectors)."""
        rows, inverse = self.distinct_actions()
        R = self.R.numpy()[rows.acts]
        return qmdp_iteration_np(R, self.discount, rows.expect, tol, deadline)[inverse]

    def fib_np(self, alpha: np.ndarray) -> np.ndarray:
        """``(A, X, Y)`` one Fast Informed Bound step (Hauskrecht 2000) from ``alpha (A2, X, Y)``::

            R[a, x, y] + gamma sum_{x2, o} max_a2 sum_y2 P(x2, y2 | x, y, a) Z[a, x2, y2, o]
                         alpha[a2, x2, y2]

        the ``(O, A2)`` products gathered per nonzero and summed per ``(a, x, y, x2)`` group.
        """
        A, X, Y, O = self.num_actions, self.num_observed, self.num_hidden, self.num_observations
        Zf = self.Z.numpy().reshape(A * X * Y, O)
        z = Zf[self._act * (X * Y) + self.col]  # (nnz, O)
        al = alpha.reshape(alpha.shape[0], X * Y)[:, self.col].T  # (nnz, A2)
        G = (self.prob[:, None] * z)[:, :, None] * al[:, None, :]  # (nnz, O, A2)
        if not self._one_per_group:
            G = np.add.reduceat(G, self._group_starts, axis=0)
        best = G.max(-1).sum(-1)  # (groups,)
        out = np.bincount(self._group_row, weights=best, minlength=A * X * Y)
        return self.R.numpy() + self.discount * out.reshape(A, X, Y)

    def fib_start(self, tol: float, deadline: Deadline, info: dict[str, Any],
                  ) -> tuple[torch.Tensor, FIBOperator | None]:  # fmt: skip
        """QMDP (to ``tol``, whatever ``deadline`` says), then :meth:`fib_np`; one ``y2`` per
        ``(a, x, y, x2)`` makes FIB equal QMDP (``sum_o Z = 1``)."""
        alpha = torch.from_numpy(self.qmdp_np(tol))  # whatever the clock says (_iterate_fib)
        if self._one_per_group:
            return alpha, None
        return alpha, lambda a: torch.from_numpy(self.fib_np(a.numpy()))

    # -- PBVI ----------------------------------------------------------------------------------
    def flattened(self) -> SparseForm:
        """The flat sparse form of ``model.to_sparse_pomdp()`` (states ``(x, y)``)."""
        flat = SparseFlatModel.from_model(self.source.to_sparse_pomdp(), dtype=self.dtype)
        return SparseForm(flat, self.source)

    def upper_vectors(self, kind: str, tol: float, max_iterations: int = 100_000) -> torch.Tensor:
        if kind == "fib":
            return self.fib_vectors(tol, NEVER, max_iterations)[0]
        return torch.from_numpy(self.qmdp_np(tol))

    def self_loop_probs(self) -> torch.Tensor:
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        loops = self_loop_probs(self.row, self.col, self.prob, A, X * Y)
        return torch.from_numpy(loops).reshape(A, X, Y)

    def step(self, x: torch.Tensor, y: torch.Tensor, beliefs: torch.Tensor, actions: torch.Tensor,
             generator: torch.Generator) -> SimStep:  # fmt: skip
        """One sampled step from ``(x, y)``: ``(x2, y2)`` among the stored successors of
        ``(a, x, y)``, ``o ~ Z[a, x2, y2]``, then the MOMDP belief update (paper Eq. 3),
        grouped by ``x``."""
        X, Y = self.num_observed, self.num_hidden
        beliefs = beliefs.to(self.dtype)
        rows = ((actions * X + x) * Y + y).cpu().numpy()
        ptr = self._cached(
            "row_ptr", 0, lambda: np.searchsorted(self.row, np.arange(self.row.max() + 2))
        )
        start, stop = ptr[rows], ptr[rows + 1]
        W = max(int((stop - start).max()), 1)
        pos = start[:, None] + np.arange(W)[None, :]
        valid = pos < stop[:, None]
        pos = np.where(valid, pos, 0)
        p = torch.from_numpy(np.where(valid, self.prob[pos], 0.0))
        pick = sample_categorical(p, generator).numpy()
        nxt = torch.from_numpy(self.col[pos[np.arange(rows.size), pick]])
        x2, y2 = nxt // Y, nxt % Y
        o = sample_categorical(self.Z[actions, x2, y2], generator)
        new = torch.empty_like(beliefs)
        for xv in torch.unique(x).tolist():  # one expansion per distinct observed value
            m = (x == xv).nonzero().squeeze(-1)
            xs, J = self.expand(xv, beliefs[m])  # (B, A, K, O, Y)
            k = torch.searchsorted(xs, x2[m])
            child = J[torch.arange(m.numel()), actions[m], k, o[m]]
            new[m] = child / child.sum(-1, keepdim=True)
        return SimStep(x2, y2, o, new)

    def point_backup(self, policy: AlphaVectorPolicy, x: torch.Tensor,
                     beliefs: torch.Tensor) -> BackupResult:  # fmt: skip
        """The factored point backup (Pineau et al. 2003) of ``(x (M,), beliefs (M, Y))``,
        grouped by ``x``: the best vector of each child ``J[a, k, o]`` among those tagged
        ``x2_k``, then every action's vector ``R[a, x] + gamma P_a sum_o Z alpha*``; chunked
        over the beliefs of a group to bound the ``(B, A, K, O, max(N, Y))`` children and
        scores, each chunk's ``(B, A, Y)`` vectors reduced to the chosen one at once (the
        result ``(M, Y)`` is all that is held across chunks)."""
        A, X, Y, O = self.num_actions, self.num_observed, self.num_hidden, self.num_observations
        beliefs = beliefs.to(self.dtype)
        padded, valid = _padded_vectors(policy.to(dtype=self.dtype), X)  # (X, N, Y), (X, N)
        N = padded.shape[1]
        result = _new_result(beliefs, A)
        for xv in torch.unique(x).tolist():
            K = self.reach[xv].numel()
            chunk = max(1, CHUNK_ELEMENTS // max(1, A * K * O * max(N, Y)))
            for m in (x == xv).nonzero().squeeze(-1).split(chunk):
                B = m.numel()
                xs, J = self.expand(xv, beliefs[m])  # (B, A, K, O, Y)
                cand = padded[xs]  # (K, N, Y)
                scores = torch.einsum("bakoy,kny->bakon", J, cand)
                del J
                scores = scores.masked_fill_(~valid[xs].view(1, 1, K, 1, N), -torch.inf)
                best = scores.argmax(-1)  # (B, A, K, O)
                del scores
                chosen = cand[torch.arange(K).view(1, 1, K, 1), best]  # (B, A, K, O, Y)
                inner = (self.observation(xv).unsqueeze(0) * chosen).sum(3)  # (B, A, K, Y)
                del chosen
                acts = torch.arange(A).repeat(B)
                back = self.backproject(xv, acts, inner.reshape(B * A, K, Y)).view(B, A, Y)
                vectors = self.R[:, xv, :].unsqueeze(0) + self.discount * back  # (B, A, Y)
                _select_into(result, m, beliefs[m], vectors)
        return result._replace(observed=x.clone())

    # -- policies: vectors over Y tagged with their observed value (as the dense MOMDP form) ----
    policy = MOMDPForm.policy
    value = MOMDPForm.value
    prune = MOMDPForm.prune


class ActionRows:
    """The MDP expectation of some actions ``acts (U,)`` of a :class:`SparseMOMDPForm`, the
    kernel of its QMDP and blind bounds::

        E[u, x, y] = sum_{x2, y2} P(x2, y2 | x, y, acts[u]) V[x2, y2]     (V (X, Y))

    or with per-action values ``V[u, x2, y2]`` (``V (U, X, Y)``). An action whose every row
    ``(x, y)`` moves to one ``x2(x)`` with probability 1 and keeps ``y`` (RockSample's moves
    and checks, a static human type) takes it as row copies ``V[x2(x), :]`` (a third of the
    time of a gather); the others gather over their nonzeros (one product per row when each
    row has one, else a sum per row). Both add ``0.0`` (``-0.0`` becomes ``0.0``, as a sum
    from zero), so the results do not depend on which way an action is taken.

    Args:
        form: the sparse MOMDP form.
        acts: the actions.
        copies_first: reorder ``acts`` so that the row-copy actions come first (one ``take``
            writes them in place); :attr:`acts` is the order of the output.

    Example:
        >>> import numpy as np
        >>> from torchhrc.solvers.forms import as_solver_model
        >>> from torchhrc.pomdp import SparseMOMDP
        >>> from torchhrc.tasks.classic import rock_sample
        >>> form = as_solver_model(SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp")))
        >>> rows = ActionRows(form, np.arange(form.num_actions))
        >>> V = np.ones((form.num_observed, form.num_hidden))  # next values all 1
        >>> bool((rows.expect(V) == 1.0).all())  # so is every expectation
        True
    """

    def __init__(self, form: SparseMOMDPForm, acts: np.ndarray, copies_first: bool = False,
                 ) -> None:  # fmt: skip
        X, Y = form.num_observed, form.num_hidden
        XY = X * Y
        ptr, ramp = form._act_ptr, np.arange(XY)
        copy: dict[int, np.ndarray] = {}
        for a in acts.tolist():
            lo, hi = ptr[a], ptr[a + 1]
            if hi - lo != XY or not (form.row[lo:hi] - a * XY == ramp).all():
                continue
            if not (form.prob[lo:hi] == 1.0).all():
                continue
            c = form.col[lo:hi].reshape(X, Y)
            x2 = c[:, 0] // Y
            if (c == (x2 * Y)[:, None] + ramp[:Y]).all():
                copy[a] = x2
        if copies_first:
            acts = np.array(sorted(acts.tolist(), key=lambda a: a not in copy), dtype=np.int64)
        self.acts = acts
        self.shape = (acts.size, X, Y)
        is_copy = np.array([a in copy for a in acts.tolist()], dtype=bool)
        self._copy_u = np.flatnonzero(is_copy)
        self._copy_prefix = bool(is_copy[: self._copy_u.size].all())
        x2s = np.array([copy[a] for a in acts[is_copy].tolist()], dtype=np.int64).reshape(-1, X)
        self._copy_x2 = x2s  # (Uc, X)
        self._copy_rows = self._copy_u[:, None] * X + x2s  # rows of V (U X, Y), per action
        self._gather_u = np.flatnonzero(~is_copy)
        spans = [np.arange(ptr[a], ptr[a + 1]) for a in acts[~is_copy].tolist()]
        e = np.concatenate(spans) if spans else np.zeros(0, dtype=np.int64)
        k = np.repeat(np.arange(len(spans)), [s.size for s in spans]).astype(np.int64)
        self._row = form.row[e] - form._act[e] * XY + k * XY  # rebased to the gathered ones
        self._col, self._prob = form.col[e], form.prob[e]
        self._col_per_action = self._col + self._gather_u[k] * XY  # into V (U X Y,)
        n = self._gather_u.size * XY
        self._one_per_row = self._row.size == n and bool((self._row == np.arange(n)).all())

    def expect(self, V: np.ndarray) -> np.ndarray:
        """``(U, X, Y)`` the expectations of ``V (X, Y)`` or per action ``V (U, X, Y)``."""
        U, X, Y = self.shape
        out = np.empty(self.shape, dtype=V.dtype)
        if self._copy_u.size:
            src, at = (V, self._copy_x2) if V.ndim == 2 else (V.reshape(U * X, Y), self._copy_rows)
            if self._copy_prefix:
                np.take(src, at, axis=0, out=out[: self._copy_u.size])
            else:
                out[self._copy_u] = np.take(src, at, axis=0)
        if self._gather_u.size:
            flat = V.reshape(-1)[self._col if V.ndim == 2 else self._col_per_action]
            if self._one_per_row:
                # one nonzero a row (deterministic moves): the sum is its one product
                vals = self._prob * flat
            else:
                n = self._gather_u.size * X * Y
                vals = np.bincount(self._row, weights=self._prob * flat, minlength=n)
            out[self._gather_u] = vals.reshape(-1, X, Y)
        out += 0.0
        return out
