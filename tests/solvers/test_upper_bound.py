"""The sawtooth bound's point storage: supports end to end (a point costs its own support),
the same values through the tensor and the numpy path, and a pruning that keeps the
surviving points exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc.solvers import upper_bound as upper_bound_module
from torchhrc.solvers.upper_bound import SawtoothUpperBound


def _reference(corner: np.ndarray, pts: list[tuple[np.ndarray, float]], b: np.ndarray) -> float:
    """``b . c + min(0, min_i (v_i - b_i . c) min_{b_i(y) > 0} b(y) / b_i(y))`` by hand."""
    base = float(b @ corner)
    corr = 0.0
    for bi, vi in pts:
        s = bi > 0
        corr = min(corr, (vi - float(bi @ corner)) * float((b[s] / bi[s]).min()))
    return base + corr


def _check_signatures(ub: SawtoothUpperBound) -> None:
    """Each stored point's support signature (what the compiled loops skip points by) is the
    one of its support: bit ``y % 64`` per hidden value ``y``."""
    stored = ub.points[0].numpy()
    want = [int(np.bitwise_or.reduce(np.left_shift(np.int64(1), np.flatnonzero(b) & 63)))
            for b in stored]  # fmt: skip
    assert ub._sig[: ub.size].tolist() == want


def _random_points(rng: np.random.Generator, Y: int, widths: list[int]):
    pts = []
    for w in widths:
        b = np.zeros(Y)
        b[np.sort(rng.choice(Y, w, replace=False))] = rng.random(w) + 0.05
        b /= b.sum()
        pts.append((b, float(b @ np.full(Y, 10.0)) - float(rng.random()) * 4))
    return pts


@pytest.mark.parametrize("batched", [False, True])
def test_a_point_costs_its_own_support_not_the_widest(batched):
    rng = np.random.default_rng(0)
    Y = 60
    widths = [Y] + [int(w) for w in rng.integers(2, 6, 200)]  # one wide point, then narrow ones
    pts = _random_points(rng, Y, widths)
    ub = SawtoothUpperBound(torch.full((1, Y), 10.0, dtype=torch.float64), capacity=4)
    beliefs = torch.from_numpy(np.stack([b for b, _ in pts]))
    values = torch.tensor([v for _, v in pts], dtype=torch.float64)
    if batched:
        ub.add(beliefs, torch.zeros(len(pts), dtype=torch.long), values)
    else:
        for b, v in pts:
            ub.add_np(b, 0, v)
    assert ub.size == len(pts)
    assert ub._used == sum(widths)  # padded rows would hold len(pts) * Y entries
    assert ub._fidx.numel() <= 2 * sum(widths)  # the flat capacity is doubled, no more
    stored, _, v = ub.points
    torch.testing.assert_close(stored, beliefs, rtol=1e-15, atol=0)  # b = 1 / (1 / b)
    assert v.tolist() == values.tolist()
    _check_signatures(ub)
    q = rng.random((25, Y)) * (rng.random((25, Y)) < 0.9)
    q /= q.sum(-1, keepdims=True)
    want = np.array([_reference(np.full(Y, 10.0), pts, row) for row in q])
    x = np.zeros(25, dtype=np.int64)
    np.testing.assert_allclose(ub.value_np(q, x), want, rtol=1e-12, atol=1e-12)
    got = ub.value(torch.from_numpy(q), torch.from_numpy(x)).numpy()
    # the tensor path agrees (its base term b . c is summed in another order)
    np.testing.assert_allclose(got, ub.value_np(q, x), rtol=1e-14, atol=0)


@pytest.mark.parametrize("block", [None, 5])  # 5: a few points a block (kmax <= 11)
def test_pruning_moves_the_kept_supports_to_the_front_unchanged(block, monkeypatch):
    if block is not None:
        monkeypatch.setattr(upper_bound_module, "_COMPACT_ENTRIES", block)
    rng = np.random.default_rng(1)
    Y = 12
    corner = np.full(Y, 10.0)
    ub = SawtoothUpperBound(torch.from_numpy(corner[None].copy()), capacity=2)
    pts = _random_points(rng, Y, [int(w) for w in rng.integers(2, Y, 40)])
    # points no lower than the corners bound nothing (gain >= 0): pruning removes them (put
    # among the others, so that the kept ones move)
    useless = [(b, float(b @ corner) + 1.0) for b, _ in _random_points(rng, Y, [3, 5, 4])]
    pts = pts[:10] + useless + pts[10:]
    for b, v in pts:
        ub.add_np(b, 0, v)
    before, _, vals = ub.points
    removed = ub.prune()
    assert removed >= 3
    after, _, kept_vals = ub.points
    # every kept point is an original one, whole, in the original order
    rows = [int(np.flatnonzero(vals.numpy() == kv)[0]) for kv in kept_vals.tolist()]
    assert rows == sorted(rows)
    torch.testing.assert_close(after, before[rows], rtol=0, atol=0)
    assert ub._used == int((after > 0).sum())
    _check_signatures(ub)  # moved with their points
    kept = [pts[i] for i in rows]
    q = rng.random((10, Y)) * (rng.random((10, Y)) < 0.6)  # sparse: points get skipped
    q[:, 0] += 0.1
    q /= q.sum(-1, keepdims=True)
    want = np.array([_reference(corner, kept, row) for row in q])
    np.testing.assert_allclose(ub.value_np(q, np.zeros(10, dtype=np.int64)), want, rtol=1e-12,
                               atol=1e-12)  # fmt: skip
    # new points go after the compacted ones
    b, v = _random_points(rng, Y, [4])[0]
    ub.add_np(b, 0, v)
    assert ub.points[0][-1].tolist() == pytest.approx(b.tolist(), rel=1e-15)


def test_a_corner_change_refreshes_the_gains_of_its_observed_value_only():
    corner = torch.tensor([[4.0, 4.0, 4.0], [2.0, 2.0, 2.0]], dtype=torch.float64)
    ub = SawtoothUpperBound(corner)
    ub.add_np(np.array([0.5, 0.5, 0.0]), 0, 3.0)  # gain 3 - 4 = -1
    ub.add_np(np.array([0.0, 0.25, 0.75]), 1, 1.0)  # gain 1 - 2 = -1
    ub.add_np(np.array([1.0, 0.0, 0.0]), 0, 2.0)  # a corner of x = 0: c = (2, 4, 4)
    assert ub.corner[0].tolist() == [2.0, 4.0, 4.0] and ub.size == 2
    assert ub._gain[:2].tolist() == [3.0 - (0.5 * 2 + 0.5 * 4), -1.0]
    b = np.array([[0.5, 0.5, 0.0], [0.0, 0.25, 0.75]])
    assert ub.value_np(b, np.array([0, 1])).tolist() == [3.0, 1.0]


@pytest.mark.parametrize("compiled", [True, False])
def test_pruning_evaluates_a_few_beliefs_at_a_time(compiled, monkeypatch):
    """The pruning disables 256 points at a time and evaluates them against the others, a
    few rows at a time (at most ``_DENSE_ENTRIES`` dense entries: 256 rows of a 100,000-state
    model were 205 MB, and their corner product as much again). The narrow beliefs of a flat
    model are given on the union of their supports (``_supports_np``: 2-6 of 2,000 states),
    not as dense rows. Either way it keeps exactly the points it keeps with all 256 rows dense
    at once."""
    rng = np.random.default_rng(7)
    Y = 2000
    corner = np.full(Y, 10.0)
    pts = _random_points(rng, Y, [int(w) for w in rng.integers(2, 7, 300)])
    # 100 copies a little higher, in the next block of 256: the originals bound them there
    pts = pts + [(b, v + 0.01) for b, v in pts[:100]]
    n = len(pts)

    def pruned(entries: int, dense: bool) -> tuple[list, list, list]:
        monkeypatch.setattr(upper_bound_module, "_DENSE_ENTRIES", entries)
        ub = SawtoothUpperBound(torch.from_numpy(corner[None].copy()), capacity=2)
        if not compiled:
            monkeypatch.setattr(ub, "_group_kernel", None, raising=False)
        for b, v in pts:
            ub.add_np(b, 0, v)
        on_supports = ub._supports_np
        rows: list = []
        widths: list = []

        def watched(ids):
            rows.append(int(ids.shape[0]))
            if dense:
                return ub._dense(torch.from_numpy(ids)).numpy(), ub._np[3][ids], None
            out = on_supports(ids)
            widths.append(out[0].shape[1])
            return out

        monkeypatch.setattr(ub, "_supports_np", watched)
        ub.prune()
        monkeypatch.setattr(ub, "_supports_np", on_supports)
        return ub.points[2].tolist(), rows, widths

    kept_all, rows_all, _ = pruned(256 * Y, dense=True)  # one dense block of 256 rows
    kept, rows, widths = pruned(50 * Y, dense=False)
    assert max(rows_all) == 256 and max(rows) <= 50 and sum(rows) == sum(rows_all) == n
    assert kept == kept_all and len(kept) < n  # the same points kept, and some pruned
    assert max(widths) <= 6 * 50 and max(widths) < Y  # the supports' union, not Y columns


@pytest.mark.parametrize("X", [1, 3])
def test_cpu_pruning_keeps_what_the_tensor_pruning_keeps(X):
    """On the CPU the pruning runs on the storage's numpy views (``_prune_np``: no libtorch
    kernel); elsewhere on tensors. Both keep the same points, in the same order, with the
    same supports, values and gains: random points (narrow and wide supports, some a little
    above others at the same belief, so that both keep and drop), one and three observed
    values."""
    rng = np.random.default_rng(3 + X)
    Y = 40
    corner = 10.0 + rng.random((X, Y))
    pts = _random_points(rng, Y, [int(w) for w in rng.integers(1, Y, 300)])
    above, below = [(b, v + 0.01) for b, v in pts[:80]], [(b, v - 0.5) for b, v in pts[80:120]]
    pts = pts + above + below + pts[120:140]  # (exact copies: each bounds the other as tightly)
    xs = rng.integers(0, X, len(pts))

    def filled() -> SawtoothUpperBound:
        ub = SawtoothUpperBound(torch.from_numpy(corner.copy()), capacity=2)
        for (b, v), x in zip(pts, xs.tolist()):
            ub.add_np(b, x, v)
        return ub

    host, tensors = filled(), filled()
    assert host._np is not None
    tensors._np = None  # as on another device: the storage's tensors only
    removed = host.prune()
    assert removed == SawtoothUpperBound.prune(tensors) and 0 < removed < len(pts)
    assert host.size == tensors.size
    for a, b in zip(host.points, tensors.points):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    n, used = host.size, host._used
    assert used == tensors._used
    for name in ("_x", "_v", "_gain", "_w", "_mass", "_sig", "_off"):
        torch.testing.assert_close(getattr(host, name)[:n], getattr(tensors, name)[:n],
                                   rtol=0, atol=0, msg=name)  # fmt: skip
    for name in ("_fidx", "_finv"):
        torch.testing.assert_close(getattr(host, name)[:used], getattr(tensors, name)[:used],
                                   rtol=0, atol=0, msg=name)  # fmt: skip
    # and the pruned bound is at most each kept point's value at its belief (a point of the
    # same block, disabled beside it while it was judged, may lie below it there)
    rows, x, v = host.points
    assert (host.value_np(rows.numpy(), x.numpy()) <= v.numpy() + 1e-12).all()


def _stored(ub: SawtoothUpperBound) -> dict:
    n = ub.size
    ids = torch.arange(n)
    entries, _ = ub._entries(ids)
    return {
        "idx": ub._fidx[entries].tolist(),
        "inv": ub._finv[entries].numpy(),
        "x": ub._x[:n].tolist(),
        "v": ub._v[:n].tolist(),
        "gain": ub._gain[:n].numpy(),
        "w": ub._w[:n].tolist(),
        "mass": ub._mass[:n].numpy(),
        "sig": ub._sig[:n].tolist(),
        "members": [ub.members(x).tolist() for x in range(ub.num_observed)],
        "sorted": [None if s is None else (s[0].tolist(), s[1]) for s in ub._sorted],
        "corner": ub.corner.numpy().copy(),
    }


@pytest.mark.skipif(upper_bound_module.backup_kernel.load() is None, reason="no extension")
def test_a_compiled_point_is_stored_as_the_numpy_steps_store_it():
    """``add_np`` in one compiled call (``backup_kernel.add_point``) against its numpy steps,
    point by point: the supports, every field, each x's members and key order (a point after
    the equal keys before it), the corner case of a one-value belief, the storage's growth
    and the key order's, built for some x and not for others."""
    rng = np.random.default_rng(3)
    X, Y = 3, 70
    corner = torch.from_numpy(rng.random((X, Y)) * 5 + 10)
    ubs = [SawtoothUpperBound(corner, capacity=2) for _ in range(2)]
    ubs[1]._add_kernel = None  # the numpy steps
    assert ubs[0]._add_kernel is not None
    pts = _random_points(rng, Y, [int(w) for w in rng.integers(2, 8, 150)] + [Y, 1, 1])
    adds = [(b, i % 2 if i < 100 else 2, v - 3.0 * (i % 3 == 0)) for i, (b, v) in enumerate(pts)]
    adds += [adds[i] for i in range(0, 20, 2)]  # x = 0 again, keys equal to earlier ones
    for ub in ubs:
        ub._sorted_points(0)  # x = 0's key order built (and kept up to date), x = 1's not
    for i, (b, x, v) in enumerate(adds):
        for ub in ubs:
            ub.add_np(b, x, v)
            if i == 120:
                ub._sorted_points(2)  # x = 2's built halfway
        got, want = _stored(ubs[0]), _stored(ubs[1])
        for key in ("idx", "x", "v", "w", "sig", "members"):
            assert got[key] == want[key], (i, key)
        for key in ("inv", "gain", "mass", "corner"):
            np.testing.assert_allclose(got[key], want[key], rtol=1e-14, atol=1e-12)
        for g, s in zip(got["sorted"], want["sorted"]):
            assert (g is None) == (s is None)
            if g is not None:
                assert g[0] == s[0], i
                np.testing.assert_allclose(g[1], s[1], rtol=1e-14, atol=1e-14)
    # not vacuous: x = 0's key order followed 50 points; x = 2's was dropped when a one-value
    # belief lowered its corner
    assert len(got["sorted"][0][0]) == 60 and got["sorted"][2] is None
    q = rng.random((20, Y))
    q /= q.sum(-1, keepdims=True)
    x = np.arange(20, dtype=np.int64) % X
    np.testing.assert_allclose(ubs[0].value_np(q, x), ubs[1].value_np(q, x), rtol=1e-13)


