"""Initialisations of many EM runs at once: the paper's random one, and k-means++.

* :func:`random_init`: the paper's lines 1-2, every transition row ~ Dirichlet(1) and
  uniformly random assignments.
* :func:`kmeans_pp_init`: k-means++ seeding (Arthur & Vassilvitskii 2007) on the
  per-sequence transition-frequency vectors ``f_n = C_n / sum C_n`` (``(A * A,)``, plus the
  one-hot first symbol when first symbols are modelled), weighted by multiplicity, followed
  by a few Lloyd iterations; the result is a hard partition per run.

All randomness comes from the ``generator`` argument; runs draw in one batch.

Example:
    >>> import torch
    >>> from torchhrc.mixture.counts import sufficient_statistics
    >>> s = sufficient_statistics(torch.tensor([[0, 0, 0], [1, 1, 1]]), torch.tensor([3, 3]), 2)
    >>> g = torch.Generator().manual_seed(0)
    >>> z = kmeans_pp_init(s, torch.ones(3, 2, dtype=torch.bool), generator=g)
    >>> bool((z[0] != z[1]).all())  # two distinct rows always get two clusters
    True
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from torchhrc.mixture._em import chunk_rows
from torchhrc.mixture.counts import SufficientStatistics

__all__ = ["kmeans_pp_init", "random_init"]


def random_init(
    stats: SufficientStatistics,
    cluster_mask: torch.Tensor,
    *,
    generator: torch.Generator,
    dtype: torch.dtype | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The paper's random start: Dirichlet(1) transition rows and random assignments.

    Args:
        stats: the distinct sequences (``U`` rows, ``A`` symbols).
        cluster_mask: ``(R, K)`` bool, the clusters of each run.
        generator: the random source (CPU).
        dtype: float dtype (default: ``stats.counts.dtype``).

    Returns:
        ``log_transition (R, K, A, A)`` and ``assignments (U, R)`` in ``[0, k_r)``.
    """
    R, K = cluster_mask.shape
    A, U = stats.num_symbols, stats.num_distinct
    dtype = dtype or stats.counts.dtype
    device = stats.counts.device
    # Dirichlet(1, ..., 1) = normalised Exp(1) draws
    expo = -torch.rand(R, K, A, A, generator=generator, dtype=dtype).clamp_min(1e-300).log()
    log_transition = (expo / expo.sum(-1, keepdim=True)).log().to(device)
    k = cluster_mask.sum(-1).to(dtype).cpu()  # (R,)
    u = torch.rand(U, R, generator=generator, dtype=dtype)
    assignments = (u * k).floor().long().clamp_max(k.long() - 1).to(device)
    return log_transition, assignments


def _features(stats: SufficientStatistics) -> torch.Tensor:
    """``(U, F)`` per-row transition frequencies (+ first-symbol frequencies)."""
    totals = stats.counts.sum(-1, keepdim=True).clamp_min(1.0)
    feats = stats.counts / totals
    if stats.first_counts is not None:
        first = stats.first_counts / stats.first_counts.sum(-1, keepdim=True).clamp_min(1.0)
        feats = torch.cat([feats, first], -1)
    return feats


def _sq_distances(x: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """``(U, F)`` x ``(R, K, F)`` -> ``(U, R, K)`` squared Euclidean distances (>= 0)."""
    R, K, Fd = centers.shape
    cross = x @ centers.reshape(R * K, Fd).transpose(0, 1)  # (U, R*K)
    d = (x * x).sum(-1, keepdim=True) - 2 * cross + (centers * centers).sum(-1).view(1, R * K)
    return d.clamp_min(0.0).view(-1, R, K)


def kmeans_pp_init(
    stats: SufficientStatistics,
    cluster_mask: torch.Tensor,
    *,
    generator: torch.Generator,
    lloyd_iterations: int = 3,
) -> torch.Tensor:
    """k-means++ seeding + Lloyd iterations on transition-frequency vectors, for ``R`` runs.

    ``D^2`` seeding: the first centre is a row drawn with probability proportional to its
    multiplicity; each next centre of run ``r`` is drawn with probability proportional to
    ``m_u * min_j ||f_u - c_j||^2``. The loop runs over the ``K`` centres, batched over runs
    and rows.

    Args:
        stats: the distinct sequences.
        cluster_mask: ``(R, K)`` bool; run ``r`` seeds ``k_r = cluster_mask[r].sum()`` centres.
        generator: the random source (CPU).
        lloyd_iterations: k-means (Lloyd) refinements after seeding.

    Returns:
        ``(U, R)`` int64 hard assignments in ``[0, k_r)``.
    """
    R, K = cluster_mask.shape
    x = _features(stats)  # (U, F)
    U = x.shape[0]
    w = stats.multiplicity  # (U,)
    device = x.device
    k = cluster_mask.sum(-1)  # (R,)
    idx = torch.zeros(R, K, dtype=torch.long, device=device)
    probs = w.expand(R, U).cpu()
    first = torch.multinomial(probs, 1, generator=generator).squeeze(-1).to(device)
    idx[:, 0] = first
    d2 = _sq_distances(x, x[first].unsqueeze(1)).squeeze(-1)  # (U, R)
    tiny = torch.finfo(x.dtype).tiny
    for j in range(1, K):
        p = (d2.transpose(0, 1) * w + tiny * w).cpu()  # (R, U), never all zero
        nxt = torch.multinomial(p, 1, generator=generator).squeeze(-1).to(device)
        active = j < k  # (R,)
        idx[:, j] = torch.where(active, nxt, idx[:, 0])
        dj = _sq_distances(x, x[nxt].unsqueeze(1)).squeeze(-1)
        d2 = torch.where(active, torch.minimum(d2, dj), d2)
    centers = x[idx]  # (R, K, F)
    inactive = torch.zeros(R, K, dtype=x.dtype, device=device).masked_fill(~cluster_mask, math.inf)
    z = _nearest(x, centers, inactive)
    for _ in range(lloyd_iterations):
        sums = x.new_zeros(R * K, x.shape[-1])
        sizes = x.new_zeros(R * K)
        for rows in chunk_rows(U, R, K):
            onehot = F.one_hot(z[rows], K).to(x.dtype).view(-1, R * K)  # (c, R*K)
            sums += onehot.transpose(0, 1) @ (x[rows] * w[rows, None])
            sizes += onehot.transpose(0, 1) @ w[rows]
        sizes = sizes.view(R, K, 1)
        centers = torch.where(sizes > 0, sums.view(R, K, -1) / sizes.clamp_min(tiny), centers)
        z = _nearest(x, centers, inactive)
    return z


def _nearest(x: torch.Tensor, centers: torch.Tensor, inactive: torch.Tensor) -> torch.Tensor:
    """``(U, R)`` index of the nearest active centre, chunk by chunk over rows."""
    U, (R, K) = x.shape[0], inactive.shape
    z = torch.empty(U, R, dtype=torch.long, device=x.device)
    for rows in chunk_rows(U, R, K):
        z[rows] = (_sq_distances(x[rows], centers) + inactive).argmin(-1)
    return z
