import math

import pytest
import torch

from torchhrc.mixture import (
    MarkovChainMixture,
    count_log_likelihood,
    mixture_log_likelihood,
    sequence_log_likelihood,
    transition_counts,
)


def test_hand_worked_example():
    # cluster 0: 0->0 .9, 0->1 .1, 1->0 .4, 1->1 .6 ; cluster 1: uniform
    T = torch.tensor([[[0.9, 0.1], [0.4, 0.6]], [[0.5, 0.5], [0.5, 0.5]]], dtype=torch.float64)
    I0 = torch.tensor([[0.8, 0.2], [0.5, 0.5]], dtype=torch.float64)
    m = MarkovChainMixture(T.log(), torch.tensor([0.3, 0.7], dtype=torch.float64).log())
    seqs = torch.tensor([[0, 0, 1, 1, 9], [1, 0, 0, 0, 0]])  # second has length 2; 9 is padding
    ll = sequence_log_likelihood(m, seqs, torch.tensor([4, 2]))
    expected = [
        [math.log(0.9 * 0.1 * 0.6), math.log(0.5**3)],
        [math.log(0.4), math.log(0.5)],
    ]
    torch.testing.assert_close(ll, torch.tensor(expected, dtype=torch.float64))
    mi = MarkovChainMixture(T.log(), m.log_weights, I0.log())
    ll_i = sequence_log_likelihood(mi, seqs, torch.tensor([4, 2]))
    torch.testing.assert_close(
        ll_i[0, 0], torch.tensor(math.log(0.8 * 0.9 * 0.1 * 0.6), dtype=torch.float64)
    )
    total = mixture_log_likelihood(T.log(), m.log_weights, seqs, torch.tensor([4, 2]))
    ref = math.log(0.3 * 0.9 * 0.1 * 0.6 + 0.7 * 0.5**3) + math.log(0.3 * 0.4 + 0.7 * 0.5)
    assert abs(total.item() - ref) < 1e-12


def test_impossible_transition_gives_minus_inf_not_nan():
    T = torch.tensor([[[1.0, 0.0], [0.5, 0.5]]], dtype=torch.float64).log()
    m = MarkovChainMixture(T, torch.zeros(1, dtype=torch.float64))
    ll = sequence_log_likelihood(m, torch.tensor([[0, 1, 1], [0, 0, 0]]), torch.tensor([3, 3]))
    assert ll[0, 0] == -math.inf and ll[1, 0] == 0.0
    floored = sequence_log_likelihood(m, torch.tensor([[0, 1, 1]]), torch.tensor([3]), floor=1e-10)
    torch.testing.assert_close(
        floored[0, 0], torch.tensor(math.log(1e-10) + math.log(0.5), dtype=torch.float64)
    )


@pytest.mark.parametrize("batch_shape", [(), (2,), (2, 3)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_batched_models_equal_per_item_loop(batch_shape, dtype):
    g = torch.Generator().manual_seed(1)
    K, A = 3, 4
    T = torch.rand(*batch_shape, K, A, A, generator=g, dtype=dtype).log_softmax(-1)
    W = torch.rand(*batch_shape, K, generator=g, dtype=dtype).log_softmax(-1)
    seqs = torch.randint(0, A, (6, 5), generator=g)
    lengths = torch.randint(1, 6, (6,), generator=g)
    out = sequence_log_likelihood(MarkovChainMixture(T, W), seqs, lengths)
    assert out.shape == (*batch_shape, 6, K) and out.dtype == dtype
    flatT, flatW = T.reshape(-1, K, A, A), W.reshape(-1, K)
    for i in range(flatT.shape[0]):
        one = sequence_log_likelihood(MarkovChainMixture(flatT[i], flatW[i]), seqs, lengths)
        torch.testing.assert_close(out.reshape(-1, 6, K)[i], one)
        # the count-based product used by EM agrees with the gather
        C = transition_counts(seqs, lengths, A).view(6, -1).to(dtype)
        torch.testing.assert_close(count_log_likelihood(C, flatT[i][None])[:, 0], one)


def test_gradcheck_marginal_log_likelihood():
    g = torch.Generator().manual_seed(2)
    K, A = 2, 3
    T = torch.randn(K, A, A, generator=g, dtype=torch.float64, requires_grad=True)
    W = torch.randn(K, generator=g, dtype=torch.float64, requires_grad=True)
    I0 = torch.randn(K, A, generator=g, dtype=torch.float64, requires_grad=True)
    seqs = torch.randint(0, A, (5, 6), generator=g)
    lengths = torch.tensor([6, 2, 4, 1, 5])

    def f(t, w, i):
        return mixture_log_likelihood(t, w, seqs, lengths, initial_logits=i)

    assert torch.autograd.gradcheck(f, (T, W, I0))
    assert torch.autograd.gradgradcheck(f, (T, W, I0))
