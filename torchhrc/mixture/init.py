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

import torch

from torchhrc.mixture._em import column_blocks, onehot_sums, run_groups
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


def _draw(weights: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """``(R,)`` one index per row of ``weights (R, U)`` (>= 0, positive sums), drawn with
    probability proportional to the weights: inverse CDF (cumulative sums and a binary
    search; an index whose weight does not raise the sum is never drawn), on the generator's
    device (CPU)."""
    cdf = weights.cpu().cumsum(-1)  # (R, U)
    u = torch.rand(cdf.shape[0], 1, generator=generator, dtype=cdf.dtype) * cdf[:, -1:]
    idx = torch.searchsorted(cdf, u, right=True).squeeze(-1)
    return idx.clamp_max(cdf.shape[-1] - 1).to(weights.device)


def _sq_distances(
    xt: torch.Tensor, x2: torch.Tensor, centers: torch.Tensor, keep: torch.Tensor
) -> torch.Tensor:
    """``(C, U)`` squared Euclidean distances (>= 0) of the columns of ``xt (F', U)`` (squared
    norms ``x2 (U,)``) to ``centers (C, F)``; ``keep (F',)`` are the features that are not
    zero in every row (the others add nothing to the product)."""
    # x2 - 2 c.x + |c|^2, in place on the product (the same roundings as written out)
    d = (centers[:, keep] @ xt).mul_(-2.0).add_(x2).add_((centers * centers).sum(-1, keepdim=True))
    return d.clamp_min_(0.0)


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
    and rows; runs are packed by their number of clusters (no masked slot is computed).

    Args:
        stats: the distinct sequences.
        cluster_mask: ``(R, K)`` bool; run ``r`` seeds ``k_r = cluster_mask[r].sum()`` centres.
        generator: the random source (CPU).
        lloyd_iterations: k-means (Lloyd) refinements after seeding.

    Returns:
        ``(U, R)`` int64 hard assignments to the slots of each run's mask.
    """
    R, K = cluster_mask.shape
    x = _features(stats)  # (U, F)
    U = x.shape[0]
    # the products see only the features that are nonzero in some row (transitions that
    # occur): the others are 0 in every row and every centre (a mean of rows), so they add
    # exactly 0; the norms are taken over all features, as written
    keep = torch.nonzero((x != 0).any(0)).squeeze(-1)  # (F',)
    xs = x[:, keep]  # (U, F')
    xt = xs.transpose(0, 1).contiguous()  # (F', U)
    x2 = (x * x).sum(-1)  # (U,)
    w = stats.multiplicity.to(x.dtype)  # (U,)
    k = cluster_mask.sum(-1)  # (R,)
    tiny = torch.finfo(x.dtype).tiny
    idx = _draw(w.expand(R, U), generator).unsqueeze(-1).repeat(1, K)  # (R, K) centre rows
    d2 = _sq_distances(xt, x2, x[idx[:, 0]], keep)  # (R, U) distance to the nearest centre
    for j in range(1, K):
        draw = _draw(d2 * w + tiny * w, generator)  # (R,), never all zero
        active = torch.nonzero(j < k).squeeze(-1)  # runs that seed a j-th centre
        if active.numel() == 0:
            continue
        nxt = draw[active]
        idx[active, j] = nxt
        d2[active] = torch.minimum(d2[active], _sq_distances(xt, x2, x[nxt], keep))
    groups = run_groups(cluster_mask)
    centers = x.new_zeros(R, K, x.shape[-1])
    for runs, slots in groups:  # the j-th centre seeded goes to the j-th used slot
        centers[runs[:, None], slots] = x[idx[runs, : slots.shape[1]]]
    zt = _nearest(xt, centers, groups, keep)
    weighted = torch.cat([xs * w[:, None], w[:, None]], -1)  # (U, F' + 1)
    for _ in range(lloyd_iterations):
        for runs, slots in groups:
            sums = onehot_sums(zt[runs], slots, weighted, slots.numel())  # (R_g * k, F' + 1)
            sums = sums.view(*slots.shape, -1)
            sizes = sums[..., -1:]
            new = centers[runs[:, None], slots]  # (R_g, k, F), 0 off the kept features
            new[..., keep] = torch.where(
                sizes > 0, sums[..., :-1] / sizes.clamp_min(tiny), new[..., keep]
            )
            centers[runs[:, None], slots] = new
        zt = _nearest(xt, centers, groups, keep)
    return zt.transpose(0, 1).contiguous()


def _nearest(
    xt: torch.Tensor,
    centers: torch.Tensor,
    groups: list[tuple[torch.Tensor, torch.Tensor]],
    keep: torch.Tensor,
) -> torch.Tensor:
    """``(R, U)`` slot of the nearest centre of each run (first one on ties), block by block.

    ``argmin_c ||x - c||^2 = argmax_c (2 x.c - ||c||^2)``; ``xt (F', U)`` holds the kept
    features ``keep (F',)`` of ``centers (R, K, F)`` (see :func:`_sq_distances`).
    """
    R, U = centers.shape[0], xt.shape[-1]
    zt = torch.zeros(R, U, dtype=torch.long, device=xt.device)
    for runs, slots in groups:
        Rg, k = slots.shape
        c = centers[runs[:, None], slots].reshape(Rg * k, -1)  # (R_g * k, F)
        half_norm = 0.5 * (c * c).sum(-1, keepdim=True)
        c = c[:, keep]  # (R_g * k, F')
        best = torch.empty(Rg, U, dtype=torch.long, device=xt.device)
        for cols in column_blocks(U, Rg * k):
            score = c @ xt[:, cols] - half_norm  # (R_g * k, b)
            best[:, cols] = score.view(Rg, k, -1).max(1).indices
        zt[runs] = slots.gather(1, best)
    return zt
