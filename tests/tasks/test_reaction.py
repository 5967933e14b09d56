"""The state model's reaction: what a type did after the robot's move in other states, mixed
into its back-off where its partners rarely made that move, with a weight its own steps give
(torchhrc.tasks.interface._reaction, reaction_weights)."""

from __future__ import annotations

import pytest
import torch
from _fetch_phases import FetchPhases, fetch_demonstrations

from torchhrc.data import Demonstrations
from torchhrc.tasks.interface import TypeEvidence, reaction_weights

#: the side each type works in phases 0-3 when the robot waits (both types alike)
_OWN = (0, 0, 1, 1)


def _demos(subjects: int = 16, per_subject: int = 3, seed: int = 0):
    """Type 0 ("keeper") works its own side of the phase whatever is fetched; type 1
    ("answerer") works the side fetched, and its own side when nothing is. Every partner
    waits, and one move in 10 fetches a part (left or right, even odds)."""
    return fetch_demonstrations(lambda y, t, a: a - 1 if y == 1 and a > 0 else _OWN[t % 4],
                                subjects, per_subject, seed)  # fmt: skip


def _evidence(task, demos, types, c: float = 64.0) -> TypeEvidence:
    V = len(demos.vocabulary)
    return TypeEvidence(torch.full((2, V, V), 1.0 / V, dtype=torch.float64),
                        tuple(tuple(v) for v in demos.vocabulary), types, task.read_steps(demos),
                        noise=0.05, pause=0.01, human_model="state", habit_weight=0.98,
                        prior_strength=c)  # fmt: skip


@pytest.mark.numeric
def test_a_type_that_answers_the_robot_is_predicted_to_answer_it():
    task = FetchPhases()
    demos, types = _demos()
    evidence = _evidence(task, demos, types)
    rho = reaction_weights(task, evidence)
    # the keeper's turns after a part fetched follow her habit: no weight on the reaction;
    # the answerer's follow the part: most of the weight
    assert float(rho[0]) == 0.0
    assert float(rho[1]) >= 0.5, rho
    b = task.human_policy(evidence)  # (Y, A, X, H + 1)
    # after a right part fetched in phase 0 (a move the partners made 1 time in 20 there,
    # whose cell holds a step or two), the answerer works right and the keeper left
    assert float(b[1, 2, 0, 1]) > 0.5, b[:, 2, 0]
    assert float(b[0, 2, 0, 0]) > 0.9, b[:, 2, 0]
    # after a wait, the partners' usual move (9 in 10), the habit decides for both in every
    # phase, though the prior weighs as 64 steps: after a wait the answerer worked her own
    # side (left in phases 0-1, right in 2-3), not the even split that her turns after a
    # wait, pooled over the phases, would give (the reaction enters a cell by how unusual
    # its move was: 0.1 here; at full weight the answerer's own side falls to 0.70-0.76)
    for phase in range(4):
        own = _OWN[phase]
        assert float(b[1, 0, 3 * phase, own]) > 0.8, (phase, b[1, 0, 3 * phase])
        assert float(b[0, 0, 3 * phase, own]) > 0.9, (phase, b[0, 0, 3 * phase])


@pytest.mark.numeric
def test_without_an_unusual_move_the_habit_is_kept():
    # partners that always wait: no step can tell a reaction from the habit, and the prior
    # keeps the habit (no weight on the reaction for either type)
    task = FetchPhases()
    seq = [step for t in range(8)
           for step in (("robot", "wait"), ("human", ("left", "right")[_OWN[t % 4]]))]  # fmt: skip
    demos = Demonstrations.from_lists([seq] * 8, subjects=[f"s{i}" for i in range(8)])
    types = torch.tensor([0, 1] * 4)
    assert reaction_weights(task, _evidence(task, demos, types)).tolist() == [0.0, 0.0]
