"""Tests of torchhrc.solvers.eval_cache: packed entries read back bit for bit."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
import torch

from torchhrc.solvers.eval_cache import PACK_FRACTION, EvaluationCache
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


@pytest.mark.parametrize(("possible", "stray"), [(0.1, False), (0.1, True), (0.9, False)])
def test_entries_read_back_bit_for_bit(possible, stray):
    rng = np.random.default_rng(0)
    cache = EvaluationCache()
    entries = {k: _entry(rng, possible, stray) for k in range(20)}
    for k, e in entries.items():
        cache[k] = e
    for k, e in entries.items():
        got = cache[k]
        for a, b in zip(got, e):
            assert a.shape == b.shape and a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
        few = np.count_nonzero(e[2]) <= PACK_FRACTION * e[2].size and e[2].size >= 128
        assert cache.packed(k) == few
    assert cache.get(99) is None and len(cache) == 20 and 3 in cache


def test_expanded_arrays_are_new():
    rng = np.random.default_rng(1)
    cache = EvaluationCache()
    cache[0] = _entry(rng, 0.1)
    first = cache[0]
    first[4][...] = 123.0
    assert not (cache[0][4] == 123.0).any()


def test_a_momdp_search_packs_its_entries():
    # Tag as a MOMDP seeing the opponent's cell: a belief has 5 actions x K reachable cells x
    # 30 observations of children, and each action moves the robot to one cell
    s = _SARSOP(_tag_seeing_cells(), SARSOPConfig(max_iterations=30), time.perf_counter(), 0.0)
    s.run()
    keys = list(s._cache)
    packed = sum(s._cache.packed(k) for k in keys)
    assert len(keys) > 20 and packed > 0.5 * len(keys)
    dense = sum(sum(a.nbytes for a in s._cache[k]) for k in keys)
    assert s._cache.nbytes() < 0.3 * dense
