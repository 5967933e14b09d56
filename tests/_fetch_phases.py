"""The four-phase fetching task of tests/tasks/test_state_smoothing.py and test_reaction.py:
the state human model's back-off after partner moves that are rare in a state."""

from __future__ import annotations

import random

import torch

from torchhrc.data import Demonstrations
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


def waiting_partner(y: int, u: float) -> int:
    """Every partner waits, and one move in 10 fetches a part (left or right, even odds),
    whatever the type (``u`` uniform in [0, 1))."""
    return 0 if u >= 0.1 else (1 if u < 0.05 else 2)


def fetch_demonstrations(side, subjects: int = 16, per_subject: int = 3, seed: int = 0,
                         partner=waiting_partner):  # fmt: skip
    """Demonstrations of the task, 8 turns each: subject ``s`` is of type ``s % 2``; the
    partner moves ``partner(type, u)`` for a uniform ``u`` (default :func:`waiting_partner`);
    the person then works ``side(type, turn, move)`` (0 left, 1 right). Returns the
    demonstrations and the ``(N,)`` types."""
    rng = random.Random(seed)
    seqs, who, types = [], [], []
    for s in range(subjects):
        y = s % 2
        for _ in range(per_subject):
            seq = []
            for t in range(8):
                a = partner(y, rng.random())
                seq += [("robot", FetchPhases.robot_actions[a]),
                        ("human", FetchPhases.human_actions[side(y, t, a)])]  # fmt: skip
            seqs.append(seq)
            who.append(f"s{s}")
            types.append(y)
    return Demonstrations.from_lists(seqs, subjects=who), torch.tensor(types)
