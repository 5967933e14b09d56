"""Shared helpers of the environment tests: a pooled chi-square goodness-of-fit test."""

from __future__ import annotations

import numpy as np
import pytest

ALPHA = 1e-3  # significance level: a correct sampler fails one fixed seed in a thousand


def pooled_chi_square(rows: np.ndarray, outcomes: np.ndarray, probs: np.ndarray) -> float:
    """p-value of "``outcomes`` of each row are draws from ``probs[row]``", all rows pooled.

    Per row with samples, Pearson's statistic over the outcomes of positive probability
    (cells whose expected count is below 5 are merged into one); the statistics and degrees
    of freedom of independent rows add up. An outcome of probability zero gives p = 0.

    Args:
        rows: ``(M,)`` row index of each sample.
        outcomes: ``(M,)`` the sampled outcome.
        probs: ``(R, K)`` the rows' probabilities.
    """
    from scipy import stats

    R, K = probs.shape
    counts = np.zeros((R, K))
    np.add.at(counts, (rows, outcomes), 1.0)
    if (counts[probs <= 0] > 0).any():
        return 0.0
    statistic, dof = 0.0, 0
    for r in np.flatnonzero(counts.sum(1) > 0):
        n = counts[r].sum()
        expected = n * probs[r]
        positive = probs[r] > 0
        e, c = expected[positive], counts[r][positive]
        small = e < 5
        if small.any():
            e = np.append(e[~small], e[small].sum())
            c = np.append(c[~small], c[small].sum())
        if e.shape[0] < 2:
            continue
        statistic += float(((c - e) ** 2 / e).sum())
        dof += e.shape[0] - 1
    return float(stats.chi2.sf(statistic, dof)) if dof else 1.0


@pytest.fixture
def chi_square():
    """:func:`pooled_chi_square`, for the tests of this folder."""
    return pooled_chi_square
