"""SARSOP's alpha set in memory: the vectors are held once, as rows (no second copy per
observed value), the per-``x`` index lists follow the rows through growth and pruning, and
neither a growth nor a pruning holds a second copy of the vectors resident."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc.solvers.sarsop import alpha_set
from torchhrc.solvers.sarsop.alpha_set import _AlphaSet


def _check_groups(s: _AlphaSet) -> None:
    """Each ``x``'s group holds exactly the flat vectors of ``x``, in index order."""
    assert s.np_vectors is not None and s.np_observed is not None
    obs = s.np_observed[: s.size]
    for x in range(s.num_observed):
        V, ids = s.group(x)
        np.testing.assert_array_equal(ids, np.flatnonzero(obs == x))
        np.testing.assert_array_equal(V, s.np_vectors[ids])


def _held_bytes(s: _AlphaSet) -> tuple[int, int]:
    """The bytes of the vectors' storage, and of every other array the set holds (outside
    ``refs``): its arrays, tensors, lists and dicts of them that do not share the storage."""
    store = s.vectors.numpy()
    other, seen = 0, set()
    for name, value in vars(s).items():
        if isinstance(value, dict):  # the remembered scoring calls: (rows, ...)
            items = [v[0] for v in value.values()]
        else:
            items = value if isinstance(value, list) and name != "refs" else [value]
        for item in items:
            a = item.numpy() if isinstance(item, torch.Tensor) else item
            if not isinstance(a, np.ndarray) or np.shares_memory(a, store):
                continue
            if a.ctypes.data not in seen:  # (a tensor and its numpy view: once)
                seen.add(a.ctypes.data)
                other += a.nbytes
    return store.nbytes, other


@pytest.mark.parametrize("X", [1, 3])
def test_the_vectors_are_held_once(X: int) -> None:
    """Besides the ``(capacity, Y)`` rows, the set holds a few integers per vector (its
    action, observed value and group index): 24 bytes each where ``Y`` floats are 8,000, and
    the rows of the last scoring calls it remembers (a per-``x`` column copy of the vectors,
    as before, would add about as much again as the rows)."""
    rng = np.random.default_rng(3)
    Y = 1000
    s = _AlphaSet(torch.from_numpy(rng.normal(size=(X, Y))), torch.zeros(X, dtype=torch.long),
                  torch.arange(X), X)  # fmt: skip
    for i in range(300):
        s.add_np(rng.normal(size=Y), 0, i % X)
    s.keep(torch.from_numpy(rng.random(s.size) < 0.5) | (torch.arange(s.size) < X))
    for i in range(100):
        s.add_np(rng.normal(size=Y), 0, i % X)
        if X == 1:  # operands kept for many column sets
            cols = rng.choice(Y, 40, replace=False)
            s.best_on_columns(None, rng.random((8, 40)), cols)
    store, other = _held_bytes(s)
    cap = s.vectors.shape[0]
    assert store == cap * Y * 8
    assert other <= cap * 8 * 3 + 64 * 8 * 40 * 8 + 4096 * X, (store, other)  # 3 int64 a row
    _check_groups(s)


def test_groups_follow_the_flat_vectors_through_growth_and_pruning() -> None:
    rng = np.random.default_rng(0)
    X, Y = 3, 12
    start = torch.from_numpy(rng.normal(size=(X, Y)))
    s = _AlphaSet(start, torch.zeros(X, dtype=torch.long), torch.arange(X), X)
    added = [start.numpy().copy()]
    for _ in range(150):  # one at a time: the flat storage (64) and the groups (4) grow
        v = rng.normal(size=Y)
        s.add_np(v, 0, int(rng.integers(X)))
        added.append(v[None])
    _check_groups(s)
    batch = torch.from_numpy(rng.normal(size=(100, Y)))  # a batch across a doubling
    s.add(batch, torch.zeros(100, dtype=torch.long), torch.from_numpy(rng.integers(X, size=100)))
    added.append(batch.numpy())
    everything = np.concatenate(added)
    np.testing.assert_array_equal(s.np_vectors[: s.size], everything)
    _check_groups(s)
    mask = torch.from_numpy(rng.random(s.size) < 0.3)
    mask[:X] = True  # (every x keeps a vector)
    moved = s.keep(mask)
    kept = np.flatnonzero(moved >= 0)
    np.testing.assert_array_equal(s.np_vectors[: s.size], everything[kept])
    _check_groups(s)
    for i in range(40):  # and grows again after the pruning
        s.add_np(rng.normal(size=Y), 0, i % X)
    _check_groups(s)


