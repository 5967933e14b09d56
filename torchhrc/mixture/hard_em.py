"""The paper's Cluster-Transition-Matrices (hard EM), for many runs at once.

Nikolaidis et al., "Efficient Model Learning for Human-Robot Collaborative Tasks",
algorithm Cluster-Transition-Matrices(k):

1. initialise ``theta_1..theta_k`` at random (rows ~ Dirichlet(1)) and the assignments ``Z``;
2. repeat
3.   E-step: ``z_i = argmax_z prod_{j>=2} theta_z(x_i^j | x_i^{j-1})``;
4.   M-step: ``theta_z(b | a) = n_z(a -> b) / sum_b' n_z(a -> b')`` (counts of the sequences
     assigned to ``z``);
5. until ``Z`` no longer changes.

Every run (restart x value of k) is a slice of one batch; see :mod:`torchhrc.mixture._em`.

**Unseen transitions** (``log 0``): the M-step keeps exact zeros, so the returned
``log_transition`` has ``-inf`` where a cluster never saw a transition. In the E-step a
probability 0 is scored as ``floor`` (default ``1e-10``, ``log = -23``): a sequence that
contains a transition no cluster has seen is still assigned, by its other transitions and
the number of unseen ones, and no ``nan`` can arise (``0 * -inf`` never occurs). A row
``a`` with no outgoing counts in a cluster (including an empty cluster) keeps its previous
values (the M-step's ``0 / 0`` is undefined). The reported log-likelihood is the paper's
``l(D; theta) = sum_i log(P(z_i) prod_j theta_{z_i}(x_i^j | x_i^{j-1}))`` with
``P(z) = n_z / n`` and the exact (unfloored) ``theta``; it is finite at convergence, since
every sequence's transitions were counted in its own cluster.

Example:
    >>> import torch
    >>> from torchhrc.mixture.counts import sufficient_statistics
    >>> s = sufficient_statistics(torch.tensor([[0, 0, 0], [1, 1, 1]]), torch.tensor([3, 3]), 2)
    >>> lt0 = torch.tensor([[[[0.9, 0.1], [0.9, 0.1]], [[0.1, 0.9], [0.1, 0.9]]]]).log().double()
    >>> hard_em(s, lt0, torch.ones(1, 2, dtype=torch.bool)).assignments[s.inverse, 0].tolist()
    [0, 1]
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F

from torchhrc.errors import ModelError
from torchhrc.mixture._em import (
    EMResult,
    chunk_rows,
    e_table,
    exact_row_log_likelihood,
    m_step_transition,
)
from torchhrc.mixture.counts import SufficientStatistics

__all__ = ["hard_em", "partition_counts", "partition_sizes"]


def _e_step(
    stats: SufficientStatistics,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    cluster_mask: torch.Tensor,
    log_floor: float,
) -> torch.Tensor:
    """E-step (argmax of the floored log-likelihood), chunk by chunk: ``(U, R)`` int64."""
    R, K, _, _ = log_transition.shape
    table = log_transition.clamp_min(log_floor)
    init_table = log_initial.clamp_min(log_floor) if log_initial is not None else None
    masked = table.new_zeros(R, K).masked_fill(~cluster_mask, -math.inf)
    z = torch.empty(stats.num_distinct, R, dtype=torch.long, device=table.device)
    for rows in chunk_rows(stats.num_distinct, R, K):
        first = stats.first_counts[rows] if stats.first_counts is not None else None
        ll = e_table(stats.counts[rows], first, table, init_table) + masked
        z[rows] = ll.max(-1).indices  # first maximum, as argmax; faster on CPU
    return z


def partition_sizes(z: torch.Tensor, multiplicity: torch.Tensor, K: int) -> torch.Tensor:
    """``(R, K)`` weighted cluster sizes of a hard partition ``z (U, R)``, by one bincount."""
    U, R = z.shape
    index = z + K * torch.arange(R, device=z.device)  # (U, R) global cluster slot
    weights = multiplicity.unsqueeze(-1).expand(U, R)
    return torch.bincount(index.reshape(-1), weights.reshape(-1), minlength=R * K).view(R, K)


def partition_counts(
    stats: SufficientStatistics, z: torch.Tensor, K: int, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Counts of a hard partition ``z (U, R)``: ``(R * K, A * A)`` and ``(R * K, A) | None``.

    One matrix product of the one-hot assignments with the (multiplicity-weighted) counts.
    """
    U, R = z.shape
    A = stats.num_symbols
    mult = stats.multiplicity.to(dtype)
    weighted = stats.counts.to(dtype) * mult.unsqueeze(-1)  # (U, D)
    counts = weighted.new_zeros(R * K, A * A)
    init_counts = weighted.new_zeros(R * K, A) if stats.first_counts is not None else None
    for rows in chunk_rows(U, R, K):
        onehot = F.one_hot(z[rows], K).to(dtype).view(-1, R * K).transpose(0, 1)  # (R*K, c)
        counts += onehot @ weighted[rows]
        if init_counts is not None and stats.first_counts is not None:
            init_counts += onehot @ (stats.first_counts[rows].to(dtype) * mult[rows, None])
    return counts, init_counts


