"""The sampled belief tree of SARSOP and the factored model view it expands with.

Two pieces, shared by the SARSOP loop (:mod:`torchhrc.solvers.sarsop`):

* :class:`FactoredModel`: a flat :class:`~torchhrc.pomdp.POMDP` or a
  :class:`~torchhrc.pomdp.MOMDP` seen as one mixed-observability model (Ong et al. 2010).
  A flat POMDP is the MOMDP with one observed value (``X = 1``, ``Y = S``), so a single code
  path serves both. For every observed value ``x`` it precomputes the next observed values
  reachable from ``x`` (``K_x`` of them, usually far fewer than ``X``) and the slices of
  ``Tx``, ``Ty`` and ``Z`` restricted to them: expanding a belief then costs
  ``A * K_x * Y`` (static hidden value) instead of ``A * X * Y`` or, flat, ``A * S * S``.
* :class:`BeliefTree`: the tree of sampled beliefs (nodes ``(x, b_y)``, children keyed by
  ``(a, x2, o)``, depth, cached bounds), stored in preallocated tensors/arrays grown
  geometrically.

The expansion (:meth:`FactoredModel.expand`) is the unnormalised MOMDP belief update of paper
Eq. 3 for every action, reachable next observed value and observation at once::

    J[..., a, k, o, y2] = Z[a, x2_k, y2, o]
                          * sum_y Tx[a, x, y, x2_k] Ty[a, x, y, x2_k, y2] b[..., y]
                        = P(x2_k, o | x, b, a) * tau(b, a, x2_k, o)[y2]

It agrees with :func:`torchhrc.belief.momdp_update_all` (tested); it is kept here, restricted
to reachable ``x2`` and unnormalised, because the sawtooth and alpha-vector bounds are
positively homogeneous and need no normalisation, which saves a division and a log per child
on the solver's hot path.

Example:
    >>> from torchhrc.testing import random_pomdp
    >>> fm = FactoredModel.from_model(random_pomdp(3, 2, 2, seed=0))
    >>> xs, J = fm.expand(0, fm.b0.unsqueeze(0))
    >>> tuple(J.shape), round(float(J.sum()), 6)  # (B, A, K, O, Y); sums to A
    ((1, 2, 1, 2, 3), 2.0)
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP

if TYPE_CHECKING:
    from torchhrc.solvers.sparse_model import SparseFlatModel
    from torchhrc.sparse import SparsePOMDP

__all__ = ["BeliefTree", "FactoredModel", "SparseBeliefTree"]


class _PerX:
    """Per-observed-value tuples ``build(x)``, computed on first use and cached."""

    def __init__(self, n: int, build: Callable[[int], tuple[Any, ...]]) -> None:
        self._build = build
        self._items: list[tuple[Any, ...] | None] = [None] * n

    def __len__(self) -> int:
        return len(self._items)

    def get(self, x: int) -> tuple[Any, ...]:
        item = self._items[x]
        if item is None:
            item = self._items[x] = self._build(x)
        return item


class _PerXView(Sequence[Any]):
    """Field ``i`` of a :class:`_PerX`, indexed by the observed value ``x``."""

    def __init__(self, cache: _PerX, i: int) -> None:
        self._cache, self._i = cache, i

    def __len__(self) -> int:
        return len(self._cache)

    def __getitem__(self, x: int) -> Any:  # type: ignore[override]
        if not isinstance(x, (int, np.integer)):
            raise TypeError(f"expected an int observed value, got {type(x).__name__}")
        return self._cache.get(int(x))[self._i]


@dataclass
class FactoredModel:
    """A POMDP or MOMDP as ``(Tx, Ty, Z, R)`` over observed ``x`` and hidden ``y``.

    Attributes:
        Tx: ``(A, X, Y, X)``, ``Tx[a, x, y, x2] = P(x2 | x, y, a)``.
        Ty: ``(A, X, Y, X, Y)`` or ``None`` (static hidden value).
        Z: ``(A, X, Y, O)``, ``Z[a, x2, y2, o] = P(o | x2, y2, a)``.
        R: ``(A, X, Y)`` rewards.
        x0: initial observed value; b0: ``(Y,)`` initial belief over the hidden value.
        discount: the discount factor.
        flat: True when built from a flat POMDP (then ``X = 1``).
        reach: per ``x``, the ``(K_x,)`` long tensor of reachable next observed values
            (this and the per-``x`` slices below are built on first access).
        reach_mask: ``(X, X)`` bool, ``reach_mask[x, x2]`` iff ``x2`` is reachable from ``x``.
        sparse: for a flat model built by :meth:`from_sparse`, its
            :class:`~torchhrc.solvers.sparse_model.SparseFlatModel` (``T`` as per-action CSR;
            ``Ty`` is then None and unused); None otherwise.
    """

    Tx: torch.Tensor
    Ty: torch.Tensor | None
    Z: torch.Tensor
    R: torch.Tensor
    x0: int
    b0: torch.Tensor
    discount: float
    flat: bool
    reach: Sequence[torch.Tensor]
    reach_mask: torch.Tensor
    _tx: Sequence[torch.Tensor]
    _ty: Sequence[torch.Tensor | None]
    _tyk: Sequence[torch.Tensor | None]
    _z: Sequence[torch.Tensor]
    _T: torch.Tensor | None
    sparse: SparseFlatModel | None = None

    @classmethod
    def from_model(cls, model: POMDP | MOMDP, *, dtype: torch.dtype | None = None) -> FactoredModel:
        """Build the factored view of ``model`` (unbatched; ``dtype`` defaults to float64).

        Raises:
            ModelError: ``model`` has batch dims (solve each problem of a batch separately).
            TypeError: ``model`` is neither a POMDP nor a MOMDP.
        """
        if not isinstance(model, (POMDP, MOMDP)):
            raise TypeError(f"expected a POMDP or MOMDP, got {type(model).__name__}")
        if len(model.batch_shape) > 0:
            raise ModelError(
                f"expected an unbatched model, got batch_shape = {tuple(model.batch_shape)}; "
                "solve each problem of the batch separately"
            )
        dt = dtype or torch.float64
        if isinstance(model, POMDP):
            A, S, O = model.num_actions, model.num_states, model.num_observations
            T = model.T.to(dt)
            Tx = T.new_ones(A, 1, S, 1)
            Ty = T.reshape(A, 1, S, 1, S)
            Z = model.Z.to(dt).reshape(A, 1, S, O)
            R = model.R.to(dt).reshape(A, 1, S)
            x0, b0, flat = 0, model.b0.to(dt), True
        else:
            Tx, Z, R = model.Tx.to(dt), model.Z.to(dt), model.R.to(dt)
            Ty = None if model.Ty is None else model.Ty.to(dt)
            x0, b0, flat = model.x0, model.b0.to(dt), False
        reach_mask = Tx.sum(dim=(0, 2)) > 0  # (X, X2)

        def slices(x: int) -> tuple[torch.Tensor, ...]:
            k = reach_mask[x].nonzero().squeeze(-1)
            tx = Tx[:, x][:, :, k].contiguous()  # (A, Y, K)
            ty = tyk = None
            if Ty is not None:
                ty = Ty[:, x][:, :, k].contiguous()  # (A, Y, K, Y2)
                # (A, K, Y, Y2): the per-(a, x2) hidden transition matrices, for batched matmuls
                tyk = ty.permute(0, 2, 1, 3).contiguous()
            z = Z[:, k].permute(0, 1, 3, 2).contiguous()  # (A, K, O, Y)
            return k, tx, ty, tyk, z

        # the slices of an observed value are built when the solver first reaches it (a
        # search usually visits a small part of a large X)
        cache = _PerX(Tx.shape[1], slices)
        return cls(
            Tx=Tx, Ty=Ty, Z=Z, R=R, x0=int(x0), b0=b0, discount=float(model.discount), flat=flat,
            reach=_PerXView(cache, 0), reach_mask=reach_mask, _tx=_PerXView(cache, 1),
            _ty=_PerXView(cache, 2), _tyk=_PerXView(cache, 3), _z=_PerXView(cache, 4),
            _T=Ty[:, 0, :, 0, :].contiguous() if flat else None,
        )  # fmt: skip

    @classmethod
    def from_sparse(
        cls, model: SparsePOMDP | SparseFlatModel, *, dtype: torch.dtype | None = None
    ) -> FactoredModel:
        """The factored view of a flat model with sparse transitions (``X = 1``).

        ``T`` stays sparse (:class:`~torchhrc.solvers.sparse_model.SparseFlatModel`, in
        :attr:`sparse`); :meth:`expand` and :meth:`backproject` use it. ``Tx`` is the
        ``(A, 1, S, 1)`` ones and ``Ty`` is None (never read on this path).

        Example:
            >>> from torchhrc.sparse import SparsePOMDP
            >>> from torchhrc.tasks.classic import tiger
            >>> fm = FactoredModel.from_sparse(SparsePOMDP.from_dense(tiger()))
            >>> fm.expand(0, fm.b0.unsqueeze(0))[1].shape  # (B, A, K, O, Y)
            torch.Size([1, 3, 1, 2, 2])
        """
        from torchhrc.solvers.sparse_model import SparseFlatModel

        dt = dtype or torch.float64
        if not isinstance(model, SparseFlatModel) or model.dtype != dt:
            model = SparseFlatModel.from_model(model, dtype=dt)  # type: ignore[arg-type]
        A, S, O = model.num_actions, model.num_states, model.num_observations
        Tx = model.R.new_ones(A, 1, S, 1)
        reach = [torch.zeros(1, dtype=torch.long)]
        return cls(
            Tx=Tx, Ty=None, Z=model.Z.reshape(A, 1, S, O), R=model.R.reshape(A, 1, S), x0=0,
            b0=model.b0, discount=model.discount, flat=True, reach=reach,
            reach_mask=torch.ones(1, 1, dtype=torch.bool), _tx=[Tx[:, 0]], _ty=[None],
            _tyk=[None], _z=[model.Z.permute(0, 2, 1).unsqueeze(1).contiguous()], _T=None,
            sparse=model,
        )  # fmt: skip

    @property
    def num_actions(self) -> int:
        return self.Tx.shape[0]

    @property
    def num_observed(self) -> int:
        return self.Tx.shape[1]

    @property
    def num_hidden(self) -> int:
        return self.Tx.shape[2]

    @property
    def num_observations(self) -> int:
        return self.Z.shape[-1]

    def expand(self, x: int, beliefs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Unnormalised successors of beliefs sharing the observed value ``x``.

        Args:
            x: the observed value of every belief.
            beliefs: ``(B, Y)`` beliefs over the hidden value.

        Returns:
            ``xs (K,)`` the reachable next observed values, and
            ``J (B, A, K, O, Y)`` with ``J[i, a, k, o, y2] = P(xs[k], o | x, b_i, a) *
            tau(b_i, a, xs[k], o)[y2]`` (the formula of the module docstring).
        """
        z = self._z[x]
        if self.sparse is not None:  # flat, sparse T: one (A S, S) x (S, B) sparse product
            pred = self.sparse.predict(beliefs).unsqueeze(2)  # (B, A, 1, S)
        elif self._T is not None:  # flat: one (B, S) x (A, S, S) product
            S = beliefs.shape[-1]
            if beliefs.shape[0] == 1 and S >= 64:
                # one belief: only the rows of T on its support matter (beliefs of structured
                # problems are sparse, e.g. RockSample's robot position is known)
                supp = beliefs[0].nonzero().squeeze(-1)
                if supp.numel() * 4 <= S:
                    rows = self._T.index_select(1, supp)  # (A, w, S)
                    pred = torch.matmul(beliefs[0, supp], rows).view(1, -1, 1, S)  # (1, A, 1, S)
                    return self.reach[x], pred.unsqueeze(-2) * z
            pred = torch.matmul(beliefs[:, None, None, :], self._T)  # (B, A, 1, S)
        elif self._ty[x] is None:
            pred = (beliefs[:, None, :, None] * self._tx[x]).transpose(-1, -2)  # (B, A, K, Y)
        else:
            # sum_y b[y] tx[a, y, k] ty[a, y, k, y2], as (B, A, K, 1, Y) @ (A, K, Y, Y2)
            w = (beliefs[:, None, :, None] * self._tx[x]).transpose(-1, -2)  # (B, A, K, Y)
            pred = torch.matmul(w.unsqueeze(-2), self._tyk[x]).squeeze(-2)
        return self.reach[x], pred.unsqueeze(-2) * z  # (B, A, K, O, Y)

    def backproject(self, x: int, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """``g[i, y] = sum_{k, y2} Tx[a_i, x, y, x2_k] Ty[a_i, x, y, x2_k, y2] values[i, k, y2]``.

        Args:
            x: the observed value.
            actions: ``(B,)`` long, one action per row.
            values: ``(B, K, Y)`` next-step values per reachable ``x2_k`` and hidden ``y2``
                (already summed over observations with ``Z``).

        Returns:
            ``(B, Y)`` the expected next-step value per current hidden value.
        """
        if self.sparse is not None:  # flat, sparse T
            return self.sparse.backproject(actions, values[:, 0, :])
        if self._T is not None:  # flat: T[a] @ values
            if actions.numel() == 1:  # a view of T[a], no (S, S) copy
                return torch.mv(self._T[int(actions[0])], values[0, 0]).unsqueeze(0)
            return torch.matmul(self._T[actions], values[:, 0, :].unsqueeze(-1)).squeeze(-1)
        tx = self._tx[x][actions]  # (B, Y, K)
        if self._ty[x] is None:
            return (tx * values.transpose(-1, -2)).sum(-1)
        # inner[b, k, y] = sum_y2 ty[a_b, y, k, y2] values[b, k, y2]
        inner = torch.matmul(self._tyk[x][actions], values.unsqueeze(-1)).squeeze(-1)
        return (tx * inner.transpose(-1, -2)).sum(-1)

    def observation_slice(self, x: int, actions: torch.Tensor) -> torch.Tensor:
        """``(B, K, O, Y)``: ``Z[a_i, x2_k, y2, o]`` for the reachable ``x2`` of ``x``."""
        return self._z[x][actions]


class BeliefTree:
    """Sampled beliefs ``(x, b_y)`` in preallocated storage grown geometrically.

    Per node ``n``: ``belief[n] (Y,)``, ``x[n]``, ``parent[n]`` (-1 at the root), the
    ``action[n]`` and ``observation[n]`` that led to it (with ``x[n]``), ``depth[n]``,
    cached ``lower[n]`` and ``upper[n]`` bounds, and ``active[n]`` (False once pruned as
    sub-optimal). Children are looked up by ``(node, a, x2, o)``. Scalars live in numpy
    arrays (cheap single-element access on the sequential trial path); beliefs in one
    ``(N, Y)`` tensor for batched bounds.

    Args:
        belief: ``(Y,)`` the root belief.
        x: the root's observed value.
        capacity: initial number of node slots.

    Example:
        >>> import torch
        >>> tree = BeliefTree(torch.tensor([0.5, 0.5], dtype=torch.float64), x=0)
        >>> child = tree.add(torch.tensor([0.85, 0.15], dtype=torch.float64), 0, 0, 0, 0)
        >>> tree.size, int(tree.depth[child]), tree.child(0, 0, 0, 0) == child
        (2, 1, True)
    """

    def __init__(self, belief: torch.Tensor, x: int, *, capacity: int = 1024) -> None:
        cap = max(int(capacity), 2)
        self._init_beliefs(belief, cap)
        self.x = np.zeros(cap, dtype=np.int64)
        self.parent = np.full(cap, -1, dtype=np.int64)
        self.action = np.full(cap, -1, dtype=np.int64)
        self.observation = np.full(cap, -1, dtype=np.int64)
        self.depth = np.zeros(cap, dtype=np.int64)
        self.lower = np.full(cap, -np.inf)
        self.upper = np.full(cap, np.inf)
        self.active = np.ones(cap, dtype=bool)
        self._children: dict[tuple[int, int, int, int], int] = {}
        self._np_beliefs: np.ndarray | None = None
        self.size = 0
        self.add(belief, x, -1, -1, -1)

    def _init_beliefs(self, belief: torch.Tensor, cap: int) -> None:
        self._beliefs = belief.new_zeros(cap, belief.shape[-1])

    @property
    def beliefs_np(self) -> np.ndarray:
        """``(capacity, Y)`` a numpy view of the belief storage (CPU only; rows ``< size``)."""
        if self._np_beliefs is None:
            self._np_beliefs = self._beliefs.numpy()
        return self._np_beliefs

    @property
    def beliefs(self) -> torch.Tensor:
        """``(N, Y)`` the node beliefs."""
        return self._beliefs[: self.size]

    def _grow_beliefs(self, cap: int) -> None:
        new = self._beliefs.new_zeros(cap, self._beliefs.shape[1])
        new[: self.size] = self._beliefs[: self.size]
        self._beliefs = new
        self._np_beliefs = None

    def _set_belief(self, n: int, belief: torch.Tensor) -> None:
        self._beliefs[n] = belief

    def _grow(self) -> None:
        cap = self.x.shape[0] * 2
        self._grow_beliefs(cap)
        for name, fill in (
            ("x", 0), ("parent", -1), ("action", -1), ("observation", -1),
            ("depth", 0), ("lower", -np.inf), ("upper", np.inf), ("active", True),
        ):  # fmt: skip
            old = getattr(self, name)
            arr = np.full(cap, fill, dtype=old.dtype)
            arr[: self.size] = old[: self.size]
            setattr(self, name, arr)

    def add(self, belief: torch.Tensor, x: int, parent: int, action: int, observation: int) -> int:
        """Add node ``(x, belief)``, the child of ``parent`` by ``(action, x, observation)``.

        Returns the new node's id (the root, with ``parent = -1``, is node 0).
        """
        if self.size == self.x.shape[0]:
            self._grow()
        n = self.size
        self._set_belief(n, belief)
        self.x[n] = x
        self.parent[n] = parent
        self.action[n] = action
        self.observation[n] = observation
        self.depth[n] = 0 if parent < 0 else self.depth[parent] + 1
        self.size = n + 1
        if parent >= 0:
            self._children[(parent, action, int(x), observation)] = n
        return n

    def child(self, node: int, action: int, x_next: int, observation: int) -> int:
        """The child id for ``(action, x_next, observation)``, or -1 if not sampled yet."""
        return self._children.get((node, action, x_next, observation), -1)

    def refresh_active(self) -> None:
        """Propagate pruning: a node is active only if its parent is (depth order)."""
        n = self.size
        if n <= 1:
            return
        order = np.argsort(self.depth[:n], kind="stable")
        parent = self.parent[:n]
        act = self.active[:n]
        for d in range(1, int(self.depth[:n].max()) + 1):
            nodes = order[self.depth[order] == d]
            act[nodes] &= act[parent[nodes]]


class _DenseRows:
    """``rows[n]``: the dense ``(S,)`` numpy row of node ``n`` of a :class:`SparseBeliefTree`."""

    def __init__(self, tree: SparseBeliefTree) -> None:
        self.tree = tree

    def __getitem__(self, n: int) -> np.ndarray:
        return self.tree.dense_np(int(n))


class SparseBeliefTree(BeliefTree):
    """A :class:`BeliefTree` that stores each belief as its support (indices and values).

    For flat models with many states whose reachable beliefs are sparse (RockSample(7, 8):
    12545 states, the robot's position known, at most 256 rock states possible): a node costs
    its support, not ``S`` floats. ``beliefs_np[n]`` returns node ``n``'s dense ``(S,)`` numpy
    row, built on demand; :meth:`csr` gives rows as a sparse CSR tensor and :attr:`beliefs` the
    dense ``(N, S)`` tensor (for small trees and tests only).

    Example:
        >>> import torch
        >>> tree = SparseBeliefTree(torch.tensor([0.5, 0.0, 0.5], dtype=torch.float64), x=0)
        >>> tree.beliefs_np[0].tolist(), tree.support_sizes().tolist()
        ([0.5, 0.0, 0.5], [2])
    """

    def _init_beliefs(self, belief: torch.Tensor, cap: int) -> None:
        self._S = int(belief.shape[-1])
        self._dtype = belief.dtype
        self._support: list[np.ndarray] = []
        self._values: list[np.ndarray] = []

    def _grow_beliefs(self, cap: int) -> None:
        pass

    def _set_belief(self, n: int, belief: torch.Tensor) -> None:
        row = belief.detach().cpu().numpy()
        idx = np.flatnonzero(row)
        if n == len(self._support):
            self._support.append(idx)
            self._values.append(row[idx].copy())
        else:
            self._support[n], self._values[n] = idx, row[idx].copy()

    def dense_np(self, n: int) -> np.ndarray:
        """``(S,)`` the dense numpy belief of node ``n``."""
        row = np.zeros(self._S, dtype=self._values[n].dtype)
        row[self._support[n]] = self._values[n]
        return row

    @property
    def beliefs_np(self) -> _DenseRows:  # type: ignore[override]
        """``rows[n]``: node ``n``'s dense ``(S,)`` numpy belief (built on demand)."""
        return _DenseRows(self)

    @property
    def beliefs(self) -> torch.Tensor:
        """``(N, S)`` the dense node beliefs (allocates ``N S`` floats: small trees only)."""
        return self.csr(np.arange(self.size)).to_dense()

    def support_sizes(self) -> np.ndarray:
        """``(N,)`` the number of nonzeros of each node's belief."""
        return np.array([s.size for s in self._support[: self.size]], dtype=np.int64)

    def csr(self, nodes: np.ndarray) -> torch.Tensor:
        """``(len(nodes), S)`` sparse CSR tensor of the given nodes' beliefs."""
        sup = [self._support[int(n)] for n in nodes]
        val = [self._values[int(n)] for n in nodes]
        lens = np.array([s.size for s in sup], dtype=np.int64)
        indptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        cols = np.concatenate(sup) if sup else np.zeros(0, dtype=np.int64)
        vals = np.concatenate(val) if val else np.zeros(0)
        with warnings.catch_warnings():  # "sparse CSR support is in beta"
            warnings.simplefilter("ignore", UserWarning)
            return torch.sparse_csr_tensor(
                torch.from_numpy(indptr), torch.from_numpy(cols.astype(np.int64)),
                torch.from_numpy(vals.astype(np.float64, copy=False)).to(self._dtype),
                size=(len(sup), self._S),
            )  # fmt: skip
