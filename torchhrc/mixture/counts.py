"""Transition counts and sufficient statistics, by ``bincount`` (no loop over sequences).

Notation: ``N`` sequences, ``L`` padded length, ``A`` symbols, ``K`` clusters, ``R``
independent runs (restarts x values of k). A sequence's likelihood under a Markov chain
depends on it only through its transition counts ``C[n, a, b]`` (and its first symbol), so
EM works on the *distinct* count vectors with their multiplicities: identical sequences
always receive identical assignments, and the computation scales with the number of
distinct sequences, not with ``N``.

Example:
    >>> import torch
    >>> seqs = torch.tensor([[0, 1, 1, 0], [1, 0, 0, 0]])
    >>> transition_counts(seqs, torch.tensor([4, 2]), 2)[1].tolist()
    [[0, 0], [1, 0]]
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from torchhrc.errors import ModelError

__all__ = [
    "SufficientStatistics",
    "check_sequences",
    "cluster_counts",
    "sufficient_statistics",
    "transition_counts",
]


def check_sequences(
    sequences: object, lengths: object, num_symbols: int | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate padded sequences ``(N, L)`` and their ``lengths (N,)``; return them as int64.

    Steps beyond a sequence's length are ignored and returned as 0.

    Raises:
        TypeError: not integer tensors.
        ModelError: wrong shapes, a length outside ``[1, L]``, a symbol outside ``[0, A)``.
    """
    if not isinstance(sequences, torch.Tensor) or sequences.is_floating_point():
        raise TypeError(
            "expected sequences to be an integer torch.Tensor (N, L), got "
            f"{type(sequences).__name__}"
            + (f" of dtype {sequences.dtype}" if isinstance(sequences, torch.Tensor) else "")
        )
    if not isinstance(lengths, torch.Tensor) or lengths.is_floating_point():
        raise TypeError(
            f"expected lengths to be an integer torch.Tensor (N,), got {type(lengths).__name__}"
        )
    if sequences.dim() != 2:
        raise ModelError(
            f"expected sequences to have shape (N, L), actual shape = {tuple(sequences.shape)}"
        )
    N, L = sequences.shape
    if lengths.shape != (N,):
        raise ModelError(
            f"expected lengths to have shape (N={N},), actual shape = {tuple(lengths.shape)}"
        )
    if N and (lengths.min() < 1 or lengths.max() > L):
        bad = int(torch.nonzero((lengths < 1) | (lengths > L))[0])
        raise ModelError(f"lengths[{bad}] = {int(lengths[bad])} is outside [1, L={L}]")
    sequences = sequences.long()
    mask = torch.arange(L, device=sequences.device) < lengths.unsqueeze(-1)
    if num_symbols is not None and N:
        bad_sym = mask & ((sequences < 0) | (sequences >= num_symbols))
        if bad_sym.any():
            n, j = torch.nonzero(bad_sym)[0].tolist()
            raise ModelError(
                f"sequences[{n}, {j}] = {int(sequences[n, j])} is not a symbol in "
                f"[0, A={num_symbols})"
            )
    # padding may hold anything; make it a valid symbol so gathers never go out of range
    sequences = torch.where(mask, sequences, sequences.new_zeros(()))
    return sequences, lengths.long()


def transition_counts(
    sequences: torch.Tensor, lengths: torch.Tensor, num_symbols: int
) -> torch.Tensor:
    """Per-sequence transition counts by one ``bincount``.

    Args:
        sequences: ``(N, L)`` int64 symbols, padded beyond ``lengths``.
        lengths: ``(N,)`` int64 true lengths.
        num_symbols: ``A``.

    Returns:
        ``(N, A, A)`` int64, ``C[n, a, b]`` = number of steps ``j`` with
        ``x_n^{j-1} = a, x_n^j = b``.

    Example:
        >>> import torch
        >>> transition_counts(torch.tensor([[0, 1, 1]]), torch.tensor([3]), 2).tolist()
        [[[0, 1], [0, 1]]]
    """
    sequences, lengths = check_sequences(sequences, lengths, num_symbols)
    N, L = sequences.shape
    A = int(num_symbols)
    prev, nxt = sequences[:, :-1], sequences[:, 1:]  # (N, L-1)
    valid = torch.arange(L - 1, device=sequences.device) < (lengths - 1).unsqueeze(-1)
    row = torch.arange(N, device=sequences.device).unsqueeze(-1)
    flat = (row * A + prev) * A + nxt  # (N, L-1)
    counts = torch.bincount(flat[valid], minlength=N * A * A)
    return counts.view(N, A, A)


