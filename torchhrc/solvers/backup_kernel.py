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
* :func:`backup_one`: the steps of one backup of a dense model's belief in one call: its
  children, their lower bounds (each against its own ``x``'s vectors, as
  :func:`group_scores`), :func:`bound_children`, and the new alpha vector of the action of
  highest ``Q_low`` (``backup_vector``; an impossible child takes the best vector of its
  ``x2`` at the belief itself). Each of the separate calls above cost about as much in
  argument handling and numpy glue as its arithmetic on the small models; the numpy
  references are those of the separate steps (``_SARSOP._evaluate_np``, ``_backup_one_np``).
* ``add_point`` (the module's, called by
  :meth:`~torchhrc.solvers.upper_bound.SawtoothUpperBound.add_np` itself): one new sawtooth
  point stored, its support, gain, mass and signature written, its ``x``'s member list
  extended and the point put into ``x``'s key order in place (its numpy reference: the same
  method's steps, about twenty numpy calls: 30 us a point on bridge-repair, 9 us now; the
  arguments in ``_backup.c``'s header).
* ``trial_step`` (the module's, called by the trial, ``_SARSOP.sample``): a trial's choice at
  a node from its cached evaluation record (``trial_step(record, A, O, target)``), the
  largest ``Q_low``, the first action of largest ``Q_up`` and how many tie with it, and its
  child of largest excess gap (its numpy and Python reference: ``_Trials._argmax_tie`` and
  ``_child_choice``; equal actions that the seeded generator draws among go that way).

* :func:`keep_alphas` and :func:`dominated`: SARSOP's pruning of the alpha vectors, those
  that win at no tree belief and those another vector of their ``x`` dominates pointwise,
  over the vectors' one store (the references: :func:`~torchhrc.solvers.pruning.\
prune_by_beliefs` and :func:`~torchhrc.solvers.pruning.prune_dominated`, the same masks but
  at near ties of the winners' scores, which these sum in support order; tiger's pruning
  took 250 us an iteration in torch calls, a quarter of its solve).

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
from typing import Any, NamedTuple

import numpy as np

from torchhrc.solvers.eval_cache import unpack

__all__ = [
    "Backup",
    "backup_one",
    "bound_children",
    "children",
    "dominated",
    "gather_columns",
    "group_scores",
    "group_upper",
    "keep_alphas",
    "load",
    "new_scratch",
]


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


class Backup(NamedTuple):
    """What :func:`backup_one` gives for a belief ``b`` at ``x`` (``C = A K O`` children)."""

    record: np.ndarray  # (2 A + 3 C,) the evaluation (eval_cache.pack's layout)
    best: np.ndarray  # (C,) int64 the best vector at each possible child, 0 elsewhere
    lower: float  # V_low(b)
    upper: float  # V_up(b)
    child_x: np.ndarray  # (C,) int64 each child's observed value
    own: int  # the best vector at b itself
    action: int  # the action of highest Q_low (-1 without the vector)
    vector: np.ndarray | None  # (Y,) its new alpha vector (None: not asked for)
    value: float  # vector . b (NaN without the vector)
    shape: tuple[int, int, int]  # (A, K, O)

    @property
    def q_low(self) -> np.ndarray:
        """``(A,)`` ``Q_low(b, a)`` (a view of the record)."""
        return self.record[: self.shape[0]]

    @property
    def q_up(self) -> np.ndarray:
        """``(A,)`` ``Q_up(b, a)``."""
        return self.record[self.shape[0] : 2 * self.shape[0]]

    @property
    def prob(self) -> np.ndarray:
        """``(A, K, O)`` ``P(x2_k, o | b, a)``."""
        return unpack(self.record, self.shape[0], self.shape[2])[2]

    @property
    def low(self) -> np.ndarray:
        """``(A, K, O)`` ``P * V_low(child)``, 0 where impossible."""
        return unpack(self.record, self.shape[0], self.shape[2])[3]

    @property
    def up(self) -> np.ndarray:
        """``(A, K, O)`` ``P * V_up(child)``."""
        return unpack(self.record, self.shape[0], self.shape[2])[4]


