"""Tests of torchhrc.solvers.eval_cache: records laid out as documented, packed entries read
back bit for bit."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
import torch

from torchhrc.solvers.eval_cache import (
    PACK_FRACTION,
    EvaluationCache,
    action_prob,
    pack,
    unpack,
    upper_part,
)
from torchhrc.solvers.sarsop import SARSOPConfig
from torchhrc.solvers.sarsop.search import _SARSOP
from torchhrc.tasks.classic import tag


def _tag_seeing_cells():  # type: ignore[no-untyped-def]
    """Tag as a MOMDP whose observation is the opponent's cell when they share the robot's
    (else "none"), as APPL's TagAvoid: 30 observations."""
    model = tag(form="momdp", robot_start=0)
    A, X, Y, _ = model.Z.shape
    Z = torch.zeros(A, X, Y, Y, dtype=torch.float64)
    same = torch.arange(X)
    Z[:, :, :, Y - 1] = 1.0  # "none" (the last value)
    Z[:, same, same, Y - 1] = 0.0
    Z[:, same, same, same] = 1.0
    return dataclasses.replace(model, Z=Z, observations=None)


def _entry(rng: np.random.Generator, possible: float, stray: bool = False):  # type: ignore[no-untyped-def]
    shape = (3, 2, 25)
    prob = rng.random(shape) * (rng.random(shape) < possible)
    low, up = -rng.random(shape) * (prob > 0), rng.random(shape) * (prob > 0)
    if stray:  # a nonzero bound at an impossible child is kept too
        i = np.flatnonzero(prob.reshape(-1) == 0)[0]
        low.reshape(-1)[i] = -7.0
    return rng.random(3), rng.random(3), prob, low, up


def test_a_record_is_laid_out_as_documented():
    """A = 2 actions, K = 1, O = 2: q_low, q_up, then prob, low, up in (a, k, o) order."""
    q_low, q_up = np.array([1.0, 2.0]), np.array([3.0, 4.0])
    prob = np.array([[[0.5, 0.5]], [[1.0, 0.0]]])
    record = pack(q_low, q_up, prob, prob * -1.0, prob * 10.0)
    assert record.tolist() == [1, 2, 3, 4, 0.5, 0.5, 1, 0, -0.5, -0.5, -1, 0, 5, 5, 10, 0]
    views = unpack(record, 2, 2)
    assert [v.shape for v in views] == [(2,), (2,), (2, 1, 2), (2, 1, 2), (2, 1, 2)]
    assert views[4][1, 0, 0] == 10.0 and views[1][1] == 4.0
    views[3][0, 0, 1] = 7.0  # views, not copies
    assert record[9] == 7.0
    q_up, up = upper_part(record, 2)  # what a backup reads of a stale record
    assert q_up.tolist() == [3, 4] and up.tolist() == [5, 5, 10, 0]
    assert action_prob(record, 2, 0).tolist() == [0.5, 0.5]  # an action's children's P
    assert action_prob(record, 2, 1).tolist() == [1, 0]
    with pytest.raises(ValueError, match="2 A \\+ 3 A K O entries"):
        unpack(record[:-1], 2, 2)
    with pytest.raises(ValueError, match="K >= 1"):
        unpack(record[:4], 2, 2)


@pytest.mark.parametrize(("possible", "stray"), [(0.1, False), (0.1, True), (0.9, False)])
def test_entries_read_back_bit_for_bit(possible, stray):
    rng = np.random.default_rng(0)
    cache = EvaluationCache(num_actions=3)
    entries = {k: pack(*_entry(rng, possible, stray)) for k in range(20)}
    for k, e in entries.items():
        cache[k] = e
    for k, e in entries.items():
        got = cache[k]
        assert got.shape == e.shape and got.dtype == e.dtype
        np.testing.assert_array_equal(got, e)
        prob = unpack(e, 3, 25)[2]
        few = np.count_nonzero(prob) <= PACK_FRACTION * prob.size and prob.size >= 128
        assert cache.packed(k) == few
    assert cache.get(99) is None and len(cache) == 20 and 3 in cache
    assert any(cache.packed(k) for k in entries) == (possible < PACK_FRACTION)


def test_expanded_arrays_are_new():
    rng = np.random.default_rng(1)
    cache = EvaluationCache(num_actions=3)
    cache[0] = pack(*_entry(rng, 0.1))
    assert cache.packed(0)
    first = cache[0]
    first[-5:] = 123.0
    assert not (cache[0] == 123.0).any()


def test_a_momdp_search_packs_its_entries():
    # Tag as a MOMDP seeing the opponent's cell: a belief has 5 actions x K reachable cells x
    # 30 observations of children, and each action moves the robot to one cell
    s = _SARSOP(_tag_seeing_cells(), SARSOPConfig(max_iterations=30), time.perf_counter(), 0.0)
    s.run()
    keys = list(s._cache)
    packed = sum(s._cache.packed(k) for k in keys)
    assert len(keys) > 20 and packed > 0.5 * len(keys)
    dense = sum(s._cache[k].nbytes for k in keys)
    assert s._cache.nbytes() < 0.3 * dense
