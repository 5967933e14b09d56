"""Shared E/M kernels for many EM runs at once (internal).

Notation: ``U`` distinct sequences (rows of :class:`SufficientStatistics`), ``R`` runs
(every restart of every k), ``K`` cluster slots (``k_max``; a run with ``k < K`` has its
extra slots masked out by ``cluster_mask (R, K)``), ``A`` symbols, ``D = A * A``.

The EM kernels pack the runs by their number of clusters (:func:`run_groups`): the runs with
``k`` clusters form one group whose ``R_k * k`` real clusters are the rows of one table, so no
work is spent on masked slots (k = 2..10 with equal restarts: 1080 columns instead of
1800). One E-step of a group is one matrix product ``(R_k * k, D) @ (D, U)`` and a
reduction over the cluster axis of the ``(R_k, k, U)`` result; the data axis ``U`` is
innermost, so the reductions over clusters vectorise over rows. One M-step is one product
``(R_k * k, U) @ (U, D)``. Columns (distinct rows) are processed in blocks
(:func:`column_blocks`) so the table is never materialised for large ``U`` (the loop runs
over memory blocks, not over sequences or runs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

__all__ = [
    "DEFAULT_PSEUDO_COUNT",
    "DEFAULT_WEIGHT_PSEUDO_COUNT",
    "OFF_SUPPORT",
    "EMResult",
    "Smoothing",
    "column_blocks",
    "e_table",
    "m_step_transition",
    "onehot_sums",
    "pseudo_parts",
    "run_groups",
]

#: Elements of a ``(packed clusters, block of rows)`` table processed at once (16 MiB in float32).
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


def run_groups(cluster_mask: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The runs grouped by their number of clusters ``k`` (runs without clusters are skipped).

    Args:
        cluster_mask: ``(R, K)`` bool, the cluster slots each run uses.

    Returns:
        ``[(runs (R_k,), slots (R_k, k))]``, increasing ``k``: ``slots[i]`` are the slots of
        run ``runs[i]`` in increasing order, so a packed column ``(i, j)`` is slot
        ``slots[i, j]`` of run ``runs[i]``.

    Example:
        >>> mask = torch.tensor([[True, True, False], [True, False, True], [True, False, False]])
        >>> [(r.tolist(), s.tolist()) for r, s in run_groups(mask)]
        [([2], [[0]]), ([0, 1], [[0, 1], [0, 2]])]
    """
    k = cluster_mask.sum(-1)  # (R,)
    groups = []
    for kv in torch.unique(k).tolist():
        if kv == 0:
            continue
        runs = torch.nonzero(k == kv).squeeze(-1)
        slots = torch.nonzero(cluster_mask[runs])[:, 1].view(-1, kv)  # row-major: ascending
        groups.append((runs, slots))
    return groups


def column_blocks(U: int, columns: int) -> list[slice]:
    """Blocks of the ``U`` data columns with at most ``_BLOCK_ELEMENTS`` elements of a
    ``(columns, block)`` table each."""
    size = max(1, _BLOCK_ELEMENTS // max(1, columns))
    return [slice(i, min(U, i + size)) for i in range(0, U, size)] or [slice(0, 0)]


def onehot_sums(
    zt: torch.Tensor, slots: torch.Tensor, weighted: torch.Tensor, columns: int
) -> torch.Tensor:
    """``(R_g * k, F)`` sums of the rows of ``weighted (U, F)`` assigned to each cluster.

    ``zt (R_g, U)`` hard assignments (slot indices) of the ``R_g`` runs of one group,
    ``slots (R_g, k)`` their slots: one-hot ``(R_g * k, block)`` matrices times the rows,
    block by block (``columns`` sizes the blocks).
    """
    Rg, k = slots.shape
    out = weighted.new_zeros(Rg * k, weighted.shape[-1])
    for cols in column_blocks(zt.shape[-1], columns):
        onehot = (zt[:, None, cols] == slots[:, :, None]).to(weighted.dtype)  # (R_g, k, c)
        out += onehot.view(Rg * k, -1) @ weighted[cols]
    return out


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


#: The soft method's default Dirichlet pseudo-count on every transition (``alpha``).
DEFAULT_PSEUDO_COUNT = 0.1

#: The soft method's default pseudo-count on every cluster size (``beta``).
DEFAULT_WEIGHT_PSEUDO_COUNT = 1.0

#: The pseudo-count of a transition outside a :class:`Smoothing`'s support, relative to
#: ``alpha``: not 0, so that every log-probability stays finite (the soft E-step's tables),
#: and negligible: the data never hold such a transition.
OFF_SUPPORT = 1e-9


@dataclass(frozen=True)
class Smoothing:
    """Dirichlet pseudo-counts on the transitions that can occur, for a chain whose symbols
    cannot follow every symbol (the context symbols of :mod:`torchhrc.mixture.history`).

    Passed where a float ``pseudo_count`` is accepted by the soft method's M-step.

    Attributes:
        transition: ``(A, A)`` pseudo-count of each transition.
        initial: ``(A,)`` pseudo-count of each first symbol.

    Example:
        >>> s = Smoothing.on_support(0.1, torch.tensor([[True, False], [True, True]]),
        ...                          torch.tensor([True, False]))
        >>> s.transition[0].tolist()[0], bool(s.transition[0, 1] < 1e-9)
        (0.1, True)
    """

    transition: torch.Tensor
    initial: torch.Tensor

    @classmethod
    def on_support(
        cls, alpha: float, transition_support: torch.Tensor, initial_support: torch.Tensor
    ) -> Smoothing:
        """``alpha`` on the support, ``alpha * OFF_SUPPORT`` elsewhere (float64)."""
        on = torch.tensor(float(alpha), dtype=torch.float64)
        off = on * OFF_SUPPORT
        return cls(
            torch.where(transition_support.cpu(), on, off),
            torch.where(initial_support.cpu(), on, off),
        )

    @property
    def alpha(self) -> float:
        """The pseudo-count on the support."""
        return float(self.transition.max())


def pseudo_parts(pseudo_count: float | Smoothing) -> tuple[Any, Any]:
    """``(transition, initial)`` pseudo-counts: the float twice, or a Smoothing's two tables."""
    if isinstance(pseudo_count, Smoothing):
        return pseudo_count.transition, pseudo_count.initial
    return pseudo_count, pseudo_count


def m_step_transition(
    cluster_counts: torch.Tensor, previous: torch.Tensor, pseudo_count: float | torch.Tensor
) -> torch.Tensor:
    """Normalised (smoothed) counts; a row without any count keeps its previous value.

    ``theta[r, k, a, b] = (n[r, k, a, b] + alpha) / sum_b' (n[r, k, a, b'] + alpha)``
    (the paper's M-step when ``alpha = 0``).

    Args:
        cluster_counts: ``(R, K, A, A)`` expected counts.
        previous: ``(R, K, A, A)`` log-probabilities kept where a row has no count.
        pseudo_count: Dirichlet pseudo-count ``alpha >= 0`` added to every entry, or an
            ``(A, A)`` (``(A,)`` for first symbols) tensor of them (:class:`Smoothing`).

    Returns:
        ``(R, K, A, A)`` log-probabilities (``-inf`` for unseen transitions when ``alpha = 0``).
    """
    if isinstance(pseudo_count, torch.Tensor):
        pseudo_count = pseudo_count.to(cluster_counts)
    smoothed = cluster_counts + pseudo_count
    rows = smoothed.sum(-1, keepdim=True)
    fresh = smoothed.log() - rows.clamp_min(torch.finfo(smoothed.dtype).tiny).log()
    return torch.where(rows > 0, fresh, previous)
