"""Sequence log-likelihoods under a mixture of Markov chains, in log space, batched.

The paper's Eq. 1-2: ``log P(x_i | z = k) = sum_{j>=2} log theta_k(x_i^j | x_i^{j-1})`` (plus
``log P(x_i^1 | k)`` when first symbols are modelled), and the marginal log-likelihood
``l(D) = sum_i logsumexp_k (log P(z = k) + log P(x_i | z = k))``.

Padded steps are removed with ``torch.where`` (never by multiplying with 0), so a ``-inf``
log-probability (a transition with probability 0) yields ``-inf``, never ``nan``.

Example:
    >>> import torch
    >>> from torchhrc.mixture import MarkovChainMixture, sequence_log_likelihood
    >>> m = MarkovChainMixture.uniform(2, 3)
    >>> sequence_log_likelihood(m, torch.tensor([[0, 1, 2]]), torch.tensor([3])).exp()
    tensor([[0.1111, 0.1111]], dtype=torch.float64)
"""

from __future__ import annotations

import math

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.mixture.counts import check_sequences
from torchhrc.mixture.model import MarkovChainMixture

__all__ = [
    "count_log_likelihood",
    "mixture_log_likelihood",
    "sequence_log_likelihood",
]


def _gather_log_likelihood(
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    sequences: torch.Tensor,
    lengths: torch.Tensor,
) -> torch.Tensor:
    """``(..., K, A, A)`` x ``(N, L)`` -> ``(..., N, K)`` by gather (differentiable)."""
    L = sequences.shape[-1]
    prev, nxt = sequences[:, :-1], sequences[:, 1:]  # (N, L-1)
    valid = torch.arange(L - 1, device=sequences.device) < (lengths - 1).unsqueeze(-1)
    steps = log_transition[..., prev, nxt]  # (..., K, N, L-1)
    steps = torch.where(valid, steps, steps.new_zeros(()))
    out = steps.sum(-1)  # (..., K, N)
    if log_initial is not None:
        out = out + log_initial[..., sequences[:, 0]]  # (..., K, N)
    return out.transpose(-1, -2)


def sequence_log_likelihood(
    model: MarkovChainMixture,
    sequences: torch.Tensor,
    lengths: torch.Tensor,
    *,
    floor: float | None = None,
) -> torch.Tensor:
    """Log-likelihood of every sequence under every cluster, one tensor op.

    ``out[..., n, k] = log P(x_n | z = k) = [log P(x_n^1 | k)] + sum_{j=2}^{len_n}
    log theta_k(x_n^j | x_n^{j-1})`` (paper Eq. 1, without the mixture weight).

    Args:
        model: the mixture, ``log_transition (..., K, A, A)``.
        sequences: ``(N, L)`` int64 symbols, padded beyond ``lengths``.
        lengths: ``(N,)`` int64 true lengths (>= 1).
        floor: if given, a probability below ``floor`` counts as ``floor`` (so transitions
            the model has never seen give a large finite penalty instead of ``-inf``).

    Returns:
        ``(..., N, K)`` log-likelihoods (``-inf`` where a sequence is impossible, never nan).

    Raises:
        ModelError: a symbol is outside ``[0, A)`` or shapes are wrong.

    Example:
        >>> import torch
        >>> T = torch.tensor([[[0.5, 0.5], [0.0, 1.0]]], dtype=torch.float64).log()
        >>> m = MarkovChainMixture(T, torch.zeros(1, dtype=torch.float64))
        >>> sequence_log_likelihood(m, torch.tensor([[0, 1, 0]]), torch.tensor([3])).tolist()
        [[-inf]]
    """
    if not isinstance(model, MarkovChainMixture):
        raise TypeError(f"expected model to be a MarkovChainMixture, got {type(model).__name__}")
    sequences, lengths = check_sequences(sequences, lengths, model.num_symbols)
    log_transition, log_initial = model.log_transition, model.log_initial
    if floor is not None:
        if not 0.0 < floor < 1.0:
            raise ValueError(f"expected floor in (0, 1), got {floor}")
        log_transition = log_transition.clamp_min(math.log(floor))
        if log_initial is not None:
            log_initial = log_initial.clamp_min(math.log(floor))
    sequences = sequences.to(log_transition.device)
    lengths = lengths.to(log_transition.device)
    return _gather_log_likelihood(log_transition, log_initial, sequences, lengths)


