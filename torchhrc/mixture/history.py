"""Second-order chains, lowered to first-order chains over context symbols.

A first-order chain predicts a step from the step before it. Where a robot "waits" between
every two of a person's actions, that step is always the wait, and a type's order (board 1,
then 2, then 3, or the reverse) is invisible to it: ``wait -> prime_i`` and
``prime_i -> wait`` occur in both orders alike. A second-order chain,
``P(a_t | a_(t-2), a_(t-1))``, sees across one step.

It is fitted by the same code as the first-order one: step ``t`` is renamed to the *context
symbol* ``(a_(t-1), a_t)`` (``a_(-1)`` = ``start``), and a first-order chain over these
symbols is the second-order chain over the recorded ones (the renaming is one-to-one on
sequences). A context symbol ``(u, v)`` can be followed only by symbols ``(v, w)``:
:class:`SecondOrder` holds that *support*, so that smoothing puts no mass on impossible
successors and the exact ICL counts ``A`` possible outcomes per context, the recorded
symbols, as for the first-order chain: the two forms' ``log p(D, z)`` are then comparable
(:func:`torchhrc.mixture.fit_mixture`, ``order="auto"``). Only the context symbols that
occur are kept (``P`` of them, at most ``(A + 1) A``).

Example:
    >>> from torchhrc.data import Demonstrations
    >>> d = Demonstrations.from_lists([[("robot", "wait"), ("human", "a"), ("robot", "wait")]])
    >>> lowered = second_order(d)
    >>> [name for _, name in lowered.data.vocabulary]
    ['human:a > wait', 'robot:wait > a', 'start > wait']
    >>> lowered.data.sequences.tolist(), lowered.outcomes
    ([[2, 1, 0]], 2)
    >>> lowered.transition_support.int().tolist(), lowered.initial_support.tolist()
    ([[0, 1, 0], [1, 0, 0], [0, 1, 0]], [False, False, True])
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch

__all__ = ["CONTEXT_SEPARATOR", "START", "SecondOrder", "num_contexts", "second_order"]

#: The name of the context before a sequence's first step.
START = "start"
#: Separates the previous step from the step in a context symbol's action name.
CONTEXT_SEPARATOR = " > "


@dataclass(frozen=True)
class SecondOrder:
    """Demonstrations over context symbols and which transitions between them can occur.

    Attributes:
        data: the :class:`~torchhrc.data.Demonstrations` over ``P`` context symbols: step
            ``t`` is ``(actor_t, "<actor_(t-1)>:<action_(t-1)> > <action_t>")`` (the first
            step's context is ``"start"``); subjects, ids and types as given.
        transition_support: ``(P, P)`` bool, ``[p, q]`` True where ``q``'s previous step is
            ``p``'s step (the only successors a context symbol can have).
        initial_support: ``(P,)`` bool, the context symbols that can start a sequence.
        outcomes: ``A``, the number of recorded symbols: the successors a context has in the
            second-order chain (the exact ICL's Dirichlet is over these).
    """

    data: Any
    transition_support: torch.Tensor
    initial_support: torch.Tensor
    outcomes: int


def num_contexts(demonstrations: Any) -> int:
    """``P``, the number of context symbols :func:`second_order` would give (without
    building them: a size check before a fit).

    Raises:
        TypeError, ValueError: as :func:`second_order`.

    Example:
        >>> from torchhrc.data import Demonstrations
        >>> d = Demonstrations.from_lists([[("robot", "w"), ("human", "a"), ("robot", "w")]])
        >>> num_contexts(d), second_order(d).data.num_symbols
        (3, 3)
    """
    return int(_context_codes(demonstrations)[1].numel())


def _context_codes(demonstrations: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """``(codes (N, L), used (P,))``: each step's context code ``previous * A + step``
    (``previous = A`` before the first step) and the sorted codes that occur."""
    if not callable(getattr(demonstrations, "with_vocabulary", None)):
        raise TypeError(
            "expected demonstrations to be a torchhrc.data.Demonstrations, got "
            f"{type(demonstrations).__name__}"
        )
    seqs, mask = demonstrations.sequences, demonstrations.mask  # (N, L)
    A = demonstrations.num_symbols
    previous = torch.cat([seqs.new_full((seqs.shape[0], 1), A), seqs[:, :-1]], 1)  # A = start
    codes = previous * A + seqs  # (N, L), in [0, (A + 1) A)
    used = torch.unique(codes[mask])  # (P,) sorted
    if used.numel() == 0:
        raise ValueError("expected demonstrations with at least one step, got none")
    return codes, used


def second_order(demonstrations: Any) -> SecondOrder:
    """Lower :class:`~torchhrc.data.Demonstrations` to context symbols (see the module).

    One pass of tensor operations over the padded sequences (no loop over sequences).

    Args:
        demonstrations: ``N`` sequences over ``A`` symbols.

    Returns:
        :class:`SecondOrder`; its data has the same ``(N, L)`` shape and lengths.

    Raises:
        TypeError: ``demonstrations`` is not a Demonstrations.
        ValueError: it holds no step.
    """
    codes, used = _context_codes(demonstrations)
    mask, A = demonstrations.mask, demonstrations.num_symbols
    index = torch.searchsorted(used, codes.clamp_max(int(used[-1]))).clamp_max(len(used) - 1)
    steps = demonstrations.vocabulary
    names = [f"{a}:{b}" for a, b in steps] + [START]
    vocabulary = tuple(
        (steps[c % A][0], f"{names[c // A]}{CONTEXT_SEPARATOR}{steps[c % A][1]}")
        for c in used.tolist()
    )
    data = dataclasses.replace(
        demonstrations, vocabulary=vocabulary, sequences=torch.where(mask, index, 0)
    )
    before, step = used // A, used % A  # (P,) each
    return SecondOrder(
        data=data,
        transition_support=before[None, :] == step[:, None],
        initial_support=before == A,
        outcomes=A,
    )
