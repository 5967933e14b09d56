"""Shared E/M kernels for many EM runs at once (internal).

Notation: ``U`` distinct sequences (rows of :class:`SufficientStatistics`), ``R`` runs
(every restart of every k), ``K`` cluster slots (``k_max``; a run with ``k < K`` has its
extra slots masked out by ``cluster_mask (R, K)``), ``A`` symbols, ``D = A * A``.

One E-step is one matrix product ``(U, D) @ (D, R * K)``; one M-step is one matrix product
``(R * K, U) @ (U, D)``. Rows are processed in chunks so the ``(U, R, K)`` table is never
materialised for large ``U`` (a chunk is a block of thousands of rows: the loop runs over
memory blocks, not over sequences or runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchhrc.mixture.counts import SufficientStatistics

__all__ = [
    "EMResult",
    "chunk_rows",
    "e_table",
    "exact_row_log_likelihood",
    "m_step_transition",
]

#: Elements of a ``(chunk, R, K)`` block processed at once.
_BLOCK_ELEMENTS = 1 << 22


@dataclass(frozen=True)
class EMResult:
    """The outcome of ``R`` EM runs.

    Attributes:
        log_transition: ``(R, K, A, A)``.
        log_weights: ``(R, K)`` (``-inf`` on masked slots and on empty clusters).
        log_initial: ``(R, K, A)`` or ``None``.
        assignments: ``(U, R)`` int64 most responsible cluster of every distinct row.
        log_likelihood: ``(R,)``: the classification log-likelihood (hard EM, the paper's
            ``l(D; theta)``) or the marginal log-likelihood (soft EM).
        entropy: ``(R,)`` entropy of the responsibilities, ``-sum_n sum_k r log r`` (0 for
            hard EM); ``ICL = BIC - entropy``.
        iterations: ``(R,)`` int64 iterations each run took.
        converged: ``(R,)`` bool.
    """

    log_transition: torch.Tensor
    log_weights: torch.Tensor
    log_initial: torch.Tensor | None
    assignments: torch.Tensor
    log_likelihood: torch.Tensor
    entropy: torch.Tensor
    iterations: torch.Tensor
    converged: torch.Tensor


def chunk_rows(U: int, R: int, K: int) -> list[slice]:
    """Row blocks of at most ``_BLOCK_ELEMENTS`` elements of a ``(rows, R, K)`` table."""
    size = max(1, _BLOCK_ELEMENTS // max(1, R * K))
    return [slice(i, min(U, i + size)) for i in range(0, U, size)] or [slice(0, 0)]


def e_table(
    counts: torch.Tensor,
    first_counts: torch.Tensor | None,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
) -> torch.Tensor:
    """``(U, R, K)`` log-likelihood of each row under each cluster; all inputs finite.

    Args:
        counts: ``(U, D)``; first_counts: ``(U, A)`` first-symbol counts or None.
        log_transition: ``(R, K, A, A)`` finite; log_initial: ``(R, K, A)`` finite or None.
    """
    R, K, A, _ = log_transition.shape
    table = log_transition.reshape(R * K, A * A).transpose(0, 1)  # (D, R*K)
    out = (counts @ table).view(counts.shape[0], R, K)
    if log_initial is not None and first_counts is not None:
        out = out + (first_counts @ log_initial.reshape(R * K, A).transpose(0, 1)).view(-1, R, K)
    return out


def m_step_transition(
    cluster_counts: torch.Tensor, previous: torch.Tensor, pseudo_count: float
) -> torch.Tensor:
    """Normalised (smoothed) counts; a row without any count keeps its previous value.

    ``theta[r, k, a, b] = (n[r, k, a, b] + alpha) / sum_b' (n[r, k, a, b'] + alpha)``
    (the paper's M-step when ``alpha = 0``).

    Args:
        cluster_counts: ``(R, K, A, A)`` expected counts.
        previous: ``(R, K, A, A)`` log-probabilities kept where a row has no count.
        pseudo_count: Dirichlet pseudo-count ``alpha >= 0`` added to every entry.

    Returns:
        ``(R, K, A, A)`` log-probabilities (``-inf`` for unseen transitions when ``alpha = 0``).
    """
    smoothed = cluster_counts + pseudo_count
    rows = smoothed.sum(-1, keepdim=True)
    fresh = smoothed.log() - rows.clamp_min(torch.finfo(smoothed.dtype).tiny).log()
    return torch.where(rows > 0, fresh, previous)


def exact_row_log_likelihood(
    stats: SufficientStatistics,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    rows: slice,
) -> torch.Tensor:
    """``(rows, R, K)`` exact log-likelihoods, ``-inf`` where a needed probability is 0.

    ``-inf`` entries are replaced by 0 in the product and the impossible rows are found by a
    second product with the indicator of zero probabilities, so ``0 * -inf`` never occurs.
    """
    impossible = torch.isneginf(log_transition)
    finite = log_transition.masked_fill(impossible, 0.0)
    counts = stats.counts[rows]
    first = stats.first_counts[rows] if stats.first_counts is not None else None
    fin_init = imp_init = None
    if log_initial is not None:
        imp_init = torch.isneginf(log_initial)
        fin_init = log_initial.masked_fill(imp_init, 0.0)
    ll = e_table(counts, first, finite, fin_init)
    bad = e_table(
        counts,
        first,
        impossible.to(counts.dtype),
        None if imp_init is None else imp_init.to(counts.dtype),
    )
    return ll.masked_fill(bad > 0, -math.inf)