def backup_one(
    kernel: ModuleType,
    b: np.ndarray,
    x: int,
    tables: tuple[np.ndarray, ...],
    scoring: tuple[np.ndarray, list[np.ndarray], np.ndarray],
    sawtooth: tuple[Any, ...],
    stale: np.ndarray | None,
    gamma: float,
    vector: bool = True,
    scratch: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> Backup:
    """One belief of a dense model evaluated, and backed up, in one compiled call.

    The same steps as :func:`children`, :func:`group_scores` on the children and ``b``,
    :func:`bound_children` and, with ``vector``, the new alpha vector ``R[a, x] + gamma
    sum_k Tx (Ty (sum_o Z alpha_{k, o}))`` of the action ``a`` of highest ``Q_low`` (the
    first), where ``alpha_{k, o}`` is the best vector at child ``(x2_k, o)``, or at an
    impossible child the best vector of ``x2_k`` at ``b`` itself (APPL's
    ``BackupAlphaPlaneMOMDP::getNewAlphaPlaneQ``). The evaluation is written as one record
    (:func:`~torchhrc.solvers.eval_cache.pack`'s layout), the form the search caches.

    Args:
        kernel: the module of :func:`load`.
        b: ``(Y,)`` float64 C-contiguous belief at observed value ``x``.
        tables: ``(tx, tyk, z, RT, cx)`` at ``x``, as :func:`children` takes them
            (:meth:`~torchhrc.solvers.forms.base.SolverModel.compiled_tables`).
        scoring: ``(vectors (cap, Y), gid, gn)`` the alpha vectors as :func:`group_scores`
            reads them (``_AlphaSet.scoring_storage``).
        sawtooth: the upper bound as :func:`bound_children` reads it, ``sorted`` built for
            ``x`` and every ``x2`` it reaches.
        stale: the record ``(2 A + 3 A K O,)`` of the belief's last evaluation (its ``Q_up``
            and children's upper bounds stay upper bounds), or ``None``.
        gamma: the discount.
        vector: whether to form the new vector (a backup) or only bound (a trial's step).
        scratch: :func:`new_scratch` ``(C, Y)``, reused between calls (the children's rows
            and indices, read within the call only), or ``None``: allocated here.

    Returns:
        :class:`Backup`.

    Raises:
        TypeError: an array of another dtype, rank, or not C-contiguous (named).
        ValueError: shapes that do not agree, or a group without vectors.
        IndexError: an observed value or a sawtooth point out of range.

    Example:
        >>> kernel = load()
        >>> if kernel is not None:  # one state, action and observation; R = 2, gamma 0.5
        ...     one = np.ones((1, 1, 1, 1))
        ...     tables = (np.empty((0, 0, 0)), one, one, np.full((1, 1), 2.0),
        ...               np.zeros(1, dtype=np.int64))
        ...     scoring = (np.full((1, 1), 3.0), [np.zeros(1, dtype=np.int64)],
        ...                np.ones(1, dtype=np.int64))
        ...     empty_i, empty_d = np.empty(0, dtype=np.int64), np.empty(0)
        ...     saw = (np.full((1, 1), 4.0), [(empty_i, empty_d)], empty_i, empty_d,
        ...            np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(1),
        ...            empty_i)
        ...     out = backup_one(kernel, np.ones(1), 0, tables, scoring, saw, None, 0.5)
        ...     bounds = (out.lower, out.upper, float(out.q_low[0]), float(out.q_up[0]))
        ...     assert bounds == (3.0, 4.0, 3.5, 4.0)
        ...     assert out.action == 0 and out.vector.tolist() == [3.5] and out.value == 3.5
        ...     assert out.record.tolist() == [3.5, 4.0, 1.0, 3.0, 4.0]  # q_low q_up P low up
    """
    tx, tyk, z, RT, cx = tables
    A, K, O, Y = z.shape
    C = A * K * O
    if scratch is None or scratch[0].shape != (C + 1, Y):
        scratch = new_scratch(C, Y)
    rows, rows_x, nz = scratch
    record = np.empty(2 * A + 3 * C)
    best = np.empty(C, dtype=np.int64)
    out = np.empty(Y) if vector else _EMPTY
    vectors, gid, gn = scoring
    corner, sorted_points, idx, inv, off, wid, gain, sig = sawtooth
    _, lo, own, cu, a, nl = kernel.backup_one(
        b, tx, tyk, z, RT, cx, rows, rows_x, nz, vectors, gid, gn, corner, sorted_points, idx,
        inv, off, wid, gain, sig, _EMPTY if stale is None else stale, record, best, out, x,
        float(gamma),
    )  # fmt: skip
    return Backup(record, best, lo, cu, cx, own, a, out if vector else None, nl, (A, K, O))


def new_scratch(num_children: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`backup_one`'s scratch for ``C`` children of width ``Y``: rows ``(C + 1, Y)``,
    their observed values and the possible children's indices (a caller that backs up many
    beliefs keeps one per shape; the rows' pages are touched only as far as children are
    written)."""
    C = num_children
    return np.empty((C + 1, width)), np.empty(C + 1, dtype=np.int64), np.empty(C, dtype=np.int64)


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


def dominated(kernel: ModuleType, vectors: np.ndarray, ids: np.ndarray,
              groups: np.ndarray | None = None, atol: float = 0.0) -> np.ndarray:  # fmt: skip
    """``(n,)`` bool: the candidates ``ids`` that no other candidate of the same group
    dominates pointwise, :func:`~torchhrc.solvers.pruning.prune_dominated`'s rule on the rows
    ``vectors[ids]``: ``i`` is dropped when some ``j != i`` has ``V[j] >= V[i] - atol``
    everywhere and either ``i`` does not dominate ``j`` back or ``j`` comes first in ``ids``
    (of equal vectors the first is kept).

    Args:
        kernel: the module of :func:`load`.
        vectors: ``(N, Y)`` C-contiguous float64 (the alpha vectors' store).
        ids: ``(n,)`` int64 rows of ``vectors``, in the order that breaks ties.
        groups: ``(n,)`` int64 each candidate's group (observed value), or ``None``: one.
        atol: the comparison's tolerance.

    Raises:
        TypeError: an array of another dtype or rank, or not C-contiguous (named).
        ValueError: an index outside ``vectors``' rows, or ``groups`` not of ``ids``' length.

    Example:
        >>> kernel = load()
        >>> if kernel is not None:
        ...     V = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.5, -1.0]])
        ...     ids = np.array([0, 1, 2, 3])
        ...     assert dominated(kernel, V, ids).tolist() == [True, False, True, False]
        ...     groups = np.array([0, 1, 1, 0])  # 1 alone in its group: kept
        ...     assert dominated(kernel, V, ids, groups).tolist() == [True, True, True, False]
    """
    ids = np.asarray(ids, dtype=np.int64)
    n = ids.shape[0]
    flags = np.empty(n, dtype=np.int64)
    if groups is None:
        kernel.dominated(vectors, ids, _NO_COLS, flags, float(atol))
        return flags.astype(bool)
    if np.shape(groups) != (n,):
        raise ValueError(f"expected groups of shape ({n},) (ids'), got {np.shape(groups)}")
    # the kernel reads each group as one run, the candidates' order kept within it (stable)
    g = np.asarray(groups, dtype=np.int64)
    order = np.argsort(g, kind="stable")
    kernel.dominated(vectors, ids[order], g[order], flags, float(atol))
    keep = np.empty(n, dtype=bool)
    keep[order] = flags.astype(bool)
    return keep


class AlphaStore(NamedTuple):
    """The alpha vectors' one store as the compiled scoring reads it (SARSOP's ``_AlphaSet``,
    :meth:`~torchhrc.solvers.sarsop.alpha_set._AlphaSet.scoring_storage`): what a belief tree
    passes to :func:`keep_alphas` where its storage allows the compiled pruning
    (:meth:`~torchhrc.solvers.belief_tree.BeliefTree.keep_alphas`).

    Example:
        >>> store = AlphaStore(None, np.zeros((4, 2)), [np.array([0, 1])], np.array([2]),
        ...                    np.zeros(2, dtype=np.int64))
        >>> store.observed.shape  # the two vectors in use
        (2,)
    """

    kernel: Any  #: the module of :func:`load`
    vectors: np.ndarray  #: ``(capacity, Y)`` float64, the rows in use first
    gid: list[np.ndarray]  #: per observed value, the indices of its vectors
    gn: np.ndarray  #: per observed value, how many of ``gid[x]`` are in use
    observed: np.ndarray  #: ``(n,)`` int64, each vector's observed value


def keep_alphas(kernel: ModuleType, vectors: np.ndarray, gid: list[np.ndarray], gn: np.ndarray,
                observed: np.ndarray, beliefs: np.ndarray, nodes: np.ndarray,
                nodes_x: np.ndarray, atol: float = 0.0) -> np.ndarray:  # fmt: skip
    """``(n,)`` bool: the alpha vectors to keep, those best at some of the beliefs ``nodes``
    among their own observed value's vectors and not pointwise dominated there (SARSOP's
    pruning, :meth:`~torchhrc.solvers.belief_tree.BeliefTree.keep_alphas`' rule over the
    vectors' one store: :func:`group_scores`, or with one observed value one BLAS product,
    then :func:`dominated` on the winners). A group without any belief keeps all its
    vectors.

    Args:
        kernel: the module of :func:`load`.
        vectors, gid, gn: the store as :func:`group_scores` reads it (``_AlphaSet``'s), the
            vectors in use its first ``n`` rows.
        observed: ``(n,)`` int64 each vector's observed value.
        beliefs: ``(capacity, Y)`` C-contiguous float64 the tree's belief rows.
        nodes: ``(M,)`` int64 the rows of ``beliefs`` to keep the winners of.
        nodes_x: ``(M,)`` int64 their observed values.
        atol: the dominance test's tolerance.

    Example:
        >>> kernel = load()
        >>> if kernel is not None:  # one observed value; vector 2 wins nowhere
        ...     V = np.array([[1.0, 0.0], [0.0, 1.0], [0.4, 0.4]])
        ...     gid, gn = [np.array([0, 1, 2])], np.array([3])
        ...     b = np.array([[0.9, 0.1], [0.2, 0.8]])
        ...     zeros = np.zeros(3, dtype=np.int64)
        ...     keep = keep_alphas(kernel, V, gid, gn, zeros, b, np.array([0, 1]), zeros[:2])
        ...     assert keep.tolist() == [True, True, False]
    """
    n = observed.shape[0]
    keep = np.zeros(n, dtype=bool)
    nodes_x = nodes_x.astype(np.int64, copy=False)
    has = gn[nodes_x] > 0  # (a belief of an x without vectors: nothing to win there)
    nodes, nodes_x = nodes[has], nodes_x[has]
    # rows gathered at a time: their copy (m, Y) and their scores (m, n) bounded
    step = max(1, _BLOCK_ROWS // max(1, beliefs.shape[1], n))
    grouped = gn.shape[0] > 1
    for start in range(0, nodes.shape[0], step):
        rows = beliefs[nodes[start : start + step]]  # (m, Y) a copy, C-contiguous
        if grouped:  # each row against its own x's vectors only
            rows_x = nodes_x[start : start + step]
            keep[group_scores(kernel, rows, rows_x, vectors, gid, gn)[1]] = True
        else:  # one product: BLAS scores many wide vectors faster (Hallway2: 1.3x)
            keep[(rows @ vectors[:n].T).argmax(1)] = True
    unseen = np.ones(gn.shape[0], dtype=bool)
    unseen[nodes_x] = False
    keep |= unseen[observed]  # a group without any belief keeps everything
    idx = np.flatnonzero(keep)
    keep[idx] = dominated(kernel, vectors, idx, observed[idx] if grouped else None, atol)
    return keep


#: Belief entries gathered, and scores formed, at a time by :func:`keep_alphas` (2 MB of
#: float64 each, as :mod:`torchhrc.solvers.pruning` scores a block of beliefs at a time).
_BLOCK_ROWS = 1 << 18

_EMPTY = np.empty(0)
_NO_COLS = np.empty(0, dtype=np.int64)
