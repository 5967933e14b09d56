import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.mixture.counts import cluster_counts, sufficient_statistics, transition_counts


def _random_sequences(N=40, L=9, A=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    seqs = torch.randint(0, A, (N, L), generator=g)
    lengths = torch.randint(1, L + 1, (N,), generator=g)
    # duplicates, so that deduplication has something to merge
    seqs[N // 2 :] = seqs[: N - N // 2]
    lengths[N // 2 :] = lengths[: N - N // 2]
    return seqs, lengths, A


def _loop_counts(seqs, lengths, A):
    out = torch.zeros(len(seqs), A, A, dtype=torch.long)
    for n, (s, m) in enumerate(zip(seqs.tolist(), lengths.tolist())):
        for j in range(1, m):
            out[n, s[j - 1], s[j]] += 1
    return out


def test_transition_counts_equal_per_sequence_loop():
    seqs, lengths, A = _random_sequences()
    assert torch.equal(transition_counts(seqs, lengths, A), _loop_counts(seqs, lengths, A))


def test_transition_counts_hand_example():
    c = transition_counts(torch.tensor([[2, 0, 2, 0, 1]]), torch.tensor([4]), 3)[0]
    assert c.tolist() == [[0, 0, 1], [0, 0, 0], [2, 0, 0]]


@pytest.mark.parametrize("initial", [False, True])
def test_sufficient_statistics_reconstruct_counts(initial):
    seqs, lengths, A = _random_sequences(seed=1)
    s = sufficient_statistics(seqs, lengths, A, initial=initial)
    assert s.num_distinct < len(seqs)
    assert s.multiplicity.sum().item() == len(seqs)
    ref = _loop_counts(seqs, lengths, A).view(len(seqs), -1).double()
    assert torch.equal(s.counts[s.inverse], ref)
    if initial:
        assert torch.equal(s.first_counts[s.inverse].argmax(-1), seqs[:, 0])
    # multiplicity = number of sequences mapped to the row
    assert torch.equal(torch.bincount(s.inverse, minlength=s.num_distinct).double(), s.multiplicity)


def test_sufficient_statistics_groups_sum_counts():
    seqs, lengths, A = _random_sequences(seed=2)
    groups = torch.arange(len(seqs)) // 4
    s = sufficient_statistics(seqs, lengths, A, groups=groups, initial=True)
    assert s.num_units == 10
    ref = _loop_counts(seqs, lengths, A).view(len(seqs), -1).double()
    for g in range(10):
        members = (groups == g).nonzero().squeeze(-1)
        assert (s.inverse[members] == s.inverse[members[0]]).all()
        assert torch.equal(s.counts[s.inverse[members[0]]], ref[members].sum(0))
        assert s.first_counts[s.inverse[members[0]]].sum().item() == len(members)


def test_cluster_counts_equal_loop():
    g = torch.Generator().manual_seed(3)
    r = torch.rand(5, 2, 3, generator=g, dtype=torch.float64)
    c = torch.rand(5, 4, generator=g, dtype=torch.float64)
    m = torch.rand(5, generator=g, dtype=torch.float64)
    out = cluster_counts(r, c, m)
    for run in range(2):
        for k in range(3):
            ref = sum(m[u] * r[u, run, k] * c[u] for u in range(5))
            torch.testing.assert_close(out[run, k], ref)


def test_bad_sequences_are_reported():
    with pytest.raises(ModelError, match=r"sequences\[0, 1\] = 7"):
        transition_counts(torch.tensor([[0, 7]]), torch.tensor([2]), 3)
    with pytest.raises(ModelError, match="lengths"):
        transition_counts(torch.tensor([[0, 1]]), torch.tensor([3]), 3)
    with pytest.raises(TypeError, match="integer"):
        transition_counts(torch.tensor([[0.0, 1.0]]), torch.tensor([2]), 3)
    with pytest.raises(ModelError, match=r"shape \(N=1,\)"):
        transition_counts(torch.tensor([[0, 1]]), torch.tensor([2, 2]), 3)


@pytest.mark.parametrize("seed", range(6))
def test_unique_rows_equals_torch_unique(seed):
    # the sort-based deduplication gives torch.unique's rows, order, inverse and counts
    from torchhrc.mixture.counts import _unique_rows

    g = torch.Generator().manual_seed(seed)
    high = [1, 2, 16, 300, 2**20, 2**40][seed]
    key = torch.randint(0, high, (50, 3 + 7 * seed), generator=g)
    key = torch.cat([key, key[:20], key[5:9]])[torch.randperm(74, generator=g)]
    expected = torch.unique(key, dim=0, return_inverse=True, return_counts=True)
    for got, want in zip(_unique_rows(key), expected):
        assert torch.equal(got, want)
