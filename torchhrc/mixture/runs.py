"""EM for every k with restarts, as one batch: the runs that model selection scores.

:func:`_em_all_k` runs every ``(k, restart)`` pair of a selection as one tensor program
(hard EM for the paper's method; k-means++ starts, short em-EM runs and soft EM to
convergence otherwise); :func:`_heldout_scores` refits them on folds of units for the
held-out criteria. Used by :mod:`.selection` (``fit_mixture``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import torch

from torchhrc.mixture._em import EMResult, Smoothing, e_table
from torchhrc.mixture.counts import SufficientStatistics
from torchhrc.mixture.criteria import _first_best
from torchhrc.mixture.hard_em import hard_em, partition_counts, partition_sizes
from torchhrc.mixture.init import _features, kmeans_pp_init, random_init
from torchhrc.mixture.soft_em import SoftStatistics, m_step, soft_em


def _soft_initial_parameters(
    stats: SufficientStatistics,
    z: torch.Tensor,
    cluster_mask: torch.Tensor,
    pseudo_count: float | Smoothing,
    weight_pseudo_count: float,
    dtype: torch.dtype,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Smoothed M-step from a hard partition ``z (U, R)``."""
    R, K = cluster_mask.shape
    A = stats.num_symbols
    flat_counts, flat_init = partition_counts(stats, z, K, dtype)  # chunked, (R*K, ...)
    counts = flat_counts.view(R, K, A, A)
    init_counts = flat_init.view(R, K, A) if flat_init is not None else None
    expected = SoftStatistics(
        counts=counts,
        initial_counts=init_counts,
        sizes=partition_sizes(z, stats.multiplicity, K).to(dtype),
        log_likelihood=counts.new_zeros(R),
        entropy=counts.new_zeros(R),
        assignments=z,
    )
    uniform = counts.new_full((R, K, A, A), -math.log(A))
    uniform_init = (
        counts.new_full((R, K, A), -math.log(A)) if stats.first_counts is not None else None
    )
    return m_step(expected, uniform, uniform_init, cluster_mask, pseudo_count, weight_pseudo_count)


def _em_all_k(
    stats: SufficientStatistics,
    ks: torch.Tensor,
    gen: torch.Generator,
    *,
    method: str,
    restarts: int,
    pseudo_count: float,
    weight_pseudo_count: float,
    tol: float,
    max_iterations: int | None,
    short_iterations: int,
    floor: float,
    initial: bool,
    dtype: torch.dtype,
    e_step: Any = None,
    progress: Callable[[int, int], None] | None = None,
    split_restarts: bool = False,
) -> tuple[EMResult, torch.Tensor, torch.Tensor, int]:
    """EM for every ``k`` in ``ks (num_k,)`` with ``restarts`` runs each, as one batch.

    With ``split_restarts`` (``fit_mixture``'s ``split_merge``, off by default there too) the
    soft method then restarts every k from the fits of k - 1 and k + 1 with one cluster split
    or two merged (:func:`_split_merge_restarts`).

    Returns:
        ``(result, run_k (R,), cluster_mask (R, K), per_group)``: the runs of ``ks[i]`` are
        ``i * per_group ... (i + 1) * per_group - 1`` (``per_group`` = 1 after the soft
        method's em-EM keeps the best short run of each k).
    """
    device = stats.counts.device
    A = stats.num_symbols
    run_k = ks.repeat_interleave(restarts)  # (R,): run r = (k index) * restarts + restart
    K = int(ks.max())
    cluster_mask = torch.arange(K, device=device) < run_k.unsqueeze(-1)  # (R, K)

    result: EMResult
    per_group = restarts
    if method == "paper":
        lt0, z0 = random_init(stats, cluster_mask, generator=gen, dtype=dtype)
        li0 = None
        if initial:
            li0 = lt0.new_full((run_k.shape[0], K, A), -math.log(A))
        result = hard_em(
            stats,
            lt0,
            cluster_mask,
            assignments=z0,
            log_initial=li0,
            floor=floor,
            max_iterations=100 if max_iterations is None else max_iterations,
            progress=progress,
        )
    else:
        z0 = kmeans_pp_init(stats, cluster_mask, generator=gen)
        lt0, lw0, li0 = _soft_initial_parameters(
            stats, z0, cluster_mask, pseudo_count, weight_pseudo_count, dtype
        )
        options = dict(
            pseudo_count=pseudo_count,
            weight_pseudo_count=weight_pseudo_count,
            tol=tol,
            e_step=e_step,
        )
        cap = 200 if max_iterations is None else max_iterations
        if restarts > 1:  # em-EM: short runs for every restart, then the best of each k
            short = soft_em(
                stats,
                lt0,
                lw0,
                cluster_mask,
                log_initial=li0,
                max_iterations=min(short_iterations, cap),
                progress=progress,
                details=False,  # only the log-likelihoods and parameters are kept
                **options,
            )
            ll = torch.nan_to_num(short.log_likelihood, nan=-math.inf).view(len(ks), restarts)
            keep = torch.arange(len(ks), device=device) * restarts + _first_best(ll)  # (num_k,)
            lt0, lw0 = short.log_transition[keep], short.log_weights[keep]
            li0 = short.log_initial[keep] if short.log_initial is not None else None
            run_k, cluster_mask, per_group = run_k[keep], cluster_mask[keep], 1
        result = soft_em(
            stats,
            lt0,
            lw0,
            cluster_mask,
            log_initial=li0,
            max_iterations=cap,
            progress=progress,
            **options,
        )
        em = dict(
            pseudo_count=pseudo_count,
            weight_pseudo_count=weight_pseudo_count,
            dtype=dtype,
            options=dict(max_iterations=cap, progress=progress, **options),
        )
        if split_restarts and len(ks) > 1:
            result = _split_merge_restarts(stats, result, cluster_mask, em)
        elif per_group == 1 and len(ks) > 1:
            result = _split_where_worse(stats, result, cluster_mask, em)

    return result, run_k, cluster_mask, per_group


