"""Task steps from plain lists, for the tests of the pieces that read the demonstrating
robot's moves (tests/tasks/test_wrong_moves.py, test_divided_types.py)."""

from __future__ import annotations

import torch

from torchhrc.tasks.interface import TaskSteps


def steps_from_rows(rows: list[list[tuple[int, ...]]]) -> TaskSteps:
    """Task steps from sequences of ``(x, a_r)`` or ``(x, a_r, a_h)`` (the human's move
    ``-1``, a turn let pass, where not given; the next state unused)."""
    L = max(len(r) for r in rows)
    states = torch.zeros(len(rows), L, dtype=torch.long)
    actions = torch.zeros(len(rows), L, dtype=torch.long)
    human = torch.full((len(rows), L), -1, dtype=torch.long)
    mask = torch.zeros(len(rows), L, dtype=torch.bool)
    for i, row in enumerate(rows):
        for t, (x, a, *h) in enumerate(row):
            states[i, t], actions[i, t], mask[i, t] = x, a, True
            human[i, t] = h[0] if h else -1
    return TaskSteps(states, actions, human, states, mask)
