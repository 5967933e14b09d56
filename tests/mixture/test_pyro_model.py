import pyro
import pytest
import torch
from pyro.infer import TraceEnum_ELBO, infer_discrete

from torchhrc.mixture import MarkovChainMixture, mixture_log_likelihood, sequence_log_likelihood
from torchhrc.mixture.pyro_model import empty_guide, mixture_model


def _random(initial, seed=0):
    g = torch.Generator().manual_seed(seed)
    K, A, N, L = 3, 4, 7, 6
    T = torch.rand(K, A, A, generator=g, dtype=torch.float64)
    T[1, 2, 3] = 0.0  # an impossible transition, which the data never uses below
    T = (T / T.sum(-1, keepdim=True)).log()
    W = torch.rand(K, generator=g, dtype=torch.float64).log_softmax(-1)
    I0 = torch.rand(K, A, generator=g, dtype=torch.float64).log_softmax(-1) if initial else None
    seqs = torch.randint(0, A, (N, L), generator=g)
    seqs[seqs == 2] = 1
    lengths = torch.randint(1, L + 1, (N,), generator=g)
    return MarkovChainMixture(T, W, I0), seqs, lengths


@pytest.mark.parametrize("initial", [False, True])
def test_enumerated_log_likelihood_equals_tensor_implementation(initial):
    m, seqs, lengths = _random(initial)
    elbo = TraceEnum_ELBO(max_plate_nesting=2)
    pyro_ll = -elbo.loss(mixture_model, empty_guide, seqs, lengths, mixture=m)
    ll = torch.logsumexp(sequence_log_likelihood(m, seqs, lengths) + m.log_weights, -1).sum()
    assert abs(pyro_ll - ll.item()) < 1e-9


def test_infer_discrete_map_equals_argmax_posterior():
    m, seqs, lengths = _random(True, seed=1)
    decoded = infer_discrete(mixture_model, first_available_dim=-3, temperature=0)
    trace = pyro.poutine.trace(decoded).get_trace(seqs, lengths, mixture=m)
    expected = (sequence_log_likelihood(m, seqs, lengths) + m.log_weights).argmax(-1)
    assert torch.equal(trace.nodes["cluster"]["value"], expected)


def test_param_sites_match_logit_likelihood():
    pyro.clear_param_store()
    _, seqs, lengths = _random(False)
    loss = TraceEnum_ELBO(max_plate_nesting=2).loss(
        mixture_model, empty_guide, seqs, lengths, num_clusters=2, num_symbols=4
    )
    store = pyro.get_param_store()
    ll = mixture_log_likelihood(store["transition_logits"], store["weight_logits"], seqs, lengths)
    assert abs(-loss - ll.item()) < 1e-9
    pyro.clear_param_store()