def count_log_likelihood(counts: torch.Tensor, log_transition: torch.Tensor) -> torch.Tensor:
    """Log-likelihoods from transition counts for many runs at once: one matrix product.

    ``out[u, r, k] = sum_{a, b} counts[u, a * A + b] * log_transition[r, k, a, b]``.

    Args:
        counts: ``(U, A * A)`` transition counts.
        log_transition: ``(R, K, A, A)``, all entries finite (``0 * -inf`` would be nan;
            clamp first).

    Returns:
        ``(U, R, K)``.

    Example:
        >>> import torch
        >>> lt = torch.full((1, 1, 2, 2), 0.5).log()
        >>> count_log_likelihood(torch.tensor([[1.0, 0.0, 2.0, 0.0]]), lt).exp()
        tensor([[[0.1250]]])
    """
    R, K, A, _ = log_transition.shape
    table = log_transition.reshape(R * K, A * A).transpose(0, 1)  # (A*A, R*K)
    return (counts @ table).view(counts.shape[0], R, K)


def mixture_log_likelihood(
    transition_logits: torch.Tensor,
    weight_logits: torch.Tensor,
    sequences: torch.Tensor,
    lengths: torch.Tensor,
    *,
    initial_logits: torch.Tensor | None = None,
) -> torch.Tensor:
    """Marginal (soft-EM) log-likelihood, differentiable in the logits.

    ``l(D) = sum_n logsumexp_k [log_softmax(weight_logits)_k + sum_j
    log_softmax(transition_logits)_{k, x^{j-1}, x^j}]`` (paper Eq. 2 with the sum over
    ``z`` kept), the quantity soft EM increases at every iteration.

    Args:
        transition_logits: ``(..., K, A, A)`` unnormalised; rows are ``log_softmax``-ed.
        weight_logits: ``(..., K)`` unnormalised mixture logits.
        sequences: ``(N, L)`` int64; lengths: ``(N,)`` int64.
        initial_logits: optional ``(..., K, A)`` first-symbol logits.

    Returns:
        ``(...)`` total log-likelihood of the ``N`` sequences.

    Example:
        >>> import torch
        >>> t = torch.zeros(2, 3, 3, requires_grad=True)
        >>> seqs, lengths = torch.tensor([[0, 1, 2]]), torch.tensor([3])
        >>> ll = mixture_log_likelihood(t, torch.zeros(2), seqs, lengths)
        >>> round(ll.item(), 4)  # 2 log(1/3)
        -2.1972
    """
    T = check_tensor("transition_logits", transition_logits)
    check_shape("transition_logits", T, (None, None, None), "(..., K, A, A)")
    K, A = T.shape[-3], T.shape[-1]
    if T.shape[-2] != A:
        raise ModelError(
            "expected transition_logits to have shape (..., K, A, A), "
            f"actual shape = {tuple(T.shape)}"
        )
    W = check_tensor("weight_logits", weight_logits)
    check_shape("weight_logits", W, (K,), f"(..., K={K})")
    log_initial = None
    if initial_logits is not None:
        I0 = check_tensor("initial_logits", initial_logits)
        check_shape("initial_logits", I0, (K, A), f"(..., K={K}, A={A})")
        log_initial = I0.log_softmax(-1)
    sequences, lengths = check_sequences(sequences, lengths, A)
    sequences, lengths = sequences.to(T.device), lengths.to(T.device)
    per = _gather_log_likelihood(T.log_softmax(-1), log_initial, sequences, lengths)  # (..., N, K)
    joint = per + W.log_softmax(-1).unsqueeze(-2)
    return torch.logsumexp(joint, dim=-1).sum(-1)
