"""Refine a hard partition by moves that raise its exact ICL (``log p(D, z)``).

Soft EM maximises the mixture's likelihood; with a type whose sign shows in only some of a
person's demonstrations (``slow_sanding``'s careful person lingers in about 2 of 3), the
maximum can sit at a partition that moves the people who showed the sign once into the other
cluster, whose chain then allows a rare sign (``docs/clustering.md``, "Refining the
partition by its exact ICL"). The exact integrated classification likelihood of Biernacki,
Celeux and Govaert (2010) (:func:`~torchhrc.mixture.criteria.exact_icl`: the chains
integrated out under Jeffreys' prior) charges such a cluster for the sign it must allow. The
refinement moves one unit (a distinct row: a subject, or identical subjects together) at a
time to the cluster that raises ``log p(D, z)`` most, while any move raises it, never
emptying a cluster (the greedy ICL search of Côme & Latouche 2015 and Bertoletti, Friel &
Rastelli 2015, at fixed k). Every move raises a bounded objective, so it stops.

The changes of every unit's move are computed in one batched pass over the nonzero counts;
only the units that gain are then moved, one by one, each rechecked against the counts of
the moves before it.

Example:
    >>> import torch
    >>> from torchhrc.mixture import sufficient_statistics
    >>> seqs = torch.tensor([[0, 1, 0, 1, 0, 1]] * 4 + [[0, 0, 0, 0, 0, 0]] * 3
    ...                     + [[0, 0, 0, 0, 0, 1]])
    >>> s = sufficient_statistics(seqs, torch.full((8,), 6), 2, groups=torch.arange(8))
    >>> start = torch.tensor([0, 0, 1])  # over the 3 distinct rows
    >>> start[s.inverse].tolist()  # each sequence's cluster: the last one with the "01"s
    [0, 0, 0, 0, 1, 1, 1, 0]
    >>> refine_partition(s, start, 2)[s.inverse].tolist()  # moved to the "00"s
    [0, 0, 0, 0, 1, 1, 1, 1]
"""

from __future__ import annotations

import torch

from torchhrc.mixture.counts import SufficientStatistics

__all__ = ["refine_partition"]


def _row_gains(
    weighted: torch.Tensor,
    z: torch.Tensor,
    totals: torch.Tensor,
    row_totals: torch.Tensor,
    row_of: torch.Tensor,
    prior: float,
    outcomes: int,
) -> torch.Tensor:
    """``(U, K)`` change of ``sum_k sum_rows log B(n_k(row, .) + prior)`` (the rows' part of
    the exact ICL) when unit ``u``, taken out of its cluster, is added to cluster ``k``.

    ``weighted (U, D)``: the units' counts times their multiplicities; ``z (U,)`` their
    clusters; ``totals (K, D)`` and ``row_totals (K, rows)``: the clusters' counts by outcome
    and by row; ``row_of (D,)``: each outcome's row. Only the units' nonzero counts are read."""
    lg = torch.lgamma
    K, U = totals.shape[0], weighted.shape[0]
    own = torch.nn.functional.one_hot(z, K).to(totals)  # (U, K)
    u, d = weighted.nonzero(as_tuple=True)
    v = weighted[u, d][:, None]  # (E, 1)
    base = totals[:, d].T - own[u] * v  # (E, K): the cluster's counts without the unit
    gains = totals.new_zeros(U, K).index_add_(0, u, lg(base + v + prior) - lg(base + prior))
    rows = row_of[d]  # the row of every nonzero count
    key = u * row_totals.shape[1] + rows
    keys, at = torch.unique(key, return_inverse=True)
    rv = weighted.new_zeros(len(keys)).index_add_(0, at, v[:, 0])[:, None]  # a unit's row sum
    ru, rr = keys // row_totals.shape[1], keys % row_totals.shape[1]
    rbase = row_totals[:, rr].T - own[ru] * rv
    mass = outcomes * prior
    return gains.index_add_(0, ru, -(lg(rbase + rv + mass) - lg(rbase + mass)))