@pytest.mark.skipif(upper_bound_module.backup_kernel.load() is None, reason="no extension")
def test_add_point_refuses_what_it_cannot_store():
    kernel = upper_bound_module.backup_kernel.load()
    i8, f8 = (lambda n: np.zeros(n, dtype=np.int64)), np.zeros
    args = [np.full(3, 1 / 3), np.ones((2, 3)), i8(8), f8(8), i8(4), f8(4), f8(4), i8(4),
            f8(4), i8(4), i8(4), i8(2), i8(2), f8(2)]  # fmt: skip
    w, pos = kernel.add_point(*args, 1, 0.5, 0, 0, 0, 0)
    assert (w, pos) == (3, 0)  # gain 0.5 - 1 < 0: put first in the empty key order
    assert kernel.add_point(*args, 1, 2.0, 1, 3, 1, -1) == (3, -1)  # no key order built
    with pytest.raises(ValueError, match="room for the point"):
        kernel.add_point(*args, 1, 2.0, 0, 6, 0, 0)  # start + Y > len(idx)
    with pytest.raises(ValueError, match="x in"):
        kernel.add_point(*args, 2, 2.0, 0, 0, 0, 0)
    with pytest.raises(ValueError, match="room in order"):
        kernel.add_point(*args, 1, 2.0, 0, 0, 0, 2)
    bad = list(args)
    bad[1] = np.ones((2, 3), dtype=np.float32)
    with pytest.raises(TypeError, match="corner"):
        kernel.add_point(*bad, 1, 2.0, 0, 0, 0, 0)
