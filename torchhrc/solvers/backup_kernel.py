"""Compiled steps of SARSOP's one-belief evaluation (CPU, float64).

A backup of one belief on the CPU is about a hundred numpy calls of one to three
microseconds each on the small models of the public suite (tiger, 4x3, aloha-10max,
bridge-repair): the arithmetic is a fraction of it. These steps are compiled (``_backup.c``,
built by ``pip install`` beside the sawtooth loop, the CPython API only):

* :func:`children`: the children of one belief of a dense model (flat, ``J[a, o] =
  (b T[a]) * Z[a, :, o]``, or a MOMDP's, at each reachable ``x2``), their probabilities, the
  possible ones packed first, and the expected rewards ``R(b, a)`` (the numpy reference:
  :meth:`~torchhrc.solvers.forms.base.SolverModel.children_np`).
* :func:`group_scores`: the best alpha vector at each child, against the vectors of the
  child's own observed value ``x`` only (a MOMDP's children lie at several; the numpy
  reference, ``_SARSOP._lower_np``, scores them in one product against the vectors of every
  ``x`` among them and masks the others out: twenty times the arithmetic on a 20-position
  random MOMDP). It reads the vectors' one store, their rows, through each ``x``'s indices.
  With one observed value the lower bounds stay one BLAS product; for beliefs given on a
  few columns, :func:`gather_columns` gathers its operand from the rows.
* :func:`bound_children`: from the children's lower bounds, every child's bounds and
  ``Q_low``, ``Q_up``, with the sawtooth upper bound evaluated lazily: only the children of
  the action with the highest cached ``Q_up`` are re-bounded until the best action is one
  just refreshed, each child at its own ``x``'s points (the numpy reference:
  ``_SARSOP._upper_np``, APPL's ``getNewUBValueUseCache``).
* :func:`group_upper`: the sawtooth upper bound of rows, each at its own ``x``'s points (the
  numpy reference: the per-``x`` loop of
  :meth:`~torchhrc.solvers.upper_bound.SawtoothUpperBound.value_np`).

The algorithm is the same; the floats are not always bit-identical to the numpy path, whose
sums are BLAS's and numpy's pairwise ones where these are sequential (they agree to about
``1e-15`` relative; a near tie may then go the other way, so a long solve can take another
path). ``TORCHHRC_NO_EXTENSION=1`` (read when a solver form or a solve is set up) selects the
numpy path, as it selects the Python sawtooth loop; the tests compare both.

Example:
    >>> import numpy as np
    >>> kernel = load()
    >>> if kernel is not None:  # one state, one action, one observation: J = b, P = 1
    ...     rows, prob = np.empty((2, 1)), np.empty(1)
    ...     rows_x, nz = np.empty(2, dtype=np.int64), np.empty(1, dtype=np.int64)
    ...     one, reward = np.ones((1, 1, 1, 1)), np.empty(1)
    ...     m = children(kernel, np.ones(1), np.empty((0, 0, 0)), one, one,
    ...                  np.full((1, 1), 2.0), np.zeros(1, dtype=np.int64), rows, rows_x, prob,
    ...                  nz, reward, 0)
    ...     assert (m, float(prob[0]), float(reward[0])) == (1, 1.0, 2.0)
"""

from __future__ import annotations

import os
from types import ModuleType
from typing import Any

import numpy as np

__all__ = ["bound_children", "children", "gather_columns", "group_scores", "group_upper", "load"]


def load() -> ModuleType | None:
    """The compiled module, or ``None`` when it is not built or ``TORCHHRC_NO_EXTENSION`` is
    set (the callers then take their numpy path; the sawtooth kernel warns once that the
    extensions are missing)."""
    if os.environ.get("TORCHHRC_NO_EXTENSION", "") not in ("", "0"):
        return None
    try:
        import torchhrc.solvers._backup as _backup
    except ImportError:
        return None
    return _backup


