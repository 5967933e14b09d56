"""The type of a new subject from several of their sequences.

* ``"posterior"`` (default, Bayesian): ``P(z = k | x_1..x_m) ∝ P(z = k) prod_i P(x_i | k)``,
  i.e. ``softmax(log prior + sum_i log P(x_i | k))``: one subject has one type, so the
  evidence of all their sequences adds up.
* ``"vote"`` (the paper's, section "Performance of Human Type Clustering"): each sequence is
  assigned to its most likely cluster ``z_i = argmax_k P(x_i | k)`` and the assignments are
  averaged with weights from the likelihoods: the weight of sequence ``i`` is the
  normalised likelihood of its winning cluster, ``w_i = max_k P(x_i | k) / sum_k P(x_i | k)``;
  ``P(type = k) = sum_i w_i [z_i = k] / sum_i w_i``.

A transition the model gives probability 0 (the paper's hard EM leaves such zeros) is scored
as ``floor`` (default ``1e-10``, as in the paper's E-step of :mod:`.hard_em`), so a sequence
impossible under every cluster still counts by its other transitions, and no ``nan`` arises.

Example:
    >>> import torch
    >>> from torchhrc.mixture import MarkovChainMixture, infer_type
    >>> T = torch.tensor([[[0.9, 0.1], [0.9, 0.1]], [[0.1, 0.9], [0.1, 0.9]]]).double().log()
    >>> m = MarkovChainMixture(T, torch.tensor([0.5, 0.5]).double().log())
    >>> infer_type(m, torch.tensor([[0, 0, 0], [0, 0, 1]]), torch.tensor([3, 3])).argmax().item()
    0
"""

from __future__ import annotations

from typing import Literal

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.mixture.likelihood import sequence_log_likelihood
from torchhrc.mixture.model import MarkovChainMixture

__all__ = ["infer_type"]


def infer_type(
    model: MarkovChainMixture,
    sequences: torch.Tensor,
    lengths: torch.Tensor,
    *,
    method: Literal["posterior", "vote"] = "posterior",
    log_prior: torch.Tensor | None = None,
    floor: float = 1e-10,
) -> torch.Tensor:
    """Probabilities of each type for one subject who demonstrated ``sequences``.

    Args:
        model: the fitted mixture, ``log_transition (..., K, A, A)``.
        sequences: ``(M, L)`` int64, the subject's ``M >= 1`` sequences, encoded in the
            model's form and symbol order: pass recorded demonstrations through
            :meth:`~torchhrc.mixture.model.MarkovChainMixture.prepare` first (a model fitted with
            exchangeable objects is over relabelled symbols, one of ``order`` 2 or 3 over context
            symbols; tensors carry no vocabulary, so this function cannot tell); lengths:
            ``(M,)``.
        method: ``"posterior"`` (Bayesian, default) or ``"vote"`` (the paper's weighted vote).
        log_prior: ``(..., K)`` log prior over types for ``"posterior"``; default the
            model's mixture weights.
        floor: probability standing for 0 (see module doc).

    Returns:
        ``(..., K)`` probabilities of the subject's type (sum to 1).

    Raises:
        ModelError: no sequences, bad shapes; ValueError: unknown method.
    """
    if method not in ("posterior", "vote"):
        raise ValueError(f"expected method 'posterior' or 'vote', got {method!r}")
    ll = sequence_log_likelihood(model, sequences, lengths, floor=floor)  # (..., M, K)
    if ll.shape[-2] < 1:
        raise ModelError("expected at least one sequence, got M = 0")
    if method == "posterior":
        prior = model.log_weights if log_prior is None else log_prior
        check_tensor("log_prior", prior)
        check_shape("log_prior", prior, (model.num_clusters,), f"(..., K={model.num_clusters})")
        joint = ll.sum(-2) + prior.to(ll)  # (..., K)
        if torch.isneginf(joint).all(-1).any():
            # every type has prior 0 somewhere: fall back to the likelihood alone
            joint = torch.where(torch.isneginf(joint).all(-1, keepdim=True), ll.sum(-2), joint)
        return torch.softmax(joint, dim=-1)
    post = torch.softmax(ll, dim=-1)  # (..., M, K) per-sequence normalised likelihoods
    weight, winner = post.max(-1)  # (..., M)
    votes = torch.zeros_like(post).scatter_(-1, winner.unsqueeze(-1), weight.unsqueeze(-1))
    total = votes.sum(-2)  # (..., K)
    return total / total.sum(-1, keepdim=True)
