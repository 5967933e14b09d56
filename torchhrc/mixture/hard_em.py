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
The runs are packed by their k (no masked cluster slots are computed), a run whose
assignments are stable is dropped from the batch, and after the first iteration the
M-step's counts are updated by the rows that changed cluster only (exact: the counts are
integer-valued).

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

from torchhrc.errors import ModelError
from torchhrc.mixture._em import (
    EMResult,
    column_blocks,
    m_step_transition,
    onehot_sums,
    run_groups,
)
from torchhrc.mixture.counts import SufficientStatistics

__all__ = ["hard_em", "partition_counts", "partition_sizes"]


def partition_sizes(z: torch.Tensor, multiplicity: torch.Tensor, K: int) -> torch.Tensor:
    """``(R, K)`` weighted cluster sizes of a hard partition ``z (U, R)``, by one bincount.

    Example:
        >>> partition_sizes(torch.tensor([[0], [1], [1]]), torch.tensor([2.0, 1.0, 1.0]), 2)
        tensor([[2., 2.]])
    """
    U, R = z.shape
    index = z + K * torch.arange(R, device=z.device)  # (U, R) global cluster slot
    weights = multiplicity.unsqueeze(-1).expand(U, R)
    return torch.bincount(index.reshape(-1), weights.reshape(-1), minlength=R * K).view(R, K)


