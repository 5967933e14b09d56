"""Tests for torchhrc.metrics: ARI against hand-worked values and a pair-counting reference,
and the one-to-one cluster matching against brute force."""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.metrics import (
    _best_assignment,
    adjusted_rand_index,
    contingency_table,
    match_clusters,
    matched_accuracy,
)


def _ari_by_pairs(a: list[int], b: list[int]) -> float:
    """Reference: count agreeing pairs one by one (Hubert & Arabie's formula)."""
    n = len(a)
    both = sum(a[i] == a[j] and b[i] == b[j] for i, j in itertools.combinations(range(n), 2))
    same_a = sum(a[i] == a[j] for i, j in itertools.combinations(range(n), 2))
    same_b = sum(b[i] == b[j] for i, j in itertools.combinations(range(n), 2))
    expected = same_a * same_b / math.comb(n, 2)
    maximum = (same_a + same_b) / 2
    return 1.0 if maximum == expected else (both - expected) / (maximum - expected)


def test_ari_hand_worked_value():
    # table [[2, 1, 0], [0, 1, 2]]: index 2, rows 3 + 3 = 6, cols 1 + 1 + 1 = 3, C(6,2) = 15
    # E = 6 * 3 / 15 = 1.2, max = 4.5, ARI = 0.8 / 3.3
    assert adjusted_rand_index([0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 2, 2]) == pytest.approx(0.8 / 3.3)


def test_ari_identical_up_to_renaming_is_one_and_trivial_cases():
    assert adjusted_rand_index(["s", "s", "e", "e", "e"], [7, 7, 3, 3, 3]) == 1.0
    assert adjusted_rand_index([0, 0, 0], [1, 1, 1]) == 1.0
    # One partition trivial, the other not: ARI 0.
    assert adjusted_rand_index([0, 0, 1, 1], [5, 5, 5, 5]) == pytest.approx(0.0)


@pytest.mark.parametrize("seed", range(5))
def test_ari_matches_pair_counting_reference(seed):
    g = torch.Generator().manual_seed(seed)
    a = torch.randint(0, 3, (25,), generator=g)
    b = torch.randint(0, 4, (25,), generator=g)
    assert adjusted_rand_index(a, b) == pytest.approx(_ari_by_pairs(a.tolist(), b.tolist()))
    assert adjusted_rand_index(a, b) == pytest.approx(adjusted_rand_index(b, a))


def test_contingency_table_and_errors():
    table, t, p = contingency_table(["x", "y", "x", "x"], torch.tensor([2, 0, 0, 2]))
    assert t == ("x", "y") and p == (2, 0)
    assert table.tolist() == [[2, 1], [0, 1]]
    with pytest.raises(ModelError, match="one length"):
        contingency_table([0, 1], [0])
    with pytest.raises(TypeError, match="integer"):
        contingency_table(torch.tensor([0.5]), [0])


def _brute_force_best(w: torch.Tensor) -> float:
    r, c = w.shape
    if r <= c:
        return max(
            sum(w[i, j] for i, j in enumerate(p)) for p in itertools.permutations(range(c), r)
        )
    return _brute_force_best(w.T)


@pytest.mark.parametrize(("rows", "cols"), [(2, 2), (3, 2), (2, 4), (4, 4), (5, 3)])
def test_best_assignment_is_optimal_and_one_to_one(rows, cols):
    g = torch.Generator().manual_seed(rows * 10 + cols)
    w = torch.randint(0, 20, (rows, cols), generator=g).to(torch.float64)
    pairs = _best_assignment(w)
    assert len(pairs) == min(rows, cols)
    assert len({i for i, _ in pairs}) == len(pairs) == len({j for _, j in pairs})
    assert sum(float(w[i, j]) for i, j in pairs) == pytest.approx(float(_brute_force_best(w)))


def test_best_assignment_scipy_path_agrees_with_dp():
    g = torch.Generator().manual_seed(0)
    w = torch.rand(13, 14, generator=g, dtype=torch.float64)
    big = _best_assignment(w)  # 14 columns: SciPy
    assert len(big) == 13
    # The DP on the transposed problem (13 rows as columns) gives the same optimum.
    small = _best_assignment(w[:, :12])
    dp_total = sum(float(w[i, j]) for i, j in small)
    scipy_small = _best_assignment(torch.cat([w[:, :12], torch.zeros(13, 2, dtype=w.dtype)], 1))
    assert sum(float(w[i, j]) for i, j in scipy_small if j < 12) == pytest.approx(dp_total)


def test_match_clusters_and_matched_accuracy():
    true = ["safe"] * 4 + ["efficient"] * 4
    pred = [1, 1, 1, 0, 0, 0, 0, 2]
    assert match_clusters(true, pred) == {1: "safe", 0: "efficient"}
    # Cluster 2 has no label of its own: its item counts as wrong. Hits: 3 + 3.
    assert matched_accuracy(true, pred) == pytest.approx(6 / 8)
    assert matched_accuracy(true, [0] * 4 + [1] * 4) == 1.0
