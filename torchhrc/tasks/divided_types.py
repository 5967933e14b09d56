"""Divided types: a learned type whose people's partners made different moves in one state.

Within one type, every demonstrating partner serves the same person's wants, so in a state
the partners of all its people make the same move (up to slips). Where a learned type's
people fall into groups whose partners made different moves there, the type holds people
who want different things: most often two types the clustering merged (a small type
that differs from another in one state of each demonstration, as the held-out task
``cabinet_glue``'s 10 % and 15 % types at 30 subjects x 4: docs/your_own_task.md, section
8). Its learned reward there is a compromise weighted by how often each group's
demonstrations visit the state, and the type-aware robot may serve neither group.

:func:`divided_states` finds such states from the demonstrations alone: each subject's
partners' own move in the state (a strict majority of at least 2 of the subject's steps
there), and a type divided where at least :data:`DIVIDED_MIN_SUBJECTS` of its subjects, and
at least :data:`DIVIDED_MIN_SHARE` of those with an own move there, had a move other than
the type's most common one. ``learn()`` records the result as ``info["divided"]``.

:func:`split_divided` acts on it: it moves the people of a divided type whose partners' move
in its most divided state was the second most common one into a type of their own, and
repeats while a type is divided (``learn()`` does this after the clustering unless given
``k`` or ``split_divided=False``; ``info["split"]`` records each split). The Markov-chain
mixture charges a whole chain for a type that differs from another in one state, so its
criteria keep such a type merged on small corpora; the partners' moves there are direct
evidence of what the people want (docs/clustering.md, "Splitting divided types").

Example:
    >>> import torch
    >>> from torchhrc.tasks.interface import TaskSteps
    >>> # one state; 6 subjects of one type, 2 steps each: 4 partners wait (0), 2 hand (1)
    >>> states = torch.zeros(12, 1, dtype=torch.long)
    >>> actions = torch.tensor([[0]] * 8 + [[1]] * 4)
    >>> steps = TaskSteps(states, actions, -torch.ones_like(states), states,
    ...                   torch.ones(12, 1, dtype=torch.bool))
    >>> subjects = torch.arange(12) // 2
    >>> divided, own = divided_states(steps, torch.zeros(12, dtype=torch.long), subjects,
    ...                               num_types=1, num_states=1, num_actions=2)
    >>> divided.tolist(), own[0, 0].tolist()  # subjects by their partners' own move
    ([[True]], [4, 2])
"""

from __future__ import annotations

import torch

from torchhrc.tasks.interface import TaskSteps

__all__ = ["DIVIDED_MIN_SHARE", "DIVIDED_MIN_SUBJECTS", "divided_states", "split_divided"]

#: The fewest subjects of a type whose partners' own move in a state differs from the type's
#: most common one, for the type to count as divided there.
DIVIDED_MIN_SUBJECTS = 2

#: The least share of a type's subjects with an own move in a state that must differ from the
#: most common one (a quarter: one group of people in four).
DIVIDED_MIN_SHARE = 0.25