def partition_counts(
    stats: SufficientStatistics, z: torch.Tensor, K: int, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Counts of a hard partition ``z (U, R)``: ``(R * K, A * A)`` and ``(R * K, A) | None``.

    One matrix product of the one-hot assignments with the (multiplicity-weighted) counts per
    group of runs with the same number of used slots (``z``'s distinct values per run).

    Example:
        >>> from torchhrc.mixture.counts import sufficient_statistics
        >>> s = sufficient_statistics(torch.tensor([[0, 1], [1, 1]]), torch.tensor([2, 2]), 2)
        >>> partition_counts(s, torch.tensor([[1], [0]]), 2, torch.float64)[0].tolist()
        [[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    """
    U, R = z.shape
    A = stats.num_symbols
    mult = stats.multiplicity.to(dtype)
    weighted = stats.counts.to(dtype) * mult.unsqueeze(-1)  # (U, D)
    if stats.first_counts is not None:
        weighted = torch.cat([weighted, stats.first_counts.to(dtype) * mult[:, None]], -1)
    zt = z.transpose(0, 1).contiguous()  # (R, U)
    used = torch.zeros(R, K, dtype=torch.bool, device=z.device)
    if U:
        used.scatter_(1, zt, True)
    out = weighted.new_zeros(R, K, weighted.shape[-1])
    for runs, slots in run_groups(used):
        out[runs[:, None], slots] = onehot_sums(zt[runs], slots, weighted, slots.numel()).view(
            *slots.shape, -1
        )
    out = out.view(R * K, -1)
    if stats.first_counts is None:
        return out, None
    return out[:, : A * A].contiguous(), out[:, A * A :].contiguous()


def _assign(
    xc: torch.Tensor, table: torch.Tensor, slots: torch.Tensor, z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """E-step of one group of runs (in place): first maximum of the floored log-likelihood.

    Args:
        xc: ``(D', U)`` counts (transitions, then first symbols when modelled) by column.
        table: ``(R_g, k, D')`` floored log-probabilities of the group's runs.
        slots: ``(R_g, k)`` the runs' slots; z: ``(R_g, U)`` assignments (slots), updated.

    Returns:
        ``run (M,)``, ``row (M,)`` of the rows that changed cluster and their old slots.
    """
    Rg, k = table.shape[:2]
    U = xc.shape[-1]
    flat = table.reshape(Rg * k, -1)
    old = z.clone()
    for cols in column_blocks(U, Rg * k):
        ll = (flat @ xc[:, cols]).view(Rg, k, -1)  # (R_g, k, c)
        # max over the cluster axis (not innermost: vectorised over rows); first maximum
        z[:, cols] = slots.gather(1, ll.max(1).indices)
    r_idx, u_idx = torch.nonzero(z != old, as_tuple=True)
    return r_idx, u_idx, old[r_idx, u_idx]


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
    U, D = stats.num_distinct, A * A
    dtype, device = log_transition.dtype, log_transition.device
    log_floor = math.log(floor)
    # data, columns = distinct rows: xc (D [+ A], U); weighted rows for the M-step
    mult = stats.multiplicity.to(dtype)
    rows_data = stats.counts.to(dtype)
    if stats.first_counts is not None:
        rows_data = torch.cat([rows_data, stats.first_counts.to(dtype)], -1)  # (U, D + A)
    xc = rows_data.transpose(0, 1).contiguous()
    weighted = rows_data * mult[:, None]
    Dc = xc.shape[0]
    z = (  # (R, U) runs-major, so a group's rows are contiguous
        assignments.to(torch.long).transpose(0, 1).contiguous()
        if assignments is not None
        else torch.full((R, U), -1, dtype=torch.long, device=device)
    )
    lt = log_transition.contiguous().view(R, K, D).clone()
    li = log_initial.clone() if log_initial is not None else None
    counts = weighted.new_zeros(R, K, Dc)
    counted = torch.zeros(R, dtype=torch.bool, device=device)
    iterations = torch.zeros(R, dtype=torch.long, device=device)
    converged = torch.zeros(R, dtype=torch.bool, device=device)
    active = cluster_mask.any(-1)  # a run without clusters has nothing to do
    # per group of runs with the same k: its state, compacted as runs converge
    state = [[runs, slots, z[runs]] for runs, slots in run_groups(cluster_mask)]
    for it in range(1, max_iterations + 1):
        for entry in state:
            runs, slots, z_g = entry
            if runs.numel() == 0:
                continue
            Rg, k = slots.shape
            rows, cols = runs[:, None], slots
            parts = [lt[rows, cols]] + ([li[rows, cols]] if li is not None else [])
            table = torch.cat(parts, -1).clamp_min(log_floor)  # (R_g, k, D')
            r_idx, u_idx, z_old = _assign(xc, table, slots, z_g)
            changes = torch.bincount(r_idx, minlength=Rg)  # (R_g,)
            fresh = ~counted[runs]
            total = int(r_idx.numel())
            if bool(fresh.any()) or total * 8 > Rg * k * U:
                # full recount: one-hot products (first iteration, or many rows moved)
                counts[rows, cols] = onehot_sums(z_g, slots, weighted, Rg * k).view(Rg, k, -1)
                counted[runs] = True
            elif total:
                # exact update by the rows that moved: + to the new cluster, - to the old
                source = weighted[u_idx]  # (M, D [+ A])
                flat = counts.view(R * K, -1)
                flat.index_add_(0, runs[r_idx] * K + z_g[r_idx, u_idx], source)
                flat.index_add_(0, runs[r_idx] * K + z_old, source, alpha=-1)
            group_counts = counts[rows, cols]  # (R_g, k, D [+ A])
            lt[rows, cols] = m_step_transition(
                group_counts[..., :D].reshape(Rg, k, A, A), lt[rows, cols].view(Rg, k, A, A), 0.0
            ).view(Rg, k, D)
            if li is not None:
                li[rows, cols] = m_step_transition(group_counts[..., D:], li[rows, cols], 0.0)
            iterations[runs] += 1
            stable = changes == 0
            if bool(stable.any()):  # stable runs are done: store them, compact the rest
                converged[runs[stable]] = True
                active[runs[stable]] = False
                z[runs[stable]] = z_g[stable]
                keep = ~stable
                entry[:] = [runs[keep], slots[keep], z_g[keep]]
        if progress is not None:
            progress(it, int(active.sum()))
        if not bool(active.any()):
            break
    for runs, _, z_g in state:  # runs stopped by max_iterations
        if runs.numel():
            z[runs] = z_g
    # P(z) = n_z / n, and the classification log-likelihood of the final partition. The
    # final parameters are the M-step of the final counts, so sum_i log theta_{z_i}(x_i) =
    # sum_z sum_ab n_z(a -> b) log theta_z(b | a) over the observed transitions (exact, no
    # pass over the data); accumulated in float64.
    sizes = partition_sizes(z.clamp_min(0).transpose(0, 1), mult, K)  # (R, K)
    log_weights = sizes.log() - sizes.sum(-1, keepdim=True).log()
    n = counts.double()
    logs = torch.cat([lt, li], -1) if li is not None else lt
    chain = torch.where(n > 0, n * logs.double(), n.new_zeros(())).sum((-2, -1))
    s64 = sizes.double()
    mix = torch.where(s64 > 0, s64 * log_weights.double(), s64.new_zeros(())).sum(-1)
    total_ll = (chain + mix).to(dtype)
    return EMResult(
        log_transition=lt.view(R, K, A, A),
        log_weights=log_weights,
        log_initial=li,
        assignments=z.transpose(0, 1).contiguous(),
        log_likelihood=total_ll,
        entropy=torch.zeros_like(total_ll),
        iterations=iterations,
        converged=converged,
    )