def _two_means(x: torch.Tensor, w: torch.Tensor, iterations: int = 5) -> torch.Tensor:
    """``(n,)`` bool: a deterministic 2-means split of the rows of ``x (n, F)`` (weights
    ``w (n,)``, positive): the halves of the principal axis of the weighted rows (power
    iteration from the row farthest from the mean), then Lloyd iterations."""
    mean = (w[:, None] * x).sum(0) / w.sum()
    centred = x - mean
    v = centred[int((centred * centred).sum(-1).argmax())]  # (F,)
    for _ in range(20):  # power iteration on the weighted scatter matrix
        v = centred.transpose(0, 1) @ (w * (centred @ v))
        v = v / v.norm().clamp_min(torch.finfo(x.dtype).tiny)
    side = (centred @ v) > 0  # (n,)
    for _ in range(iterations):
        if bool(side.all()) or not bool(side.any()):
            break
        a = (w[side, None] * x[side]).sum(0) / w[side].sum()
        b = (w[~side, None] * x[~side]).sum(0) / w[~side].sum()
        new = ((x - a) ** 2).sum(-1) < ((x - b) ** 2).sum(-1)
        if bool((new == side).all()):
            break
        side = new
    return side


def _refit_starts(
    stats: SufficientStatistics,
    fields: dict[str, Any],
    i: int,
    starts: list[torch.Tensor],
    mask_row: torch.Tensor,
    em: dict[str, Any],
) -> None:
    """Fit the hard partitions ``starts`` (each ``(U,)``, slots of ``mask_row (K,)``) to
    convergence as one batch; the best replaces run ``i`` of ``fields`` (in place) where its
    log-likelihood is higher beyond round-off."""
    if not starts:
        return
    z0 = torch.stack(starts, -1)  # (U, C)
    mask = mask_row.expand(z0.shape[1], -1).contiguous()  # (C, K)
    lt0, lw0, li0 = _soft_initial_parameters(
        stats, z0, mask, em["pseudo_count"], em["weight_pseudo_count"], em["dtype"]
    )
    fits = soft_em(stats, lt0, lw0, mask, log_initial=li0, **em["options"])
    ll = torch.nan_to_num(fits.log_likelihood, nan=-math.inf)
    best = int(_first_best(ll[None])[0])
    current = float(fields["log_likelihood"][i])
    if not float(ll[best]) > current + 1e-7 * max(abs(current), 1.0):  # a real gain only
        return
    for name, value in fields.items():
        if value is None:
            continue
        if name == "assignments":
            value[:, i] = fits.assignments[:, best]
        else:
            value[i] = getattr(fits, name)[best]


