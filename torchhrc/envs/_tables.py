"""Row-stochastic tables in compressed form, sampled by inverse CDF (numpy, for single envs).

A table of ``R`` rows over ``K`` outcomes (``T[a, s, :]`` flattened to rows ``a * S + s``,
``Tx``, ``Ty``, ``Z`` of a MOMDP, or the nonzeros of a :class:`~torchhrc.pomdp.SparsePOMDP`)
keeps only its nonzero entries, sorted by row, and one global cumulative array in which row
``r``'s cumulative probabilities run over ``(r, r + 1]``::

    cdf[j] = r + sum_{i <= j, row(i) = r} p_i / sum_{row(i) = r} p_i     (last of a row: r + 1)

so a draw of row ``r`` with a uniform ``u`` in ``[0, 1)`` is one ``searchsorted(cdf, r + u,
side="right")`` over the whole table, for any number of rows at once; zero entries are never
drawn. Dense and sparse models go through the same code.

Example:
    >>> import numpy as np
    >>> t = CategoricalRows.from_dense(np.array([[0.0, 1.0], [0.5, 0.5]]))
    >>> t.sample(np.array([0, 1, 1]), np.array([0.9, 0.2, 0.7])).tolist()
    [1, 0, 1]
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["CategoricalRows"]


class CategoricalRows:
    """Compressed rows of a row-stochastic table (see the module docstring).

    Args:
        row: ``(M,)`` int64 row of each nonzero entry.
        col: ``(M,)`` int64 outcome of each nonzero entry.
        prob: ``(M,)`` its probability (rows are renormalised).
        num_rows: ``R``; every row must have at least one positive entry.

    Raises:
        ValueError: a row has no positive entry, or the arrays disagree in length.
    """

    def __init__(self, row: np.ndarray, col: np.ndarray, prob: np.ndarray, num_rows: int) -> None:
        row = np.asarray(row, dtype=np.int64)
        col = np.asarray(col, dtype=np.int64)
        prob = np.asarray(prob, dtype=np.float64)
        if not row.shape == col.shape == prob.shape or row.ndim != 1:
            raise ValueError(
                f"expected row, col, prob of one shape (M,), got {row.shape}, {col.shape}, "
                f"{prob.shape}"
            )
        keep = prob > 0
        row, col, prob = row[keep], col[keep], prob[keep]
        order = np.lexsort((col, row))
        row, col, prob = row[order], col[order], prob[order]
        counts = np.bincount(row, minlength=num_rows)
        if counts.shape[0] != num_rows or (counts == 0).any():
            empty = int(np.flatnonzero(counts == 0)[0]) if (counts == 0).any() else num_rows
            raise ValueError(f"row {empty} of the table has no positive entry (R={num_rows})")
        totals = np.bincount(row, weights=prob, minlength=num_rows)
        within = np.cumsum(prob)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        before = np.concatenate([[0.0], within])[starts]  # cumulative mass before each row
        cdf = (within - before[row]) / totals[row]
        last = np.cumsum(counts) - 1
        cdf[last] = 1.0  # exact row ends: a uniform in [0, 1) never leaves its row
        self.cdf = row + cdf
        self.col = col
        self.num_rows = int(num_rows)

    @classmethod
    def from_dense(cls, probs: np.ndarray | torch.Tensor) -> CategoricalRows:
        """The table of ``probs (..., K)``, rows flattened in C order (``(...)`` -> ``R``).

        Example:
            >>> CategoricalRows.from_dense(np.eye(3)).num_rows
            3
        """
        if isinstance(probs, torch.Tensor):
            probs = probs.detach().cpu().numpy()
        probs = np.asarray(probs, dtype=np.float64)
        flat = probs.reshape(-1, probs.shape[-1])
        row, col = np.nonzero(flat)
        return cls(row, col, flat[row, col], flat.shape[0])

    def sample(self, rows: np.ndarray, u: np.ndarray) -> np.ndarray:
        """One outcome per entry of ``rows (...)`` from uniforms ``u (...)`` in ``[0, 1)``.

        Returns:
            ``(...)`` int64 outcomes.
        """
        rows = np.asarray(rows, dtype=np.float64)
        # r + u may round up to r + 1 for u close to 1: keep the key inside row r
        key = np.minimum(rows + np.asarray(u), np.nextafter(rows + 1.0, rows))
        index = np.searchsorted(self.cdf, key, side="right")
        return self.col[np.minimum(index, self.col.shape[0] - 1)]