def divided_states(
    steps: TaskSteps,
    assignments: torch.Tensor,
    subjects: torch.Tensor,
    *,
    num_types: int,
    num_states: int,
    num_actions: int,
    min_subjects: int = DIVIDED_MIN_SUBJECTS,
    min_share: float = DIVIDED_MIN_SHARE,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The states where a learned type's people had partners with different own moves.

    Args:
        steps: the demonstrations as task steps (``N`` sequences).
        assignments: ``(N,)`` int64 the learned type of each demonstration.
        subjects: ``(N,)`` int64 the subject of each demonstration (any ids; a subject whose
            demonstrations have several types counts in each).
        num_types, num_states, num_actions: ``K``, ``X``, ``A``.
        min_subjects: at least this many subjects off the type's most common move.
        min_share: and at least this share of the type's subjects with an own move there.

    Returns:
        ``divided (K, X)`` bool and ``own (K, X, A)`` int64: per type and state, how many of
        its subjects had each move as their partners' own move there.

    Raises:
        ValueError: ``assignments`` or ``subjects`` not of shape ``(N,)``, ``min_subjects``
            below 1 or ``min_share`` outside (0, 1].
    """
    N = steps.mask.shape[0]
    for name, t in (("assignments", assignments), ("subjects", subjects)):
        if tuple(t.shape) != (N,):
            raise ValueError(f"expected {name} of shape (N,) = ({N},), one per demonstration, "
                             f"got {tuple(t.shape)}")  # fmt: skip
    if min_subjects < 1 or not 0.0 < min_share <= 1.0:
        raise ValueError(f"expected min_subjects >= 1 and min_share in (0, 1], got "
                         f"{min_subjects}, {min_share}")  # fmt: skip
    K, X, A = num_types, num_states, num_actions
    dev = steps.mask.device
    mask = steps.mask
    y = assignments.to(dev).long()[:, None].expand_as(mask)[mask]
    s = subjects.to(dev).long()[:, None].expand_as(mask)[mask]
    x, a = steps.states[mask], steps.actions[mask]
    # each (type, subject, state) group's counts of the partners' moves
    groups, slot = torch.unique(torch.stack([y, s, x]), dim=1, return_inverse=True)
    counts = torch.zeros(groups.shape[1], A, dtype=torch.long, device=dev)
    counts.view(-1).index_add_(0, slot * A + a, torch.ones_like(a))
    top, best = counts.max(-1)
    # a subject's own move: a strict majority of at least 2 of its steps there
    own_move = (top >= 2) & (2 * top > counts.sum(-1))
    own = torch.zeros(K * X * A, dtype=torch.long, device=dev)
    key = (groups[0] * X + groups[2]) * A + best
    own.index_add_(0, key[own_move], torch.ones_like(key[own_move]))
    own = own.view(K, X, A)
    total = own.sum(-1)
    off = total - own.max(-1).values  # the subjects off the most common move
    divided = (off >= min_subjects) & (off >= min_share * total)
    return divided, own


def split_divided(
    steps: TaskSteps,
    assignments: torch.Tensor,
    subjects: torch.Tensor,
    *,
    num_types: int,
    num_states: int,
    num_actions: int,
    max_types: int,
    min_subjects: int = DIVIDED_MIN_SUBJECTS,
    min_share: float = DIVIDED_MIN_SHARE,
    settle: bool = True,
) -> tuple[torch.Tensor, list[dict[str, int]]]:
    """Split the divided types (:func:`divided_states`) by the partners' moves there.

    While fewer than ``max_types`` types and some type ``y`` is divided in a state ``x``
    where at least ``min_subjects`` of its subjects had the second most common own move
    ``m``: take the ``(y, x)`` with the most such subjects (the first on a tie), and move to
    a new type ``K`` the demonstrations of type ``y`` of every subject whose partners made
    ``m`` in ``x`` more often than the type's most common own move (a subject seen there once
    counts by that step). Then, with ``settle``, the subjects of the two halves are settled
    by all their partners' moves (a subject whose partners met ``x`` rarely or never goes to
    the half whose partners moved as its own did elsewhere: :func:`_settle`).

    Args:
        steps: the demonstrations as task steps (``N`` sequences).
        assignments: ``(N,)`` int64 the type of each demonstration, in ``[0, num_types)``.
        subjects: ``(N,)`` int64 the subject of each demonstration.
        num_types, num_states, num_actions: ``K``, ``X``, ``A``.
        max_types: split no further than this many types.
        min_subjects, min_share: :func:`divided_states`'s thresholds.
        settle: reassign the two halves' subjects by all their partners' moves after each
            split.

    Returns:
        ``(N,)`` int64 the new types (the new ones numbered ``K``, ``K + 1``, ... in order of
        the splits) and one record per split: ``type``, ``state``, ``move`` (the partners'
        move of the new type), ``kept_move`` (the type's most common own move),
        ``subjects`` (how many moved by ``x``) and ``settled`` (the new type's subjects after
        the settling).

    Raises:
        ValueError: as :func:`divided_states`; ``max_types`` below 1.

    Example:
        >>> from torchhrc.tasks.interface import TaskSteps
        >>> # one state; 6 subjects of one type, 2 steps each: 4 partners wait (0), 2 hand (1)
        >>> states = torch.zeros(12, 1, dtype=torch.long)
        >>> actions = torch.tensor([[0]] * 8 + [[1]] * 4)
        >>> steps = TaskSteps(states, actions, -torch.ones_like(states), states,
        ...                   torch.ones(12, 1, dtype=torch.bool))
        >>> z, splits = split_divided(steps, torch.zeros(12, dtype=torch.long),
        ...                           torch.arange(12) // 2, num_types=1, num_states=1,
        ...                           num_actions=2, max_types=6)
        >>> z.tolist(), splits[0]["subjects"]
        ([0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1], 2)
    """
    if max_types < 1:
        raise ValueError(f"expected max_types >= 1, got {max_types}")
    z = assignments.to(steps.mask.device).long().clone()
    _, subject = torch.unique(subjects.to(z.device).long(), return_inverse=True)
    S = int(subject.max()) + 1 if subject.numel() else 0
    mask = steps.mask
    K, X, A = num_types, num_states, num_actions
    splits: list[dict[str, int]] = []
    while K < max_types:
        divided, own = divided_states(steps, z, subject, num_types=K, num_states=X,
                                      num_actions=A, min_subjects=min_subjects,
                                      min_share=min_share)  # fmt: skip
        kept = own.argmax(-1)  # (K, X) the most common own move (the first on a tie)
        second = own.scatter(-1, kept[..., None], -1).max(-1)  # the next one
        score = torch.where(divided & (second.values >= min_subjects), second.values, 0)
        if not bool((score > 0).any()):
            break
        y, x = divmod(int(score.view(-1).argmax()), X)
        move, main = int(second.indices[y, x]), int(kept[y, x])
        at = mask & (z[:, None] == y) & (steps.states == x)  # (N, L) type y's steps in x
        who = subject[:, None].expand_as(mask)[at]
        made = steps.actions[at]
        more = torch.bincount(who[made == move], minlength=S) > torch.bincount(
            who[made == main], minlength=S
        )  # (S,) subjects whose partners made ``move`` more often
        moved = (z == y) & more[subject]
        z[moved] = K
        if settle:
            z = _settle(steps, z, subject, (y, K), num_states=X, num_actions=A)
        splits.append({"type": y, "state": x, "move": move, "kept_move": main,
                       "subjects": int(more.sum()),
                       "settled": int(torch.unique(subject[z == K]).numel())})  # fmt: skip
        K += 1
    return z, splits


#: The pseudo-count of :func:`_settle`'s partner-move tables (per state and move).
SETTLE_PSEUDO_COUNT = 0.5

#: The most reassignment rounds of :func:`_settle`.
SETTLE_ROUNDS = 10


def _settle(steps: TaskSteps, z: torch.Tensor, subject: torch.Tensor, pair: tuple[int, int], *,
            num_states: int, num_actions: int) -> torch.Tensor:  # fmt: skip
    """Reassign the subjects of the two types of a split by all their partners' moves.

    The split reads one state; a subject whose partners never met it, or met it once, can sit
    in the wrong half while its partners' moves elsewhere (the other states where the halves'
    partners differ) say which half it belongs to. Each round scores every subject of the
    pair under each half's table of partner moves, ``P_g(a | x)`` (the half's counts plus
    :data:`SETTLE_PSEUDO_COUNT`, leaving the subject's own steps out of its half) and the
    half's share of subjects (leave-one-out, plus one), and moves it to the better half
    (a tie stays), until no subject moves, :data:`SETTLE_ROUNDS` rounds, or a half would
    keep fewer than :data:`DIVIDED_MIN_SUBJECTS` subjects (then the last assignment stays).
    States where the halves' partners move alike score both halves the same, up to the
    counts' noise.
    """
    X, A = num_states, num_actions
    mask = steps.mask
    in_pair = (z == pair[0]) | (z == pair[1])
    at = mask & in_pair[:, None]  # (N, L) the pair's steps
    g_step = (z[:, None].expand_as(mask)[at] == pair[1]).long()  # 0 old half, 1 new half
    s_step = subject[:, None].expand_as(mask)[at]
    cell = steps.states[at] * A + steps.actions[at]  # (T,) (x, a) of each step
    row = steps.states[at]
    subs, s_local = torch.unique(s_step, return_inverse=True)  # the pair's subjects
    n = subs.numel()
    # each (subject, x, a) cell's count, and each (subject, x) row's, to leave out
    _, key_sa_inv = torch.unique(s_local * (X * A) + cell, return_inverse=True)
    own_sa = torch.bincount(key_sa_inv)[key_sa_inv].double()  # (T,)
    _, key_sx_inv = torch.unique(s_local * X + row, return_inverse=True)
    own_sx = torch.bincount(key_sx_inv)[key_sx_inv].double()  # (T,)
    # a subject's half: its demonstrations in the pair are in one half (moved together)
    half = torch.zeros(n, dtype=torch.long, device=z.device)
    half[s_local] = g_step
    alpha = SETTLE_PSEUDO_COUNT
    for _ in range(SETTLE_ROUNDS):
        g = half[s_local]  # (T,)
        cells = torch.zeros(2, X * A, dtype=torch.float64, device=z.device)
        cells.index_put_((g, cell), torch.ones_like(cell, dtype=torch.float64), accumulate=True)
        rows = cells.view(2, X, A).sum(-1)  # (2, X)
        sizes = torch.bincount(half, minlength=2).double()  # (2,)
        score = torch.zeros(n, 2, dtype=torch.float64, device=z.device)
        for h in (0, 1):
            mine = (g == h).double()  # leave the subject's own steps out of its own half
            num = cells[h, cell] - mine * own_sa + alpha
            den = rows[h, row] - mine * own_sx + alpha * A
            score[:, h].index_add_(0, s_local, torch.log(num) - torch.log(den))
            score[:, h] += torch.log(sizes[h] - (half == h).double() + 1.0)
        other = 1 - half
        kept = score.gather(1, half[:, None]).squeeze(1)
        better = score.gather(1, other[:, None]).squeeze(1) > kept
        if not bool(better.any()):
            break
        new_half = torch.where(better, other, half)
        if int(torch.bincount(new_half, minlength=2).min()) < DIVIDED_MIN_SUBJECTS:
            break
        half = new_half
    # write back: each subject's demonstrations in the pair go to its half
    out = z.clone()
    lookup = torch.full((int(subject.max()) + 1,), -1, dtype=torch.long, device=z.device)
    lookup[subs] = half
    h_n = lookup[subject]
    out[in_pair] = torch.where(h_n[in_pair] == 1, pair[1], pair[0])
    return out
