"""Soft EM (responsibilities) with Dirichlet pseudo-count smoothing, for many runs at once.

MAP-EM for a mixture of Markov chains with symmetric Dirichlet priors (Dempster, Laird,
Rubin 1977; smoothing as in Jääskinen et al. 2013, cited by the paper):

* E-step: ``r[n, k] = w_k P(x_n | k) / sum_k' w_k' P(x_n | k')`` (log space, logsumexp);
* M-step: ``theta_k(b | a) = (sum_n r[n, k] n_n(a -> b) + alpha)
  / (sum_n r[n, k] n_n(a) + A alpha)``
  and ``w_k = (sum_n r[n, k] + beta) / (n + k beta)``.

With ``alpha > 0`` every probability is positive, so no ``-inf`` (nor ``nan``) can occur.
A run stops when its marginal log-likelihood changes by less than ``tol * |l|``; its
parameters are then frozen, so each run's result equals running it alone.

Example:
    >>> import torch
    >>> from torchhrc.mixture.counts import sufficient_statistics
    >>> s = sufficient_statistics(torch.tensor([[0, 0, 0], [1, 1, 1]]), torch.tensor([3, 3]), 2)
    >>> lt0 = torch.tensor([[[[0.9, 0.1], [0.9, 0.1]], [[0.1, 0.9], [0.1, 0.9]]]]).log().double()
    >>> r = soft_em(s, lt0, torch.zeros(1, 2).double(), torch.ones(1, 2, dtype=torch.bool))
    >>> r.assignments[s.inverse, 0].tolist()
    [0, 1]
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from torchhrc.errors import ModelError
from torchhrc.mixture._em import (
    EMResult,
    Smoothing,
    column_blocks,
    m_step_transition,
    pseudo_parts,
    run_groups,
)
from torchhrc.mixture.counts import SufficientStatistics

__all__ = ["EStep", "SoftStatistics", "m_step", "soft_em", "soft_pass", "sum_statistics"]


@dataclass(frozen=True)
class SoftStatistics:
    """What one pass over the data gives (all batched over the ``R`` runs).

    Attributes:
        counts: ``(R, K, A, A)`` expected transition counts.
        initial_counts: ``(R, K, A)`` expected first-symbol counts, or None.
        sizes: ``(R, K)`` expected cluster sizes ``sum_n r[n, k]``.
        log_likelihood: ``(R,)`` marginal log-likelihood of the parameters used.
        entropy: ``(R,)`` entropy of the responsibilities (0 when not computed).
        assignments: ``(U, R)`` most responsible cluster (``(0, R)`` when not computed).
    """

    counts: torch.Tensor
    initial_counts: torch.Tensor | None
    sizes: torch.Tensor
    log_likelihood: torch.Tensor
    entropy: torch.Tensor
    assignments: torch.Tensor


#: ``e_step(log_transition, log_weights, log_initial, cluster_mask, details) -> SoftStatistics``
EStep = Callable[
    [torch.Tensor, torch.Tensor, "torch.Tensor | None", torch.Tensor, bool], SoftStatistics
]


class _Data:
    """The distinct rows laid out for the packed kernels (built once per EM call).

    Only the transitions seen somewhere in the rows (``support (D',)``, indices into the
    ``D = A * A`` transitions) enter the products: an unseen transition has count 0 in every
    row, so it adds exactly 0 to every joint log-likelihood and to every expected count.
    Dropping those columns changes no result (the products add the same nonzero terms in
    the same order) and shrinks both matrix products of a pass; place-and-drill
    demonstrations alternate human and robot actions, so half of the ``A * A`` transitions
    never occur (``D' = D / 2``).

    ``rows (U, D' [+ A] + 1)``: transition counts on the support, first-symbol counts (when
    modelled) and a column of ones side by side (the M-step's right operand: expected counts
    and sizes in one product); ``xt`` its transpose (the E-step's right operand: with the
    log weights as the table's last column, the product is the joint log-likelihood);
    ``mult (U,)``.
    """

    def __init__(self, stats: SufficientStatistics, dtype: torch.dtype) -> None:
        counts = stats.counts.to(dtype)
        U = counts.shape[0]
        self.support = torch.nonzero((counts != 0).any(0)).squeeze(-1)  # (D',)
        counts = counts[:, self.support]  # (U, D')
        self.mult = stats.multiplicity.to(dtype)
        first = stats.first_counts.to(dtype) if stats.first_counts is not None else None
        ones = counts.new_ones(U, 1)
        # E-step operand (D' [+ A] + 1, U): the last row of ones adds each cluster's log weight
        parts = [counts, first, ones] if first is not None else [counts, ones]
        self.xt = torch.cat(parts, -1).transpose(0, 1).contiguous()
        # M-step operand (U, D' [+ A] + 1): the last column of ones sums the cluster sizes
        self.rows = torch.cat(parts, -1)
        self.num_symbols = stats.num_symbols


def _pass(
    data: _Data,
    log_transition: torch.Tensor,
    log_weights: torch.Tensor,
    log_initial: torch.Tensor | None,
    cluster_mask: torch.Tensor,
    details: bool,
) -> SoftStatistics:
    """:func:`soft_pass` on prepared data (see there)."""
    R, K, A, _ = log_transition.shape
    D, U, Ds = A * A, data.xt.shape[-1], data.support.shape[0]
    lt = log_transition.reshape(R, K, D)[..., data.support]  # (R, K, D') the seen transitions
    stat = log_transition.new_zeros(R, K, data.rows.shape[-1])  # (R, K, D' [+ A] + 1)
    total = log_transition.new_zeros(R)
    entropy = log_transition.new_zeros(R)
    z = torch.empty(U if details else 0, R, dtype=torch.long, device=lt.device)
    zt = z.transpose(0, 1)  # (R, U) view
    for runs, slots in run_groups(cluster_mask):
        Rg, k = slots.shape
        rows, cols_k = runs[:, None], slots
        parts = [lt[rows, cols_k]]  # (R_g, k, D')
        if log_initial is not None:
            parts.append(log_initial[rows, cols_k])  # (R_g, k, A)
        parts.append(log_weights[rows, cols_k].unsqueeze(-1))  # (R_g, k, 1)
        table = torch.cat(parts, -1).view(Rg * k, -1)  # (R_g * k, D' [+ A] + 1)
        g_stat = stat.new_zeros(Rg * k, data.rows.shape[-1])
        g_total = stat.new_zeros(Rg)
        g_entropy = stat.new_zeros(Rg)
        for cols in column_blocks(U, Rg * k):
            joint = table @ data.xt[:, cols]  # (R_g * k, c) log w_k + log P(x_u | k)
            j3 = joint.view(Rg, k, -1)
            # reductions over the cluster axis (not innermost: vectorised over rows)
            if details:
                top, idx = j3.max(1, keepdim=True)  # (R_g, 1, c)
                zt[runs, cols] = slots.gather(1, idx.squeeze(1))
            else:
                top = j3.amax(1, keepdim=True)  # every run has a finite cluster
            j3 -= top
            j3.exp_()  # unnormalised responsibilities, 0 where log w = -inf
            mass = j3.sum(1, keepdim=True)  # (R_g, 1, c), in [1, k]
            m = data.mult[cols]
            g_total += (top + mass.log()).view(Rg, -1) @ m  # sum_u m_u logsumexp_u
            if details:
                resp = j3 / mass
                g_entropy -= torch.xlogy(resp, resp).sum(1) @ m
            j3 *= m / mass  # m_u r[u, k]
            g_stat += joint @ data.rows[cols]  # expected counts and sizes
        stat[rows, cols_k] = g_stat.view(Rg, k, -1)
        total[runs] = g_total
        entropy[runs] = g_entropy
    counts = stat.new_zeros(R, K, D)  # unseen transitions: expected count 0
    counts[..., data.support] = stat[..., :Ds]
    return SoftStatistics(
        counts=counts.view(R, K, A, A),
        initial_counts=stat[..., Ds:-1] if log_initial is not None else None,
        sizes=stat[..., -1],
        log_likelihood=total,
        entropy=entropy,
        assignments=z,
    )


def soft_pass(
    stats: SufficientStatistics,
    log_transition: torch.Tensor,
    log_weights: torch.Tensor,
    log_initial: torch.Tensor | None,
    cluster_mask: torch.Tensor,
    *,
    details: bool = True,
) -> SoftStatistics:
    """E-step and expected counts for ``R`` runs, packed by k, block by block over the rows.

    Args:
        stats: distinct rows; log_transition: ``(R, K, A, A)`` finite;
        log_weights: ``(R, K)``; log_initial: ``(R, K, A)`` finite or None;
        cluster_mask: ``(R, K)`` bool (masked slots get no responsibility, zero counts).
        details: also compute the entropy and the assignments (``False``: entropy 0 and
            ``assignments`` of shape ``(0, R)``; what EM iterations need is cheaper).

    Example:
        >>> from torchhrc.mixture.counts import sufficient_statistics
        >>> s = sufficient_statistics(torch.tensor([[0, 0], [1, 1]]), torch.tensor([2, 2]), 2)
        >>> lt = torch.full((1, 2, 2, 2), 0.5).log()
        >>> soft_pass(s, lt, torch.zeros(1, 2), None, torch.ones(1, 2, dtype=torch.bool)).sizes
        tensor([[1., 1.]])
    """
    dtype = log_transition.dtype
    return _pass(
        _Data(stats, dtype),
        log_transition,
        log_weights.to(dtype),
        log_initial,
        cluster_mask,
        details,
    )


def sum_statistics(parts: list[SoftStatistics]) -> SoftStatistics:
    """The statistics of the whole data from those of disjoint chunks of its rows.

    Every field of :class:`SoftStatistics` but the assignments is a sum over rows, so a
    sharded E-step (:func:`soft_pass` on ``stats.rows(chunk)`` per worker) adds up to the
    one-pass result; the assignments are concatenated along the rows.

    Example:
        >>> from torchhrc.mixture.counts import sufficient_statistics
        >>> s = sufficient_statistics(torch.tensor([[0, 0], [1, 1]]), torch.tensor([2, 2]), 2)
        >>> lt, lw = torch.full((1, 2, 2, 2), 0.5).log(), torch.zeros(1, 2)
        >>> mask = torch.ones(1, 2, dtype=torch.bool)
        >>> parts = [soft_pass(s.rows(slice(i, i + 1)), lt, lw, None, mask) for i in (0, 1)]
        >>> sum_statistics(parts).sizes
        tensor([[1., 1.]])
    """
    if not parts:
        raise ValueError("expected at least one SoftStatistics to sum, got none")
    first = parts[0]
    return SoftStatistics(
        counts=sum((p.counts for p in parts[1:]), first.counts),
        initial_counts=None
        if first.initial_counts is None
        else sum((p.initial_counts for p in parts[1:]), first.initial_counts),  # type: ignore[misc]
        sizes=sum((p.sizes for p in parts[1:]), first.sizes),
        log_likelihood=sum((p.log_likelihood for p in parts[1:]), first.log_likelihood),
        entropy=sum((p.entropy for p in parts[1:]), first.entropy),
        assignments=torch.cat([p.assignments for p in parts], 0),
    )


def m_step(
    expected: SoftStatistics,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    cluster_mask: torch.Tensor,
    pseudo_count: float | Smoothing,
    weight_pseudo_count: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """MAP parameters from expected counts: ``(R, K, A, A)``, ``(R, K)``, ``(R, K, A) | None``."""
    on_transitions, on_first = pseudo_parts(pseudo_count)
    lt = m_step_transition(expected.counts, log_transition, on_transitions)
    li = None
    if log_initial is not None and expected.initial_counts is not None:
        li = m_step_transition(expected.initial_counts, log_initial, on_first)
    sizes = (expected.sizes + weight_pseudo_count).masked_fill(~cluster_mask, 0.0)
    log_weights = sizes.log() - sizes.sum(-1, keepdim=True).log()
    return lt, log_weights, li


def soft_em(
    stats: SufficientStatistics,
    log_transition: torch.Tensor,
    log_weights: torch.Tensor,
    cluster_mask: torch.Tensor,
    *,
    log_initial: torch.Tensor | None = None,
    pseudo_count: float | Smoothing = 0.1,
    weight_pseudo_count: float = 1.0,
    tol: float = 1e-6,
    max_iterations: int = 200,
    progress: Callable[[int, int], None] | None = None,
    details: bool = True,
    e_step: EStep | None = None,
) -> EMResult:
    """Run soft EM from ``R`` initial models at once.

    Args:
        stats: the distinct sequences.
        log_transition: ``(R, K, A, A)`` initial log transition matrices (finite).
        log_weights: ``(R, K)`` initial log mixture weights.
        cluster_mask: ``(R, K)`` bool, the clusters each run uses.
        log_initial: ``(R, K, A)`` initial first-symbol log-probabilities, or None.
        pseudo_count: Dirichlet pseudo-count ``alpha > 0`` added to every transition count,
            or a :class:`~torchhrc.mixture._em.Smoothing` (``alpha`` on the transitions that
            can occur only: the context symbols of :mod:`torchhrc.mixture.history`).
        weight_pseudo_count: pseudo-count ``beta >= 0`` added to every cluster size.
        tol: relative change of the log-likelihood below which a run has converged.
        max_iterations: cap on iterations.
        progress: called as ``progress(iteration, runs_still_running)``.
        details: compute the final entropy and assignments (one more pass over the data;
            ``False``: ``entropy`` is 0 and ``assignments`` has shape ``(0, R)``).
        e_step: computes every pass over the data instead of this process, called as
            ``e_step(log_transition, log_weights, log_initial, cluster_mask, details)`` and
            returning :class:`SoftStatistics` of all of ``stats``' rows (e.g. the sum of the
            passes over chunks of the rows on a Ray cluster,
            :class:`torchhrc.mixture.ray_estep.RayEStep`); ``None``: :func:`soft_pass` here.

    Returns:
        :class:`~torchhrc.mixture._em.EMResult` whose ``log_likelihood`` is the marginal
        log-likelihood of the returned parameters.

    Raises:
        ModelError: shapes disagree; ValueError: a non-positive pseudo-count.
    """
    if log_transition.dim() != 4 or log_transition.shape[-1] != stats.num_symbols:
        raise ModelError(
            f"expected log_transition to have shape (R, K, A={stats.num_symbols}, "
            f"A={stats.num_symbols}), actual shape = {tuple(log_transition.shape)}"
        )
    R, K, _, _ = log_transition.shape
    if cluster_mask.shape != (R, K) or log_weights.shape != (R, K):
        raise ModelError(
            f"expected cluster_mask and log_weights to have shape (R={R}, K={K}), actual "
            f"shapes = {tuple(cluster_mask.shape)}, {tuple(log_weights.shape)}"
        )
    alpha = pseudo_count.alpha if isinstance(pseudo_count, Smoothing) else pseudo_count
    if not alpha > 0:
        raise ValueError(f"expected pseudo_count > 0, got {alpha}")
    if weight_pseudo_count < 0:
        raise ValueError(f"expected weight_pseudo_count >= 0, got {weight_pseudo_count}")
    if max_iterations < 1:
        raise ValueError(f"expected max_iterations >= 1, got {max_iterations}")
    if (log_initial is None) != (stats.first_counts is None):
        raise ModelError("log_initial must be given exactly when stats keep first symbols")
    lt = log_transition.clone()
    lw = log_weights.masked_fill(~cluster_mask, -math.inf)
    li = log_initial.clone() if log_initial is not None else None
    iterations = torch.zeros(R, dtype=torch.long, device=lt.device)
    converged = torch.zeros(R, dtype=torch.bool, device=lt.device)
    if e_step is None:
        data = _Data(stats, lt.dtype)

        def e_step(lt_, lw_, li_, mask_, details_):  # type: ignore[no-redef]
            return _pass(data, lt_, lw_, li_, mask_, details_)

    # the iterations need only the expected counts and the log-likelihood; the entropy and
    # the assignments of the final parameters come from one pass at the end
    expected = e_step(lt, lw, li, cluster_mask, False)
    log_likelihood = expected.log_likelihood.clone()
    # only runs that have not converged are computed (compaction); a converged run keeps
    # its parameters, so every run's result equals running it alone
    active = torch.arange(R, device=lt.device)
    for it in range(1, max_iterations + 1):
        sub_li = li[active] if li is not None else None
        new_lt, new_lw, new_li = m_step(
            expected, lt[active], sub_li, cluster_mask[active], pseudo_count, weight_pseudo_count
        )
        lt[active], lw[active] = new_lt, new_lw
        if li is not None and new_li is not None:
            li[active] = new_li
        iterations[active] += 1
        previous = log_likelihood[active]
        expected = e_step(new_lt, new_lw, new_li, cluster_mask[active], False)
        log_likelihood[active] = expected.log_likelihood
        done = (expected.log_likelihood - previous).abs() <= tol * expected.log_likelihood.abs()
        converged[active[done]] = True
        active = active[~done]
        expected = _subset(expected, ~done)
        if progress is not None:
            progress(it, int(active.numel()))
        if active.numel() == 0:
            break
    if details:
        final = e_step(lt, lw, li, cluster_mask, True)
        entropy, assignments = final.entropy, final.assignments
    else:
        entropy = torch.zeros_like(log_likelihood)
        assignments = torch.empty(0, R, dtype=torch.long, device=lt.device)
    return EMResult(
        log_transition=lt,
        log_weights=lw,
        log_initial=li,
        assignments=assignments,
        log_likelihood=log_likelihood,
        entropy=entropy,
        iterations=iterations,
        converged=converged,
    )


def _subset(stats: SoftStatistics, keep: torch.Tensor) -> SoftStatistics:
    """The runs ``keep`` (bool ``(R,)``) of ``stats``."""
    return SoftStatistics(
        counts=stats.counts[keep],
        initial_counts=None if stats.initial_counts is None else stats.initial_counts[keep],
        sizes=stats.sizes[keep],
        log_likelihood=stats.log_likelihood[keep],
        entropy=stats.entropy[keep],
        assignments=stats.assignments[:, keep],
    )