def _split_restart(
    stats: SufficientStatistics,
    fields: dict[str, Any],
    i: int,
    k_of: list[int],
    x: torch.Tensor,
    w: torch.Tensor,
    cluster_mask: torch.Tensor,
    em: dict[str, Any],
) -> None:
    """Restart run ``i`` (``k = k_of[i]``) from the fit of run ``i - 1`` (``k - 1``) with each
    of its clusters split in two by 2-means of its members' transition frequencies
    (:func:`_two_means`); the best replaces run ``i`` where its log-likelihood is higher."""
    k = k_of[i]
    parent = fields["assignments"][:, i - 1]  # (U,)
    starts = []
    for j in range(k - 1):
        members = torch.nonzero(parent == j).squeeze(-1)
        if members.numel() < 2:
            continue
        side = _two_means(x[members], w[members])
        if bool(side.all()) or not bool(side.any()):
            continue
        z = parent.clone()
        z[members[side]] = k - 1
        starts.append(z)
    _refit_starts(stats, fields, i, starts, cluster_mask[i], em)


def _split_where_worse(
    stats: SufficientStatistics,
    result: EMResult,
    cluster_mask: torch.Tensor,
    em: dict[str, Any],
) -> EMResult:
    """Split restarts (:func:`_split_restart`) of every k whose fit is *below* the fit of
    k - 1 in log-likelihood, in increasing k.

    A mixture of k chains contains every mixture of k - 1 (one weight at 0), so a best run of
    k below the best run of k - 1 proves that EM's starts missed; the fit of k - 1 with one
    cluster split is a start at least as good (``five_parts``, a held-out task with 5 types:
    its k = 5 fit 0.024 nats per transition below its k = 4 fit at 30 x 4, seed 0). Only
    those k are restarted, so the cost is paid where the search failed.

    ``result`` holds one run per k (``cluster_mask (num_k, K)``, increasing k by one).
    """
    k_of = cluster_mask.sum(-1).tolist()  # (num_k,)
    ll = result.log_likelihood
    worse = [i for i in range(1, len(k_of)) if float(ll[i]) < float(ll[i - 1])]
    if not worse:
        return result
    fields = {f.name: getattr(result, f.name) for f in dataclasses.fields(result)}
    fields = {name: None if v is None else v.clone() for name, v in fields.items()}
    x = _features(stats).to(em["dtype"])  # (U, F)
    w = stats.multiplicity.to(em["dtype"])  # (U,)
    for i in range(1, len(k_of)):  # in increasing k: a repaired k - 1 is the next start
        if float(fields["log_likelihood"][i]) < float(fields["log_likelihood"][i - 1]):
            _split_restart(stats, fields, i, k_of, x, w, cluster_mask, em)
    return EMResult(**fields)


def _split_merge_restarts(
    stats: SufficientStatistics,
    result: EMResult,
    cluster_mask: torch.Tensor,
    em: dict[str, Any],
) -> EMResult:
    """Restarts of every k from the fits of k - 1 (a cluster split) and k + 1 (two merged).

    Random starts of k clusters can miss a partition that the fit of ``k - 1`` misses by one
    merged cluster, or that the fit of ``k + 1`` holds with one type cut in two (split and
    merge moves, after Ueda, Nakano, Ghahramani and Hinton's SMEM, 2000). In increasing k,
    every cluster ``j`` of the (final) fit of ``k - 1`` is split in two by 2-means of its
    members' transition frequencies (:func:`_two_means`); then in decreasing k, every cluster
    of the fit of ``k + 1`` is merged with its nearest one (by their members' mean transition
    frequencies; at most ``k + 1`` pairs, not all ``k (k + 1) / 2``). Each set of hard
    partitions is refitted to convergence (one batch) and the best replaces the fit of k
    where its log-likelihood is higher, so the fit of every k stays the best of its starts.
    All deterministic.

    ``result`` holds one run per k (``cluster_mask (num_k, K)``, increasing k by one);
    returns it with the improved runs replaced.
    """
    fields = {f.name: getattr(result, f.name) for f in dataclasses.fields(result)}
    fields = {name: None if v is None else v.clone() for name, v in fields.items()}
    k_of = cluster_mask.sum(-1).tolist()  # (num_k,)
    x = _features(stats).to(em["dtype"])  # (U, F)
    w = stats.multiplicity.to(em["dtype"])  # (U,)
    for i in range(1, len(k_of)):  # split: k - 1 -> k
        _split_restart(stats, fields, i, k_of, x, w, cluster_mask, em)
    for i in range(len(k_of) - 2, -1, -1):  # merge: k + 1 -> k
        k = k_of[i]
        parent = fields["assignments"][:, i + 1]  # (U,), slots 0..k
        onehot = torch.nn.functional.one_hot(parent, k + 1).to(x.dtype) * w[:, None]
        size = onehot.sum(0)  # (k + 1,)
        centre = (onehot.transpose(0, 1) @ x) / size.clamp_min(1e-300)[:, None]  # (k + 1, F)
        gap = torch.cdist(centre, centre).fill_diagonal_(math.inf)
        gap[:, size == 0] = math.inf
        pairs = sorted({tuple(sorted((a, int(gap[a].argmin())))) for a in range(k + 1)
                        if bool(size[a] > 0) and bool(gap[a].isfinite().any())})  # fmt: skip
        starts = []
        for a, b in pairs:  # each cluster with its nearest one (by mean frequencies)
            z = torch.where(parent == b, a, parent)
            starts.append(torch.where(z == k, b, z) if b < k else z)  # slots 0..k - 1
        _refit_starts(stats, fields, i, starts, cluster_mask[i], em)
    return EMResult(**fields)


