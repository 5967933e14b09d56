"""The sampled belief tree of SARSOP: beliefs stored as dense rows or by their support.

:class:`BeliefTree` holds the tree of sampled beliefs (nodes ``(x, b_y)``, children keyed by
``(a, x2, o)``, depth, cached bounds) in preallocated tensors/arrays grown geometrically;
:class:`SparseBeliefTree` stores each belief by its support (large flat models whose
reachable beliefs are sparse). A model form picks its tree
(:meth:`~torchhrc.solvers.forms.base.SolverModel.new_tree`); the tree also decides which
alpha vectors to keep at a pruning (:meth:`BeliefTree.keep_alphas`), the test that costs what
its storage allows.

Example:
    >>> import torch
    >>> tree = BeliefTree(torch.tensor([0.5, 0.5], dtype=torch.float64), x=0)
    >>> tree.add(torch.tensor([0.85, 0.15], dtype=torch.float64), 0, 0, 0, 0), tree.size
    (1, 2)
"""

from __future__ import annotations

import warnings

import numpy as np
import torch

from torchhrc._host import alloc, copy_front
from torchhrc.solvers import backup_kernel
from torchhrc.solvers.pruning import _GATHER_ELEMENTS, prune_by_beliefs, prune_dominated

__all__ = ["BeliefTree", "SparseBeliefTree"]

#: bits of a child's key per field: an action, observed value or observation below 2**21
_EDGE_BITS = 21
_EDGE_LIMIT = 1 << _EDGE_BITS


#: each node's scalar arrays and their fill (:meth:`BeliefTree._grow`)
_NODE_ARRAYS = (
    ("x", 0), ("parent", -1), ("action", -1), ("observation", -1), ("depth", 0),
    ("lower", -np.inf), ("upper", np.inf), ("active", True), ("first_child", -1),
    ("next_sibling", -1),
)  # fmt: skip


def _edge_key(parent: int, action: int, x: int, observation: int) -> int:
    """The one int that keys the child ``(action, x, observation)`` of ``parent`` (as ints: a
    numpy int64 would overflow the shifts); unchecked, see :func:`_checked_edge_key`."""
    key = ((int(parent) << _EDGE_BITS | int(action)) << _EDGE_BITS | int(x)) << _EDGE_BITS
    return key | int(observation)


def _checked_edge_key(parent: int, action: int, x: int, observation: int) -> int:
    """:func:`_edge_key`, each of ``action``, ``x`` and ``observation`` checked to fit."""
    for name, v in (("action", action), ("x", x), ("observation", observation)):
        if not 0 <= v < _EDGE_LIMIT:
            raise ValueError(f"expected a child's {name} in [0, 2**{_EDGE_BITS}), got {v}")
    return _edge_key(parent, action, x, observation)


