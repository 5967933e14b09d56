"""Higher-order chains, lowered to first-order chains over context symbols.

A first-order chain predicts a step from the step before it. Where a robot "waits" between
every two of a person's actions, that step is always the wait, and a type's order (board 1,
then 2, then 3, or the reverse) is invisible to it: ``wait -> prime_i`` and
``prime_i -> wait`` occur in both orders alike. A second-order chain,
``P(a_t | a_(t-2), a_(t-1))``, sees across one step; a third-order chain,
``P(a_t | a_(t-3), a_(t-2), a_(t-1))``, sees the person's last two actions across the
robot's moves (a rhythm of tools, drill, drill, saw, saw, in which the last action alone
does not say what comes next).

They are fitted by the same code as the first-order one: step ``t`` is renamed to the
*context symbol* ``(a_(t-m+1), ..., a_(t-1), a_t)`` of an order-``m`` chain (``a_(-1)``,
``a_(-2)``, ... = ``start``), and a first-order chain over these symbols is the order-``m``
chain over the recorded ones (the renaming is one-to-one on sequences). A context symbol
can be followed only by the symbols whose context is its own last ``m - 1`` steps:
:class:`SecondOrder` holds that *support*, so that smoothing puts no mass on impossible
successors and the exact ICL counts ``A`` possible outcomes per context, the recorded
symbols, as for the first-order chain: the forms' ``log p(D, z)`` are then comparable
(:func:`torchhrc.mixture.fit_mixture`, ``order="auto"``). Only the context symbols that
occur are kept (``P`` of them, at most ``(A + 1)^(m - 1) A``).

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
    >>> [name for _, name in context_symbols(d, 3).data.vocabulary]
    ['robot:wait > human:a > wait', 'start > robot:wait > a', 'start > start > wait']
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import torch

__all__ = [
    "CONTEXT_SEPARATOR",
    "MAX_ORDER",
    "START",
    "SecondOrder",
    "context_symbols",
    "num_contexts",
    "second_order",
]

#: The name of the context before a sequence's first step.
START = "start"
#: Separates the previous steps from the step in a context symbol's action name.
CONTEXT_SEPARATOR = " > "
#: The highest order :func:`context_symbols` lowers (``fit_mixture(order=)``: 1 to this).
MAX_ORDER = 3


@dataclass(frozen=True)
class SecondOrder:
    """Demonstrations over context symbols and which transitions between them can occur
    (of a chain of order 2, or of any order ``m`` from :func:`context_symbols`).

    Attributes:
        data: the :class:`~torchhrc.data.Demonstrations` over ``P`` context symbols: step
            ``t`` is ``(actor_t, "<actor_(t-1)>:<action_(t-1)> > <action_t>")`` for order 2
            (the first step's context is ``"start"``), ``"<t-2> > <t-1> > <action_t>"`` for
            order 3; subjects, ids and types as given.
        transition_support: ``(P, P)`` bool, ``[p, q]`` True where ``q``'s previous
            ``m - 1`` steps are ``p``'s last ``m - 1`` (the only successors a context
            symbol can have).
        initial_support: ``(P,)`` bool, the context symbols that can start a sequence.
        outcomes: ``A``, the number of recorded symbols: the successors a context has in the
            order-``m`` chain (the exact ICL's Dirichlet is over these).
    """

    data: Any
    transition_support: torch.Tensor
    initial_support: torch.Tensor
    outcomes: int


def num_contexts(demonstrations: Any, order: int = 2) -> int:
    """``P``, the number of context symbols :func:`context_symbols` would give at ``order``
    (without building them: a size check before a fit).

    Raises:
        TypeError, ValueError: as :func:`context_symbols`.

    Example:
        >>> from torchhrc.data import Demonstrations
        >>> d = Demonstrations.from_lists([[("robot", "w"), ("human", "a"), ("robot", "w")]])
        >>> num_contexts(d), second_order(d).data.num_symbols
        (3, 3)
    """
    return int(_context_codes(demonstrations, order)[1].numel())


def _context_codes(demonstrations: Any, order: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(codes (N, L), used (P,))``: each step's context code ``previous * A + step``, where
    ``previous`` is its ``order - 1`` previous steps in base ``A + 1`` (the oldest first;
    ``A`` before the first step), and the sorted codes that occur."""
    if not callable(getattr(demonstrations, "with_vocabulary", None)):
        raise TypeError(
            "expected demonstrations to be a torchhrc.data.Demonstrations, got "
            f"{type(demonstrations).__name__}"
        )
    if isinstance(order, bool) or not isinstance(order, int) or not 2 <= order <= MAX_ORDER:
        raise ValueError(f"expected order to be an int in [2, {MAX_ORDER}], got {order!r}")
    seqs, mask = demonstrations.sequences, demonstrations.mask  # (N, L)
    A = demonstrations.num_symbols
    padded = torch.cat([seqs.new_full((seqs.shape[0], order - 1), A), seqs], 1)  # A = start
    L = seqs.shape[1]
    previous = torch.zeros_like(seqs)
    for lag in range(order - 1, 0, -1):  # the oldest step first (order - 1 is at most 2)
        previous = previous * (A + 1) + padded[:, order - 1 - lag : order - 1 - lag + L]
    codes = previous * A + seqs  # (N, L), in [0, (A + 1)^(order - 1) A)
    used = torch.unique(codes[mask])  # (P,) sorted
    if used.numel() == 0:
        raise ValueError("expected demonstrations with at least one step, got none")
    return codes, used


def second_order(demonstrations: Any) -> SecondOrder:
    """Lower :class:`~torchhrc.data.Demonstrations` to the context symbols of a second-order
    chain: :func:`context_symbols` at ``order=2``.

    Raises:
        TypeError: ``demonstrations`` is not a Demonstrations. ValueError: it holds no step.
    """
    return context_symbols(demonstrations, 2)


def context_symbols(demonstrations: Any, order: int) -> SecondOrder:
    """Lower :class:`~torchhrc.data.Demonstrations` to the context symbols of an order-``m``
    chain (see the module).

    One pass of tensor operations over the padded sequences (no loop over sequences).

    Args:
        demonstrations: ``N`` sequences over ``A`` symbols.
        order: ``m``, 2 or 3.

    Returns:
        :class:`SecondOrder`; its data has the same ``(N, L)`` shape and lengths.

    Raises:
        TypeError: ``demonstrations`` is not a Demonstrations.
        ValueError: it holds no step, or ``order`` is not in ``[2, MAX_ORDER]``.

    Example:
        >>> from torchhrc.data import Demonstrations
        >>> d = Demonstrations.from_lists([[("robot", "w"), ("human", "a"), ("robot", "w")]])
        >>> low = context_symbols(d, 3)
        >>> low.data.sequences.tolist(), low.transition_support.int().tolist()
        ([[2, 1, 0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    """
    codes, used = _context_codes(demonstrations, order)
    mask, A = demonstrations.mask, demonstrations.num_symbols
    index = torch.searchsorted(used, codes.clamp_max(int(used[-1]))).clamp_max(len(used) - 1)
    steps = demonstrations.vocabulary
    names = [f"{a}:{b}" for a, b in steps] + [START]

    def context_name(previous: int) -> str:
        parts = []
        for _ in range(order - 1):
            previous, symbol = divmod(previous, A + 1)
            parts.append(names[symbol])
        return CONTEXT_SEPARATOR.join(reversed(parts))

    vocabulary = tuple(
        (steps[c % A][0], f"{context_name(c // A)}{CONTEXT_SEPARATOR}{steps[c % A][1]}")
        for c in used.tolist()
    )
    data = dataclasses.replace(
        demonstrations, vocabulary=vocabulary, sequences=torch.where(mask, index, 0)
    )
    before, step = used // A, used % A  # (P,) each: the previous steps' code, the step
    # q can follow p where q's previous steps are p's last order - 1 steps: p's previous
    # steps but the oldest, then p's step
    after = (before % (A + 1) ** (order - 2)) * (A + 1) + step  # (P,)
    return SecondOrder(
        data=data,
        transition_support=before[None, :] == after[:, None],
        initial_support=before == (A + 1) ** (order - 1) - 1,  # every previous step "start"
        outcomes=A,
    )
