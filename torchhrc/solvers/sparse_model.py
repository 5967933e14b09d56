"""Sparse flat transitions for the solvers: the operations SARSOP needs, without a dense ``T``.

RockSample(7, 8) has ``S = 12545`` states and ``A = 13`` actions: a dense ``T (A, S, S)``
would hold 2e9 entries (16 GB in float64), but only 163085 are nonzero (each move or check
leads to one or two states). :class:`SparseFlatModel` keeps ``T`` as its nonzeros sorted by
``(a, s)`` (per-action CSR) and by ``(a, s2)`` (the transposes, stacked), with ``Z (A, S, O)``
and ``R (A, S)`` dense (``A S O`` entries are few), and implements the operations of a
point-based solver on them:

* prediction (paper Eq. 3 before the observation; Kurniawati et al. 2008, belief expansion)::

      pred[a, s2] = sum_s T[a, s, s2] b[s]            visiting only the support of b

* back-projection of the backup (Pineau et al. 2003)::

      g[s] = sum_s2 T[a, s, s2] v[s2]                 v = sum_o Z[a, ., o] alpha_o

* the blind-policy lower bound ``alpha_a = R_a + gamma T_a alpha_a`` (Hauskrecht 2000) and the
  MDP and FIB operators (via :func:`torchhrc.solvers.sarsop.fib_corner_values`).

Every nonzero of ``T`` is touched at most once per operation; beliefs with a small support
(RockSample: the robot's position is known) touch only the rows on it. The numpy methods
(``*_np``) serve the sequential one-belief path of SARSOP; the torch ones (sparse CSR tensors)
the batched path. Alpha vectors stay dense ``(S,)``.

Example:
    >>> from torchhrc.pomdp import SparsePOMDP
    >>> from torchhrc.tasks.classic import tiger
    >>> sm = SparseFlatModel.from_model(SparsePOMDP.from_dense(tiger()))
    >>> sm.predict_np(sm.b0.numpy()).shape  # (A, S)
    (3, 2)
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import POMDP
from torchhrc.pomdp.sparse import SparsePOMDP, check_dense_size, coalesce
from torchhrc.solvers._factored import (
    BRACKET_ROUND_OFF,
    DIRECT_SOLVE_SIZE,
    SPARSE_DIRECT_SOLVE_SIZE,
    bracket_slack,
)
from torchhrc.solvers.clock import NEVER, Deadline
from torchhrc.solvers.policy import AlphaVectorPolicy

__all__ = ["SparseFlatModel", "sparse_blind_policy", "sparse_blind_vectors"]

#: Pairs of a FIB step's products formed at a time (:meth:`SparseFlatModel.fib_np`; whole
#: ``(a, s, o)`` groups, about this many pairs: 2^20 x A2 floats).
_FIB_PAIRS = 1 << 20


def _csr(
    indptr: np.ndarray, indices: np.ndarray, values: np.ndarray, shape: tuple[int, int]
) -> torch.Tensor:
    with warnings.catch_warnings():  # "sparse CSR support is in beta"
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(
            torch.from_numpy(indptr.astype(np.int64)),
            torch.from_numpy(indices.astype(np.int64)),
            torch.from_numpy(values),
            size=shape,
        )


class SparseFlatModel:
    """A flat POMDP with sparse ``T``, dense ``Z`` and ``R``, prepared for the solvers.

    Attributes:
        Z: ``(A, S, O)`` dense, ``Z[a, s2, o] = P(o | s2, a)``.
        R: ``(A, S)`` rewards.
        b0: ``(S,)`` initial belief.
        discount: the discount factor.
        T_csr: per action the ``(S, S)`` sparse CSR tensor ``T[a]`` (rows ``s``).
        Tt_stacked: ``(A S, S)`` sparse CSR, row ``a S + s2`` holds ``T[a, :, s2]``.
        nnz: number of stored nonzeros of ``T``.

    Args:
        index: ``(M, 3)`` int64 ``[a, s, s2]`` of the nonzeros of ``T``.
        prob: ``(M,)`` their probabilities (duplicates are summed).
        Z, R, b0, discount: as the attributes.
        dtype: the floating dtype of every tensor (default float64).
    """

    def __init__(
        self,
        index: torch.Tensor,
        prob: torch.Tensor,
        Z: torch.Tensor,
        R: torch.Tensor,
        b0: torch.Tensor,
        discount: float,
        *,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        A, S, O = Z.shape
        self.num_actions, self.num_states, self.num_observations = A, S, O
        self.discount = float(discount)
        self.dtype = dtype
        self.Z = Z.to("cpu", dtype).contiguous()
        self.R = R.to("cpu", dtype).expand(A, S).contiguous()
        self.b0 = b0.to("cpu", dtype).contiguous()
        idx = index.cpu().numpy().astype(np.int64)
        p = prob.cpu().to(dtype).numpy()
        a, s, s2 = idx[:, 0], idx[:, 1], idx[:, 2]
        # sum duplicates: one entry per (a, s, s2), sorted by (a, s, s2)
        uniq, vals = coalesce((a * S + s) * S + s2, p)
        row = uniq // S  # a S + s
        self._col = (uniq % S).astype(np.int64)  # s2
        self._val = vals
        self._row = row
        self._ptr = np.searchsorted(row, np.arange(A * S + 1))  # (A S + 1,) CSR over (a, s)
        self._act = (row // S).astype(np.int64)
        self._src = (row % S).astype(np.int64)
        self._acol = self._act * S + self._col  # a S + s2: the (a, s2) cell of each nonzero
        # deterministic transitions (RockSample, Tag's robot): one nonzero per (a, s) row,
        # so row sums are plain gathers
        self._one_per_row = vals.size == A * S and bool((np.diff(self._ptr) == 1).all())
        self.nnz = int(vals.size)
        # torch CSR: T[a] (S, S) per action and the stacked transposes (A S, S)
        self.T_csr = [
            _csr(
                self._ptr[a * S : (a + 1) * S + 1] - self._ptr[a * S],
                self._col[self._ptr[a * S] : self._ptr[(a + 1) * S]],
                self._val[self._ptr[a * S] : self._ptr[(a + 1) * S]],
                (S, S),
            )
            for a in range(A)
        ]
        trow = self._act * S + self._col  # a S + s2
        order = np.argsort(trow * S + self._src, kind="stable")
        tptr = np.searchsorted(trow[order], np.arange(A * S + 1))
        self.Tt_stacked = _csr(tptr, self._src[order], self._val[order], (A * S, S))

    @classmethod
    def from_model(
        cls, model: SparsePOMDP | POMDP | SparseFlatModel, *, dtype: torch.dtype | None = None
    ) -> SparseFlatModel:
        """Build from a :class:`~torchhrc.pomdp.SparsePOMDP` or an unbatched dense POMDP, or
        take a prepared model (itself where it has ``dtype`` already).

        The builder is looked up by the model's type (``_SOURCES``), never by testing it.

        Args:
            model: the model.
            dtype: the floating dtype (default float64; a prepared model's own).

        Raises:
            ModelError: a batched dense model, or ``Z`` too large to hold densely.
            TypeError: ``model`` of another type.
        """
        for kind in type(model).__mro__:
            build = _SOURCES.get(kind)
            if build is not None:
                return build(cls, model, dtype)
        raise TypeError(f"expected a SparsePOMDP or POMDP, got {type(model).__name__}")

    # -- numpy, one belief ---------------------------------------------------------------------
    def _entries(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of the nonzeros of the ``(a, s)`` rows ``rows`` (flattened ``a S + s``),
        and for each the index into ``rows`` it came from."""
        start, stop = self._ptr[rows], self._ptr[rows + 1]
        lens = stop - start
        total = int(lens.sum())
        owner = np.repeat(np.arange(rows.size), lens)
        offset = np.arange(total) - np.repeat(np.cumsum(lens) - lens, lens)
        return start[owner] + offset, owner

    def predict_np(self, b: np.ndarray) -> np.ndarray:
        """``(A, S)`` ``pred[a, s2] = sum_s T[a, s, s2] b[s]`` for one belief ``b (S,)``.

        Only the rows of ``T`` on the support of ``b`` are visited.
        """
        A, S = self.num_actions, self.num_states
        supp = np.flatnonzero(b)
        rows = (np.arange(A)[:, None] * S + supp[None, :]).reshape(-1)  # (A w,)
        pos, owner = self._entries(rows)
        w = b[supp][owner % supp.size] * self._val[pos]
        out = np.bincount(self._act[pos] * S + self._col[pos], weights=w, minlength=A * S)
        return out.astype(b.dtype, copy=False).reshape(A, S)

    def predict_columns_np(self, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The prediction on its support: ``cols (C,)`` sorted, the union of the successors of
        ``supp(b)`` under every action and of ``supp(b)`` itself, and ``pred (A, C)`` with
        ``pred[a, j] = sum_s T[a, s, cols[j]] b[s]``."""
        A, S = self.num_actions, self.num_states
        supp = np.flatnonzero(b)
        rows = (np.arange(A)[:, None] * S + supp[None, :]).reshape(-1)  # (A w,)
        pos, owner = self._entries(rows)
        col = self._col[pos]
        cols = np.union1d(col, supp)
        C = cols.size
        w = b[supp][owner % supp.size] * self._val[pos]
        key = self._act[pos] * C + np.searchsorted(cols, col)
        out = np.bincount(key, weights=w, minlength=A * C)
        return cols, out.astype(b.dtype, copy=False).reshape(A, C)

    def predict_action_np(self, b: np.ndarray, a: int) -> np.ndarray:
        """``(S,)`` the prediction of one action ``a`` (the row ``a`` of :meth:`predict_np`)."""
        S = self.num_states
        supp = np.flatnonzero(b)
        pos, owner = self._entries(a * S + supp)
        w = b[supp][owner] * self._val[pos]
        return np.bincount(self._col[pos], weights=w, minlength=S).astype(b.dtype, copy=False)

    def backproject_np(self, a: int, v: np.ndarray) -> np.ndarray:
        """``(S,)`` ``g[s] = sum_s2 T[a, s, s2] v[s2]`` for one action and ``v (S,)``."""
        S = self.num_states
        lo, hi = self._ptr[a * S], self._ptr[(a + 1) * S]
        w = self._val[lo:hi] * v[self._col[lo:hi]]
        if self._one_per_row:
            return w.astype(v.dtype, copy=False)
        return np.bincount(self._src[lo:hi], weights=w, minlength=S).astype(v.dtype, copy=False)

    def expect_np(self, V: np.ndarray) -> np.ndarray:
        """``(A, S)`` ``sum_s2 T[a, s, s2] V[s2]`` for ``V (S,)``, or per action ``V (A, S)``
        (``V[a, s2]``); one pass over the nonzeros of every action."""
        A, S = self.num_actions, self.num_states
        flat = V[self._col] if V.ndim == 1 else V.reshape(-1)[self._acol]
        if self._one_per_row:
            return (self._val * flat).astype(V.dtype, copy=False).reshape(A, S)
        out = np.bincount(self._row, weights=self._val * flat, minlength=A * S)
        return out.astype(V.dtype, copy=False).reshape(A, S)

    def self_loop_probs(self) -> np.ndarray:
        """``(A, S)`` ``T[a, s, s]`` (:func:`self_loop_probs`)."""
        A, S = self.num_actions, self.num_states
        return self_loop_probs(self._row, self._col, self._val, A, S)

    @property
    def deterministic(self) -> bool:
        """True when every ``(a, s)`` has exactly one successor (then FIB equals QMDP:
        ``sum_o max_a2 Z[a, s2, o] alpha[a2, s2] = max_a2 alpha[a2, s2]`` for the one ``s2``)."""
        return self._one_per_row

    def qmdp_np(self, tol: float = 1e-8, deadline: Deadline = NEVER) -> np.ndarray:
        """``(A, S)`` QMDP vectors by value iteration on the underlying MDP (Littman et al.
        1995), :func:`qmdp_iteration_np` with this model's ``expect_np``."""
        return qmdp_iteration_np(self.R.numpy(), self.discount, self.expect_np, tol, deadline)

    def fib_np(self, alpha: np.ndarray) -> np.ndarray:
        """``(A, S)`` one Fast Informed Bound step (Hauskrecht 2000) from ``alpha (A2, S)``::

            R[a, s] + gamma sum_o max_a2 sum_s2 T[a, s, s2] Z[a, s2, o] alpha[a2, s2]

        (:meth:`fib_operator`'s step; an iteration takes the operator, which forms the pairs
        of nonzeros once).
        """
        return self.fib_operator()(alpha)

    def fib_operator(self) -> Callable[[np.ndarray], np.ndarray]:
        """:meth:`fib_np` as a function of ``alpha``, over the pairs of a nonzero of ``T`` and
        a nonzero of ``Z`` in the row it leads to (:meth:`_fib_pairs`), formed once for the
        operator and freed with it: one ``(A2,)`` product per pair, summed per ``(a, s, o)``.
        The work is ``A2`` times the pairs, where a product over every observation was
        ``O A2`` per nonzero of ``T`` (a random sparse model of 5,000 states, 16 observations,
        3 possible a state: 330 ms a step, so SARSOP's initial bound stopped on its budget).
        The pairs are the initial bound's only (14 MB on the 20,000-state model of the scale
        check set, 70 MB at 100,000 states): the model held them for the whole solve until
        the forty-second session.

        Example:
            >>> from torchhrc.pomdp import SparsePOMDP
            >>> from torchhrc.tasks.classic import tiger
            >>> model = SparseFlatModel.from_model(SparsePOMDP.from_dense(tiger()))
            >>> step = model.fib_operator()
            >>> alpha = np.zeros((3, 2))
            >>> bool(np.allclose(step(alpha), model.R.numpy()))  # from 0: the rewards
            True
        """
        A, S, O = self.num_actions, self.num_states, self.num_observations
        zval, tval, col, starts, cells = self._fib_pairs()
        R, gamma = self.R.numpy(), self.discount

        def step(alpha: np.ndarray) -> np.ndarray:
            # the products as (Z alpha) T, summed in T's order, and the sum over o of a dense
            # (A, S, O), as the product over every observation did: the same floats but where
            # numpy's reduceat adds a group's terms in another order (three of them against
            # four with a zero: the last bit, on Tag). The (P, A2) products are formed a run
            # of whole groups at a time (about 2^20 pairs), in place, and each run's maxima go
            # straight into the (A, S, O) table: a step's temporaries on a 100,000-state
            # model 168 -> 88 MB
            U, P = starts.size, zval.size
            best = np.zeros(A * S * O, dtype=np.result_type(alpha, zval))
            i0 = 0
            while i0 < U:
                p0 = int(starts[i0])
                i1 = max(i0 + 1, int(np.searchsorted(starts, p0 + _FIB_PAIRS, side="left")))
                p1 = int(starts[i1]) if i1 < U else P
                contrib = alpha.T[col[p0:p1]]  # (p, A2), then (Z alpha) T in place
                np.multiply(zval[p0:p1, None], contrib, out=contrib)
                np.multiply(contrib, tval[p0:p1, None], out=contrib)
                # per (a, s, o): the sum over its pairs, the max over a2
                best[cells[i0:i1]] = np.add.reduceat(contrib, starts[i0:i1] - p0, axis=0).max(1)
                i0 = i1
            return R + gamma * best.reshape(A, S, O).sum(-1)

        return step

    def _fib_pairs(self) -> tuple[np.ndarray, ...]:
        """The pairs ``(t, z)`` of a nonzero ``t`` of ``T`` (row ``(a, s)``, column ``s2``) and
        a nonzero ``z`` of ``Z[a, s2]`` (observation ``o``), sorted by ``(a, s, o)`` (stable:
        within a group in ``T``'s order): ``Z`` values, ``T`` values, ``s2`` ``(P,)`` each,
        the start of each ``(a, s, o)`` group ``(U,)`` and its cell ``(a S + s) O + o``
        ``(U,)``."""
        A, S, O = self.num_actions, self.num_states, self.num_observations
        Z = self.Z.numpy().reshape(A * S, O)
        zr, zo = np.nonzero(Z)  # row-major: sorted by the row a S + s2
        zptr = np.searchsorted(zr, np.arange(A * S + 1))
        first = zptr[self._acol]
        counts = zptr[self._acol + 1] - first  # (nnz,) observations after each nonzero
        t = np.repeat(np.arange(self.nnz), counts)
        ends = np.cumsum(counts)
        z = np.repeat(first - (ends - counts), counts) + np.arange(int(ends[-1]))
        key = self._row[t] * O + zo[z]  # (a S + s) O + o
        order = np.argsort(key, kind="stable")
        key, t, z = key[order], t[order], z[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        return Z[zr[z], zo[z]], self._val[t], self._col[t], starts, key[starts]

    # -- torch, batched --------------------------------------------------------------------------
    def predict(self, beliefs: torch.Tensor) -> torch.Tensor:
        """``(B, A, S)`` the predictions of beliefs ``(B, S)`` under every action."""
        B, S = beliefs.shape
        out = self.Tt_stacked @ beliefs.T.to(self.dtype).contiguous()  # (A S, B)
        return out.T.reshape(B, self.num_actions, S)

    def predict_actions(self, beliefs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """``(M, S)`` the prediction of each belief ``(M, S)`` under its own action ``(M,)``:
        ``pred[m, s2] = sum_s T[actions[m], s, s2] beliefs[m, s]`` (one sparse product per
        distinct action)."""
        out = beliefs.new_zeros(beliefs.shape)
        for a in torch.unique(actions).tolist():
            rows = (actions == a).nonzero().squeeze(-1)
            out[rows] = (self.T_csr[a].t() @ beliefs[rows].T.to(self.dtype).contiguous()).T
        return out

    def successors(self, actions: torch.Tensor, states: torch.Tensor,
                   ) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """The successors of ``(actions[m], states[m])``, ``(M,)`` each, padded per row:
        ``next (M, W)`` states and ``prob (M, W)`` their probabilities ``T[a, s, next]``
        (0 on padding), ``W`` the most successors of a row."""
        S = self.num_states
        rows = (actions * S + states).cpu().numpy()
        start, stop = self._ptr[rows], self._ptr[rows + 1]
        W = max(int((stop - start).max()) if rows.size else 1, 1)
        pos = start[:, None] + np.arange(W)[None, :]  # (M, W)
        valid = pos < stop[:, None]
        pos = np.where(valid, pos, 0)
        prob = np.where(valid, self._val[pos] if self.nnz else 0.0, 0.0)
        nxt = np.where(valid, self._col[pos] if self.nnz else 0, 0)
        return torch.from_numpy(nxt), torch.from_numpy(prob.astype(self._val.dtype, copy=False))

    def backproject(self, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """``(B, S)``: ``g[i] = T[actions[i]] @ values[i]`` for ``values (B, S)``."""
        out = torch.empty_like(values)
        acts = actions.tolist()
        for a in sorted(set(acts)):
            rows = torch.tensor([i for i, ai in enumerate(acts) if ai == a])
            out[rows] = (self.T_csr[a] @ values[rows].T.contiguous()).T
        return out

    def expect(self, V: torch.Tensor) -> torch.Tensor:
        """``(A, S)`` ``sum_s2 T[a, s, s2] V[s2]`` for ``V (S,)``, or per action ``V (A, S)``."""
        if V.dim() == 1:
            return torch.stack([t @ V for t in self.T_csr])
        return torch.stack([t @ V[a] for a, t in enumerate(self.T_csr)])

    def dense_T(self) -> torch.Tensor:
        """``(A, S, S)`` the dense transitions (for small models and tests only)."""
        A, S = self.num_actions, self.num_states
        check_dense_size("T", A * S * S)
        T = torch.zeros(A * S * S, dtype=self.dtype)
        T[torch.from_numpy(self._row * S + self._col)] = torch.from_numpy(self._val)
        return T.view(A, S, S)


def _from_dense(
    cls: type[SparseFlatModel], model: POMDP, dtype: torch.dtype | None
) -> SparseFlatModel:
    """:meth:`SparseFlatModel.from_model` of an unbatched dense POMDP."""
    dtype = torch.float64 if dtype is None else dtype
    if len(model.batch_shape):
        raise ModelError(f"expected an unbatched POMDP, got batch shape {tuple(model.batch_shape)}")
    index = torch.nonzero(model.T)
    A, S, O = model.num_actions, model.num_states, model.num_observations
    return cls(index, model.T[tuple(index.T)], model.Z.expand(A, S, O),
               model.R, model.b0, model.discount, dtype=dtype)  # fmt: skip


def _from_sparse(
    cls: type[SparseFlatModel], model: SparsePOMDP, dtype: torch.dtype | None
) -> SparseFlatModel:
    """:meth:`SparseFlatModel.from_model` of a :class:`~torchhrc.pomdp.SparsePOMDP`."""
    dtype = torch.float64 if dtype is None else dtype
    A, S, O = model.num_actions, model.num_states, model.num_observations
    check_dense_size("Z", A * S * O, hint="too many observations for the sparse solver")
    Z = torch.zeros(A, S, O, dtype=dtype)
    zi, zp = model.observations_
    Z.index_put_((zi[:, 0], zi[:, 1], zi[:, 2]), zp.to(dtype), accumulate=True)
    idx, p = model.transitions
    return cls(idx, p, Z, model.R, model.b0, model.discount, dtype=dtype)


def _from_prepared(
    cls: type[SparseFlatModel], model: SparseFlatModel, dtype: torch.dtype | None
) -> SparseFlatModel:
    """:meth:`SparseFlatModel.from_model` of a prepared model: itself in its own dtype, else
    rebuilt from its nonzeros in ``dtype``."""
    if dtype is None or dtype == model.dtype:
        return model
    index = torch.from_numpy(np.stack([model._act, model._src, model._col], axis=1))
    return cls(index, torch.from_numpy(model._val), model.Z, model.R, model.b0, model.discount,
               dtype=dtype)  # fmt: skip


#: how :meth:`SparseFlatModel.from_model` builds from each kind of model
_SOURCES: dict[type, Callable[..., SparseFlatModel]] = {
    POMDP: _from_dense,
    SparsePOMDP: _from_sparse,
    SparseFlatModel: _from_prepared,
}


def sparse_blind_vectors(
    model: SparseFlatModel, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> torch.Tensor:
    """Blind-policy lower-bound vectors ``(A, S)`` of a sparse model (Hauskrecht 2000).

    ``alpha_a = R_a + gamma T_a alpha_a``, iterated from ``min R / (1 - gamma)`` with
    ``max(new, old)`` (monotone, so every iterate is a lower bound, as
    :func:`~torchhrc.solvers.blind.blind_vectors`), each state's self-loop solved exactly
    (:func:`blind_iteration_np`). Up to :data:`~torchhrc.solvers._factored.SPARSE_DIRECT_SOLVE_SIZE`
    states it is solved exactly by LU, as the dense function solves a sparse operator: above,
    the dense ``(A, S, S)`` LU costs ``A S^3`` time and ``2 A S^2`` floats (an 1,600-state
    RockSample: 2 s and 400 MB) where an iteration costs the nonzeros.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> from torchhrc.pomdp import SparsePOMDP
        >>> sm = SparseFlatModel.from_model(SparsePOMDP.from_dense(tiger()))
        >>> sparse_blind_vectors(sm).shape
        torch.Size([3, 2])
    """
    g = model.discount
    if g >= 1.0:
        raise ModelError(f"the blind lower bound needs discount < 1, got {g}")
    R = model.R
    S = model.num_states
    if S <= SPARSE_DIRECT_SOLVE_SIZE:
        eye = torch.eye(S, dtype=R.dtype)
        return torch.linalg.solve(eye - g * model.dense_T(), R.unsqueeze(-1)).squeeze(-1)
    loops = model.self_loop_probs()
    return torch.from_numpy(
        blind_iteration_np(R.numpy(), g, model.expect_np, tol, max_iterations, self_prob=loops)
    )


def qmdp_iteration_np(
    R: np.ndarray,
    discount: float,
    expect_np: Callable[[np.ndarray], np.ndarray],
    tol: float = 1e-8,
    deadline: Deadline = NEVER,
    max_iterations: int = 100_000,
) -> np.ndarray:
    """QMDP action values ``Q (A, *S)``, an upper bound, by value iteration on the underlying
    MDP (Littman et al. 1995), for any sparse form: ``expect_np(V)`` maps values ``V (*S)`` to
    ``(A, *S)`` expectations ``sum_s2 P(s2 | s, a) V[s2]`` (``*S`` is ``(S,)`` flat, ``(X, Y)``
    for a MOMDP).

    The iteration ``V_{k+1} = max_a (R_a + gamma P_a V_k)`` starts from ``V_0 = 0`` (as APPL's
    ``FullObsUBInitializer`` and :func:`~torchhrc.solvers.qmdp.mdp_q_values`). Whatever the
    start, the operator is a monotone ``gamma``-contraction that moves with a constant, so
    with ``d_k = V_{k+1} - V_k``,
    ``V_{k+1} + gamma min(d_k) / (1 - gamma) <= V* <= V_{k+1} + gamma max(d_k) / (1 - gamma)``
    (MacQueen 1966; Porteus 1971): the running minimum ``U`` of the right-hand
    side, and ``max R / (1 - gamma)`` before the first step, bounds ``V*`` from above at
    every ``k``, so stopping anywhere is safe. The iteration stops once ``U`` is within
    ``tol`` of ``V*``: the two sides within ``tol`` (or within the round-off of ``d_k``
    amplified by ``gamma / (1 - gamma)``, where that is wider), or the largest change below
    ``tol (1 - gamma) / (2 gamma)``; else after ``max_iterations`` or at ``deadline``. Near
    discount 1 the sides meet long before the change is that small (discount 0.9999, 6
    states: 0.8 CPU-s before). A change below ``tol`` alone is not enough there: on
    pomdp.org's ``baseball`` (discount 0.999) it left ``U`` 0.006 above ``V*`` at ``b0``,
    six times SARSOP's target gap. The returned vectors are
    ``Q_a = min(R_a + gamma P_a U, U) >= Q*_a`` (as ``Q*_a <= V* <= U``).

    Why from zero and not from the upper bound ``max R / (1 - gamma)`` (every iterate of which
    is an upper bound too): from above, the excess over ``V*`` shrinks by ``gamma`` per
    iteration wherever a cycle (a move and its reverse) carries it, so reaching ``tol`` takes
    ``log(tol (1 - gamma) / max R) / log(gamma)`` iterations (about 300 on RockSample(11, 11),
    5 CPU-s). From zero, when ``V* >= 0`` and the optimal policy reaches zero-reward
    absorbing states within ``L`` steps of deterministic moves (RockSample), ``V_L = V*``
    exactly and the change is 0 one step later (60 iterations on RockSample(11, 11)); on
    other models both starts converge at the rate ``gamma``.

    Example:
        >>> R = np.array([[1.0, 0.0]])  # one action, two absorbing states
        >>> qmdp_iteration_np(R, 0.5, lambda V: V[None, :]).round(6)
        array([[2., 0.]])
    """
    g = discount
    shape = R.shape[1:]
    V = np.zeros(shape, dtype=R.dtype)
    U = np.full(shape, float(R.max()) / (1.0 - g), dtype=R.dtype)  # V* <= max R / (1 - g)
    # the weight of a constant, g times each row's sum (1 within the model's tolerance, so
    # measured): a rise c >= 0 costs at most g s_max c a step, a fall c < 0 at least g s_min c
    sums = expect_np(np.ones(shape, dtype=R.dtype))
    w_hi, w_lo = g * float(sums.max()), g * float(sums.min())
    slack_hi, slack_lo = bracket_slack(w_hi), bracket_slack(w_lo)
    threshold = tol * (1.0 - g) / (2.0 * g) if g > 0.0 else math.inf
    for _ in range(max_iterations):
        if deadline.passed():
            break
        E = _fresh(expect_np(V), V)  # updated in place: no further temporaries
        E *= g
        E += R
        new = E.max(0)
        d = new - V
        hi, lo = (float(d.max()), float(d.min())) if d.size else (0.0, 0.0)
        change = max(hi, -lo)
        V = new
        # V* <= V + g max(d) / (1 - g) (MacQueen 1966; with max |d|: the contraction bound)
        slack = slack_hi if hi >= 0.0 else slack_lo
        if math.isfinite(slack):
            np.minimum(U, V + slack * hi, out=U)
        if change < threshold:  # |V - V*| <= g change / (1 - g) <= tol / 2
            break
        if math.isfinite(slack_hi):  # U within tol of V* (or of the round-off of k d)
            floor = BRACKET_ROUND_OFF * slack_hi * float(np.abs(V).max(initial=0.0))
            if slack_hi * (hi - lo) < max(tol, floor):
                break
    Q = _fresh(expect_np(U), U)
    Q *= g
    Q += R
    np.minimum(Q, U, out=Q)
    return Q


def _fresh(out: np.ndarray, source: np.ndarray) -> np.ndarray:
    """``out``, copied if it may share memory with ``source`` (an ``expect_np`` that returns
    a view), so that the iterations can update it in place."""
    return out.copy() if np.may_share_memory(out, source) else out


def self_loop_probs(
    row: np.ndarray, col: np.ndarray, prob: np.ndarray, num_actions: int, num_states: int
) -> np.ndarray:
    """``(A, S)`` ``P(s | s, a)``, the probability that action ``a`` leaves state ``s`` where
    it is, from the nonzeros ``prob`` at rows ``a S + s`` and columns ``s2`` (duplicates of a
    cell summed).

    Example:
        >>> self_loop_probs(np.array([0, 0, 1]), np.array([0, 1, 0]), np.array([0.3, 0.7, 1.0]),
        ...                 1, 2)
        array([[0.3, 0. ]])
    """
    A, S = num_actions, num_states
    loop = col == row % S
    out = np.bincount(row[loop], weights=prob[loop], minlength=A * S)
    return out.astype(prob.dtype, copy=False).reshape(A, S)


def blind_iteration_np(
    R: np.ndarray,
    discount: float,
    expect_np: Callable[[np.ndarray], np.ndarray],
    tol: float = 1e-8,
    max_iterations: int = 100_000,
    self_prob: np.ndarray | None = None,
) -> np.ndarray:
    """Blind-policy vectors ``alpha (A, *S)`` (Hauskrecht 2000), ``alpha_a = R_a + gamma
    P_a alpha_a``, iterated from ``min R / (1 - gamma)`` with ``max(new, old)`` (every iterate
    a lower bound); ``expect_np(alpha)`` maps per-action values ``(A, *S)`` to their
    ``(A, *S)`` expectations (as in :func:`qmdp_iteration_np`). Stops when the largest change
    is below ``tol (1 - gamma)`` or after ``max_iterations``.

    With ``self_prob`` ``(A, *S)``, ``p = P(s | s, a)`` (:func:`self_loop_probs`), each step
    solves every state's own self-loop exactly (Jacobi value iteration, Puterman 1994,
    Sec. 6.3.3)::

        alpha_a(s) <- (R_a(s) + gamma (P_a alpha_a)(s) - gamma p alpha_a(s)) / (1 - gamma p)

    This is still monotone, its fixed point is the same ``alpha_a`` (solve the fixed-point
    equation for ``alpha_a(s)``), and from a lower bound ``L <= alpha_a`` it gives a lower
    bound (replace ``L`` by ``alpha_a`` on the right: the result is ``alpha_a``), so every
    iterate is still a lower bound; it contracts by ``gamma (1 - p) / (1 - gamma p) <= gamma``
    per row. A state that only loops on itself (RockSample: a move into the wall, a check, the
    exit's absorbing state) gets its exact value ``R / (1 - gamma)`` at once instead of after
    ``log(tol) / log(gamma)`` steps, and chains of deterministic moves ending there are exact
    after their length (13 iterations on RockSample(11, 11), where 135 plain iterations left
    the bound about 2 below the exact value everywhere).

    Example:
        >>> R = np.array([[1.0, 0.0]])  # one action, two absorbing states
        >>> blind_iteration_np(R, 0.5, lambda a: a).round(6)
        array([[2., 0.]])
        >>> blind_iteration_np(R, 0.5, lambda a: a, max_iterations=1, self_prob=np.ones((1, 2)))
        array([[2., 0.]])
    """
    g = discount
    alpha = np.full_like(R, float(R.min()) / (1.0 - g))
    scale = None if self_prob is None else 1.0 / (1.0 - g * self_prob)
    for _ in range(max_iterations):
        new = _fresh(expect_np(alpha), alpha)  # updated in place
        if self_prob is not None:
            new -= self_prob * alpha  # the state's own share, solved for below
        new *= g
        new += R
        if scale is not None:
            new *= scale
        np.maximum(new, alpha, out=new)
        alpha -= new  # <= 0 (new >= alpha): its most negative entry is minus the largest change
        change = -float(alpha.min())
        alpha = new
        if change < tol * (1.0 - g):
            break
    return alpha


def default_blind_iterations(num_states: int, discount: float) -> int:
    """The iteration cap of a sparse form's blind evaluation when none is given.

    Up to :data:`~torchhrc.solvers._factored.DIRECT_SOLVE_SIZE` states (where a dense model's
    blind vectors are exact by LU) the iteration runs to its tolerance (cap 100,000), so the
    two forms start from the same bound up to that tolerance. Above, the ``k`` with
    ``gamma^k <= 1e-3`` (at most 1000): the discounted tail below 1e-3 of the first step's
    (as APPL's SARSOP).

    Example:
        >>> default_blind_iterations(1600, 0.95), default_blind_iterations(12545, 0.95)
        (100000, 135)
    """
    if num_states <= DIRECT_SOLVE_SIZE:
        return 100_000
    if discount <= 0:
        return 1
    return int(min(1000, math.ceil(math.log(1e-3) / math.log(discount))))


def sparse_blind_policy(
    model: SparseFlatModel | SparsePOMDP, *, tol: float = 1e-8, max_iterations: int | None = None
) -> AlphaVectorPolicy:
    """The blind policies of a sparse model as an :class:`AlphaVectorPolicy` (flat).

    ``max_iterations`` defaults to :func:`default_blind_iterations`.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> from torchhrc.pomdp import SparsePOMDP
        >>> sparse_blind_policy(SparsePOMDP.from_dense(tiger())).num_vectors
        3
    """
    model = SparseFlatModel.from_model(model)  # a prepared one: itself
    if max_iterations is None:
        max_iterations = default_blind_iterations(model.num_states, model.discount)
    vectors = sparse_blind_vectors(model, tol=tol, max_iterations=max_iterations)
    return AlphaVectorPolicy.from_action_vectors(vectors, momdp=False)
