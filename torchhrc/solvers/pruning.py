"""Pruning of alpha-vector sets: pointwise dominance and belief-point dominance.

Alpha vectors ``alphas: (N, S)`` represent the piecewise-linear convex value function
``V(b) = max_n alphas[n] . b``. A vector can be dropped without changing ``V`` when another
vector is at least as large at every state (pointwise dominance, Cassandra et al. 1997);
point-based solvers also drop vectors that are not the maximum at any belief of a finite set
(Pineau et al. 2003; SARSOP's "delayed" pruning, Kurniawati et al. 2008), which changes ``V``
only away from those beliefs.

For MOMDP policies (Ong et al. 2010) vectors are grouped by the observed value ``x`` they
belong to (``groups: (N,)``); comparisons happen only inside a group.

Both functions return a boolean ``keep: (N,)`` mask and never drop every vector of a
non-empty group.

Example:
    >>> import torch
    >>> alphas = torch.tensor([[1.0, 1.0], [0.0, 0.5], [2.0, -1.0]])
    >>> prune_dominated(alphas).tolist()
    [True, False, True]
"""

from __future__ import annotations

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError

__all__ = ["prune_by_beliefs", "prune_dominated"]

_CHUNK_ELEMENTS = 1 << 22  # booleans of the (chunk, N, S) comparison tensor held at once
# floats of one gathered (pairs, S) block of the grouped tests, and of one (beliefs, vectors)
# score block (2 MB in float64): with 1 << 24 the gathers, products and comparisons of one
# chunk took 128 MB each, the peak memory of a whole solve (RockSample_7_8.pomdpx: 790 MB,
# against 410 MB between prunings); with 1 << 20 a pruning still raised Hallway2's peak by
# 22 MB (60 CPU-s: 364 MB, APPL 172 MB), at no measurable gain in speed over 1 << 18
_GATHER_ELEMENTS = 1 << 18
_PROBE_STATES = 8  # states compared first in the grouped dominance test


def _check_alphas(alphas: object, groups: object) -> tuple[torch.Tensor, torch.Tensor | None]:
    alphas = check_tensor("alphas", alphas)
    if alphas.dim() != 2:
        raise ModelError(
            f"expected alphas to have shape (N, S), actual shape = {tuple(alphas.shape)}"
        )
    if groups is not None:
        groups = check_tensor("groups", groups, floating=False)
        if groups.shape != alphas.shape[:1]:
            raise ModelError(
                f"expected groups to have shape (N={alphas.shape[0]},), "
                f"actual shape = {tuple(groups.shape)}"
            )
    return alphas, groups


