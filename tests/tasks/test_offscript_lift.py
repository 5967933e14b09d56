"""The state model's off-script lift: how many more turns a type let pass after its partners'
unusual moves (their slips) than its habit predicts in the same states, pooled over the
states, added to its "no action" after the moves its partners rarely made
(torchhrc.tasks.interface._offscript_lift, offscript_lifts)."""

from __future__ import annotations

import pytest
import torch
from _fetch_phases import FetchPhases

from torchhrc.data import Demonstrations
from torchhrc.tasks.interface import TypeEvidence, offscript_lifts, reaction_weights


def _turns(phases: range, first: str | None = None) -> list[tuple[str, str]]:
    """Every partner waits and the person works left in every phase; with ``first``, the
    partner's first move in phase 0 is ``first`` and the person lets that turn pass."""
    seq: list[tuple[str, str]] = [("robot", first)] if first else []
    for _ in phases:
        seq += [("robot", "wait"), ("human", "left")]
    return seq


def _evidence(task: FetchPhases, habit_weight: float = 1.0) -> TypeEvidence:
    # types 0 and 1, four demonstrations each; type 1 lets two turns pass in phase 0: after
    # her partner's slip (a left part fetched), and once after a wait
    seqs = [_turns(range(4)) for _ in range(4)]
    seqs += [_turns(range(4), "fetch_left"), _turns(range(4), "wait")]
    seqs += [_turns(range(4)) for _ in range(2)]
    demos = Demonstrations.from_lists(seqs, subjects=[f"s{i}" for i in range(8)])
    types = torch.tensor([0] * 4 + [1] * 4)
    V = len(demos.vocabulary)
    return TypeEvidence(torch.full((2, V, V), 1.0 / V, dtype=torch.float64),
                        tuple(tuple(v) for v in demos.vocabulary), types, task.read_steps(demos),
                        noise=0.0, pause=0.0, human_model="state", habit_weight=habit_weight,
                        prior_strength=1.0)  # fmt: skip


@pytest.mark.numeric
def test_the_lift_worked_by_hand():
    # Type 1's turns with weight: in state 0 her partners fetched once (the turn let pass)
    # and waited four times (one turn let pass); the fetch is unusual there,
    # u = 1 - (1 - 1) / 4 = 1, each wait u = 1 - (4 - 1) / 4 = 1/4; the wait in state 1
    # (after the fetch) is her only visit there, u = 1; in phases 1-3 her partners always
    # waited, u = 0. Each turn's excess: 1 for a pass (else 0) less her habit's pass share
    # in its state with the turn left out: her turns in state 0 (3 left, 2 passes) less the
    # turn, plus the chain prior (one turn's worth: (1 - r) / 2 each side, r to the pass,
    # r = (2 + 0.5) / (18 + 1) = 5/38 her pass share over all turns), over 5 turns: after
    # either pass (1 + 5/38) / 5 = 43/190, after a left (2 + 5/38) / 5 = 81/190; in state 1
    # only the prior, 5/38 = 25/190. Sum of u * excess: 147/190 (the fetch)
    # + (147 - 3 * 81) / 190 / 4 (the waits) - 25/190 (state 1) = 98/190, of weight 3.
    # Type 0: no unusual move, weight 0. The lift of all types, shrunk toward none by two
    # turns: (98/190) / (3 + 2) = 49/475; each type's, shrunk toward it by two turns:
    # type 0 (0 + 2 * 49/475) / (0 + 2) = 49/475, type 1 (98/190 + 2 * 49/475) / (3 + 2)
    # = 343/2375.
    d = offscript_lifts(FetchPhases(), _evidence(FetchPhases()))
    torch.testing.assert_close(d, torch.tensor([49 / 475, 343 / 2375], dtype=torch.float64))


@pytest.mark.numeric
def test_after_a_move_the_partners_never_made_she_lets_more_turns_pass():
    task = FetchPhases()
    evidence = _evidence(task)
    assert reaction_weights(task, evidence).tolist() == [0.0, 0.0]  # the habit alone
    b = task.human_policy(evidence)  # (Y, A, X, H + 1), habit weight 1: the habit
    # a right part fetched in phase 1 (state 3): no partner of either type did it there,
    # and no demonstration reached the state after it, so the habit decides: both types
    # always worked left in phase 1, so its pass share is the chain prior's, r / 5 (type 0:
    # r = 0.5 / 17, type 1: r = 5/38); after the unusual move each lets its lift more pass
    want = torch.tensor([1 / 170 + 49 / 475, 1 / 38 + 343 / 2375], dtype=torch.float64)
    torch.testing.assert_close(b[:, 2, 3, 2], want)
    torch.testing.assert_close(b.sum(-1), torch.ones(b.shape[:-1], dtype=torch.float64))
    # her actions share the rest in their proportions (the habit's left : right)
    ratio = b[1, 2, 3, 0] / b[1, 2, 3, 1]
    torch.testing.assert_close(ratio, torch.tensor((4 + 33 / 76) / (33 / 76), dtype=torch.float64))
    # after the usual move (the wait) the habit stands: type 1 works left, as she always did
    assert float(b[1, 0, 3, 0]) > 0.9, b[1, 0, 3]