def test_growth_never_holds_two_copies_resident(monkeypatch) -> None:
    """A growth copies the rows into the larger storage from the last, handing each copied
    block's old pages back: the process's resident memory, read after every block, stays
    within a few blocks of where it started (the whole old storage, 20 MB, without that)."""
    from torchhrc.solvers._memory import resident_bytes

    if resident_bytes() is None or alpha_set.release_pages(np.ones(1 << 12), 0) == 0:
        pytest.skip("no /proc/self/statm or no madvise")
    monkeypatch.setattr(alpha_set, "_BLOCK", 1 << 17)  # 1 MB blocks: 32 rows of Y = 4096
    rng = np.random.default_rng(1)
    Y, n = 4096, 600  # 19.7 MB of vectors, capacity 1,200
    V = rng.normal(size=(n, Y))
    s = _AlphaSet(torch.from_numpy(V), torch.zeros(n, dtype=torch.long),
                  torch.zeros(n, dtype=torch.long), 1)  # fmt: skip
    seen = []
    release = alpha_set.release_pages

    def watched(array: np.ndarray, start: int) -> int:
        freed = release(array, start)
        seen.append(resident_bytes())
        return freed

    monkeypatch.setattr(alpha_set, "release_pages", watched)
    extra = rng.normal(size=(700, Y))  # (allocated before the reading starts)
    before = resident_bytes()
    s.add(torch.from_numpy(extra), torch.zeros(700, dtype=torch.long),
          torch.zeros(700, dtype=torch.long))  # fmt: skip
    assert s.vectors.shape[0] == 2400 and len(seen) >= n // 32
    assert before is not None and None not in seen
    assert max(seen) - before <= 6 * (1 << 20), (max(seen) - before, n * Y * 8)
    np.testing.assert_array_equal(s.np_vectors[:n], V)
    np.testing.assert_array_equal(s.np_vectors[n : s.size], extra)
    _check_groups(s)


@pytest.mark.parametrize("X", [1, 2])
def test_pruning_hands_the_dropped_vectors_pages_back(X: int) -> None:
    """After a pruning drops most vectors, the flat storage's rows past the kept ones do not
    stay resident: the process shrinks by them."""
    from torchhrc.solvers._memory import resident_bytes

    if resident_bytes() is None or alpha_set.release_pages(np.ones(1 << 12), 0) == 0:
        pytest.skip("no /proc/self/statm or no madvise")
    rng = np.random.default_rng(2)
    Y, n = 4096, 1024  # 32 MB of vectors
    V = torch.from_numpy(rng.normal(size=(n, Y)))
    s = _AlphaSet(V, torch.zeros(n, dtype=torch.long), torch.arange(n) % X, X)
    mask = torch.zeros(n, dtype=torch.bool)
    mask[:16] = True
    before = resident_bytes()
    s.keep(mask)
    after = resident_bytes()
    assert before is not None and after is not None
    dropped = (n - 16) * Y * 8
    assert before - after >= 0.8 * dropped, (before, after, dropped)
    np.testing.assert_array_equal(s.np_vectors[:16], V[:16].numpy())
    _check_groups(s)


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


