"""SAPIEN 3 scenes of the tasks (the ``sim`` extra: ``pip install torchhrc[sim]``): the
hand-finishing scene (:mod:`.scene`, :mod:`.replay`) and the place-and-drill workbench with
its separation measure (:mod:`.workbench`, :mod:`.drill_replay`, :mod:`.capsules`).

SAPIEN is imported only when a scene is built, so ``import torchhrc.sim`` works without it.

Example:
    >>> from torchhrc.sim import HandFinishingScene, RenderUnavailableError
    >>> issubclass(RenderUnavailableError, RuntimeError)
    True
"""

from __future__ import annotations

from torchhrc.sim.capsules import Capsule, capsule_separation, segment_distance
from torchhrc.sim.drill_replay import ExecutionReplay, execution_steps, replay_execution
from torchhrc.sim.replay import ReplayResult, box_moves, replay_box_moves
from torchhrc.sim.scene import (
    HandFinishingScene,
    MoveResult,
    RenderUnavailableError,
    check_render_device,
)
from torchhrc.sim.workbench import DrillResult, PlaceAndDrillScene, WorkbenchLayout

__all__ = [
    "Capsule",
    "DrillResult",
    "ExecutionReplay",
    "HandFinishingScene",
    "MoveResult",
    "PlaceAndDrillScene",
    "RenderUnavailableError",
    "ReplayResult",
    "WorkbenchLayout",
    "box_moves",
    "capsule_separation",
    "check_render_device",
    "execution_steps",
    "replay_box_moves",
    "replay_execution",
    "segment_distance",
]
