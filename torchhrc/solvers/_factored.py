"""Tensor kernels shared by the bound computations (internal): flat and MOMDP expectations.

Flat::

    expect(T, V)[..., a, s]    = sum_s2 T[..., a, s, s2] V[..., s2]           V: (..., S)
    expect(T, V, per_action)   = sum_s2 T[..., a, s, s2] V[..., a, s2]        V: (..., A, S)

MOMDP (Ong et al. 2010), never forming the flat ``(X Y) x (X Y)`` matrix::

    expect(Tx, Ty, V)[..., a, x, y] = sum_{x2, y2} Tx[..., a, x, y, x2] Ty[..., a, x, y, x2, y2]
                                      V[..., x2, y2]                         V: (..., X, Y)

with ``Ty = None`` (static hidden value) reducing to ``sum_x2 Tx[..., a, x, y, x2] V[..., x2, y]``.

An unbatched model whose operator is sparse (deterministic moves, a few successors per
state: RockSample, the hand-finishing task, Tag) is stored row-sparse (:class:`RowSparse`,
built from the nonzeros of ``Tx`` and the ``Ty`` rows they select, never forming the dense
``Tx * Ty``), so an expectation costs ``O(nnz)``; the bounds then iterate it instead of a
dense LU (:data:`SPARSE_DIRECT_SOLVE_SIZE`).

The kernels learn a model's layout in one place, :func:`state_dims` (its type looked up in
a table, as :func:`~torchhrc.solvers.forms.as_solver_model` picks a form): 1 for a flat
model's values ``(S,)``, 2 for a MOMDP's ``(X, Y)``; they never test a model's class.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from torchhrc._checks import broadcast_shapes
from torchhrc.pomdp import MOMDP, POMDP

__all__: list[str] = []


#: the relative round-off below which the bracket of MacQueen (1966) around a value
#: iteration's fixed point stops shrinking: the iterates' differences carry about this much
#: error relative to the values, and the bracket multiplies them by ``discount / (1 -
#: discount)`` (:func:`~torchhrc.solvers.qmdp.mdp_q_values` stops there when its tolerance
#: lies below it)
BRACKET_ROUND_OFF = 16.0 * float(torch.finfo(torch.float64).eps)


def bracket_slack(weight: float) -> float:
    """``k = w / (1 - w)``, the factor of the bracket of MacQueen (1966) around the fixed point
    of a monotone operator whose weight on a constant is ``w`` (``F(v + c) - F(v) = w c``:
    the discount times a row's sum of probabilities); ``inf`` (no bracket) unless
    ``0 <= w < 1``.

    Example:
        >>> bracket_slack(0.95), bracket_slack(1.0)
        (18.999999999999982, inf)
    """
    return weight / (1.0 - weight) if 0.0 <= weight < 1.0 else math.inf


def flat_expect(T: torch.Tensor, V: torch.Tensor, *, per_action: bool = False) -> torch.Tensor:
    """``(..., A, S)`` expected next values under ``T (..., A, S, S)``."""
    if per_action:
        return (T @ V.unsqueeze(-1)).squeeze(-1)
    return (T @ V.unsqueeze(-2).unsqueeze(-1)).squeeze(-1)


#: Largest system solved directly by :meth:`Expectation.solve_fixed_point` (states per system).
DIRECT_SOLVE_SIZE = 2048
#: Largest system solved directly when the operator is sparse (above it, iterating the sparse
#: product is far cheaper than a dense LU).
SPARSE_DIRECT_SOLVE_SIZE = 256


def _batched_solve(lhs: torch.Tensor, rhs: torch.Tensor) -> torch.Tensor:
    """``torch.linalg.solve(lhs (..., n, n), rhs (..., n, 1))``.

    On the CPU without autograd, by numpy's LAPACK (``numpy.linalg.solve``, the same LU with
    partial pivoting): a process's first ``torch.linalg.solve`` touches pages of libtorch's
    code that nothing else of a small model's SARSOP solve needs (Tiger's net peak 14.5 ->
    13.5 MB; docs/benchmarks.md, "One record a belief, ..."). Otherwise one system
    at a time on a multi-threaded CPU: torch 2.13's batched LU (MKL) with 2 or more threads
    returns invalid pivots for ``n`` above about 150 (``lu_solve`` then raises; found by the
    2-thread rerun of ``.ci/run``); a single system is factored correctly."""
    batch = lhs.shape[:-2]
    cpu = lhs.device.type == "cpu" and rhs.device.type == "cpu"
    if cpu and not (lhs.requires_grad or rhs.requires_grad) and lhs.dtype == rhs.dtype \
            and lhs.dtype in (torch.float32, torch.float64):  # fmt: skip
        try:
            out = np.linalg.solve(lhs.numpy(), rhs.numpy())
        except np.linalg.LinAlgError as e:  # torch's error for a singular system
            raise torch.linalg.LinAlgError(str(e)) from None
        return torch.from_numpy(out)
    if not cpu or torch.get_num_threads() < 2 or math.prod(batch) < 2:
        return torch.linalg.solve(lhs, rhs)
    n = lhs.shape[-1]
    flat_l, flat_r = lhs.reshape(-1, n, n), rhs.reshape(-1, n, rhs.shape[-1])
    out = [torch.linalg.solve(flat_l[i], flat_r[i]) for i in range(flat_l.shape[0])]
    return torch.stack(out).reshape(*batch, n, rhs.shape[-1])


class RowSparse:
    """A ``(R, C)`` matrix with few nonzeros per row, stored padded per row (ELL format).

    ``cols: (W, R)`` column indices and ``vals: (W, R)`` values (slot-major, so the sum over
    slots runs over the leading dim), rows padded with column 0 and value 0 to the widest row
    ``W``; a product ``M @ v`` is one ``index_select``, one multiply and one sum over ``W``, on
    any device (torch's CSR product is slower at these sizes on CPU).

    Args:
        rows, cols, vals: ``(nnz,)`` coordinates (``rows`` sorted ascending) and values.
        shape: ``(R, C)``.
    """

    def __init__(self, rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor,
                 shape: tuple[int, int]) -> None:  # fmt: skip
        R, C = shape
        self.shape = (int(R), int(C))
        counts = torch.bincount(rows, minlength=R)  # (R,)
        W = int(counts.max()) if rows.numel() else 1
        starts = torch.cumsum(counts, 0) - counts
        pos = torch.arange(rows.numel(), device=rows.device) - starts[rows]
        W = max(W, 1)
        self.cols = torch.zeros(W, R, dtype=torch.long, device=rows.device)
        self.vals = vals.new_zeros(W, R)
        self.cols[pos, rows] = cols
        self.vals[pos, rows] = vals
        self._flat_cols = self.cols.reshape(-1)
        self.nnz = int(rows.numel())

    def __matmul__(self, v: torch.Tensor) -> torch.Tensor:
        """``(R,)`` for ``v (C,)``; ``(R, m)`` for ``v (C, m)``."""
        W, R = self.cols.shape
        g = v.index_select(0, self._flat_cols)  # (W R,) or (W R, m)
        if v.dim() == 1:
            return (self.vals * g.view(W, R)).sum(0)
        return (self.vals.unsqueeze(-1) * g.view(W, R, -1)).sum(0)


def _worth_sparse(nnz_rows_max: int, rows: int, cols: int) -> bool:
    """ELL pays when the padded size is well below the dense one (and the matrix is not tiny)."""
    return rows * cols >= 4096 and 4 * nnz_rows_max * rows <= rows * cols


class Expectation:
    """The transition operator of a POMDP or MOMDP, prepared once for repeated use.

    Flat: ``T (..., A, S, S)``. Static MOMDP: ``Tx`` permuted to ``(..., A, Y, X, X2)`` so an
    expectation is one batched matmul per hidden value. General MOMDP: ``Tx * Ty`` flattened
    to ``(..., A, X Y, X2 Y2)`` (the size of ``Ty`` itself), then as flat. An unbatched
    model with a sparse operator keeps ``sparse``: the operator and its per-action form as
    :class:`RowSparse` matrices with rows ``(a, s)`` / ``(a, x, y)`` (``matrix`` is then
    only built for a small direct solve).
    """

    def __init__(self, model: POMDP | MOMDP) -> None:
        self.momdp = state_dims(model) == 2
        self.sparse: tuple[RowSparse, RowSparse] | None = None
        if not self.momdp:
            self.kind = "flat"
            self.matrix = model.T  # (..., A, S, S)
            if model.T.dim() == 3:
                self.sparse = _sparse_flat(model.T)
                self.A = model.T.shape[0]
            return
        X, Y = model.num_observed, model.num_hidden
        self.X, self.Y = X, Y
        unbatched = model.Tx.dim() == 4
        if model.Ty is None:
            self.kind = "static"
            if unbatched:
                self.sparse = _sparse_static(model.Tx)
            if self.sparse is None:
                self.matrix = model.Tx.transpose(-3, -2).contiguous()  # (..., A, Y, X, X2)
        else:
            self.kind = "joint"
            if unbatched:
                self.sparse = _sparse_joint(model.Tx, model.Ty)
            if self.sparse is None:
                P = model.Tx.unsqueeze(-1) * model.Ty  # (..., A, X, Y, X2, Y2)
                self.matrix = P.reshape(*P.shape[:-4], X * Y, X * Y)
        if self.sparse is not None:
            self.A = model.Tx.shape[0]

    def __call__(self, V: torch.Tensor, *, per_action: bool = False) -> torch.Tensor:
        """Expected next values: ``V`` is ``(..., S)`` / ``(..., X, Y)``, or per action."""
        if self.sparse is not None:
            # unbatched model: one row-sparse product, rows (a, s) or (a, x, y); batch dims of
            # V (if any) become the columns of the right-hand side
            M = self.sparse[1 if per_action else 0]
            state = (-1,) if self.kind == "flat" else (self.X, self.Y)
            lead = V.shape[: V.dim() - len(state) - per_action]
            if not lead:
                return (M @ V.reshape(-1)).view(self.A, *state)
            out = M @ V.reshape(-1, M.shape[1]).T  # (R, batch)
            return out.T.reshape(*lead, self.A, *state)
        if self.kind == "flat":
            return flat_expect(self.matrix, V, per_action=per_action)
        if self.kind == "static":
            # V^T: (..., [A,] Y, X2) -> (..., A or 1, Y, X2, 1)
            Vt = V.transpose(-1, -2).unsqueeze(-1)
            if not per_action:
                Vt = Vt.unsqueeze(-4)
            return (self.matrix @ Vt).squeeze(-1).transpose(-1, -2)
        flat_V = V.reshape(*V.shape[:-2], self.X * self.Y)
        out = flat_expect(self.matrix, flat_V, per_action=per_action)
        return out.reshape(*out.shape[:-1], self.X, self.Y)

    def solve_fixed_point(self, R: torch.Tensor, discount: float) -> torch.Tensor | None:
        """Exact ``alpha_a = R_a + discount E_a alpha_a`` per action, or None if too large.

        ``R`` is ``(..., A, S)`` or ``(..., A, X, Y)``; solves ``(I - discount T_a) alpha_a =
        R_a`` by LU (for a static MOMDP one ``X x X`` system per action and hidden value).
        A sparse operator above :data:`SPARSE_DIRECT_SOLVE_SIZE` returns None (iterating it is
        cheaper than a dense LU).
        """
        if self.sparse is not None:
            n = self.X if self.kind == "static" else self.sparse[0].shape[1]
            if n > SPARSE_DIRECT_SOLVE_SIZE:
                return None
            self._densify()
        if self.kind == "static":
            n = self.X
            if n > DIRECT_SOLVE_SIZE:
                return None
            eye = torch.eye(n, dtype=self.matrix.dtype, device=self.matrix.device)
            rhs = R.transpose(-1, -2).unsqueeze(-1)  # (..., A, Y, X, 1)
            lhs = eye - discount * self.matrix
            batch = broadcast_shapes(lhs.shape[:-2], rhs.shape[:-2])
            out = _batched_solve(lhs.expand(*batch, n, n), rhs.expand(*batch, n, 1))
            return out.squeeze(-1).transpose(-1, -2)
        n = self.matrix.shape[-1]
        if n > DIRECT_SOLVE_SIZE:
            return None
        eye = torch.eye(n, dtype=self.matrix.dtype, device=self.matrix.device)
        flat_R = R if self.kind == "flat" else R.reshape(*R.shape[:-2], n)
        lhs = eye - discount * self.matrix
        rhs = flat_R.unsqueeze(-1)
        batch = broadcast_shapes(lhs.shape[:-2], rhs.shape[:-2])
        out = _batched_solve(lhs.expand(*batch, n, n), rhs.expand(*batch, n, 1)).squeeze(-1)
        return out if self.kind == "flat" else out.reshape(*out.shape[:-1], self.X, self.Y)

    def _densify(self) -> None:
        """Give a sparse operator its dense ``matrix`` too (for a direct solve)."""
        if hasattr(self, "matrix"):
            return
        M = self.sparse[0]  # type: ignore[index]
        dense = M.vals.new_zeros(M.shape[0], M.shape[1])
        dense.scatter_add_(1, M.cols.T, M.vals.T)  # padding adds 0 to column 0
        if self.kind == "flat":
            self.matrix = dense.view(self.A, -1, M.shape[1])
        elif self.kind == "static":  # rows (a, x, y), columns (x2, y) -> (A, Y, X, X2)
            d = dense.view(self.A, self.X, self.Y, self.X, self.Y)
            self.matrix = torch.diagonal(d, dim1=2, dim2=4).permute(0, 3, 1, 2).contiguous()
        else:
            self.matrix = dense.view(self.A, self.X * self.Y, self.X * self.Y)


def _ell(rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor, R: int, C: int,
         A: int) -> tuple[RowSparse, RowSparse] | None:  # fmt: skip
    """The operator and its per-action form (columns offset by ``a * C``), or None if dense.

    ``rows`` index ``(a, state)`` (``R = A * n`` rows, ``a = rows // n``), ``cols`` the next
    state in ``[0, C)``, sorted by row.
    """
    counts = torch.bincount(rows, minlength=R)
    if not _worth_sparse(int(counts.max()) if rows.numel() else 0, R, C):
        return None
    a = rows // (R // A)
    return RowSparse(rows, cols, vals, (R, C)), RowSparse(rows, cols + a * C, vals, (R, A * C))


def _sparse_flat(T: torch.Tensor) -> tuple[RowSparse, RowSparse] | None:
    """``T (A, S, S)``: rows ``(a, s)``, columns ``s2``."""
    A, S, _ = T.shape
    nz = T.reshape(A * S, S).nonzero()  # (nnz, 2), sorted by row
    vals = T.reshape(A * S, S)[nz[:, 0], nz[:, 1]]
    return _ell(nz[:, 0], nz[:, 1], vals, A * S, S, A)


def _sparse_static(Tx: torch.Tensor) -> tuple[RowSparse, RowSparse] | None:
    """``Tx (A, X, Y, X2)``, static ``y``: rows ``(a, x, y)``, columns ``(x2, y)``."""
    A, X, Y, _ = Tx.shape
    flat = Tx.reshape(A * X * Y, X)
    nz = flat.nonzero()  # (nnz, 2): row (a, x, y), x2
    vals = flat[nz[:, 0], nz[:, 1]]
    return _ell(nz[:, 0], nz[:, 1] * Y + nz[:, 0] % Y, vals, A * X * Y, X * Y, A)


def _sparse_joint(Tx: torch.Tensor, Ty: torch.Tensor) -> tuple[RowSparse, RowSparse] | None:
    """``Tx (A, X, Y, X2)``, ``Ty (A, X, Y, X2, Y2)``: rows ``(a, x, y)``, columns ``(x2, y2)``.

    Built from the nonzeros of ``Tx`` and the ``Ty`` rows they select, never forming the
    dense ``Tx * Ty``.
    """
    A, X, Y, _ = Tx.shape
    flat = Tx.reshape(A * X * Y, X)
    nz = flat.nonzero()  # (m, 2)
    tx = flat[nz[:, 0], nz[:, 1]]  # (m,)
    ty = Ty.reshape(A * X * Y, X, Y)[nz[:, 0], nz[:, 1]]  # (m, Y2)
    P = tx.unsqueeze(-1) * ty  # (m, Y2)
    e, y2 = P.nonzero().unbind(-1)  # sorted by e, hence by row
    return _ell(nz[e, 0], nz[e, 1] * Y + y2, P[e, y2], A * X * Y, X * Y, A)


def momdp_expect(
    Tx: torch.Tensor, Ty: torch.Tensor | None, V: torch.Tensor, *, per_action: bool = False
) -> torch.Tensor:
    """``(..., A, X, Y)`` expected next values by einsum (the reference form)."""
    if Ty is None:
        if per_action:  # V: (..., A, X2, Y)
            return torch.einsum("...axyz,...azy->...axy", Tx, V)
        return torch.einsum("...axyz,...zy->...axy", Tx, V)
    if per_action:
        return torch.einsum("...axyz,...axyzw,...azw->...axy", Tx, Ty, V)
    return torch.einsum("...axyz,...axyzw,...zw->...axy", Tx, Ty, V)


def expect(model: POMDP | MOMDP, V: torch.Tensor, *, per_action: bool = False) -> torch.Tensor:
    """Expected next values for either model kind (see the module docstring)."""
    if state_dims(model) == 2:
        return momdp_expect(model.Tx, model.Ty, V, per_action=per_action)
    return flat_expect(model.T, V, per_action=per_action)


#: the number of trailing state dims of a tensor model's values, by the model's type
_STATE_DIMS: dict[type, int] = {POMDP: 1, MOMDP: 2}


def state_dims(model: object) -> int:
    """Number of trailing state dims of a value tensor: 1 (S) or 2 (X, Y).

    The one place the tensor kernels learn a model's layout (its type, or a base of it, looked
    up in ``_STATE_DIMS``).

    Raises:
        TypeError: ``model`` is no tensor model (a POMDP or MOMDP).

    Example:
        >>> from torchhrc.testing import random_momdp, random_pomdp
        >>> state_dims(random_pomdp(3, 2, 2, seed=0)), state_dims(random_momdp(3, 2, 2, 2, seed=0))
        (1, 2)
    """
    for cls in type(model).__mro__:
        dims = _STATE_DIMS.get(cls)
        if dims is not None:
            return dims
    raise TypeError(f"expected model to be a POMDP or MOMDP, got {type(model).__name__}")


def reward_bounds(model: POMDP | MOMDP) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-problem ``(min R, max R)``, each of shape ``batch_shape``."""
    R = model.R
    flat = R.reshape(*R.shape[: R.dim() - 1 - state_dims(model)], -1)
    return flat.amin(-1), flat.amax(-1)


def check_model(model: object) -> POMDP | MOMDP:
    """Raise TypeError unless ``model`` is a POMDP or MOMDP (:func:`state_dims` knows it)."""
    state_dims(model)
    return model  # type: ignore[return-value]


def check_unit_discount(model: POMDP | MOMDP, what: str) -> None:
    """The infinite-horizon bounds need discount < 1."""
    from torchhrc.errors import ModelError

    if model.discount >= 1.0:
        raise ModelError(f"{what} needs discount < 1, got {model.discount}")
