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
from torchhrc.mixture._em import EMResult, chunk_rows, e_table, m_step_transition
from torchhrc.mixture.counts import SufficientStatistics

__all__ = ["SoftStatistics", "soft_em", "soft_pass"]


@dataclass(frozen=True)
class SoftStatistics:
    """What one pass over the data gives (all batched over the ``R`` runs).

    Attributes:
        counts: ``(R, K, A, A)`` expected transition counts.
        initial_counts: ``(R, K, A)`` expected first-symbol counts, or None.
        sizes: ``(R, K)`` expected cluster sizes ``sum_n r[n, k]``.
        log_likelihood: ``(R,)`` marginal log-likelihood of the parameters used.
        entropy: ``(R,)`` entropy of the responsibilities.
        assignments: ``(U, R)`` most responsible cluster.
    """

    counts: torch.Tensor
    initial_counts: torch.Tensor | None
    sizes: torch.Tensor
    log_likelihood: torch.Tensor
    entropy: torch.Tensor
    assignments: torch.Tensor


def soft_pass(
    stats: SufficientStatistics,
    log_transition: torch.Tensor,
    log_weights: torch.Tensor,
    log_initial: torch.Tensor | None,
    cluster_mask: torch.Tensor,
) -> SoftStatistics:
    """E-step and expected counts for ``R`` runs, chunk by chunk over the distinct rows.

    Args:
        stats: distinct rows; log_transition: ``(R, K, A, A)`` finite;
        log_weights: ``(R, K)``; log_initial: ``(R, K, A)`` finite or None;
        cluster_mask: ``(R, K)`` bool.
    """
    R, K, A, _ = log_transition.shape
    U = stats.num_distinct
    lw = log_weights.masked_fill(~cluster_mask, -math.inf)  # (R, K)
    mult = stats.multiplicity
    weighted = stats.counts * mult.unsqueeze(-1)  # (U, D)
    counts = log_transition.new_zeros(R * K, A * A)
    init_counts = log_transition.new_zeros(R * K, A) if log_initial is not None else None
    sizes = log_transition.new_zeros(R * K)
    total = log_transition.new_zeros(R)
    entropy = log_transition.new_zeros(R)
    z = torch.empty(U, R, dtype=torch.long, device=log_transition.device)
    for rows in chunk_rows(U, R, K):
        first = stats.first_counts[rows] if stats.first_counts is not None else None
        joint = e_table(stats.counts[rows], first, log_transition, log_initial) + lw  # (c, R, K)
        # one max gives both the assignments and the stable logsumexp shift
        top = joint.max(-1, keepdim=True)  # every run has an active, finite cluster
        z[rows] = top.indices.squeeze(-1)
        shifted = joint - top.values  # (c, R, K), -inf on masked slots
        unnorm = shifted.exp()
        total_mass = unnorm.sum(-1, keepdim=True)  # in [1, K]
        log_mass = total_mass.log()
        log_norm = top.values + log_mass  # (c, R, 1) = logsumexp
        log_resp = shifted - log_mass
        resp = unnorm / total_mass  # exactly 0 on masked slots
        m = mult[rows]
        total += (log_norm.squeeze(-1) * m.unsqueeze(-1)).sum(0)
        plogp = torch.where(resp > 0, resp * log_resp, resp.new_zeros(()))
        entropy -= (plogp.sum(-1) * m.unsqueeze(-1)).sum(0)
        flat = resp.view(-1, R * K)  # (c, R*K)
        counts += flat.transpose(0, 1) @ weighted[rows]
        sizes += flat.transpose(0, 1) @ m
        if init_counts is not None and first is not None:
            init_counts += flat.transpose(0, 1) @ (first * m[:, None])
    return SoftStatistics(
        counts=counts.view(R, K, A, A),
        initial_counts=None if init_counts is None else init_counts.view(R, K, A),
        sizes=sizes.view(R, K),
        log_likelihood=total,
        entropy=entropy,
        assignments=z,
    )


def m_step(
    expected: SoftStatistics,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    cluster_mask: torch.Tensor,
    pseudo_count: float,
    weight_pseudo_count: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """MAP parameters from expected counts: ``(R, K, A, A)``, ``(R, K)``, ``(R, K, A) | None``."""
    lt = m_step_transition(expected.counts, log_transition, pseudo_count)
    li = None
    if log_initial is not None and expected.initial_counts is not None:
        li = m_step_transition(expected.initial_counts, log_initial, pseudo_count)
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
    pseudo_count: float = 0.1,
    weight_pseudo_count: float = 1.0,
    tol: float = 1e-6,
    max_iterations: int = 200,
    progress: Callable[[int, int], None] | None = None,
) -> EMResult:
    """Run soft EM from ``R`` initial models at once.

    Args:
        stats: the distinct sequences.
        log_transition: ``(R, K, A, A)`` initial log transition matrices (finite).
        log_weights: ``(R, K)`` initial log mixture weights.
        cluster_mask: ``(R, K)`` bool, the clusters each run uses.
        log_initial: ``(R, K, A)`` initial first-symbol log-probabilities, or None.
        pseudo_count: Dirichlet pseudo-count ``alpha > 0`` added to every transition count.
        weight_pseudo_count: pseudo-count ``beta >= 0`` added to every cluster size.
        tol: relative change of the log-likelihood below which a run has converged.
        max_iterations: cap on iterations.
        progress: called as ``progress(iteration, runs_still_running)``.

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
    if not pseudo_count > 0:
        raise ValueError(f"expected pseudo_count > 0, got {pseudo_count}")
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
    expected = soft_pass(stats, lt, lw, li, cluster_mask)
    log_likelihood = expected.log_likelihood.clone()
    entropy = expected.entropy.clone()
    assignments = expected.assignments.clone()
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
        expected = soft_pass(stats, new_lt, new_lw, new_li, cluster_mask[active])
        log_likelihood[active] = expected.log_likelihood
        entropy[active] = expected.entropy
        assignments[:, active] = expected.assignments
        done = (expected.log_likelihood - previous).abs() <= tol * expected.log_likelihood.abs()
        converged[active[done]] = True
        active = active[~done]
        expected = _subset(expected, ~done)
        if progress is not None:
            progress(it, int(active.numel()))
        if active.numel() == 0:
            break
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