def children(
    kernel: ModuleType,
    b: np.ndarray,
    tx: np.ndarray,
    tyk: np.ndarray,
    z: np.ndarray,
    RT: np.ndarray,
    cx: np.ndarray,
    rows: np.ndarray,
    rows_x: np.ndarray,
    prob: np.ndarray,
    nz: np.ndarray,
    reward: np.ndarray,
    x: int,
) -> int:
    """The children of one belief ``b (Y,)`` at ``x`` of a dense model, written in place::

        J[a, k, o, y2] = (sum_y b[y] tx[a, y, k] tyk[a, k, y, y2]) Z[a, x2_k, y2, o]

    (a flat model: ``K = 1``, no ``tx``, ``tyk = T``; a static hidden value: no ``tyk``).

    Args:
        kernel: the module of :func:`load`.
        b: ``(Y,)`` float64 belief. tx: ``(A, Y, K)`` ``Tx[a, x, y, x2_k]`` or empty
            ``(0, 0, 0)``. tyk: ``(A, K, Y, Y)`` ``Ty[a, x, y, x2_k, y2]`` or empty
            ``(0, 0, 0, 0)`` (not both empty). z: ``(A, K, O, Y)`` ``Z[a, x2_k, y2, o]``
            transposed. RT: ``(Y, A)`` rewards at ``x``. cx: ``(A K O,)`` int64 each child's
            observed value. All C-contiguous.
        rows: ``(A K O + 1, Y)`` written: the ``m`` possible unnormalised children
            (``P > 0``) in ``(a, k, o)`` order, then ``b`` (rows past ``m + 1`` are scratch).
        rows_x: ``(A K O + 1,)`` int64 written: their observed values (``x`` for ``b``).
        prob: ``(A K O,)`` written: ``P(x2_k, o | b, a)`` of every child.
        nz: ``(A K O,)`` int64 written: the first ``m`` are the possible children's indices.
        reward: ``(A,)`` written: ``R(b, a)``.
        x: the belief's observed value.

    Returns:
        ``m``, the number of possible children.

    Raises:
        TypeError: an array of another dtype, rank, or not C-contiguous (named).
        ValueError: shapes that do not agree.
    """
    return int(kernel.children(b, tx, tyk, z, RT, cx, rows, rows_x, prob, nz, reward, x))


def bound_children(
    kernel: ModuleType,
    rows: np.ndarray,
    rows_x: np.ndarray,
    nz: np.ndarray,
    low_r: np.ndarray,
    best_r: np.ndarray,
    reward: np.ndarray,
    gamma: float,
    stale: tuple[np.ndarray, np.ndarray] | None,
    sawtooth: tuple[Any, ...],
    num_children: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Every child's bounds and the belief's ``Q`` values (see the module docstring).

    Args:
        kernel: the module of :func:`load`.
        rows: ``(m + 1, S)`` the possible children, then the belief ``b`` itself.
        rows_x: ``(m + 1,)`` int64 their observed values (all 0 with one observed value).
        nz: ``(m,)`` int64 increasing indices of the possible children among the ``C``.
        low_r: ``(m + 1,)`` the rows' lower bounds; best_r: ``(m + 1,)`` int64 their best
            alpha vectors.
        reward: ``(A,)`` ``R(b, a)``; the ``C`` children are ``C / A`` per action, in order.
        gamma: the discount.
        stale: ``(Q_up (A,), up (C,))`` of the belief's last evaluation (their values stay
            upper bounds), or ``None``: every possible child is bounded.
        sawtooth: ``(corner (X, S), sorted, idx, inv, off, wid, gain, sig)`` of the upper
            bound, ``sorted`` built for every ``x`` of ``rows_x``
            (:meth:`~torchhrc.solvers.upper_bound.SawtoothUpperBound.loop_storage`).
        num_children: ``C``.

    Returns:
        ``low (C,)``, ``best (C,)`` int64 (0 at impossible children), ``q_low (A,)``,
        ``up (C,)``, ``q_up (A,)`` and ``V_up(b)``.
    """
    A = reward.shape[0]
    low = np.empty(num_children)
    best = np.empty(num_children, dtype=np.int64)
    up = np.empty(num_children)
    q_low, q_up = np.empty(A), np.empty(A)
    sq, su = stale if stale is not None else (_EMPTY, _EMPTY)
    cu = kernel.bound_children(rows, rows_x, nz, low_r, best_r, reward, sq, su, *sawtooth,
                               low, best, q_low, up, q_up, float(gamma))  # fmt: skip
    return low, best, q_low, up, q_up, float(cu)


def group_scores(
    kernel: ModuleType,
    rows: np.ndarray,
    rows_x: np.ndarray,
    vectors: np.ndarray,
    gid: list[np.ndarray],
    gn: np.ndarray,
    cols: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``max_n rows[i] . V_n`` over the vectors ``n`` of row ``i``'s own observed value, and
    the argmax (the first maximum in group order, as ``numpy.argmax``).

    Each score is summed over the row's support in column order, reading each vector's row
    of ``vectors`` there (the one store of the alpha vectors: a backup reads whole rows).

    Args:
        kernel: the module of :func:`load`.
        rows: ``(B, W)`` C-contiguous float64 (unnormalised) beliefs, or ``(1, W)``: one
            belief, scored under each observed value of ``rows_x``.
        rows_x: ``(B,)`` int64 the rows' observed values.
        vectors: ``(N, Y)`` C-contiguous float64 the alpha vectors (``_AlphaSet``'s storage).
        gid: per observed value ``x``, ``(cap_x,)`` int64 the indices of its vectors.
        gn: ``(X,)`` int64 the vectors in use per group (at least one where a row needs it).
        cols: ``(W,)`` int64 the columns of ``vectors`` the rows are given on (a sparse
            belief's support), or ``None``: ``W = Y``, every column.

    Returns:
        ``(B,)`` the best scores and ``(B,)`` int64 the indices of the vectors.

    Raises:
        TypeError: an array of another dtype or rank, not C-contiguous, or ``gid`` not a
            list (named).
        ValueError: shapes that do not agree, a group without vectors, or an index out of
            range.
        IndexError: an observed value outside ``[0, X)``.
    """
    B = rows_x.shape[0]
    val = np.empty(B)
    best = np.empty(B, dtype=np.int64)
    kernel.group_scores(rows, rows_x, vectors, _NO_COLS if cols is None else cols, gid, gn, val,
                        best)  # fmt: skip
    return val, best


