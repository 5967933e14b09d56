"""Tests of torchhrc.solvers.pruning: the same-group pair path against the dense masked one."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.solvers import pruning


def _dense(monkeypatch, fn, *args):
    """Run ``fn`` with the pair path disabled (the dense masked reference)."""
    with monkeypatch.context() as m:
        m.setattr(pruning, "_pairs_pay", lambda left, right: False)
        return fn(*args)


@pytest.mark.parametrize("chunk", [1, 7, 1 << 20])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_grouped_pruning_matches_dense_reference(monkeypatch, chunk, seed):
    g = torch.Generator().manual_seed(seed)
    N, S, G, M = 300, 3, 40, 200
    alphas = torch.randn(N, S, generator=g, dtype=torch.float64)
    alphas[::2, 0] += 2 * alphas[::2, 1].abs()  # some dominated pairs
    groups = torch.randint(0, G, (N,), generator=g)
    beliefs = torch.rand(M, S, generator=g, dtype=torch.float64)
    bgroups = torch.randint(0, G + 5, (M,), generator=g)  # some groups without vectors
    monkeypatch.setattr(pruning, "_CHUNK_ELEMENTS", chunk * S)  # pairs split across chunks
    assert pruning._pairs_pay(groups, groups) and pruning._pairs_pay(bgroups, groups)
    want = _dense(monkeypatch, pruning.prune_dominated, alphas, groups)
    assert torch.equal(pruning.prune_dominated(alphas, groups), want)
    assert 0 < int(want.sum()) < N
    want = _dense(monkeypatch, pruning.prune_by_beliefs, alphas, beliefs, groups, bgroups)
    assert torch.equal(pruning.prune_by_beliefs(alphas, beliefs, groups, bgroups), want)


def test_grouped_pruning_with_ties_keeps_the_value_at_every_belief():
    g = torch.Generator().manual_seed(3)
    N, S, G = 400, 3, 30
    alphas = torch.randint(0, 4, (N, S), generator=g).double()  # many duplicates and ties
    groups = torch.randint(0, G, (N,), generator=g)
    beliefs = torch.rand(100, S, generator=g, dtype=torch.float64)
    bgroups = torch.randint(0, G, (100,), generator=g)
    for keep in (
        pruning.prune_dominated(alphas, groups),
        pruning.prune_by_beliefs(alphas, beliefs, groups, bgroups),
    ):
        for m in range(100):
            mine = groups == bgroups[m]
            full = (alphas[mine] @ beliefs[m]).max()
            kept = (alphas[mine & keep] @ beliefs[m]).max()
            assert float(kept) == float(full)
    # duplicates: exactly one copy of each distinct (vector, group) survives dominance pruning
    keep = pruning.prune_dominated(alphas, groups)
    distinct = {(int(x), tuple(a.tolist())) for a, x in zip(alphas, groups, strict=True)}
    kept = [(int(x), tuple(a.tolist())) for a, x in zip(alphas[keep], groups[keep], strict=True)]
    assert len(kept) == len(set(kept)) <= len(distinct)


def _winners_by_hand(alphas, beliefs, groups=None, bgroups=None):
    """Vectors that are the (first) maximum of their group at some belief; groups without a
    belief keep all their vectors."""
    keep = torch.zeros(alphas.shape[0], dtype=torch.bool)
    for m in range(beliefs.shape[0]):
        mine = torch.ones_like(keep) if groups is None else groups == bgroups[m]
        if mine.any():
            scores = torch.where(mine, alphas @ beliefs[m], -torch.inf)
            keep[int(scores.argmax())] = True
    if groups is not None:
        keep |= ~torch.isin(groups, bgroups)
    return keep


@pytest.mark.parametrize("grouped", [False, True])
@pytest.mark.parametrize("block", [1, 3, 1 << 20])
def test_beliefs_scored_a_block_at_a_time_and_by_rows(monkeypatch, grouped, block):
    g = torch.Generator().manual_seed(4)
    N, S, M = 50, 4, 60
    alphas = torch.randn(N, S, generator=g, dtype=torch.float64)
    beliefs = torch.rand(M, S, generator=g, dtype=torch.float64)
    groups = torch.randint(0, 3, (N,), generator=g) if grouped else None
    bgroups = torch.randint(0, 2, (M,), generator=g) if grouped else None  # group 2: no belief
    monkeypatch.setattr(pruning, "_GATHER_ELEMENTS", block * N)  # `block` beliefs per block
    if grouped:
        assert not pruning._pairs_pay(bgroups, groups)  # the blocked dense path
    want = _winners_by_hand(alphas, beliefs, groups, bgroups)
    assert 0 < int(want.sum()) < N
    assert torch.equal(pruning.prune_by_beliefs(alphas, beliefs, groups, bgroups), want)
    rows = torch.tensor([5, 0, 41, 17, 17, 59])  # some rows, in any order, repeated
    sub = None if bgroups is None else bgroups[rows]
    want = _winners_by_hand(alphas, beliefs[rows], groups, sub)
    assert torch.equal(pruning.prune_by_beliefs(alphas, beliefs, groups, sub, rows=rows), want)
    with pytest.raises(ModelError, match=f"rows in \\[0, {M}\\).*from {M} to {M}"):
        pruning.prune_by_beliefs(alphas, beliefs, rows=torch.tensor([M]))
    with pytest.raises(ModelError, match="rows to be a 1-D index"):
        pruning.prune_by_beliefs(alphas, beliefs, rows=torch.tensor([[0]]))
    if grouped:
        with pytest.raises(ModelError, match="belief_groups"):
            pruning.prune_by_beliefs(alphas, beliefs, groups, bgroups, rows=rows)
