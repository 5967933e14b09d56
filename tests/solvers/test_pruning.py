"""Tests of torchhrc.solvers.pruning: the same-group pair path against the dense masked one."""

from __future__ import annotations

import pytest
import torch

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
