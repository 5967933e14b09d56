import math

import numpy as np
import torch

from torchhrc.mixture import hard_em, random_init, sufficient_statistics


def _data(seed=0, N=60, L=8, A=4):
    """Two well separated chains (0 -> 1 -> 2 ... vs. self loops) with noise."""
    g = torch.Generator().manual_seed(seed)
    seqs = torch.empty(N, L, dtype=torch.long)
    seqs[:, 0] = torch.randint(0, A, (N,), generator=g)
    for j in range(1, L):
        cyc = (seqs[:, j - 1] + 1) % A
        nxt = torch.where(torch.arange(N) % 2 == 0, cyc, seqs[:, j - 1])
        noise = torch.rand(N, generator=g) < 0.1
        seqs[:, j] = torch.where(noise, torch.randint(0, A, (N,), generator=g), nxt)
    lengths = torch.randint(3, L + 1, (N,), generator=g)
    return seqs, lengths, A


def _reference(counts, mult, lt0, k, floor, max_iterations=100):
    """The paper's Cluster-Transition-Matrices, one run, plain numpy loops over sequences."""
    theta = np.exp(lt0[:k].numpy())
    A = theta.shape[-1]
    U = counts.shape[0]
    C = counts.numpy().reshape(U, A, A)
    z = np.full(U, -1)
    for _ in range(max_iterations):
        new = np.empty(U, dtype=np.int64)
        for u in range(U):
            scores = [(C[u] * np.log(np.maximum(theta[c], floor))).sum() for c in range(k)]
            new[u] = int(np.argmax(scores))
        n = np.zeros((k, A, A))
        for u in range(U):
            n[new[u]] += mult[u].item() * C[u]
        rows = n.sum(-1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.where(rows > 0, n / np.where(rows > 0, rows, 1), theta)
        stable = (new == z).all()
        z = new
        if stable:
            break
    return z, theta


def test_batched_runs_equal_per_run_reference():
    seqs, lengths, A = _data()
    stats = sufficient_statistics(seqs, lengths, A)
    ks = torch.tensor([1, 2, 2, 3, 3, 4])
    mask = torch.arange(4) < ks[:, None]
    g = torch.Generator().manual_seed(5)
    lt0, z0 = random_init(stats, mask, generator=g)
    res = hard_em(stats, lt0, mask, assignments=z0, floor=1e-10)
    assert res.converged.all()
    for r, k in enumerate(ks.tolist()):
        z_ref, theta_ref = _reference(stats.counts, stats.multiplicity, lt0[r], k, 1e-10)
        assert res.assignments[:, r].tolist() == z_ref.tolist()
        np.testing.assert_allclose(res.log_transition[r, :k].exp().numpy(), theta_ref, atol=1e-12)
        # alone == in the batch
        alone = hard_em(stats, lt0[r : r + 1], mask[r : r + 1], assignments=z0[:, r : r + 1])
        assert torch.equal(alone.assignments[:, 0], res.assignments[:, r])
        torch.testing.assert_close(alone.log_likelihood[0], res.log_likelihood[r])
        assert alone.iterations[0] == res.iterations[r]


def test_log_likelihood_is_the_classification_likelihood_and_finite():
    seqs, lengths, A = _data(seed=1)
    stats = sufficient_statistics(seqs, lengths, A)
    mask = torch.ones(3, 2, dtype=torch.bool)
    lt0, z0 = random_init(stats, mask, generator=torch.Generator().manual_seed(0))
    res = hard_em(stats, lt0, mask, assignments=z0)
    assert torch.isfinite(res.log_likelihood).all()
    for r in range(3):
        z = res.assignments[:, r]
        sizes = torch.bincount(z, weights=stats.multiplicity, minlength=2)
        ll = 0.0
        for u in range(stats.num_distinct):
            logp = res.log_transition[r, z[u]].reshape(-1)
            used = stats.counts[u] > 0
            ll += stats.multiplicity[u] * (
                (stats.counts[u][used] * logp[used]).sum() + math.log(sizes[z[u]] / sizes.sum())
            )
        assert abs(ll.item() - res.log_likelihood[r].item()) < 1e-9


def test_unseen_transitions_never_give_nan():
    # every sequence uses a transition that the initial matrices give probability 0
    seqs = torch.tensor([[0, 1, 2, 3], [3, 2, 1, 0], [0, 0, 1, 1], [2, 3, 2, 3]])
    stats = sufficient_statistics(seqs, torch.tensor([4, 4, 4, 4]), 4)
    lt0 = torch.full((1, 2, 4, 4), -math.inf, dtype=torch.float64)
    lt0[..., 0] = 0.0  # only "-> 0" is possible
    res = hard_em(stats, lt0, torch.ones(1, 2, dtype=torch.bool))
    assert not torch.isnan(res.log_transition).any()
    assert not torch.isnan(res.log_likelihood).any()
    assert torch.isfinite(res.log_likelihood).all()
