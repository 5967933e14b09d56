"""Clustering scores: adjusted Rand index, contingency tables, cluster-to-label matching.

Labels may be any hashable values (strings, ints) or an int tensor; they are compared by
equality only. All counts come from one ``bincount`` over the encoded label pairs.

Example:
    >>> from torchhrc.metrics import adjusted_rand_index
    >>> adjusted_rand_index(["a", "a", "b", "b"], [1, 1, 0, 0])
    1.0
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import torch

from torchhrc.errors import ModelError

__all__ = [
    "adjusted_rand_index",
    "contingency_table",
    "match_clusters",
    "matched_accuracy",
]

Labels = Sequence[Hashable] | torch.Tensor

# Above this many columns the exact subset DP gets slow; use SciPy's Hungarian solver.
_DP_MAX_COLUMNS = 12


def _encode(name: str, labels: Labels) -> tuple[torch.Tensor, tuple[Hashable, ...]]:
    """``(N,)`` int64 codes and the distinct values (in order of first appearance)."""
    if isinstance(labels, torch.Tensor):
        if labels.dim() != 1:
            raise ModelError(f"expected {name} to have shape (N,), got {tuple(labels.shape)}")
        if labels.is_floating_point() or labels.is_complex():
            raise TypeError(f"expected {name} to hold integer labels, got dtype {labels.dtype}")
        labels = labels.tolist()
    if isinstance(labels, (str, bytes)):
        raise TypeError(f"expected {name} to be a sequence of labels, got a string")
    values = tuple(dict.fromkeys(labels))
    lookup = {v: i for i, v in enumerate(values)}
    return torch.tensor([lookup[v] for v in labels], dtype=torch.int64), values


def contingency_table(
    labels_true: Labels, labels_pred: Labels
) -> tuple[torch.Tensor, tuple[Hashable, ...], tuple[Hashable, ...]]:
    """Counts of each (true label, predicted label) pair.

    Returns:
        ``(table (C, K) int64, true_values (C,), pred_values (K,))`` with
        ``table[c, k]`` = number of items with true label ``true_values[c]`` and predicted
        label ``pred_values[k]``; values in order of first appearance.

    Example:
        >>> table, t, p = contingency_table(["x", "x", "y"], [0, 1, 1])
        >>> table.tolist(), t, p
        ([[1, 1], [0, 1]], ('x', 'y'), (0, 1))
    """
    true_codes, true_values = _encode("labels_true", labels_true)
    pred_codes, pred_values = _encode("labels_pred", labels_pred)
    if true_codes.shape != pred_codes.shape:
        raise ModelError(
            f"expected labels_true and labels_pred of one length, got {true_codes.numel()} "
            f"and {pred_codes.numel()}"
        )
    c, k = len(true_values), len(pred_values)
    table = torch.bincount(true_codes * k + pred_codes, minlength=c * k).reshape(c, k)
    return table, true_values, pred_values


def adjusted_rand_index(labels_true: Labels, labels_pred: Labels) -> float:
    """Adjusted Rand index of two partitions (Hubert & Arabie 1985).

    ``ARI = (sum_ij C(n_ij, 2) - E) / ((sum_i C(a_i, 2) + sum_j C(b_j, 2)) / 2 - E)`` with
    ``E = sum_i C(a_i, 2) * sum_j C(b_j, 2) / C(n, 2)``, ``n_ij`` the contingency table,
    ``a``, ``b`` its row and column sums. 1 for identical partitions (up to renaming),
    about 0 for independent ones; 1 when both partitions are trivial in the same way (the
    denominator vanishes), as in scikit-learn.

    Example:
        >>> round(adjusted_rand_index([0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 2, 2]), 6)
        0.242424
    """
    table, _, _ = contingency_table(labels_true, labels_pred)
    t = table.to(torch.float64)
    n = t.sum()

    def pairs(x: torch.Tensor) -> torch.Tensor:
        return (x * (x - 1) / 2).sum()

    index = pairs(t)
    rows, cols = pairs(t.sum(1)), pairs(t.sum(0))
    total = n * (n - 1) / 2
    expected = rows * cols / total if total > 0 else torch.zeros((), dtype=torch.float64)
    maximum = (rows + cols) / 2
    if float(maximum - expected) == 0.0:
        return 1.0
    return float((index - expected) / (maximum - expected))


def _best_assignment(weights: torch.Tensor) -> list[tuple[int, int]]:
    """Row-column pairs maximising the total weight, each row and column used at most once.

    Exact: a DP over subsets of columns (``R * 2^C * C``) for ``C <= 12`` columns, SciPy's
    ``linear_sum_assignment`` above that.
    """
    w = weights.to(torch.float64)
    transpose = w.shape[0] > w.shape[1]
    if transpose:
        w = w.T
    n_rows, n_cols = w.shape
    if n_rows == 0:
        return []
    if n_cols > _DP_MAX_COLUMNS:
        try:
            from scipy.optimize import linear_sum_assignment
        except ImportError as error:  # pragma: no cover - scipy ships with the [full] extra
            raise ImportError(
                "matching more than 12 clusters needs SciPy: pip install torchhrc[full]"
            ) from error
        r, c = linear_sum_assignment(w.numpy(), maximize=True)
        pairs = list(zip(r.tolist(), c.tolist()))
    else:
        values = w.tolist()
        # best[mask] = (score, assignment) for the first popcount(mask) rows using `mask`.
        best: dict[int, tuple[float, tuple[int, ...]]] = {0: (0.0, ())}
        for i in range(n_rows):
            nxt: dict[int, tuple[float, tuple[int, ...]]] = {}
            for mask, (score, cols) in best.items():
                for j in range(n_cols):
                    if mask >> j & 1:
                        continue
                    cand = (score + values[i][j], (*cols, j))
                    key = mask | 1 << j
                    if key not in nxt or cand[0] > nxt[key][0]:
                        nxt[key] = cand
            best = nxt
        _, cols = max(best.values(), key=lambda item: item[0])
        pairs = list(enumerate(cols))
    return [(c, r) for r, c in pairs] if transpose else pairs


def match_clusters(labels_true: Labels, clusters: Labels) -> dict[Hashable, Hashable]:
    """The one-to-one map cluster -> label that agrees with ``labels_true`` most often.

    The best assignment of the contingency table (Hungarian problem, solved exactly).
    Clusters left without a label (more clusters than labels) are absent from the map.

    Example:
        >>> match_clusters(["safe", "safe", "efficient"], [1, 1, 0])
        {1: 'safe', 0: 'efficient'}
    """
    table, true_values, pred_values = contingency_table(labels_true, clusters)
    pairs = _best_assignment(table.T)  # rows: clusters, columns: labels
    return {pred_values[k]: true_values[c] for k, c in sorted(pairs)}


def matched_accuracy(labels_true: Labels, clusters: Labels) -> float:
    """Fraction of items whose cluster maps to their label under :func:`match_clusters`.

    Example:
        >>> matched_accuracy(["a", "a", "b", "b"], [0, 0, 0, 1])
        0.75
    """
    mapping = match_clusters(labels_true, clusters)
    true_codes, true_values = _encode("labels_true", labels_true)
    pred = clusters.tolist() if isinstance(clusters, torch.Tensor) else list(clusters)
    if not pred:
        return float("nan")
    hits = sum(
        mapping.get(p, _MISSING) == true_values[t] for p, t in zip(pred, true_codes.tolist())
    )
    return hits / len(pred)


_MISSING = object()