def prune_dominated(
    alphas: torch.Tensor, groups: torch.Tensor | None = None, *, atol: float = 0.0
) -> torch.Tensor:
    """Mask of the vectors that no other vector (of the same group) pointwise dominates.

    Vector ``i`` is dropped when some ``j != i`` has ``alphas[j] >= alphas[i] - atol`` at every
    state, and either ``i`` does not dominate ``j`` back or ``j < i`` (of equal vectors the
    first is kept). Computed as batched comparisons, in chunks of rows to bound memory.

    Args:
        alphas: ``(N, S)`` alpha vectors (``(N, Y)`` for a MOMDP policy).
        groups: optional ``(N,)`` int64 group of each vector (the observed ``x``).
        atol: tolerance of the comparison.

    Returns:
        ``(N,)`` bool, True for the vectors to keep.

    Example:
        >>> a = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        >>> prune_dominated(a, torch.tensor([0, 0, 1])).tolist()
        [True, False, True]
    """
    alphas, groups = _check_alphas(alphas, groups)
    N, S = alphas.shape
    keep = torch.ones(N, dtype=torch.bool, device=alphas.device)
    if N <= 1:
        return keep
    if groups is not None and _pairs_pay(groups, groups):
        # many groups (a MOMDP's observed values): compare only the pairs inside a group
        # a few probe states first: j can dominate i only if it does at those (most pairs
        # fail there), so the full comparison runs on the survivors only (same result)
        probe = torch.linspace(0, S - 1, min(S, _PROBE_STATES), device=alphas.device).long()
        sub = alphas[:, probe].contiguous()  # (N, k)
        for i, j in _same_group_pairs(groups, groups, max(1, _GATHER_ELEMENTS // max(1, S))):
            off = i != j
            i, j = i[off], j[off]
            maybe = (sub[j] >= sub[i] - atol).all(-1)
            i, j = i[maybe], j[maybe]
            ai, aj = alphas[i], alphas[j]  # gathered once
            ge = (aj >= ai - atol).all(-1)
            # the reverse test only where j dominates i and comes after it (same result)
            i, j, ai, aj = i[ge], j[ge], ai[ge], aj[ge]
            later = j > i
            le = torch.zeros_like(later)
            le[later] = (ai[later] >= aj[later] - atol).all(-1)
            keep[i[~le]] = False
        return keep
    index = torch.arange(N, device=alphas.device)
    chunk = max(1, _CHUNK_ELEMENTS // max(1, N * S))
    for start in range(0, N, chunk):
        rows = alphas[start : start + chunk]  # (C, S)
        # ge[c, j]: alphas[j] >= rows[c] - atol everywhere;  le[c, j]: rows[c] >= alphas[j] - atol
        ge = (alphas.unsqueeze(0) >= rows.unsqueeze(1) - atol).all(-1)  # (C, N)
        le = (rows.unsqueeze(1) >= alphas.unsqueeze(0) - atol).all(-1)  # (C, N)
        i = index[start : start + chunk].unsqueeze(1)  # (C, 1)
        j = index.unsqueeze(0)  # (1, N)
        dominated_by = ge & (j != i) & (~le | (j < i))
        if groups is not None:
            dominated_by &= groups[start : start + chunk].unsqueeze(1) == groups.unsqueeze(0)
        keep[start : start + chunk] = ~dominated_by.any(-1)
    return keep


def prune_by_beliefs(
    alphas: torch.Tensor,
    beliefs: torch.Tensor,
    groups: torch.Tensor | None = None,
    belief_groups: torch.Tensor | None = None,
    *,
    rows: torch.Tensor | None = None,
) -> torch.Tensor:
    """Mask of the vectors that are the maximum at one or more of the given beliefs.

    The beliefs are scored a block at a time (about ``2^20`` scores each), so memory stays
    bounded however many there are (SARSOP prunes against every active tree belief: TagAvoid,
    12,000 beliefs x 2,000 vectors, was one 190 MB score matrix).

    Args:
        alphas: ``(N, S)`` alpha vectors.
        beliefs: ``(M, S)`` belief points (rows need not be normalised).
        groups: optional ``(N,)`` group (observed ``x``) of each vector.
        belief_groups: ``(M,)`` group of each belief (of each of ``rows`` when given);
            required with ``groups``.
        rows: optional ``(M',)`` long, the rows of ``beliefs`` to use (gathered a block at a
            time, never copied whole); default every row.

    Returns:
        ``(N,)`` bool, True for vectors that win at some belief of their group. Groups with
        vectors but no belief keep all their vectors.

    Example:
        >>> a = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.4, 0.4]])
        >>> prune_by_beliefs(a, torch.tensor([[0.9, 0.1], [0.2, 0.8]])).tolist()
        [True, True, False]
        >>> prune_by_beliefs(a, torch.tensor([[0.9, 0.1], [0.2, 0.8]]), rows=torch.tensor([1]))
        tensor([False,  True, False])
    """
    alphas, groups = _check_alphas(alphas, groups)
    beliefs = check_tensor("beliefs", beliefs)
    check_shape("beliefs", beliefs, (alphas.shape[1],), f"(M, S={alphas.shape[1]})")
    if beliefs.dim() != 2:
        raise ModelError(
            f"expected beliefs to have shape (M, S), actual shape = {tuple(beliefs.shape)}"
        )
    if rows is None:
        rows = torch.arange(beliefs.shape[0], device=beliefs.device)
    else:
        rows = check_tensor("rows", rows, floating=False)
        if rows.dim() != 1:
            raise ModelError(
                f"expected rows to be a 1-D index of the {beliefs.shape[0]} beliefs, got "
                f"shape {tuple(rows.shape)}"
            )
        if rows.numel() and not (0 <= int(rows.min()) and int(rows.max()) < len(beliefs)):
            raise ModelError(
                f"expected rows in [0, {beliefs.shape[0]}) (the beliefs), got values from "
                f"{int(rows.min())} to {int(rows.max())}"
            )
    N = alphas.shape[0]
    keep = torch.zeros(N, dtype=torch.bool, device=alphas.device)
    if N == 0:
        return keep
    seen = None  # (N,) the vectors whose group has a belief
    if groups is not None:
        if belief_groups is None:
            raise ModelError("belief_groups is required when groups is given")
        belief_groups = check_tensor("belief_groups", belief_groups, floating=False)
        if belief_groups.shape != rows.shape:
            raise ModelError(
                f"expected belief_groups to have shape (M={rows.shape[0]},), "
                f"actual shape = {tuple(belief_groups.shape)}"
            )
        if _pairs_pay(belief_groups, groups):
            return _grouped_winners(alphas, beliefs, rows, groups, belief_groups)
        seen = torch.zeros(N, dtype=torch.bool, device=alphas.device)
    step = max(1, _GATHER_ELEMENTS // N)
    for start in range(0, rows.shape[0], step):
        blk = beliefs.index_select(0, rows[start : start + step]).to(alphas.dtype)
        scores = blk @ alphas.T  # (m, N)
        if groups is None:
            keep[scores.argmax(-1)] = True
            continue
        assert belief_groups is not None and seen is not None
        same = belief_groups[start : start + step].unsqueeze(1) == groups.unsqueeze(0)  # (m, N)
        scores = scores.masked_fill(~same, -torch.inf)
        keep[scores.argmax(-1)[same.any(-1)]] = True
        seen |= same.any(0)
    if seen is not None:
        keep |= ~seen  # groups without any belief keep everything
    return keep


def _pairs_pay(left: torch.Tensor, right: torch.Tensor) -> bool:
    """Whether the same-group pairs are far fewer than all pairs (many small groups)."""
    if left.numel() == 0 or right.numel() == 0:
        return False
    G = int(max(int(left.max()), int(right.max()))) + 1
    pairs = int((torch.bincount(left, minlength=G) * torch.bincount(right, minlength=G)).sum())
    return 4 * pairs <= left.numel() * right.numel()


def _same_group_pairs(left: torch.Tensor, right: torch.Tensor, chunk: int):
    """Yield ``(i, j)`` index tensors of all pairs with ``left[i] == right[j]``, ``i`` ascending.

    In chunks of about ``chunk`` pairs (a left index's partners are never split), so memory
    stays bounded however large the groups are.
    """
    dev = left.device
    G = int(max(int(left.max()), int(right.max()))) + 1
    order = torch.argsort(right, stable=True)
    counts = torch.bincount(right, minlength=G)
    starts = torch.cumsum(counts, 0) - counts  # (G,) first slot of each group in `order`
    per = counts[left]  # (M,) partners of each left index
    ends = torch.cumsum(per, 0)
    M = left.numel()
    lo = 0
    while lo < M:
        # the left indices whose partners fit in this chunk (at least one)
        base = int(ends[lo - 1]) if lo > 0 else 0
        hi = int(torch.searchsorted(ends, base + chunk, right=True))
        hi = min(max(hi, lo + 1), M)
        p = per[lo:hi]
        i = torch.repeat_interleave(torch.arange(lo, hi, device=dev), p)
        first = torch.cumsum(p, 0) - p
        offs = torch.arange(i.numel(), device=dev) - torch.repeat_interleave(first, p)
        j = order[starts[left[i]] + offs]
        yield i, j
        lo = hi


def _grouped_winners(
    alphas: torch.Tensor,
    beliefs: torch.Tensor,
    rows: torch.Tensor,
    groups: torch.Tensor,
    belief_groups: torch.Tensor,
) -> torch.Tensor:
    """:func:`prune_by_beliefs` scoring only the (belief, vector) pairs of the same group.

    Of the vectors tied for the maximum at a belief the lowest index wins, as ``argmax`` over
    all of the group's vectors would pick. One group at a time: its beliefs ``(M_g, S)``
    against its vectors ``(N_g, S)`` as a broadcast ``(m, N_g, S)`` product summed over
    ``S`` (the same products and sums as a pair-by-pair gather, so the same scores bit for
    bit, without gathering a belief row and a vector row per pair: RockSample_7_8.pomdpx,
    a 10 CPU-s solve's prunings 1.4 s -> 0.2 s), in blocks of about ``_GATHER_ELEMENTS``
    floats.
    """
    N, S = alphas.shape
    keep = torch.zeros(N, dtype=torch.bool, device=alphas.device)
    G = int(max(int(groups.max()), int(belief_groups.max()))) + 1
    a_order = torch.argsort(groups, stable=True)  # each group's vectors, index ascending
    b_order = torch.argsort(belief_groups, stable=True)
    a_count = torch.bincount(groups, minlength=G).tolist()
    b_count = torch.bincount(belief_groups, minlength=G).tolist()
    a0 = b0 = 0
    for g in range(G):
        ja = a_order[a0 : a0 + a_count[g]]
        ib = b_order[b0 : b0 + b_count[g]]
        a0, b0 = a0 + a_count[g], b0 + b_count[g]
        if not ja.numel():
            continue
        if not ib.numel():  # groups without any belief keep everything
            keep[ja] = True
            continue
        vec = alphas.index_select(0, ja)  # (N_g, S)
        bel = beliefs.index_select(0, rows[ib]).to(alphas.dtype)  # (M_g, S)
        step = max(1, _GATHER_ELEMENTS // (ja.numel() * max(1, S)))
        for start in range(0, bel.shape[0], step):
            score = (bel[start : start + step, None, :] * vec[None]).sum(-1)  # (m, N_g)
            win = score >= score.amax(-1, keepdim=True)
            keep[torch.where(win, ja, N).amin(-1)] = True
    return keep