@dataclass(frozen=True)
class SufficientStatistics:
    """The distinct units' statistics, with multiplicities (what EM needs).

    A *unit* is what one cluster label is given to: a sequence, or a group of sequences
    (e.g. all demonstrations of one subject, who has one type).

    Attributes:
        counts: ``(U, A * A)`` float transition counts of the ``U`` distinct units.
        first_counts: ``(U, A)`` float first-symbol counts of each distinct unit, or ``None``
            when first symbols are not modelled.
        multiplicity: ``(U,)`` float number of units sharing each distinct row.
        inverse: ``(N,)`` int64, ``inverse[n]`` = the distinct row of sequence ``n``.
        num_units: the number of units (sequences, or groups) ``n`` of the BIC.
        num_symbols: ``A``.
    """

    counts: torch.Tensor
    first_counts: torch.Tensor | None
    multiplicity: torch.Tensor
    inverse: torch.Tensor
    num_units: int
    num_symbols: int

    @property
    def num_sequences(self) -> int:
        """N, the number of sequences (with repetitions)."""
        return self.inverse.shape[0]

    @property
    def num_distinct(self) -> int:
        """U, the number of distinct rows."""
        return self.counts.shape[0]

    def rows(self, index: slice | torch.Tensor) -> SufficientStatistics:
        """The statistics of some distinct rows only (a chunk of the data for a sharded
        E-step: :func:`~torchhrc.mixture.soft_em.soft_pass` on each chunk, then
        :func:`~torchhrc.mixture.soft_em.sum_statistics`). ``inverse`` is kept as is (it
        refers to the full table) and ``num_units`` counts the chunk's units.

        Example:
            >>> s = sufficient_statistics(torch.tensor([[0, 1], [1, 1]]), torch.tensor([2, 2]), 2)
            >>> s.rows(slice(0, 1)).counts.tolist()
            [[0.0, 0.0, 0.0, 1.0]]
        """
        mult = self.multiplicity[index]
        return SufficientStatistics(
            counts=self.counts[index],
            first_counts=None if self.first_counts is None else self.first_counts[index],
            multiplicity=mult,
            inverse=self.inverse,
            num_units=int(mult.sum().round()),
            num_symbols=self.num_symbols,
        )


