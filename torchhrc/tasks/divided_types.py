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
    by all their partners' moves and all their own (a subject whose partners met ``x``
    rarely or never goes to the half whose partners and people moved as its own did
    elsewhere: :func:`_settle`).

    Args:
        steps: the demonstrations as task steps (``N`` sequences).
        assignments: ``(N,)`` int64 the type of each demonstration, in ``[0, num_types)``.
        subjects: ``(N,)`` int64 the subject of each demonstration.
        num_types, num_states, num_actions: ``K``, ``X``, ``A``.
        max_types: split no further than this many types.
        min_subjects, min_share: :func:`divided_states`'s thresholds.
        settle: reassign the two halves' subjects by all their partners' moves and all
            their own after each split.

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


def _per_subject(subject: torch.Tensor, key: torch.Tensor) -> torch.Tensor:
    """``(T,)`` float64: how many of the steps share each step's subject and ``key``."""
    width = int(key.max()) + 1 if key.numel() else 1
    _, inverse = torch.unique(subject * width + key, return_inverse=True)
    return torch.bincount(inverse)[inverse].double()


#: The pseudo-count of the pair's pooled tables in :func:`_settle` (per context and move).
SETTLE_PSEUDO_COUNT = 0.5

#: The weight, in steps, of the pair's pooled table in each half's table in :func:`_settle`:
#: a half's ``P_g(o | c)`` is its counts plus this many steps of the pooled ``P(o | c)``, so
#: that a context seen a few times in the smaller half scores as the pair does, not as a
#: uniform guess (a uniform prior over the person's moves charged the smaller half about
#: 0.7 nats a step where both halves act alike).
SETTLE_POOL_STEPS = 2.0

#: :func:`_settle` moves at most this many times the pair's number of subjects, one subject
#: a move.
SETTLE_MOVES_PER_SUBJECT = 2


def _settle(steps: TaskSteps, z: torch.Tensor, subject: torch.Tensor, pair: tuple[int, int], *,
            num_states: int, num_actions: int) -> torch.Tensor:  # fmt: skip
    """Reassign the subjects of the two types of a split by all their partners' moves and
    all their own.

    The split reads one state; a subject whose partners never met it, or met it once, can sit
    in the wrong half while the rest of its demonstrations say which half it belongs to: its
    partners' moves elsewhere (the other states where the halves' partners differ) and the
    person's own moves (where the halves' people act otherwise, as the held-out task
    ``bento_line``'s two types that differ only at the end: one fetches the sauce, the other
    the lid, and the partner's move in the state that tells them apart is often pre-empted
    by the person's own). Every subject of the pair is scored under each half's tables of
    partner moves, ``P_g(a | x)``, and of the person's moves after them, ``P_g(a_h | x, a)``
    (a turn let pass is a move): the half's counts, leaving the subject's own steps out of
    its own half, plus :data:`SETTLE_POOL_STEPS` steps of the pair's pooled table (its
    counts plus :data:`SETTLE_PSEUDO_COUNT` a move), and the half's share of subjects
    (leave-one-out, plus one). The subject that gains most by changing halves moves, one at
    a time, until none gains, ``SETTLE_MOVES_PER_SUBJECT`` moves a subject, or a half would
    keep fewer than :data:`DIVIDED_MIN_SUBJECTS` subjects (then the last assignment stays).
    Where the halves' partners and people move alike both halves score alike. (Moving every
    subject that gains at once, as this did first, can swing subjects back and forth.)
    """
    X, A = num_states, num_actions
    mask = steps.mask
    in_pair = (z == pair[0]) | (z == pair[1])
    at = mask & in_pair[:, None]  # (N, L) the pair's steps
    g_step = (z[:, None].expand_as(mask)[at] == pair[1]).long()  # 0 old half, 1 new half
    s_step = subject[:, None].expand_as(mask)[at]
    cell = steps.states[at] * A + steps.actions[at]  # (T,) (x, a) of each step
    row = steps.states[at]
    H = int(steps.human[mask].max()) + 2 if bool(mask.any()) else 1  # the moves and a pass
    said = cell * H + steps.human[at] + 1  # (T,) (x, a, a_h): the person's move after it
    subs, s_local = torch.unique(s_step, return_inverse=True)  # the pair's subjects
    n = subs.numel()
    # (outcome, context, outcomes, width) of each table: the partner's move in x (A moves),
    # the person's after it in (x, a) (H moves)
    tables = ((cell, row, X * A, A), (said, cell, X * A * H, H))
    # each (subject, outcome) and (subject, context) count, to leave the subject's steps out
    own = [(_per_subject(s_local, out), _per_subject(s_local, ctx)) for out, ctx, _, _ in tables]
    alpha, beta = SETTLE_PSEUDO_COUNT, SETTLE_POOL_STEPS
    pooled = []  # (T,) per table: the pair's P(o | c) at each step, whatever the halves
    for out, ctx, outcomes, width in tables:
        both = torch.bincount(out, minlength=outcomes).double()
        pooled.append((both[out] + alpha) / (both.view(-1, width).sum(-1)[ctx] + alpha * width))
    # a subject's half: its demonstrations in the pair are in one half (moved together)
    half = torch.zeros(n, dtype=torch.long, device=z.device)
    half[s_local] = g_step
    # each half's counts of each table (whole numbers: updated by the steps of the subject
    # that moves, they stay exact)
    counts = []
    for out, _, outcomes, _ in tables:
        c = torch.zeros(2, outcomes, dtype=torch.float64, device=z.device)
        c.index_put_((g_step, out), torch.ones_like(out, dtype=torch.float64), accumulate=True)
        counts.append(c)
    for _ in range(SETTLE_MOVES_PER_SUBJECT * n):
        g = half[s_local]  # (T,)
        sizes = torch.bincount(half, minlength=2).double()  # (2,)
        score = torch.zeros(n, 2, dtype=torch.float64, device=z.device)
        for (out, ctx, _, width), (own_out, own_ctx), prior, c in zip(tables, own, pooled, counts):
            totals = c.view(2, -1, width).sum(-1)  # (2, contexts)
            for h in (0, 1):
                mine = (g == h).double()  # leave the subject's own steps out of its own half
                num = c[h, out] - mine * own_out + beta * prior
                den = totals[h, ctx] - mine * own_ctx + beta
                score[:, h].index_add_(0, s_local, torch.log(num) - torch.log(den))
        for h in (0, 1):
            score[:, h] += torch.log(sizes[h] - (half == h).double() + 1.0)
        stay = score.gather(1, half[:, None]).squeeze(1)
        gain = score.gather(1, (1 - half)[:, None]).squeeze(1) - stay  # (n,) by moving
        best = int(gain.argmax())
        if not float(gain[best]) > 0:
            break
        if int((half == half[best]).sum()) - 1 < DIVIDED_MIN_SUBJECTS:
            break
        was = int(half[best])
        half[best] = 1 - was
        mover = s_local == best  # its steps change halves
        for (out, _, _, _), c in zip(tables, counts):
            ones = torch.ones(int(mover.sum()), dtype=torch.float64, device=z.device)
            c[was].index_add_(0, out[mover], -ones)
            c[1 - was].index_add_(0, out[mover], ones)
    # write back: each subject's demonstrations in the pair go to its half
    out = z.clone()
    lookup = torch.full((int(subject.max()) + 1,), -1, dtype=torch.long, device=z.device)
    lookup[subs] = half
    h_n = lookup[subject]
    out[in_pair] = torch.where(h_n[in_pair] == 1, pair[1], pair[0])
    return out
