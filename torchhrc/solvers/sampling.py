"""Batched simulation steps shared by belief expansion and Monte Carlo evaluation.

One call advances many (state, belief) pairs by one step at once: sample the successor state
and the observation from the model, then update the belief with :mod:`torchhrc.pomdp.belief`.
All randomness comes from an explicit ``torch.Generator``.

Example:
    >>> import torch
    >>> from torchhrc.tasks.classic import tiger
    >>> m = tiger()
    >>> g = torch.Generator().manual_seed(0)
    >>> step = flat_step(m, torch.tensor([0, 1]), m.b0.expand(2, 2), torch.tensor([0, 0]), g)
    >>> step.belief.shape, step.reward.tolist()
    (torch.Size([2, 2]), [-1.0, -1.0])
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import torch

from torchhrc.pomdp import MOMDP, POMDP, split_initial
from torchhrc.pomdp.belief import momdp_update, update

__all__ = [
    "SPARSE_BELIEF_STATES",
    "FlatStep",
    "MOMDPStep",
    "flat_step",
    "momdp_start",
    "momdp_step",
    "mostly_zero",
    "normalize_rows",
    "sample_categorical",
    "to_csr",
]

#: beliefs over this many states or more are checked for sparsity: a simulated belief of
#: Tag has at most 29 of 870 states nonzero, one of RockSample(7, 8) 256 of 12,545, and
#: products over their support are 10-50x cheaper than dense ones
SPARSE_BELIEF_STATES = 256


def to_csr(beliefs: torch.Tensor) -> torch.Tensor:
    """``beliefs (M, S)`` as a sparse CSR tensor (torch's beta warning silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return beliefs.to_sparse_csr()


def mostly_zero(beliefs: torch.Tensor, *, fraction: float = 0.1) -> bool:
    """Whether ``beliefs (E, S)`` (on the CPU, ``S >= SPARSE_BELIEF_STATES``) have fewer
    than ``fraction`` of their entries nonzero.

    Example:
        >>> mostly_zero(torch.eye(300, dtype=torch.float64))
        True
    """
    if beliefs.dim() != 2 or beliefs.device.type != "cpu" or beliefs.shape[0] == 0:
        return False
    if beliefs.shape[-1] < SPARSE_BELIEF_STATES:
        return False
    return int(torch.count_nonzero(beliefs)) < fraction * beliefs.numel()


def normalize_rows(joint: torch.Tensor) -> torch.Tensor:
    """``joint (M, S)`` with each row divided by its sum, in place; a row summing to 0 (an
    observation of probability 0, which a sampled one never has) becomes uniform, as
    :func:`torchhrc.pomdp.belief.update` with ``on_zero="ninf"``.

    Example:
        >>> normalize_rows(torch.tensor([[1.0, 3.0], [0.0, 0.0]])).tolist()
        [[0.25, 0.75], [0.5, 0.5]]
    """
    total = joint.sum(-1, keepdim=True)
    zero = (total <= 0).squeeze(-1)
    joint.div_(total.clamp_(min=torch.finfo(joint.dtype).tiny))
    if bool(zero.any()):
        joint[zero] = 1.0 / joint.shape[-1]
    return joint


def sample_categorical(probs: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """One draw per row of ``probs (..., K)`` (rows need not be normalised): int64 ``(...)``.

    Example:
        >>> sample_categorical(torch.tensor([[0.0, 1.0], [1.0, 0.0]]),
        ...                    torch.Generator().manual_seed(0)).tolist()
        [1, 0]
    """
    shape = probs.shape[:-1]
    flat = probs.reshape(-1, probs.shape[-1])
    if flat.shape[0] == 0:
        return torch.zeros(shape, dtype=torch.long, device=probs.device)
    # inverse-CDF sampling: one uniform per row, deterministic given the generator
    cdf = flat.cumsum(-1)
    u = torch.rand(flat.shape[0], 1, generator=generator, dtype=flat.dtype, device=flat.device)
    u = u * cdf[:, -1:]
    draws = torch.searchsorted(cdf, u, right=True).clamp_(max=flat.shape[-1] - 1)
    # never return a zero-probability index (u exactly at a flat part of the cdf)
    zero = flat.gather(1, draws) <= 0
    if bool(zero.any()):
        draws[zero] = flat[zero.squeeze(1)].argmax(-1)
    return draws.reshape(shape)


def momdp_start(
    model: MOMDP, episodes: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The first states of ``episodes`` episodes of an unbatched MOMDP: ``x (E,)``,
    ``y (E,)`` and the belief over ``y`` given the seen ``x``, ``(E, Y)``.

    ``x = x0`` and ``y ~ b0``, or, for a random start (:attr:`~torchhrc.pomdp.MOMDP.initial`),
    ``(x, y)`` drawn from the joint and the belief ``P(. | x)``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> x, y, b = momdp_start(m, 4, torch.Generator().manual_seed(0))
        >>> x.tolist(), b.shape
        ([0, 0, 0, 0], torch.Size([4, 2]))
    """
    E, device = int(episodes), model.b0.device
    if model.initial is None:
        x = torch.full((E,), model.x0, dtype=torch.long, device=device)
        belief = model.b0.expand(E, -1).clone()
        return x, sample_categorical(belief, generator), belief
    Y = model.num_hidden
    s = sample_categorical(model.initial.reshape(1, -1).expand(E, -1), generator)
    x, y = s // Y, s % Y
    return x, y, split_initial(model.initial)[1][x]


class FlatStep(NamedTuple):
    """One simulated step of a flat POMDP, for ``E`` episodes at once.

    Attributes:
        state: ``(E,)`` next state.
        observation: ``(E,)`` observation received.
        belief: ``(E, S)`` updated belief.
        reward: ``(E,)`` reward of the action in the current state.
    """

    state: torch.Tensor
    observation: torch.Tensor
    belief: torch.Tensor
    reward: torch.Tensor


class MOMDPStep(NamedTuple):
    """One simulated step of a MOMDP, for ``E`` episodes at once.

    Attributes:
        x: ``(E,)`` next observed value.
        y: ``(E,)`` next hidden value.
        observation: ``(E,)`` observation received.
        belief: ``(E, Y)`` updated belief over the hidden value.
        reward: ``(E,)`` reward of the action in the current state.
    """

    x: torch.Tensor
    y: torch.Tensor
    observation: torch.Tensor
    belief: torch.Tensor
    reward: torch.Tensor


def flat_step(
    model: POMDP,
    state: torch.Tensor,
    belief: torch.Tensor,
    action: torch.Tensor,
    generator: torch.Generator,
) -> FlatStep:
    """Advance ``E`` episodes of an unbatched POMDP by one step.

    Args:
        model: the POMDP (``T (A, S, S)``, ``Z (A, S, O)``, ``R (A, S)``).
        state: ``(E,)`` int64 current states.
        belief: ``(E, S)`` current beliefs.
        action: ``(E,)`` int64 actions.
        generator: the randomness.

    Returns:
        :class:`FlatStep`.
    """
    reward = model.R[action, state]
    s2 = sample_categorical(model.T[action, state], generator)
    o = sample_categorical(model.Z[action, s2], generator)
    if model.T.dim() == 3 and action.dim() == 1 and mostly_zero(belief):
        # predict on the beliefs' support: (m, S) CSR @ T[a] (S, S) per action used
        new = torch.empty_like(belief)
        for a in torch.unique(action).tolist():
            rows = (action == a).nonzero().squeeze(-1)
            pred = to_csr(belief[rows].to(model.T.dtype)) @ model.T[a]
            new[rows] = pred * model.Z[a][:, o[rows]].T
        return FlatStep(s2, o, normalize_rows(new), reward)
    new = update(model, belief, action, o, on_zero="ninf").belief
    return FlatStep(s2, o, new, reward)


def momdp_step(
    model: MOMDP,
    x: torch.Tensor,
    y: torch.Tensor,
    belief: torch.Tensor,
    action: torch.Tensor,
    generator: torch.Generator,
) -> MOMDPStep:
    """Advance ``E`` episodes of an unbatched MOMDP by one step (paper Eq. 3 for the belief).

    Args:
        model: the MOMDP.
        x: ``(E,)`` int64 observed values.
        y: ``(E,)`` int64 hidden values.
        belief: ``(E, Y)`` beliefs over the hidden value.
        action: ``(E,)`` int64 actions.
        generator: the randomness.

    Returns:
        :class:`MOMDPStep`.
    """
    reward = model.R[action, x, y]
    x2 = sample_categorical(model.Tx[action, x, y], generator)
    y2 = y if model.Ty is None else sample_categorical(model.Ty[action, x, y, x2], generator)
    o = sample_categorical(model.Z[action, x2, y2], generator)
    new = momdp_update(model, x, belief, action, x2, o, on_zero="ninf").belief
    return MOMDPStep(x2, y2, o, new, reward)
