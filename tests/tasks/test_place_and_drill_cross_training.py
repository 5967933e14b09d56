"""Tests of torchhrc.tasks.place_and_drill.cross_training (Nikolaidis & Shah 2013 as a baseline)."""

from __future__ import annotations

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.tasks.place_and_drill.cross_training import fit_cross_training
from torchhrc.tasks.place_and_drill.demos import demonstration
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask


@pytest.fixture(scope="module")
def fitted():
    task = PlaceAndDrillTask(3)
    demos = Demonstrations.from_lists(
        [demonstration("safe", "ABC")] * 3 + [demonstration("efficient", "CBA")] * 3,
        subjects=["s"] * 3 + ["e"] * 3,
    )
    return task, demos, fit_cross_training(task, demos)


def test_transitions_are_counts_plus_prior(fitted):
    task, _, ct = fitted
    assert ct.subjects == ("s", "e")
    torch.testing.assert_close(ct.T.sum(-1), torch.ones(2, 4, 27, dtype=torch.float64))
    x = task.state_names.index("PEE")
    # subject "s": 3 demonstrated waits in PEE all led to PPE; prior 1 split over PPE / PEP
    ppe, pep = task.state_names.index("PPE"), task.state_names.index("PEP")
    assert ct.T[0, 0, x, ppe].item() == pytest.approx((3 + 0.5) / 4)
    assert ct.T[0, 0, x, pep].item() == pytest.approx(0.5 / 4)


def test_policy_replays_the_demonstrations(fitted):
    task, demos, ct = fitted
    steps = task.read_steps(demos)
    sid = demos.subject_index
    for n in range(demos.num_sequences):
        for t in range(int(steps.lengths[n])):
            x, a = int(steps.states[n, t]), int(steps.actions[n, t])
            best = ct.best[sid[n], x]
            assert best[a] and best.sum() == 1, (n, t, task.state_names[x])


def test_unvisited_states_have_no_demonstrated_reward(fitted):
    task, _, ct = fitted
    unvisited = ~ct.visited[0]
    assert torch.all(ct.R[0][:, unvisited] <= 1.0 + 1e-12)  # goal reward only
    # "s" never saw EPE: there, every action is scored by the task's goal alone
    x = task.state_names.index("EPE")
    assert bool(unvisited[x])


def test_action_breaks_ties_uniformly(fitted):
    task, _, ct = fitted
    x = task.terminal_state  # every action ties in the absorbing state
    assert bool(ct.best[0, x].all())
    u = torch.linspace(0, 0.999, 400, dtype=torch.float64)
    a = ct.action(0, torch.full((400,), x), u)
    assert torch.bincount(a, minlength=4).tolist() == [100, 100, 100, 100]


def test_pause_at_full_bench_earns_no_reward():
    """A demonstrated wait that changes nothing must not create an endless reward loop."""
    task = PlaceAndDrillTask(2)
    slip = [
        ("human", "place_A"), ("robot", "wait"), ("human", "place_B"), ("robot", "wait"),
        ("human", "wait"), ("robot", "drill_A"), ("human", "wait"), ("robot", "drill_B"),
    ]  # fmt: skip
    demos = Demonstrations.from_lists([slip] * 3)
    ct = fit_cross_training(task, demos)
    full = task.state_names.index("PP")
    assert ct.R[0, 0, full].item() == 0.0
    assert ct.best[0, full].tolist() == [False, True, False]


def test_bad_arguments():
    task = PlaceAndDrillTask(1)
    demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "drill_A")]])
    with pytest.raises(ModelError, match="prior"):
        fit_cross_training(task, demos, prior=0.0)
    with pytest.raises(ValueError, match="reward"):
        fit_cross_training(task, demos, reward="sum")  # type: ignore[arg-type]
