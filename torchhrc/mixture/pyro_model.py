"""A Pyro model of the mixture of Markov chains, the cluster enumerated out.

``z_n ~ Categorical(w)``; ``x_n^1 ~ Categorical(pi_{z_n})`` when first symbols are modelled;
``x_n^j ~ Categorical(theta_{z_n}(. | x_n^{j-1}))`` for ``j >= 2``. The cluster site is marked
``infer={"enumerate": "parallel"}``, so ``TraceEnum_ELBO`` with an empty guide computes the
exact marginal log-likelihood and ``infer_discrete`` draws (or maximises) the clusters.
Parameters are fixed tensors when given, else ``pyro.param`` sites (learnable by SVI).

Plates: ``sequences`` (dim -1) and ``steps`` (dim -2); ``max_plate_nesting = 2``.

Example:
    >>> import torch, pyro
    >>> from pyro.infer import TraceEnum_ELBO
    >>> from torchhrc.mixture import MarkovChainMixture
    >>> from torchhrc.mixture.pyro_model import mixture_model, empty_guide
    >>> m = MarkovChainMixture.uniform(2, 3)
    >>> elbo = TraceEnum_ELBO(max_plate_nesting=2)
    >>> s, n = torch.tensor([[0, 1, 2]]), torch.tensor([3])
    >>> round(-elbo.loss(mixture_model, empty_guide, s, n, mixture=m), 4)  # 2 log(1/3)
    -2.1972
"""

from __future__ import annotations

import torch

from torchhrc.mixture.counts import check_sequences
from torchhrc.mixture.model import MarkovChainMixture

__all__ = ["empty_guide", "mixture_model"]


def _pyro():  # lazy: pyro is a runtime dependency, but keep `import torchhrc` light
    import pyro
    import pyro.distributions as dist

    return pyro, dist


def mixture_model(
    sequences: torch.Tensor,
    lengths: torch.Tensor,
    *,
    mixture: MarkovChainMixture | None = None,
    num_clusters: int | None = None,
    num_symbols: int | None = None,
) -> None:
    """Pyro model of ``N`` sequences ``(N, L)`` (padded) with lengths ``(N,)``.

    Args:
        sequences: ``(N, L)`` int64; lengths: ``(N,)`` int64.
        mixture: fixed parameters; when ``None``, ``pyro.param`` sites ``"transition_logits"``
            ``(K, A, A)`` and ``"weight_logits"`` ``(K,)`` are used (initialised at 0 plus a
            small deterministic asymmetry), sized by ``num_clusters`` and ``num_symbols``.

    Sites: ``"cluster"`` (enumerated), ``"first"`` (if modelled), ``"step"`` (observed,
    masked beyond each length).
    """
    pyro, dist = _pyro()
    if mixture is not None:
        log_transition, log_weights = mixture.log_transition, mixture.log_weights
        log_initial = mixture.log_initial
        A = mixture.num_symbols
    else:
        if num_clusters is None or num_symbols is None:
            raise ValueError("without mixture, give num_clusters and num_symbols")
        K, A = int(num_clusters), int(num_symbols)
        init = 0.01 * torch.arange(K * A * A, dtype=torch.float64).view(K, A, A).sin()
        log_transition = pyro.param("transition_logits", init).log_softmax(-1)
        log_weights = pyro.param("weight_logits", torch.zeros(K, dtype=torch.float64))
        log_weights = log_weights.log_softmax(-1)
        log_initial = None
    sequences, lengths = check_sequences(sequences, lengths, A)
    N, L = sequences.shape
    sequences = sequences.to(log_transition.device)
    lengths = lengths.to(log_transition.device)
    prev = sequences[:, :-1].transpose(0, 1)  # (L-1, N)
    nxt = sequences[:, 1:].transpose(0, 1)  # (L-1, N)
    valid = torch.arange(L - 1, device=sequences.device).unsqueeze(-1) < (lengths - 1)  # (L-1, N)
    with pyro.plate("sequences", N, dim=-1):
        z = pyro.sample(
            "cluster",
            dist.Categorical(logits=log_weights),
            infer={"enumerate": "parallel"},
        )  # (N,) or (K, 1, 1) when enumerated
        if log_initial is not None:
            pyro.sample("first", dist.Categorical(logits=log_initial[z]), obs=sequences[:, 0])
        with pyro.plate("steps", L - 1, dim=-2):
            # z (K, 1, 1) -> logits (K, L-1, N, A); z (N,) -> (L-1, N, A)
            logits = log_transition[z.unsqueeze(-2) if z.dim() == 1 else z, prev]
            pyro.sample(
                "step",
                dist.Categorical(logits=logits).mask(valid),
                obs=nxt,
            )


def empty_guide(*args: object, **kwargs: object) -> None:
    """The guide when every latent site is enumerated: nothing to sample."""
