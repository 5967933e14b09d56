import itertools

import torch
from test_hard_em import _data

from torchhrc.mixture import kmeans_pp_init, sufficient_statistics
from torchhrc.mixture.runs import _soft_initial_parameters
from torchhrc.mixture.soft_em import soft_em


def _start(seed=0, restarts=4, K=3):
    seqs, lengths, A = _data(seed)
    stats = sufficient_statistics(seqs, lengths, A, initial=True)
    ks = torch.tensor([1, 2, 3, 3])[:restarts]
    mask = torch.arange(K) < ks[:, None]
    z0 = kmeans_pp_init(stats, mask, generator=torch.Generator().manual_seed(seed))
    lt, lw, li = _soft_initial_parameters(stats, z0, mask, 0.1, 1.0, torch.float64)
    return stats, mask, lt, lw, li


def _map_objective(stats, res, alpha, beta):
    """log-likelihood + log Dirichlet prior (up to constants): what MAP-EM never decreases."""
    lt, lw, li = res.log_transition, res.log_weights, res.log_initial
    prior = alpha * lt.sum((-1, -2)) + alpha * li.sum(-1)
    prior = torch.where(torch.isfinite(lw), prior + beta * lw, torch.zeros_like(prior))
    return res.log_likelihood + prior.sum(-1)


def test_batched_runs_equal_lone_runs():
    stats, mask, lt, lw, li = _start()
    res = soft_em(stats, lt, lw, mask, log_initial=li, tol=1e-8)
    for r in range(mask.shape[0]):
        one = soft_em(
            stats,
            lt[r : r + 1],
            lw[r : r + 1],
            mask[r : r + 1],
            log_initial=li[r : r + 1],
            tol=1e-8,
        )
        assert one.iterations[0] == res.iterations[r]
        torch.testing.assert_close(one.log_transition[0], res.log_transition[r])
        torch.testing.assert_close(one.log_likelihood[0], res.log_likelihood[r])
        assert torch.equal(one.assignments[:, 0], res.assignments[:, r])


def test_map_objective_never_decreases():
    stats, mask, lt, lw, li = _start(seed=1)
    previous = None
    for t in range(1, 8):
        res = soft_em(stats, lt, lw, mask, log_initial=li, max_iterations=t, tol=0.0)
        obj = _map_objective(stats, res, 0.1, 1.0)
        if previous is not None:
            assert (obj >= previous - 1e-9).all()
        previous = obj
    assert torch.isfinite(res.log_transition).all()  # smoothing: no zero probability
    # masked slots carry no weight
    assert torch.isneginf(res.log_weights[~mask]).all()


def test_details_flag_changes_only_what_is_reported():
    stats, mask, lt, lw, li = _start(seed=2)
    full = soft_em(stats, lt, lw, mask, log_initial=li, tol=1e-8)
    lean = soft_em(stats, lt, lw, mask, log_initial=li, tol=1e-8, details=False)
    assert torch.equal(full.iterations, lean.iterations)
    torch.testing.assert_close(full.log_likelihood, lean.log_likelihood)
    torch.testing.assert_close(full.log_transition, lean.log_transition)
    assert lean.assignments.shape == (0, mask.shape[0])
    assert (full.entropy >= 0).all() and (lean.entropy == 0).all()


def test_chunked_e_step_sums_to_the_one_pass_statistics():
    """A sharded E-step (soft_pass per chunk of rows, then sum_statistics) equals one pass."""
    from torchhrc.mixture.soft_em import soft_pass, sum_statistics

    stats, mask, lt, lw, li = _start(seed=3)
    whole = soft_pass(stats, lt, lw, li, mask)
    cuts = [0, 5, 17, stats.num_distinct]
    chunks = [slice(a, b) for a, b in itertools.pairwise(cuts)]
    parts = [soft_pass(stats.rows(c), lt, lw, li, mask) for c in chunks]
    total = sum_statistics(parts)
    for name in ("counts", "initial_counts", "sizes", "log_likelihood", "entropy"):
        torch.testing.assert_close(getattr(total, name), getattr(whole, name))
    assert torch.equal(total.assignments, whole.assignments)
    assert stats.rows(slice(0, 5)).num_units == int(stats.multiplicity[:5].sum())
