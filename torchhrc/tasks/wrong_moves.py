"""The price of a wrong move where the types' partners disagree (a prior on learned rewards).

Where the demonstrating partners of every type made their type's right move, the
demonstrations rank each type's move first but do not say what the other moves cost
against a wait: inverse RL sees a wait and a wrong move as two equally rare slips and gives
them about the same reward. That does not matter where all types want the same move. It
decides the robot's choice where they do not (a *contested* state): a robot that does not
know the type yet either guesses a move or waits, and with a wrong move priced like a wait a
guess always looks better than waiting (the task suite's ``fetch_order`` and the held-out
``finish_late``: the type-aware robot guessed where the true model waits).

:func:`price_wrong_moves` puts the missing price in: in a contested state, a move a type's
partners (almost) never made costs that type at least as much below the wait as the type's
own move gains above it (``R(wrong) <= R(wait) - max(R(own) - R(wait), 0)``). The prior is
symmetric about the wait: a wrong move loses what a right one wins. Where a type's own move
is the wait (its partners held back: a person who wants the robot still while she works),
it gains nothing by its own move, and the scale comes from the other side: a move it never
made costs it what that move gains the types whose own move it is (the largest such gain),
``R(wrong) <= R(wait) - max_z (R_z(move) - R_z(wait))``. It changes nothing
where the task has no wait (an action that changes no state), where one type's partners
made several moves (each of them is that type's), or outside the contested states.

``learn()`` applies it by default (``IRLConfig(wrong_moves="symmetric")``); the measurements
that decided it are in ``docs/evaluation_history.md``, "The price of a wrong move".

Example:
    >>> import torch
    >>> from torchhrc.tasks.interface import TaskSteps
    >>> # one state, actions wait / left / right; type 0's partners go left, type 1's right
    >>> effect = torch.tensor([[0], [1], [2]])
    >>> R = torch.tensor([[[0.0, 0.0]], [[1.0, -0.1]], [[-0.1, 1.0]]])  # (A, X, K)
    >>> states = torch.zeros(6, 1, dtype=torch.long)
    >>> steps = TaskSteps(states, torch.tensor([[1], [1], [1], [2], [2], [2]]),
    ...                   -torch.ones(6, 1, dtype=torch.long), states,
    ...                   torch.ones(6, 1, dtype=torch.bool))
    >>> priced, capped = price_wrong_moves(R, steps, torch.tensor([0, 0, 0, 1, 1, 1]), effect)
    >>> priced[:, 0].tolist()  # type 0's "right" and type 1's "left" now cost -1
    [[0.0, 0.0], [1.0, -1.0], [-1.0, 1.0]]
"""

from __future__ import annotations

import torch

from torchhrc.tasks.interface import TaskSteps

__all__ = ["WRONG_MOVE_RARE", "WRONG_MOVE_VISITS", "contested_states", "price_wrong_moves"]

#: A type's partners must have acted at least this often in a state for its move there to
#: count (fewer steps say little about which move is the type's).
WRONG_MOVE_VISITS = 3

#: A move a type's partners made in less than this share of their steps in a state is not
#: the type's (the demonstrations' slips: at noise 0.05 a random action, about 0.05 / A each).
WRONG_MOVE_RARE = 0.1


def _contest(counts: torch.Tensor, visits: int) -> tuple[torch.Tensor, ...]:
    """From ``counts (K, X, A)``: ``contested (X,)``, ``own (K, X)``, ``share (K, X, A)``,
    ``seen (K, X)`` (the type counts there)."""
    n = counts.sum(-1)  # (K, X)
    share = counts / n.clamp_min(1.0).unsqueeze(-1)
    own = counts.argmax(-1)  # (K, X)
    seen = n >= visits
    big = torch.iinfo(torch.int64).max
    low = torch.where(seen, own, big).min(0).values  # (X,) the smallest move of a counting type
    high = torch.where(seen, own, -1).max(0).values
    contested = seen.sum(0).ge(2) & (low != high)
    return contested, own, share, seen