def _heldout_scores(
    stats: SufficientStatistics,
    ks: torch.Tensor,
    gen: torch.Generator,
    folds: int,
    em: dict[str, Any],
) -> tuple[torch.Tensor, torch.Tensor]:
    """Held-out log-likelihood of every unit under every k, by ``folds``-fold cross-validation.

    The units (subjects, or sequences) are dealt at random into ``F = min(folds, n)`` folds;
    for each fold, the mixture of every k is fitted to the other folds (the same EM as the
    full fit, :func:`_em_all_k`, its best run per k by log-likelihood) and each held-out unit
    is scored by its mixture likelihood ``log sum_k w_k prod_(a,b) theta_k(b | a)^n(a, b)``
    (no held-out label is used).

    Returns:
        ``(values (P, num_k), weights (P,))``: ``P`` pairs (distinct row, fold), the
        held-out log-likelihood of one unit of the row under each k and how many units of
        the row the fold holds out (their weighted sum is the held-out total).
    """
    U = stats.num_distinct
    mult = stats.multiplicity.round().long().cpu()  # (U,)
    n = int(mult.sum())
    F_ = max(2, min(int(folds), n))
    unit_row = torch.repeat_interleave(torch.arange(U), mult)  # (n,)
    fold = torch.empty(n, dtype=torch.long)
    fold[torch.randperm(n, generator=gen)] = torch.arange(n) % F_
    held = torch.zeros(U, F_, dtype=torch.long)
    held.index_put_((unit_row, fold), torch.ones(n, dtype=torch.long), accumulate=True)
    device, floor = stats.counts.device, math.log(em["floor"])
    values, weights = [], []
    for f in range(F_):
        train = (mult - held[:, f]).to(stats.multiplicity)
        keep = torch.nonzero(train > 0).flatten().to(device)
        part = dataclasses.replace(stats, multiplicity=train.to(device)).rows(keep)
        result, _, mask, per_group = _em_all_k(part, ks, gen, **em)
        ll = torch.nan_to_num(result.log_likelihood, nan=-math.inf).view(len(ks), per_group)
        best = torch.arange(len(ks), device=device) * per_group + _first_best(ll)  # (num_k,)
        out = torch.nonzero(held[:, f] > 0).flatten().to(device)
        lt = result.log_transition[best].clamp_min(floor)  # (num_k, K, A, A)
        li = None if result.log_initial is None else result.log_initial[best].clamp_min(floor)
        first = None if stats.first_counts is None else stats.first_counts[out]
        joint = e_table(stats.counts[out], first, lt.to(stats.counts.dtype), li)  # (u, num_k, K)
        joint = joint + result.log_weights[best].to(joint.dtype)
        joint = joint.masked_fill(~mask[best], -math.inf)
        values.append(torch.logsumexp(joint, -1))  # (u, num_k)
        weights.append(held[out.cpu(), f].to(joint.dtype).to(device))
    return torch.cat(values), torch.cat(weights)
