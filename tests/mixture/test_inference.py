import math

import pytest
import torch

from torchhrc.mixture import MarkovChainMixture, infer_type


def _model():
    T = torch.tensor([[[0.9, 0.1], [0.9, 0.1]], [[0.2, 0.8], [0.2, 0.8]]], dtype=torch.float64)
    return MarkovChainMixture(T.log(), torch.tensor([0.25, 0.75], dtype=torch.float64).log())


def test_posterior_hand_worked():
    seqs = torch.tensor([[0, 0, 0], [0, 1, 0]])
    lengths = torch.tensor([3, 3])
    # cluster 0: .9*.9 * .1*.9 ; cluster 1: .2*.2 * .8*.2 ; prior .25/.75
    p0 = 0.25 * (0.9 * 0.9) * (0.1 * 0.9)
    p1 = 0.75 * (0.2 * 0.2) * (0.8 * 0.2)
    post = infer_type(_model(), seqs, lengths)
    torch.testing.assert_close(post, torch.tensor([p0, p1], dtype=torch.float64) / (p0 + p1))
    uniform = infer_type(_model(), seqs, lengths, log_prior=torch.zeros(2, dtype=torch.float64))
    q0, q1 = p0 / 0.25, p1 / 0.75
    torch.testing.assert_close(uniform, torch.tensor([q0, q1], dtype=torch.float64) / (q0 + q1))


def test_vote_hand_worked():
    seqs = torch.tensor([[0, 0, 0], [1, 1, 1], [1, 1, 0]])
    lengths = torch.tensor([3, 3, 3])
    lik = torch.tensor(
        [[0.81, 0.04], [0.01, 0.64], [0.09, 0.16]], dtype=torch.float64
    )  # P(x_i | k) by hand
    norm = lik / lik.sum(-1, keepdim=True)
    w0 = norm[0, 0]  # sequence 0 votes for 0
    w1 = norm[1, 1] + norm[2, 1]  # sequences 1, 2 vote for 1
    vote = infer_type(_model(), seqs, lengths, method="vote")
    torch.testing.assert_close(vote, torch.stack([w0, w1]) / (w0 + w1))


@pytest.mark.parametrize("method", ["posterior", "vote"])
def test_sequences_impossible_under_every_type_give_no_nan(method):
    T = torch.tensor([[[1.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [0.0, 1.0]]], dtype=torch.float64)
    m = MarkovChainMixture(T.log(), torch.tensor([0.5, 0.5], dtype=torch.float64).log())
    seqs = torch.tensor([[0, 1, 1], [0, 1, 1]])  # 0 -> 1 is impossible for both types
    probs = infer_type(m, seqs, torch.tensor([3, 3]), method=method)
    assert torch.isfinite(probs).all()
    assert abs(probs.sum().item() - 1) < 1e-12
    # the first sequence's "1 -> 1" is possible only under type 1
    assert probs[1] > probs[0]


def test_batched_model():
    m = _model()
    batched = MarkovChainMixture(m.log_transition.expand(3, 2, 2, 2), m.log_weights)
    seqs, lengths = torch.tensor([[0, 1, 1]]), torch.tensor([3])
    out = infer_type(batched, seqs, lengths)
    assert out.shape == (3, 2)
    torch.testing.assert_close(out[1], infer_type(m, seqs, lengths))
    with pytest.raises(ValueError, match="method"):
        infer_type(m, seqs, lengths, method="majority")
    assert not math.isnan(out.sum().item())