def _pack_rows(key: torch.Tensor, bits: int) -> torch.Tensor:
    """Nonnegative int ``key (N, F)`` (entries < ``2**bits``) packed big-endian into ``(N, W)``
    int64 words of at most 62 bits: comparing word rows lexicographically compares the rows."""
    N, Fd = key.shape
    per_word = max(1, 62 // bits)
    pad = (-Fd) % per_word
    key = key.to(torch.int64)
    padded = torch.cat([key, key.new_zeros(N, pad)], -1) if pad else key
    shifts = bits * torch.arange(per_word - 1, -1, -1, device=key.device)  # big-endian
    return (padded.view(N, -1, per_word) << shifts).sum(-1)  # (N, W), each < 2^62


def _unique_words(words: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(first (U,), inverse (N,), counts (U,))`` of the distinct rows of ``words (N, W)``,
    in lexicographic order, by stable sorts (an LSD radix sort over words): ``first[u]`` is a
    row holding the ``u``-th distinct value."""
    N = words.shape[0]
    order = torch.arange(N, device=words.device)
    for w in range(words.shape[-1] - 1, -1, -1):
        order = order[torch.sort(words[order, w], stable=True).indices]
    sorted_words = words[order]
    start = torch.ones(N, dtype=torch.bool, device=words.device)
    start[1:] = (sorted_words[1:] != sorted_words[:-1]).any(-1)
    group = start.cumsum(0) - 1  # (N,) distinct index of each sorted row
    inverse = torch.empty_like(group).scatter_(0, order, group)
    first = order[start]
    counts = torch.bincount(group, minlength=int(first.numel()))
    return first, inverse, counts


def _unique_rows(key: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``torch.unique(key, dim=0, return_inverse=True, return_counts=True)`` for a
    nonnegative int64 ``key (N, F)``, by sorting instead of row-by-row comparisons.

    The columns are packed big-endian into 62-bit words (``bits`` per entry, enough for the
    largest entry), which keeps the lexicographic order; the rows are then sorted by the
    words, last word first, with stable sorts (an LSD radix sort over words). Exact, and
    the distinct rows come out in the same (lexicographic) order as ``torch.unique``.
    """
    N, Fd = key.shape
    if N == 0 or Fd == 0:
        return torch.unique(key, dim=0, return_inverse=True, return_counts=True)
    bits = max(1, int(key.max()).bit_length())
    first, inverse, counts = _unique_words(_pack_rows(key, bits))
    return key[first], inverse, counts


def sufficient_statistics(
    sequences: torch.Tensor,
    lengths: torch.Tensor,
    num_symbols: int,
    *,
    initial: bool = False,
    groups: torch.Tensor | None = None,
    dtype: torch.dtype = torch.float64,
    deduplicate: bool = True,
) -> SufficientStatistics:
    """Transition counts of the distinct units (``torch.unique`` over count rows).

    Args:
        sequences: ``(N, L)`` int64 symbols; ``lengths``: ``(N,)`` int64.
        num_symbols: ``A``.
        initial: keep first-symbol counts (needed when they are modelled).
        groups: ``(N,)`` int64 group of every sequence (e.g. its subject): the sequences
            of a group share one cluster, their counts are added (``index_add``). ``None``:
            every sequence is its own unit.
        dtype: float dtype of ``counts`` and ``multiplicity``.
        deduplicate: merge identical rows (exact: they always get equal assignments).

    Returns:
        :class:`SufficientStatistics` with ``U <= N`` rows.

    Example:
        >>> import torch
        >>> seqs = torch.tensor([[0, 1], [0, 1], [1, 1]])
        >>> s = sufficient_statistics(seqs, torch.tensor([2, 2, 2]), 2)
        >>> s.num_distinct, s.multiplicity[s.inverse].tolist()
        (2, [2.0, 2.0, 1.0])
    """
    sequences, lengths = check_sequences(sequences, lengths, num_symbols)
    A = int(num_symbols)
    N = sequences.shape[0]
    C = transition_counts(sequences, lengths, A).view(N, A * A)  # (N, A*A) int64
    key = C
    if initial:
        key = torch.cat([C, F.one_hot(sequences[:, 0], A)], dim=-1)  # (N, A*A + A)
    unit_of = torch.arange(N, device=C.device)
    if groups is not None:
        if (
            not isinstance(groups, torch.Tensor)
            or groups.shape != (N,)
            or groups.is_floating_point()
        ):
            raise ModelError(
                f"expected groups to be an int64 tensor of shape (N={N},), got "
                + (
                    f"shape {tuple(groups.shape)}"
                    if isinstance(groups, torch.Tensor)
                    else type(groups).__name__
                )
            )
        labels, unit_of = torch.unique(groups.to(C.device), return_inverse=True)
        key = key.new_zeros(labels.shape[0], key.shape[-1]).index_add_(0, unit_of, key)
    if deduplicate and N:
        uniq, row_of_unit, mult = _unique_rows(key)
    else:
        uniq, row_of_unit = key, torch.arange(key.shape[0], device=C.device)
        mult = torch.ones(key.shape[0], dtype=torch.long, device=C.device)
    return SufficientStatistics(
        counts=uniq[:, : A * A].to(dtype),
        first_counts=uniq[:, A * A :].to(dtype) if initial else None,
        multiplicity=mult.to(dtype),
        inverse=row_of_unit[unit_of],
        num_units=key.shape[0],
        num_symbols=A,
    )


def cluster_counts(
    responsibilities: torch.Tensor, counts: torch.Tensor, multiplicity: torch.Tensor | None = None
) -> torch.Tensor:
    """Expected transition counts of every cluster of every run, as one matrix product.

    Args:
        responsibilities: ``(U, R, K)``, ``r[u, run, k]`` = weight of row ``u`` in cluster
            ``k`` of run ``run`` (one-hot for hard EM).
        counts: ``(U, A * A)`` transition counts.
        multiplicity: ``(U,)`` row multiplicities, or ``None`` (all 1).

    Returns:
        ``(R, K, A * A)``: ``sum_u multiplicity[u] * r[u, run, k] * counts[u]``.

    Example:
        >>> import torch
        >>> r = torch.tensor([[[1.0, 0.0]], [[0.0, 1.0]]])
        >>> cluster_counts(r, torch.tensor([[1.0, 2.0], [3.0, 4.0]])).tolist()
        [[[1.0, 2.0], [3.0, 4.0]]]
    """
    U, R, K = responsibilities.shape
    weighted = counts if multiplicity is None else counts * multiplicity.unsqueeze(-1)
    out = responsibilities.reshape(U, R * K).transpose(0, 1) @ weighted  # (R*K, A*A)
    return out.view(R, K, counts.shape[-1])