def gather_columns(kernel: ModuleType, vectors: np.ndarray, n: int, cols: np.ndarray,
                   ) -> np.ndarray:  # fmt: skip
    """``(c, n)`` C-contiguous ``vectors[:n, cols].T``: the columns ``cols (c,)`` int64 of the
    first ``n`` rows of ``vectors (N, Y)`` (C-contiguous float64), read row by row.

    Raises:
        TypeError: an array of another dtype or rank, or not C-contiguous (named).
        ValueError: ``n`` above ``N`` or a column outside ``[0, Y)``.
    """
    out = np.empty((cols.shape[0], n))
    kernel.gather_columns(vectors, cols.astype(np.int64, copy=False), out)
    return out


def group_upper(
    kernel: ModuleType,
    rows: np.ndarray,
    rows_x: np.ndarray,
    sawtooth: tuple[Any, ...],
    out: np.ndarray,
) -> None:
    """The sawtooth upper bound ``corner[x] . b + correction`` of each row at its own ``x``,
    written into ``out (B,)``.

    Args:
        kernel: the module of :func:`load`.
        rows: ``(B, Y)`` C-contiguous float64 non-negative weights; rows_x: ``(B,)`` int64.
        sawtooth: ``(corner (X, Y), sorted, idx, inv, off, wid, gain, sig)``: the corner
            values, per observed value ``(order (P_x,) int64, key (P_x,) float64)`` (its points
            with a negative gain by increasing key, built for every ``x`` of ``rows_x``), and
            the points' storage as
            :func:`~torchhrc.solvers.sawtooth_kernel.sawtooth_corrections` (``sig`` the
            support signatures, or empty: no point skipped)
            (:meth:`~torchhrc.solvers.upper_bound.SawtoothUpperBound.loop_storage`).
        out: ``(B,)`` float64, written.

    Raises:
        TypeError: an array of another dtype or rank, not C-contiguous, or an entry of
            ``sorted`` that is not a pair (named).
        ValueError: shapes that do not agree. IndexError: an observed value or a point out
            of range.
    """
    corner, sorted_points, idx, inv, off, wid, gain, sig = sawtooth
    kernel.group_upper(rows, rows_x, corner, sorted_points, idx, inv, off, wid, gain, sig, out)


_EMPTY = np.empty(0)
_NO_COLS = np.empty(0, dtype=np.int64)