def _update_counts(
    stats: SufficientStatistics,
    counts: torch.Tensor,
    init_counts: torch.Tensor | None,
    runs: torch.Tensor,
    z_old: torch.Tensor,
    z_new: torch.Tensor,
    K: int,
) -> None:
    """Move the counts of the rows whose cluster changed (in place; exact integer sums).

    ``counts (R * K, D)``; ``runs (R_active,)`` the global index of each column of
    ``z_old, z_new (U, R_active)``.
    """
    u, r = torch.nonzero(z_new != z_old, as_tuple=True)
    if u.numel() == 0:
        return
    w = stats.multiplicity[u].unsqueeze(-1)
    source = stats.counts[u] * w  # (M, D)
    counts.index_add_(0, runs[r] * K + z_new[u, r], source)
    counts.index_add_(0, runs[r] * K + z_old[u, r], -source)
    if init_counts is not None and stats.first_counts is not None:
        first = stats.first_counts[u] * w
        init_counts.index_add_(0, runs[r] * K + z_new[u, r], first)
        init_counts.index_add_(0, runs[r] * K + z_old[u, r], -first)


def hard_em(
    stats: SufficientStatistics,
    log_transition: torch.Tensor,
    cluster_mask: torch.Tensor,
    *,
    assignments: torch.Tensor | None = None,
    log_initial: torch.Tensor | None = None,
    floor: float = 1e-10,
    max_iterations: int = 100,
    progress: Callable[[int, int], None] | None = None,
) -> EMResult:
    """Run the paper's hard EM from ``R`` initial models at once.

    Args:
        stats: the distinct sequences (:func:`~torchhrc.mixture.counts.sufficient_statistics`).
        log_transition: ``(R, K, A, A)`` initial log transition matrices of every run.
        cluster_mask: ``(R, K)`` bool, ``True`` on the clusters run ``r`` uses (its ``k``).
        assignments: ``(U, R)`` initial assignments (the paper's line 2); only compared
            with the first E-step's. ``None``: all -1 (never equal).
        log_initial: ``(R, K, A)`` initial first-symbol log-probabilities, or ``None`` (the
            paper: first symbols are not modelled).
        floor: probability used for a zero probability in the E-step (see module doc).
        max_iterations: cap on E/M iterations (a run not stable by then is reported as
            not converged).
        progress: called as ``progress(iteration, runs_still_changing)`` after each iteration.

    Returns:
        :class:`~torchhrc.mixture._em.EMResult`; a run's parameters stop changing once its
        assignments are stable, so every run's result equals running it alone.

    Raises:
        ModelError: shapes disagree.
    """
    if log_transition.dim() != 4 or log_transition.shape[-1] != stats.num_symbols:
        raise ModelError(
            f"expected log_transition to have shape (R, K, A={stats.num_symbols}, "
            f"A={stats.num_symbols}), actual shape = {tuple(log_transition.shape)}"
        )
    R, K, A, _ = log_transition.shape
    if cluster_mask.shape != (R, K):
        raise ModelError(
            f"expected cluster_mask to have shape (R={R}, K={K}), "
            f"actual shape = {tuple(cluster_mask.shape)}"
        )
    if not 0.0 < floor < 1.0:
        raise ValueError(f"expected floor in (0, 1), got {floor}")
    if max_iterations < 1:
        raise ValueError(f"expected max_iterations >= 1, got {max_iterations}")
    if (log_initial is None) != (stats.first_counts is None):
        raise ModelError("log_initial must be given exactly when stats keep first symbols")
    U = stats.num_distinct
    log_floor = math.log(floor)
    z = (
        assignments.to(torch.long).clone()
        if assignments is not None
        else torch.full((U, R), -1, dtype=torch.long, device=log_transition.device)
    )
    lt = log_transition.clone()
    li = log_initial.clone() if log_initial is not None else None
    iterations = torch.zeros(R, dtype=torch.long, device=lt.device)
    converged = torch.zeros(R, dtype=torch.bool, device=lt.device)
    # only the runs whose assignments still change are computed (compaction): a run whose
    # assignments are stable has met the paper's stopping rule and is frozen. After the
    # first iteration the M-step's counts are updated by the rows that changed cluster only.
    active = torch.arange(R, device=lt.device)
    counts = init_counts = None
    for it in range(1, max_iterations + 1):
        sub_lt = lt[active]
        sub_li = li[active] if li is not None else None
        z_new = _e_step(stats, sub_lt, sub_li, cluster_mask[active], log_floor)
        z_old = z[:, active]
        changes = (z_new != z_old).sum(0)  # (active,)
        if counts is None or int(changes.sum()) * A * A > (1 << 24):
            counts, init_counts = partition_counts(stats, z_new, K, lt.dtype)
            # keep the counts of all runs addressable by global run index
            counts_all = lt.new_zeros(R * K, A * A)
            counts_all.view(R, K, -1)[active] = counts.view(-1, K, A * A)
            counts = counts_all
            if init_counts is not None:
                init_all = lt.new_zeros(R * K, A)
                init_all.view(R, K, -1)[active] = init_counts.view(-1, K, A)
                init_counts = init_all
        else:
            _update_counts(stats, counts, init_counts, active, z_old, z_new, K)
        z[:, active] = z_new
        lt[active] = m_step_transition(counts.view(R, K, A, A)[active], sub_lt, 0.0)
        if li is not None and sub_li is not None and init_counts is not None:
            li[active] = m_step_transition(init_counts.view(R, K, A)[active], sub_li, 0.0)
        changed = changes > 0
        iterations[active] += 1
        converged[active[~changed]] = True
        active = active[changed]
        if progress is not None:
            progress(it, int(active.numel()))
        if active.numel() == 0:
            break
    # P(z) = n_z / n and the classification log-likelihood of the final partition
    mult = stats.multiplicity
    sizes = partition_sizes(z.clamp_min(0), mult, K).to(lt.dtype)  # (R, K)
    log_weights = sizes.log() - sizes.sum(-1, keepdim=True).log()
    total = lt.new_zeros(R)
    for rows in chunk_rows(U, R, K):
        ll = exact_row_log_likelihood(stats, lt, li, rows)  # (c, R, K)
        own = ll.gather(-1, z[rows].clamp_min(0).unsqueeze(-1)).squeeze(-1)  # (c, R)
        own = own + log_weights.gather(-1, z[rows].clamp_min(0).transpose(0, 1)).transpose(0, 1)
        total += (own * mult[rows, None]).sum(0)
    return EMResult(
        log_transition=lt,
        log_weights=log_weights,
        log_initial=li,
        assignments=z,
        log_likelihood=total,
        entropy=torch.zeros_like(total),
        iterations=iterations,
        converged=converged,
    )