def contested_states(
    steps: TaskSteps,
    assignments: torch.Tensor,
    num_types: int,
    num_states: int,
    num_actions: int,
    *,
    visits: int = WRONG_MOVE_VISITS,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The states where the types' partners made different moves.

    Args:
        steps: the demonstrations as task steps.
        assignments: ``(N,)`` the type of each demonstration.
        num_types, num_states, num_actions: ``K``, ``X``, ``A``.
        visits: the steps a type needs in a state for its move there to count.

    Returns:
        ``contested (X,)`` bool: two types that each count there have different most
        frequent moves; ``own (K, X)`` int64: each type's most frequent move;
        ``share (K, X, A)``: each type's share of each move (0 where it never acted).

    Example:
        >>> from torchhrc.tasks.interface import TaskSteps
        >>> states = torch.zeros(6, 1, dtype=torch.long)
        >>> steps = TaskSteps(states, torch.tensor([[1], [1], [1], [2], [2], [2]]),
        ...                   -torch.ones(6, 1, dtype=torch.long), states,
        ...                   torch.ones(6, 1, dtype=torch.bool))
        >>> contested, own, _ = contested_states(steps, torch.tensor([0, 0, 0, 1, 1, 1]),
        ...                                      2, 1, 3)
        >>> contested.tolist(), own.tolist()
        ([True], [[1], [2]])
    """
    counts = steps.robot_moves(assignments, num_types, num_states, num_actions)
    contested, own, share, _ = _contest(counts, visits)
    return contested, own, share


def price_wrong_moves(
    reward: torch.Tensor,
    steps: TaskSteps,
    assignments: torch.Tensor,
    robot_effect: torch.Tensor,
    *,
    visits: int = WRONG_MOVE_VISITS,
    rare: float = WRONG_MOVE_RARE,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Price the moves a type's partners never made in the contested states (module doc).

    Args:
        reward: ``(A, X, K)`` learned rewards per type.
        steps: the demonstrations as task steps.
        assignments: ``(N,)`` int64 the learned type of each demonstration.
        robot_effect: ``(A, X)`` int64 the state after each robot action (the wait is the
            first action that changes no state).
        visits: the steps a type needs in a state for its move there to count.
        rare: below this share of a type's steps in a state, a move is not the type's.

    Returns:
        ``(reward (A, X, K), capped (A, X, K) bool)``: the priced rewards (a new tensor) and
        which entries were lowered.

    Raises:
        ValueError: shapes that disagree, ``visits < 1`` or ``rare`` outside (0, 1].
    """
    if reward.dim() != 3:
        raise ValueError(f"expected reward of shape (A, X, K), got {tuple(reward.shape)}")
    A, X, K = reward.shape
    if tuple(robot_effect.shape) != (A, X):
        raise ValueError(f"expected robot_effect of shape (A, X) = ({A}, {X}) like reward's, "
                         f"got {tuple(robot_effect.shape)}")  # fmt: skip
    if tuple(assignments.shape) != (steps.mask.shape[0],):
        raise ValueError(f"expected assignments of shape (N,) = ({steps.mask.shape[0]},), one "
                         f"per demonstration, got {tuple(assignments.shape)}")  # fmt: skip
    if visits < 1 or not 0.0 < rare <= 1.0:
        raise ValueError(f"expected visits >= 1 and rare in (0, 1], got {visits}, {rare}")
    capped = torch.zeros(A, X, K, dtype=torch.bool, device=reward.device)
    still = (robot_effect == torch.arange(X, device=robot_effect.device)).all(-1)  # (A,)
    if K < 2 or not bool(still.any()):
        return reward.clone(), capped
    wait = int(still.nonzero()[0])
    counts = steps.robot_moves(assignments, K, X, A).to(reward.device)
    contested, own, share, seen = _contest(counts, visits)
    R = reward.permute(2, 1, 0)  # (K, X, A)
    own_value = R.gather(-1, own.unsqueeze(-1)).squeeze(-1)  # (K, X)
    wait_value = R[..., wait]
    gain = (own_value - wait_value).clamp_min(0.0)  # (K, X) what each type's own move gains
    actions = torch.arange(A, device=reward.device)
    # a type whose own move is the wait: a move it never made costs it what the move gains
    # the types whose own move it is (0 where no counting type made it: the wait's value)
    made = (own.unsqueeze(-1) == actions) & seen.unsqueeze(-1)  # (K, X, A)
    theirs = torch.where(made, gain.unsqueeze(-1), torch.zeros_like(R)).amax(0)  # (X, A)
    cap = torch.where((own == wait).unsqueeze(-1), theirs, gain.unsqueeze(-1))  # (K, X, A)
    cap = wait_value.unsqueeze(-1) - cap
    lower = (
        (contested & seen).unsqueeze(-1)  # (K, X, 1): a type that counts, a contested state
        & (actions != wait)
        & (actions != own.unsqueeze(-1))
        & (share < rare)
        & (R > cap)
    )
    priced = torch.where(lower, cap, R)
    return priced.permute(2, 1, 0).contiguous(), lower.permute(2, 1, 0).contiguous()
