"""The sawtooth's inner loop: the C extension, its Python reference and the numpy fallback
equal the exhaustive formula bit for bit, and the extension rejects arrays that would make
it read stray memory."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from torchhrc.solvers import sawtooth_kernel
from torchhrc.solvers.sawtooth_kernel import (
    _corrections,
    _corrections_np,
    sawtooth_corrections,
    support_signatures,
)

try:
    from torchhrc.solvers._sawtooth import corrections as compiled
except ImportError:  # pragma: no cover - the extension is built by pip install
    compiled = None

needs_extension = pytest.mark.skipif(compiled is None, reason="the C extension is not built")


def _problem(seed: int, *, mapped: bool, Y: int = 30, density: float = 0.8):
    """Random points (supports of 1..8 of Y values, negative and positive gains), queries.

    The supports lie end to end in one flat array, as in the bound's storage, but in shuffled
    order and with unused entries between them (the offsets, not the order, locate them)."""
    rng = np.random.default_rng(seed)
    P, K, B = 40, 8, 12
    wid = np.zeros(P + 5, dtype=np.int64)  # 5 free slots, as in the bound's storage
    off = np.zeros(P + 5, dtype=np.int64)
    mass = np.ones(P + 5)
    idx = np.full(P * (K + 2), Y + 7, dtype=np.int64)  # stray values where no point lies
    inv = np.full(P * (K + 2), np.nan)
    start = 0
    for i in rng.permutation(P):
        w = int(rng.integers(1, K + 1))
        supp = np.sort(rng.choice(Y, w, replace=False))
        p = rng.random(w) + 0.05
        p /= p.sum()
        off[i], wid[i] = start, w
        idx[start : start + w], inv[start : start + w] = supp, 1.0 / p
        mass[i] = p.sum()
        start += w + int(rng.integers(0, 3))
    gain = rng.normal(-1.0, 1.0, P + 5)
    beliefs = rng.random((B, Y)) * (rng.random((B, Y)) < density) * rng.uniform(0.2, 1.0, (B, 1))
    ids = np.flatnonzero(gain[:P] < 0)
    key = gain[ids] / mass[ids]
    order = ids[np.argsort(key, kind="stable")]
    key = np.sort(key, kind="stable")
    local = None
    if mapped:  # the beliefs given on some columns only (zero elsewhere)
        cols = np.sort(rng.choice(Y, 20, replace=False))
        local = np.full(Y, cols.size, dtype=np.int64)
        local[cols] = np.arange(cols.size)
        beliefs = np.ascontiguousarray(beliefs[:, cols])
    return beliefs, order, (idx, inv, off, wid, gain), key, local


def _exhaustive(beliefs, order, points, local):
    """``min(0, min_i g_i min_k b(y_k) / b_i(y_k))`` over every candidate point."""
    idx, inv, off, wid, gain = points
    out = np.zeros(beliefs.shape[0])
    for q, b in enumerate(beliefs):
        full = b if local is None else np.append(b, 0.0)[np.minimum(local, b.size)]
        for j in order:
            seg = slice(off[j], off[j] + wid[j])
            r = (full[idx[seg]] * inv[seg]).min()
            out[q] = min(out[q], gain[j] * r)
    return out


@pytest.mark.parametrize("mapped", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_early_stops_give_the_exhaustive_minimum(seed, mapped, monkeypatch):
    beliefs, order, pts, key, local = _problem(seed, mapped=mapped)
    rows = np.arange(beliefs.shape[0], dtype=np.int64)
    want = _exhaustive(beliefs, order, pts, local)
    assert (want < 0).sum() >= 6  # the points do lower the bound at most queries
    monkeypatch.setattr(sawtooth_kernel, "_KERNEL", _corrections)
    ref = sawtooth_corrections(beliefs, rows, order, *pts, key, local)
    np.testing.assert_array_equal(ref, want)  # bit for bit: the same products are kept
    monkeypatch.setattr(sawtooth_kernel, "_KERNEL", _corrections_np)
    np.testing.assert_array_equal(
        sawtooth_corrections(beliefs, rows, order, *pts, key, local), want
    )
    monkeypatch.setattr(sawtooth_kernel, "_BLOCK", 7)  # blocks of one row (its entries > 7)
    sub = rows[::3][::-1].copy()
    part = sawtooth_corrections(beliefs, sub, order, *pts, key, local)
    np.testing.assert_array_equal(part, want[sub])
    if compiled is not None:
        monkeypatch.setattr(sawtooth_kernel, "_KERNEL", compiled)
        got = sawtooth_corrections(beliefs, rows, order, *pts, key, local)
        np.testing.assert_array_equal(got, want)
        sub = rows[::3][::-1].copy()  # a subset of the rows, in any order
        part = sawtooth_corrections(beliefs, sub, order, *pts, key, local)
        np.testing.assert_array_equal(part, want[sub])


def test_no_candidate_point_gives_zero():
    beliefs, _, pts, _, _ = _problem(0, mapped=False)
    rows = np.arange(3, dtype=np.int64)
    empty = np.empty(0, dtype=np.int64)
    out = sawtooth_corrections(beliefs, rows, empty, *pts, empty.astype(float))
    np.testing.assert_array_equal(out, np.zeros(3))


@needs_extension
def test_extension_rejects_bad_arrays():
    beliefs, order, pts, key, _ = _problem(0, mapped=False)
    idx, inv, off, wid, gain = pts
    rows = np.arange(2, dtype=np.int64)
    out = np.empty(2)
    none = np.empty(0, dtype=np.int64)
    args = [beliefs, rows, order, idx, inv, off, wid, gain, key, none, none, out]
    with pytest.raises(TypeError, match="inv"):
        compiled(*args[:4], inv.astype(np.float32), *args[5:])
    with pytest.raises(TypeError, match="idx"):
        compiled(*args[:3], idx.reshape(-1, 2), *args[4:])  # 2-D: the old padded layout
    with pytest.raises(TypeError, match="beliefs"):
        compiled(np.asfortranarray(beliefs), *args[1:])
    with pytest.raises(TypeError, match="12 arguments"):
        compiled(*args[:11])
    with pytest.raises(IndexError, match="row"):
        compiled(beliefs, np.array([0, beliefs.shape[0]]), *args[2:])
    with pytest.raises(IndexError, match="point"):
        compiled(*args[:2], np.array([off.shape[0]]), *args[3:8], key[:1], none, none, out)
    far = off.copy()
    far[order[0]] = idx.shape[0] - wid[order[0]] + 1  # a support running past the array
    with pytest.raises(IndexError, match="point"):
        compiled(*args[:5], far, *args[6:])
    bad = idx.copy()
    bad[off[order[0]]] = 10_000  # a support index past the columns
    with pytest.raises(IndexError, match="support index"):
        compiled(*args[:3], bad, *args[4:])
    with pytest.raises(ValueError, match="shapes"):
        compiled(*args[:11], np.empty(5))
    with pytest.raises(ValueError, match="shapes"):  # signatures of another length
        compiled(*args[:10], np.zeros(3, dtype=np.int64), out)


def test_without_the_extension_numpy_runs_with_a_warning(monkeypatch):
    beliefs, order, pts, key, _ = _problem(1, mapped=False)
    rows = np.arange(beliefs.shape[0], dtype=np.int64)
    want = _exhaustive(beliefs, order, pts, None)
    monkeypatch.setitem(sys.modules, "torchhrc.solvers._sawtooth", None)  # import fails
    monkeypatch.setattr(sawtooth_kernel, "_KERNEL", None)
    monkeypatch.delenv("TORCHHRC_NO_EXTENSION", raising=False)
    with pytest.warns(RuntimeWarning, match="build_ext --inplace"):
        got = sawtooth_corrections(beliefs, rows, order, *pts, key)
    np.testing.assert_array_equal(got, want)
    assert sawtooth_kernel._KERNEL is _corrections_np
    monkeypatch.setattr(sawtooth_kernel, "_KERNEL", None)
    monkeypatch.setenv("TORCHHRC_NO_EXTENSION", "1")  # forced: no warning
    got = sawtooth_corrections(beliefs, rows, order, *pts, key)
    np.testing.assert_array_equal(got, want)
    assert sawtooth_kernel._KERNEL is _corrections_np


def test_a_float32_bound_is_evaluated_in_float64():
    beliefs, order, (idx, inv, off, wid, gain), key, _ = _problem(2, mapped=False)
    rows = np.arange(beliefs.shape[0], dtype=np.int64)
    f = np.float32
    got = sawtooth_corrections(beliefs.astype(f), rows, order, idx, inv.astype(f),
                               off, wid, gain.astype(f), key.astype(f))  # fmt: skip
    b64, inv64, gain64 = (a.astype(f).astype(float) for a in (beliefs, inv, gain))
    want = _exhaustive(b64, order, (idx, inv64, off, wid, gain64), None)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


@needs_extension
def test_extension_writes_only_a_writable_out():
    beliefs, order, pts, key, _ = _problem(0, mapped=False)
    out = np.empty(2)
    out.flags.writeable = False
    rows = np.arange(2, dtype=np.int64)
    with pytest.raises(TypeError, match="out"):
        none = np.empty(0, dtype=np.int64)
        compiled(beliefs, rows, order, *pts, key, none, none, out)


def test_support_signatures_worked_by_hand():
    # supports {0, 2} and {1, 65}: bits 0 and 2 -> 5; bits 1 and 65 % 64 = 1 -> 2
    got = support_signatures(np.array([0, 2, 1, 65]), np.array([0, 2]))
    assert got.tolist() == [5, 2]
    top = support_signatures(np.array([63]), np.array([0]))  # bit 63: the sign bit of int64
    assert top.tolist() == [-(2**63)]


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_signatures_skip_points_and_keep_the_minimum(seed):
    # 150 hidden values (several share a bit of the 64) and sparse queries: many points
    # cover a value where the query is 0, and the compiled loop skips them by signature
    beliefs, order, pts, key, _ = _problem(seed, mapped=False, Y=150, density=0.3)
    idx, inv, off, wid, gain = pts
    sig = np.zeros(off.shape[0], dtype=np.int64)
    for j in order:
        sig[j] = support_signatures(idx[off[j] : off[j] + wid[j]], np.array([0]))[0]
    rows = np.arange(beliefs.shape[0], dtype=np.int64)
    row_sig = [support_signatures(np.flatnonzero(b), np.array([0]))[0] for b in beliefs]
    skipped = sum(int((sig[j] & ~r) != 0) for r in row_sig for j in order)
    assert skipped > len(order) * len(rows) // 2  # the filter is exercised
    want = _exhaustive(beliefs, order, pts, None)
    assert (want < 0).sum() >= 3
    for kernel in (_corrections, compiled):
        if kernel is None:
            continue
        out = np.empty(rows.shape[0])
        kernel(beliefs, rows, order, idx, inv, off, wid, gain, key, np.empty(0, np.int64), sig,
               out)  # fmt: skip
        np.testing.assert_array_equal(out, want)
