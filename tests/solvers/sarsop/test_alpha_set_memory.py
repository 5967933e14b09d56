"""SARSOP's alpha set in memory: the per-``x`` column blocks stay exact copies of the flat
storage through growth and pruning, and no growth holds two copies of a block at once."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import torch

from torchhrc.solvers.sarsop import alpha_set
from torchhrc.solvers.sarsop.alpha_set import _AlphaSet


def _check_blocks(s: _AlphaSet) -> None:
    """Each ``x``'s block holds exactly the flat vectors of ``x``, in index order."""
    assert s.np_vectors is not None and s.np_observed is not None
    obs = s.np_observed[: s.size]
    for x in range(s.num_observed):
        cols, ids = s.group_columns(x)
        np.testing.assert_array_equal(ids, np.flatnonzero(obs == x))
        np.testing.assert_array_equal(cols, s.np_vectors[ids].T)  # copies: the same floats


def test_blocks_equal_the_flat_vectors_through_growth_and_pruning(monkeypatch) -> None:
    monkeypatch.setattr(alpha_set, "_BLOCK", 64)  # many blocks per copy (5 vectors of Y=12)
    rng = np.random.default_rng(0)
    X, Y = 3, 12
    start = torch.from_numpy(rng.normal(size=(X, Y)))
    s = _AlphaSet(start, torch.zeros(X, dtype=torch.long), torch.arange(X), X)
    added = [start.numpy().copy()]
    for _ in range(150):  # one at a time: the flat storage (64) and the blocks (4) grow
        v = rng.normal(size=Y)
        s.add_np(v, 0, int(rng.integers(X)))
        added.append(v[None])
    _check_blocks(s)
    batch = torch.from_numpy(rng.normal(size=(100, Y)))  # a batch across a doubling
    s.add(batch, torch.zeros(100, dtype=torch.long), torch.from_numpy(rng.integers(X, size=100)))
    added.append(batch.numpy())
    _check_blocks(s)
    everything = np.concatenate(added)
    mask = torch.from_numpy(rng.random(s.size) < 0.3)
    mask[:X] = True  # (every x keeps a vector)
    moved = s.keep(mask)
    kept = np.flatnonzero(moved >= 0)
    np.testing.assert_array_equal(s.np_vectors[: s.size], everything[kept])
    _check_blocks(s)
    for i in range(40):  # and grows again after the pruning
        s.add_np(rng.normal(size=Y), 0, i % X)
    _check_blocks(s)


def test_growth_never_holds_two_copies_of_a_block(monkeypatch) -> None:
    """The numpy memory (traced: the column blocks and the copies' temporaries; the flat
    storage is torch's) peaks at the largest block plus one block of copying, not at the old
    block beside its twice-as-wide successor (1.5 times the largest block)."""
    monkeypatch.setattr(alpha_set, "_BLOCK", 1 << 12)
    rng = np.random.default_rng(1)
    Y = 1000
    # two observed values, the added vectors all at x = 0: its block fills (and grows)
    # before the flat storage does (whose growth rebuilds every block)
    s = _AlphaSet(torch.from_numpy(rng.normal(size=(2, Y))), torch.zeros(2, dtype=torch.long),
                  torch.arange(2), 2)  # fmt: skip
    rows = rng.normal(size=(600, Y))
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        for v in rows:
            s.add_np(v, 0, 0)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    block = s._gcol[0].nbytes  # the largest block, the last one made
    assert block >= 600 * Y * 8
    copying = 2 * alpha_set._BLOCK * 8 + (1 << 16)  # a gathered part, its transpose, slack
    assert peak <= block + copying, (peak, block)
    _check_blocks(s)


@pytest.mark.parametrize("X", [1, 2])
def test_pruning_hands_the_dropped_vectors_pages_back(X: int) -> None:
    """After a pruning drops most vectors, neither the flat storage's rows past the kept
    ones nor the old column blocks stay resident: the process shrinks by both copies."""
    from torchhrc.solvers._memory import resident_bytes

    if resident_bytes() is None or alpha_set.release_pages(np.ones(1 << 12), 0) == 0:
        pytest.skip("no /proc/self/statm or no madvise")
    rng = np.random.default_rng(2)
    Y, n = 4096, 1024  # 32 MB of vectors
    V = torch.from_numpy(rng.normal(size=(n, Y)))
    s = _AlphaSet(V, torch.zeros(n, dtype=torch.long), torch.arange(n) % X, X)
    mask = torch.zeros(n, dtype=torch.bool)
    mask[:16] = True
    blocks = sum(c.nbytes for c in s._gcol)  # at most this much of them is resident
    before = resident_bytes()
    s.keep(mask)
    after = resident_bytes()
    assert before is not None and after is not None
    dropped = (n - 16) * Y * 8
    # the old blocks go whole, and the dropped rows' pages with them (without those: about
    # the blocks alone, 64 MB against 126 here)
    assert before - after >= blocks + 0.8 * dropped, (before, after, blocks, dropped)
    np.testing.assert_array_equal(s.np_vectors[:16], V[:16].numpy())
    _check_blocks(s)


def test_release_pages_keeps_every_byte_before_start() -> None:
    """Only whole pages at or past ``start`` go: the bytes before it (the page they share
    with ``start`` included) keep their values, the released pages read back as zeros."""
    from torchhrc.solvers._memory import _PAGE, release_pages

    a = np.arange(1 << 16, dtype=np.float64) + 1.0  # 512 kB, no zero
    start = 100 * 8 + _PAGE * 3  # inside a page
    freed = release_pages(a, start)
    if freed == 0:
        pytest.skip("no madvise here")
    head = -(-(a.ctypes.data + start) // _PAGE) * _PAGE - a.ctypes.data  # first released byte
    np.testing.assert_array_equal(a[: head // 8], np.arange(head // 8) + 1.0)
    assert head >= start and freed >= a.nbytes - head - _PAGE
    assert (a[head // 8 : (head + freed) // 8] == 0).all()
