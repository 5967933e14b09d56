"""Hand-finishing through the task interface: the pipeline builds the task's own MOMDP."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.mixture import fit_mixture
from torchhrc.tasks.hand_finishing import HandFinishingTask
from torchhrc.tasks.hand_finishing.collaborative import (
    HandFinishingCollaborativeTask,
    first_sides_from_chains,
)
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
from torchhrc.tasks.hand_finishing.person import simulate_demonstrations
from torchhrc.tasks.hand_finishing.sensing import observation_grid
from torchhrc.tasks.interface import check_task
from torchhrc.tasks.pipeline import build_model

GEOMETRY = BoxGeometry(horizontal=(-0.3, 0.0, 0.3), vertical=(0.2,), tilt=(-0.5, 0.0, 0.5))


def _base(sides=("left", "right")) -> HandFinishingTask:
    feasible = torch.zeros(3, 1, 3, 2, dtype=torch.bool)
    feasible[:, :, 0, 0] = True  # tilt -0.5: comfortable for the left side
    feasible[:, :, 2, 1] = True  # tilt +0.5: the right side
    feasible[1, :, 1, :] = True  # the centre, flat: both
    return HandFinishingTask.build(feasible=feasible, geometry=GEOMETRY, work_units=2,
                                   first_sides=sides)  # fmt: skip


@pytest.fixture(scope="module")
def clusters():
    demos = simulate_demonstrations(["left"] * 3 + ["right"] * 3, seed=0)
    fit = fit_mixture(demos, k_min=1, k_max=4, seed=0, initial=True, objects="raw")
    return demos, fit


def test_the_pipeline_builds_the_hand_finishing_momdp(clusters):
    demos, fit = clusters
    sides = first_sides_from_chains(fit.model.transition, demos.vocabulary)
    assert sorted(sides) == ["left", "right"]
    reference_task = _base(sides)
    hand = reference_task.observation_model(observation_grid(), loc=torch.tensor([0.1, 0.0]),
                                            scale=torch.tensor([0.2, 0.2]))  # fmt: skip
    reference = reference_task.momdp(hand)
    task = HandFinishingCollaborativeTask(_base(("left",)))  # the base's sides are ignored
    check_task(task)
    got = task.learned_momdp(demos, fit.model.transition, fit.assignments, hand)
    for name in ("Tx", "R", "Z", "b0"):
        assert torch.equal(getattr(got, name), getattr(reference, name)), name
    assert got.x0 == reference.x0 and got.observed_states == reference.observed_states
    assert got.hidden_states == reference.hidden_states == tuple(f"{s}-first" for s in sides)
    trivial = build_model(task, demos, fit.model.transition, fit.assignments)
    assert trivial.momdp.num_observations == 1 and trivial.weights.shape == (2, 0)
    assert torch.equal(trivial.momdp.Tx, reference.Tx)


def test_a_wrong_observation_is_rejected(clusters):
    demos, fit = clusters
    base = _base()
    task = HandFinishingCollaborativeTask(
        base, observation_model=lambda m: torch.ones(7, m.num_observed, 3, 1, dtype=torch.float64)
    )
    with pytest.raises(ModelError, match=r"observation\(\) has 3 types .*Y=2"):
        build_model(task, demos, fit.model.transition, fit.assignments)


def test_first_sides_need_the_side_symbols(clusters):
    fit = clusters[1]
    with pytest.raises(ModelError, match="lacks human:work_left"):
        first_sides_from_chains(fit.model.transition[:, :2, :2], [("human", "a"), ("robot", "b")])