class _Partition:
    """A hard partition's cluster totals (by outcome and by row), kept up to date move by
    move."""

    def __init__(self, stats: SufficientStatistics, z: torch.Tensor, k: int) -> None:
        A = stats.num_symbols
        self.k, self.z = k, z
        self.m = stats.multiplicity.to(torch.float64)
        self.parts = [(stats.counts.to(torch.float64) * self.m[:, None],
                       torch.arange(A * A, device=z.device) // A)]  # fmt: skip
        if stats.first_counts is not None:
            first = stats.first_counts.to(torch.float64) * self.m[:, None]
            self.parts.append((first, torch.zeros(A, dtype=torch.long, device=z.device)))
        self.totals = [w.new_zeros(k, w.shape[1]).index_add_(0, z, w) for w, _ in self.parts]
        self.row_totals = [
            t.new_zeros(k, int(rows.max()) + 1).index_add_(1, rows, t)
            for (_, rows), t in zip(self.parts, self.totals)
        ]
        self.sizes = self.m.new_zeros(k).index_add_(0, z, self.m)

    def gains(self, units: torch.Tensor, prior: float, weight_prior: float,
              outcomes: int) -> torch.Tensor:  # fmt: skip
        """``(len(units), k)`` exact-ICL change of moving each unit into each cluster."""
        z, m = self.z[units], self.m[units]
        tables = zip(self.parts, self.totals, self.row_totals)
        out = sum(_row_gains(w[units], z, t, rt, rows, prior, outcomes)
                  for (w, rows), t, rt in tables)  # fmt: skip
        base = self.sizes[None] - torch.nn.functional.one_hot(z, self.k).to(m) * m[:, None]
        return (
            out + torch.lgamma(base + m[:, None] + weight_prior) - torch.lgamma(base + weight_prior)
        )

    def move(self, u: int, to: int) -> None:
        own = int(self.z[u])
        for (w, rows), t, rt in zip(self.parts, self.totals, self.row_totals):
            d = w[u].nonzero().squeeze(-1)
            t[own, d] -= w[u, d]
            t[to, d] += w[u, d]
            rt[own].index_add_(0, rows[d], -w[u, d])
            rt[to].index_add_(0, rows[d], w[u, d])
        self.sizes[own] -= self.m[u]
        self.sizes[to] += self.m[u]
        self.z[u] = to


def refine_partition(
    stats: SufficientStatistics,
    assignments: torch.Tensor,
    k: int,
    *,
    prior: float = 0.5,
    weight_prior: float = 1.0,
    outcomes: int | None = None,
    max_sweeps: int = 100,
) -> torch.Tensor:
    """Greedy single-unit moves that raise the exact ICL of a hard partition (see the module).

    Args:
        stats: the distinct units (:func:`~torchhrc.mixture.sufficient_statistics`).
        assignments: ``(U,)`` int64 cluster in ``[0, k)`` of every distinct row.
        k: the number of clusters (each keeps at least one unit).
        prior, weight_prior, outcomes: the exact ICL's Dirichlet concentrations and the
            number of outcomes of every row's Dirichlet, as
            :func:`~torchhrc.mixture.criteria.exact_icl` (``outcomes`` None: ``A``).
        max_sweeps: at most this many batched passes (each moves every unit that still gains).

    Returns:
        ``(U,)`` int64, a partition whose exact ICL is at least the given one's.

    Raises:
        ValueError: assignments of the wrong shape or outside ``[0, k)``.
    """
    U = stats.counts.shape[0]
    if assignments.shape != (U,):
        raise ValueError(f"expected assignments of shape ({U},) (one per distinct row), "
                         f"got {tuple(assignments.shape)}")  # fmt: skip
    if U and (int(assignments.min()) < 0 or int(assignments.max()) >= k):
        raise ValueError(f"expected assignments in [0, {k}), got values in "
                         f"[{int(assignments.min())}, {int(assignments.max())}]")  # fmt: skip
    outcomes = stats.num_symbols if outcomes is None else int(outcomes)
    part = _Partition(stats, assignments.clone().to(torch.long), k)
    everyone = torch.arange(U, device=part.z.device)
    for _ in range(max_sweeps):
        gains = part.gains(everyone, prior, weight_prior, outcomes)
        better = gains.max(-1).values - gains.gather(1, part.z[:, None]).squeeze(1)
        candidates = (better > 1e-9).nonzero().squeeze(-1)
        moved = 0
        for u in candidates[better[candidates].argsort(descending=True)].tolist():
            row = part.gains(torch.tensor([u]), prior, weight_prior, outcomes)[0]  # now
            own, best = int(part.z[u]), int(row.argmax())
            if (
                best != own
                and float(row[best] - row[own]) > 1e-9
                and (float(part.sizes[own]) > float(part.m[u]))
            ):
                part.move(u, best)
                moved += 1
        if not moved:
            break
    return part.z
