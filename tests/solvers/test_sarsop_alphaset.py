"""SARSOP's alpha set: the dominance lookup used when pruning keeps referenced vectors."""

from __future__ import annotations

import numpy as np
import torch

from torchhrc.solvers.sarsop import _AlphaSet


def _brute_force(V: np.ndarray, obs: np.ndarray, need: np.ndarray, kept: np.ndarray) -> list:
    out = []
    for i in need.tolist():
        hits = [j for j in kept.tolist() if obs[j] == obs[i] and (V[j] >= V[i]).all()]
        out.append(hits[0] if hits else -1)
    return out


def test_dominating_finds_the_first_pointwise_dominating_kept_vector_of_the_same_x() -> None:
    rng = np.random.default_rng(0)
    n, Y, X = 300, 40, 3
    # coarse values, so that ties and dominance are common; a few exact copies shifted up
    V = rng.integers(0, 3, size=(n, Y)).astype(np.float64)
    V[200:260] = V[:60] + rng.integers(0, 2, size=(60, Y))
    obs = rng.integers(0, X, size=n)
    obs[200:260] = obs[:60]
    alphas = _AlphaSet(
        torch.from_numpy(V), torch.zeros(n, dtype=torch.long), torch.from_numpy(obs), X
    )
    kept = np.sort(rng.choice(n, size=150, replace=False))
    need = np.setdiff1d(np.arange(n), kept)
    found = alphas._dominating(need, kept)
    assert found.tolist() == _brute_force(V, obs, need, kept)
    assert (found >= 0).sum() >= 8  # the case is not vacuous (10 found)
