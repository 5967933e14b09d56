"""The instance of the study's factored-vs-flat SARSOP measurement.

At the paper's size the flat POMDP of the task does not fit in memory (its ``Z`` has
``A * X * Y * X * O``, about 640 million, entries), so the study
(:func:`torchhrc.experiments.hand_finishing.run_study`) times SARSOP factored and flat on a
reduced instance: the robot's task on the horizontal positions
``settings.speedup_horizontal`` only, with ``settings.speedup_work_units`` work units, and the
robot's planning hand model.

Example:
    >>> import torch
    >>> from dataclasses import replace
    >>> from torchhrc.tasks.hand_finishing.geometry import BoxFeasibility
    >>> from torchhrc.tasks.hand_finishing.sensing import true_observation
    >>> from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings
    >>> s = replace(HandFinishingSettings.create(quick=True), speedup_horizontal=(0, 1),
    ...             speedup_work_units=1)
    >>> ok = torch.ones(3, 1, 3, dtype=torch.bool)
    >>> f = BoxFeasibility(reachable=ok, comfortable=ok[..., None].expand(3, 1, 3, 2),
    ...                    mask=ok, joints=torch.zeros(3, 1, 3, 7), position_error=ok.double())
    >>> robot = HandFinishingTask.build(feasible=f.comfortable, geometry=s.geometry,
    ...                                 work_units=s.work_units)
    >>> speedup_momdp(s, f, robot, true_observation(robot, 0.2)).num_observed  # 6 x (2 W + 1)
    18
"""

from __future__ import annotations

import torch

from torchhrc.pomdp import MOMDP
from torchhrc.tasks.hand_finishing.geometry import BoxFeasibility, BoxGeometry
from torchhrc.tasks.hand_finishing.model import HandFinishingTask
from torchhrc.tasks.hand_finishing.sensing import observation_grid
from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings

__all__ = ["speedup_momdp"]


def speedup_momdp(
    settings: HandFinishingSettings,
    feasibility: BoxFeasibility,
    robot_task: HandFinishingTask,
    plan: torch.nn.Module,
) -> MOMDP:
    """The MOMDP whose factored and flat solves the study times.

    Args:
        settings: the study's settings; ``speedup_horizontal`` (``None``: the robot's own
            MOMDP) and ``speedup_work_units`` (``None``: ``work_units``) fix the instance.
        feasibility: the kinematic checks of ``settings.geometry``'s configurations.
        robot_task: the robot's task (its types' first sides and rewards are kept).
        plan: the robot's planning hand model, a
            :class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation` of ``robot_task``
            (``loc``, ``log_scale`` of shape ``(..., Y, 2)``); the reduced instance gets the
            same offsets and spreads per type.

    Returns:
        ``robot_task.momdp(plan)``, or that of the reduced task.
    """
    if settings.speedup_horizontal is None:
        return robot_task.momdp(plan)
    robot_sides = robot_task.first_sides
    keep = list(settings.speedup_horizontal)
    geo = settings.geometry
    sub_geo = BoxGeometry(horizontal=[geo.horizontal[i] for i in keep], vertical=geo.vertical,
                          tilt=geo.tilt, forward=geo.forward, size=geo.size)  # fmt: skip
    sub = HandFinishingTask.build(
        feasible=feasibility.comfortable[keep], reachable=feasibility.reachable[keep],
        geometry=sub_geo, first_sides=robot_sides, rewards=settings.rewards,
        work_units=settings.speedup_work_units or settings.work_units,
    )  # fmt: skip
    with torch.no_grad():
        sub_obs = sub.observation_model(
            observation_grid(), loc=plan.loc.reshape(-1, 2),
            scale=plan.log_scale.exp().reshape(-1, 2),
        )  # fmt: skip
    return sub.momdp(sub_obs)