@pytest.mark.parametrize("compiled", [False, True])
def test_best_on_columns_equals_a_fresh_argmax(compiled: bool) -> None:
    """:meth:`_AlphaSet.best_on_columns` (remembered maxima, extended by the vectors added
    since) equals the argmax over every vector afresh, the first of tied maxima included,
    through additions, a growth and a pruning; rows changed under the same columns are
    scored afresh."""
    from torchhrc.solvers import backup_kernel

    kernel = backup_kernel.load() if compiled else None
    if compiled and kernel is None:
        pytest.skip("the C extension is not built")
    rng = np.random.default_rng(4)
    Y = 50
    s = _AlphaSet(torch.from_numpy(rng.normal(size=(3, Y))), torch.zeros(3, dtype=torch.long),
                  torch.zeros(3, dtype=torch.long), 1)  # fmt: skip
    sets = [np.array([1, 7, 8, 30]), np.array([0, 49]), np.array([5])]
    rows = [rng.random((4, c.size)) for c in sets]
    for step in range(200):
        v = rng.normal(size=Y)
        if step % 9 == 0:  # a tie with row 0's best vector on the columns of sets[0]
            V0 = s.np_vectors[: s.size][:, sets[0]]
            v[sets[0]] = V0[(V0 @ rows[0][0]).argmax()]
        s.add_np(v, 0, 0)
        if step == 120:
            s.keep(torch.from_numpy(rng.random(s.size) < 0.5))
        if step == 150:
            rows[1] = rng.random((4, 2))  # other rows on the same columns
        k = step % 3
        val, arg = s.best_on_columns(kernel, rows[k], sets[k])
        scores = rows[k] @ s.np_vectors[: s.size][:, sets[k]].T
        np.testing.assert_allclose(val, scores.max(-1), rtol=1e-14, atol=0)
        assert arg.tolist() == scores.argmax(-1).tolist()


def test_lent_views_keep_their_values_through_a_pruning() -> None:
    """The final policy's views (:meth:`_AlphaSet.lend`) are not copies, and a later pruning
    of the set leaves them as they were (it moves the set to a copy first)."""
    rng = np.random.default_rng(5)
    V = rng.normal(size=(40, 6))
    s = _AlphaSet(torch.from_numpy(V), torch.arange(40) % 3, torch.zeros(40, dtype=torch.long))
    vectors, actions, _ = s.lend()
    assert np.shares_memory(vectors.numpy(), s.np_vectors)
    s.add_np(rng.normal(size=6), 1, 0)  # past the views
    s.keep(torch.from_numpy(rng.random(s.size) < 0.3) | (torch.arange(s.size) == 0))
    np.testing.assert_array_equal(vectors.numpy(), V)
    assert actions.tolist() == (torch.arange(40) % 3).tolist()
    _check_groups(s)


def test_the_dominance_lookup_never_copies_the_candidates() -> None:
    """``_dominating`` (a pruning's lookup of a kept vector that dominates a referred one)
    reads the candidates' rows where it needs them: its temporary memory stays far below one
    copy of the kept vectors (``V[cand]`` copied them all: about 480 MB of a 20,000-state
    solve's peak, docs/benchmarks.md), and it finds the same dominating vectors."""
    import tracemalloc

    rng = np.random.default_rng(5)
    Y, n, k = 4096, 2000, 10
    V = rng.normal(size=(n, Y))
    kept, need = np.arange(n - k), np.arange(n - k, n)
    V[need[:5]] = V[kept[:5]] - 1.0  # dominated by kept vectors 0-4 (random rows never are)
    s = _AlphaSet(torch.from_numpy(V), torch.zeros(n, dtype=torch.long),
                  torch.zeros(n, dtype=torch.long), 1)  # fmt: skip
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        found = s._dominating(need, kept)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert found.tolist() == [0, 1, 2, 3, 4] + [-1] * 5
    copy = kept.size * Y * 8  # 65 MB
    assert peak < copy / 8, (peak, copy)
