"""The four-phase fetching task of tests/tasks/test_state_smoothing.py and test_reaction.py:
the state human model's back-off after partner moves that are rare in a state."""

from __future__ import annotations

import torch

from torchhrc.tasks.interface import CollaborativeTask


class FetchPhases(CollaborativeTask):
    """Four phases; the robot fetches a left or a right part (or waits), the person works
    left or right, which moves on to the next phase and clears the fetched part.
    State ``3 * phase + fetched`` (fetched: 0 none, 1 left, 2 right)."""

    state_names = tuple(f"p{p}{f}" for p in range(4) for f in ".LR")
    robot_actions = ("wait", "fetch_left", "fetch_right")
    human_actions = ("left", "right")
    robot_effect = torch.tensor(
        [[3 * (x // 3) + (x % 3 if a == 0 else a) for x in range(12)] for a in range(3)]
    )
    human_effect = torch.tensor([[3 * ((x // 3 + 1) % 4)] * 2 for x in range(12)])
    human_model = "state"