class BeliefTree:
    """Sampled beliefs ``(x, b_y)`` in preallocated storage grown geometrically.

    Per node ``n``: ``belief[n] (Y,)``, ``x[n]``, ``parent[n]`` (-1 at the root), the
    ``action[n]`` and ``observation[n]`` that led to it (with ``x[n]``), ``depth[n]``,
    cached ``lower[n]`` and ``upper[n]`` bounds, and ``active[n]`` (False once pruned as
    sub-optimal). Children are looked up by ``(node, a, x2, o)``, packed into one int key
    (``a``, ``x2`` and ``o`` each below ``2**21``), and listed by :meth:`children_of` (each
    node's first child and next sibling, two arrays; a tuple key and a list per parent held
    about 170 bytes a node). Scalars live in numpy arrays (cheap single-element access on
    the sequential trial path); beliefs in one ``(N, Y)`` tensor for batched bounds.

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
        self.first_child = np.full(cap, -1, dtype=np.int64)
        self.next_sibling = np.full(cap, -1, dtype=np.int64)
        self._children: dict[int, int] = {}
        self._np_beliefs: np.ndarray | None = None
        self._kernel = backup_kernel.load()  # refresh_active's compiled pass (None: numpy)
        self.size = 0
        self.add(belief, x, -1, -1, -1)

    def _init_beliefs(self, belief: torch.Tensor, cap: int) -> None:
        self._beliefs = alloc((cap, belief.shape[-1]), belief.dtype, belief.device)

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
        # empty, not zeros: a row is written whole when its node is added, and the slots
        # past ``size`` stay untouched pages (not resident) until then
        old = self._beliefs
        new = alloc((cap, old.shape[1]), old.dtype, old.device, fill=None)
        copy_front(new, old, self.size)
        self._beliefs = new
        self._np_beliefs = None

    def _set_belief(self, n: int, belief: torch.Tensor | np.ndarray) -> None:
        if isinstance(belief, np.ndarray):  # the CPU search's numpy rows (CPU storage)
            self.beliefs_np[n] = belief
        elif belief.device.type == "cpu" and self._beliefs.device.type == "cpu":
            self.beliefs_np[n] = belief.numpy()  # a row copy without tensor indexing (~15 us)
        else:
            self._beliefs[n] = belief

    def node_bytes(self) -> int:
        """The bytes a node takes in the storage that :meth:`add` grows by doubling: its
        scalar arrays and its dense belief row (a doubling copies ``size * node_bytes()``;
        the search's memory guard reserves it)."""
        return self._beliefs.shape[1] * self._beliefs.element_size() + self._scalar_bytes()

    def _scalar_bytes(self) -> int:
        """The bytes of a node's entries in the scalar arrays (:data:`_NODE_ARRAYS`)."""
        return sum(getattr(self, name).itemsize for name, _ in _NODE_ARRAYS)

    def _grow(self) -> None:
        cap = self.x.shape[0] * 2
        self._grow_beliefs(cap)
        for name, fill in _NODE_ARRAYS:
            old = getattr(self, name)
            arr = np.full(cap, fill, dtype=old.dtype)
            arr[: self.size] = old[: self.size]
            setattr(self, name, arr)

    def add(self, belief: torch.Tensor | np.ndarray, x: int, parent: int, action: int,
            observation: int) -> int:  # fmt: skip
        """Add node ``(x, belief)``, the child of ``parent`` by ``(action, x, observation)``
        (``belief`` ``(Y,)``: a tensor, or a numpy row when the storage is on the CPU).

        Returns the new node's id (the root, with ``parent = -1``, is node 0).

        Raises:
            ValueError: ``action``, ``x`` or ``observation`` of a child outside
                ``[0, 2**21)``.
        """
        if parent >= 0:
            key = _checked_edge_key(parent, action, int(x), observation)
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
            self._children[key] = n
            self.next_sibling[n] = self.first_child[parent]
            self.first_child[parent] = n
        return n

    def child(self, node: int, action: int, x_next: int, observation: int) -> int:
        """The child id for ``(action, x_next, observation)``, or -1 if not sampled yet."""
        return self._children.get(_edge_key(node, action, x_next, observation), -1)

    def children_of(self, node: int) -> list[int]:
        """The children of ``node``, the latest added first."""
        out = []
        c = int(self.first_child[node])
        while c >= 0:
            out.append(c)
            c = int(self.next_sibling[c])
        return out

    def refresh_active(self) -> None:
        """Propagate pruning: a node is active only if its parent is.

        Nodes are added after their parents, so one pass in index order reaches every
        descendant: compiled where the extension is built (``propagate_inactive`` of
        ``_backup.c``; 0.2-0.6 ms a SARSOP iteration in numpy on RockSample(8,4) as a MOMDP
        and bridge-repair), level by level in numpy otherwise (the same result)."""
        n = self.size
        if n <= 1:
            return
        if self._kernel is not None:
            self._kernel.propagate_inactive(self.parent[:n], self.active)
            return
        depth = self.depth[:n]
        order = np.argsort(depth, kind="stable")
        # level d is order[starts[d]:starts[d + 1]] (one pass, not one scan per level: a
        # trial of a discount-0.99 model is hundreds of levels deep)
        starts = np.searchsorted(depth[order], np.arange(int(depth.max()) + 2))
        parent = self.parent[:n]
        act = self.active[:n]
        for d in range(1, starts.size - 1):
            nodes = order[starts[d] : starts[d + 1]]
            act[nodes] &= act[parent[nodes]]

    def keep_alphas(self, vectors: torch.Tensor, groups: torch.Tensor | None,
                    nodes: np.ndarray, store: backup_kernel.AlphaStore | None = None,
                    ) -> torch.Tensor:  # fmt: skip
        """``(N,)`` bool: the alpha vectors ``(N, Y)`` to keep, those that win at some of the
        tree beliefs ``nodes`` and are not pointwise dominated.

        The quadratic dominance test runs only on the survivors of the cheap belief test
        (both keep the maximum at every tree belief). ``groups`` ``(N,)``: the observed value
        of each vector (None: one observed value); a vector competes only at beliefs of its
        own observed value. With ``store``, the same vectors' store as the compiled scoring
        reads it, and rows of float64 on the CPU, the compiled rule decides
        (:func:`~torchhrc.solvers.backup_kernel.keep_alphas`: the same winners, a vector
        apart only where it scores within rounding of a winner).
        """
        if store is not None and self._beliefs.dtype == torch.float64 and not self._beliefs.is_cuda:
            return torch.from_numpy(backup_kernel.keep_alphas(
                store.kernel, store.vectors, store.gid, store.gn, store.observed,
                self.beliefs_np, nodes, self.x[nodes]))  # fmt: skip
        dev = self._beliefs.device
        bgroups = None
        if groups is not None:
            bgroups = torch.from_numpy(self.x[nodes]).to(dev)
        rows = torch.from_numpy(nodes).to(dev)
        keep = prune_by_beliefs(vectors, self.beliefs, groups, bgroups, rows=rows)
        idx = keep.nonzero().squeeze(-1)
        keep[idx] = prune_dominated(vectors[idx], None if groups is None else groups[idx])
        return keep


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

    def node_bytes(self) -> int:
        """:meth:`BeliefTree.node_bytes` without a belief row: a support is its node's own
        array, not part of the storage a doubling copies."""
        return self._scalar_bytes()

    def _set_belief(self, n: int, belief: torch.Tensor | np.ndarray) -> None:
        row = belief if isinstance(belief, np.ndarray) else belief.detach().cpu().numpy()
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

    def keep_alphas(self, vectors: torch.Tensor, groups: torch.Tensor | None,
                    nodes: np.ndarray, store: backup_kernel.AlphaStore | None = None,
                    ) -> torch.Tensor:  # fmt: skip
        """``(N,)`` bool: the vectors that win at some tree belief of ``nodes`` (a sparse
        ``(M, S) x (S, N)`` product, by blocks; flat, so ``groups`` is unused, and the
        compiled rule, which reads dense rows, too: ``store``).

        The pointwise-dominance test is skipped: it costs ``N^2 S`` comparisons (large ``S``
        is why this storage exists), and a dominated vector never wins at a belief unless tied.
        """
        N, M = vectors.shape[0], len(nodes)
        keep = torch.zeros(N, dtype=torch.bool)
        if not M or not N:
            return keep
        # the vectors as columns a block at a time (2^18 entries, 2 MB; a whole transposed
        # copy is as large as the vectors: 200 MB at 1,300 vectors of 20,000 states), each
        # belief's first maximum over the blocks as an argmax over all. Blocks of 16 MB left
        # up to 120 MB more resident after each pruning of the 20,000-state model's vectors
        # (freed heap that glibc kept), and took twice as long
        cols = max(1, min(N, _GATHER_ELEMENTS // max(1, vectors.shape[1])))
        step = max(1, _GATHER_ELEMENTS // cols)  # (m, cols) scores a block at once
        csr = [self.csr(nodes[start : start + step]) for start in range(0, M, step)]
        dtype = csr[0].dtype  # the beliefs' (narrower vectors are scored in it, a block at a time)
        best_v = torch.full((M,), -torch.inf, dtype=dtype)
        best_i = torch.zeros(M, dtype=torch.long)
        for j in range(0, N, cols):
            vt = vectors[j : j + cols].T.to(dtype).contiguous()
            for start, rows in zip(range(0, M, step), csr):
                v, i = (rows @ vt).max(-1)
                sl = slice(start, start + v.shape[0])
                up = v > best_v[sl]  # ties stay with the earlier block (the first maximum)
                best_v[sl] = torch.where(up, v, best_v[sl])
                best_i[sl] = torch.where(up, i + j, best_i[sl])
        keep[best_i] = True
        return keep

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
