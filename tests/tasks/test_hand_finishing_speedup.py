"""Tests of torchhrc.tasks.hand_finishing.speedup: the instance of the factored-vs-flat
measurement is the robot's task restricted to some horizontal positions."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from torchhrc.tasks.hand_finishing.geometry import BoxFeasibility
from torchhrc.tasks.hand_finishing.model import HandFinishingTask
from torchhrc.tasks.hand_finishing.sensing import observation_grid
from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings
from torchhrc.tasks.hand_finishing.speedup import speedup_momdp


def _setup():
    settings = HandFinishingSettings.create(quick=True)
    H, V, T = settings.geometry.shape  # 3 x 1 x 3
    g = torch.Generator().manual_seed(0)
    reach = torch.ones(H, V, T, dtype=torch.bool)
    reach[2, 0, 0] = False
    comfort = torch.rand(H, V, T, 2, generator=g) > 0.2
    feasibility = BoxFeasibility(reachable=reach, comfortable=comfort,
                                 mask=reach & comfort.any(-1), joints=torch.zeros(H, V, T, 7),
                                 position_error=torch.zeros(H, V, T))  # fmt: skip
    robot = HandFinishingTask.build(feasible=comfort, reachable=reach, geometry=settings.geometry,
                                    work_units=settings.work_units,
                                    first_sides=("right", "left"))  # fmt: skip
    plan = robot.observation_model(observation_grid(), loc=torch.tensor([[0.05, 0.0], [0.1, 0.02]]),
                                   scale=torch.tensor([[0.2, 0.3], [0.25, 0.2]]))  # fmt: skip
    return settings, feasibility, robot, plan


@pytest.mark.parametrize("horizontal", [None, (0, 1, 2)], ids=["no reduction", "every position"])
def test_no_reduction_and_every_position_give_the_robots_own_momdp(horizontal):
    settings, feasibility, robot, plan = _setup()
    settings = replace(settings, speedup_horizontal=horizontal)
    own = robot.momdp(plan)
    got = speedup_momdp(settings, feasibility, robot, plan)
    for name in ("Tx", "Z", "R"):
        assert torch.allclose(getattr(got, name), getattr(own, name)), name


def test_reduced_instance_keeps_the_kept_configurations_of_those_positions():
    settings, feasibility, robot, plan = _setup()
    reduced = replace(settings, speedup_horizontal=(1, 2), speedup_work_units=1)
    got = speedup_momdp(reduced, feasibility, robot, plan)
    kept = int(feasibility.mask[[1, 2]].sum())  # configurations of positions 1 and 2
    assert got.num_observed == kept * (2 * 1 + 1)
    assert got.num_hidden == 2 and got.num_observations == 48
