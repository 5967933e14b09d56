"""Split and merge restarts (:func:`torchhrc.mixture.runs._split_merge_restarts`), and the
split restarts of a k whose fit is below k - 1's (``_split_where_worse``)."""

import dataclasses

import torch

from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture.counts import sufficient_statistics
from torchhrc.mixture.runs import (
    _soft_initial_parameters,
    _split_merge_restarts,
    _split_where_worse,
)
from torchhrc.mixture.soft_em import soft_em

# three types of cycles over 4 symbols; 12 sequences each, with 5 % random symbols
CYCLES = ((0, 1, 2, 3), (0, 2, 1, 3), (0, 3, 2, 1))
K = 4


def _data():
    g = torch.Generator().manual_seed(0)
    seqs, types = [], []
    for y, cycle in enumerate(CYCLES):
        for _ in range(12):
            start = int(torch.randint(4, (), generator=g))
            seq = [cycle[(start + t) % 4] for t in range(16)]
            slip = torch.rand(16, generator=g) < 0.05
            noise = torch.randint(4, (16,), generator=g)
            seqs.append([int(n) if s else a for a, s, n in zip(seq, slip, noise)])
            types.append(y)
    stats = sufficient_statistics(torch.tensor(seqs), torch.full((36,), 16), 4)
    row_type = torch.zeros(stats.num_distinct, dtype=torch.long)
    row_type[stats.inverse] = torch.tensor(types)
    return stats, torch.tensor(types), row_type


def _fits(stats, partitions):
    """Soft EM to convergence from hard partitions (one run each, slots 0..k-1 of K)."""
    z = torch.stack(partitions, -1)  # (U, R)
    mask = torch.arange(K) < (z.max(0).values + 1)[:, None]  # (R, K)
    lt, lw, li = _soft_initial_parameters(stats, z, mask, 0.1, 1.0, torch.float64)
    return soft_em(stats, lt, lw, mask, log_initial=li, max_iterations=200), mask


def _em(dtype=torch.float64):
    return dict(pseudo_count=0.1, weight_pseudo_count=1.0, dtype=dtype,
                options=dict(max_iterations=200, pseudo_count=0.1, weight_pseudo_count=1.0,
                             tol=1e-6))  # fmt: skip


def _ari(stats, types, result, run):
    return adjusted_rand_index(types.tolist(), result.assignments[:, run][stats.inverse].tolist())


def test_a_k_fit_that_merged_two_types_is_restarted_from_the_split_of_k_minus_1():
    stats, types, row_type = _data()
    # k = 2: types 0 + 1 | 2 (a right coarsening); k = 3: a local optimum that merges
    # types 1 + 2 and cuts type 0 by the parity of its first symbol
    k2 = torch.where(row_type == 2, 1, 0)
    first = stats.counts.view(-1, 4, 4).sum(-1).argmax(-1)  # some per-row feature
    k3 = torch.where(row_type == 0, (first % 2) * 2, 1)
    result, mask = _fits(stats, [k2, k3])
    assert _ari(stats, types, result, 1) < 0.8  # EM stays in the bad partition
    out = _split_merge_restarts(stats, result, mask, _em())
    assert _ari(stats, types, out, 1) == 1.0
    assert float(out.log_likelihood[1]) > float(result.log_likelihood[1]) + 10.0
    # the fit of k = 2 cannot get worse (the merge pass may better it from the new k = 3)
    assert float(out.log_likelihood[0]) >= float(result.log_likelihood[0]) - 1e-9


def test_a_k_fit_is_restarted_from_the_merge_of_two_clusters_of_k_plus_1():
    stats, types, row_type = _data()
    # k = 3 as above (bad), k = 4: the true types with type 2 cut in two
    first = stats.counts.view(-1, 4, 4).sum(-1).argmax(-1)
    k3 = torch.where(row_type == 0, (first % 2) * 2, 1)
    k4 = torch.where((row_type == 2) & (first % 2 == 1), 3, row_type)
    result, mask = _fits(stats, [k3, k4])
    assert _ari(stats, types, result, 0) < 0.8
    out = _split_merge_restarts(stats, result, mask, _em())
    assert _ari(stats, types, out, 0) == 1.0
    assert float(out.log_likelihood[0]) > float(result.log_likelihood[0]) + 10.0
    assert float(out.log_likelihood[1]) >= float(result.log_likelihood[1]) - 1e-9


def test_a_k_fit_below_the_fit_of_k_minus_1_is_restarted_from_its_split():
    """A mixture of k chains holds every mixture of k - 1, so a k fit below the k - 1 fit is a
    failed search: it is restarted from the k - 1 fit with a cluster split, and reaches the
    true types; a k - 1 fit, or a k fit that is not below, is left as it was. (The k = 3 fit
    here is the bad local optimum above, its log-likelihood recorded below the k = 2 fit's.)"""
    stats, types, row_type = _data()
    k2 = torch.where(row_type == 2, 1, 0)  # types 0 + 1 | 2
    first = stats.counts.view(-1, 4, 4).sum(-1).argmax(-1)
    k3 = torch.where(row_type == 0, (first % 2) * 2, 1)
    fitted, mask = _fits(stats, [k2, k3])
    assert _split_where_worse(stats, fitted, mask, _em()) is fitted  # k = 3 above k = 2
    below = fitted.log_likelihood.clone()
    below[1] = below[0] - 1.0
    result = dataclasses.replace(fitted, log_likelihood=below)
    out = _split_where_worse(stats, result, mask, _em())
    assert _ari(stats, types, out, 1) == 1.0
    assert float(out.log_likelihood[1]) > float(fitted.log_likelihood[1]) + 10.0
    assert torch.equal(out.log_transition[0], fitted.log_transition[0])
    assert float(out.log_likelihood[0]) == float(fitted.log_likelihood[0])
