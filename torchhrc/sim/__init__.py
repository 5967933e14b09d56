"""SAPIEN 3 scenes of the tasks (the ``sim`` extra: ``pip install torchhrc[sim]``): the scene
machinery the tasks' scenes share (:mod:`.scene`) and the place-and-drill workbench with its
separation measure (:mod:`.workbench`, :mod:`.drill_replay`, :mod:`.capsules`). The
hand-finishing scene and its replay live with their task
(:mod:`torchhrc.tasks.hand_finishing.scene`, :mod:`torchhrc.tasks.hand_finishing.replay`).

SAPIEN is imported only when a scene is built, so ``import torchhrc.sim`` works without it.

Example:
    >>> from torchhrc.sim import RenderUnavailableError
    >>> issubclass(RenderUnavailableError, RuntimeError)
    True
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute
from torchhrc.sim.capsules import Capsule, capsule_separation, segment_distance
from torchhrc.sim.drill_replay import ExecutionReplay, execution_steps, replay_execution
from torchhrc.sim.scene import RenderUnavailableError, check_render_device
from torchhrc.sim.workbench import DrillResult, PlaceAndDrillScene, WorkbenchLayout

__all__ = [
    "Capsule",
    "DrillResult",
    "ExecutionReplay",
    "PlaceAndDrillScene",
    "RenderUnavailableError",
    "WorkbenchLayout",
    "capsule_separation",
    "check_render_device",
    "execution_steps",
    "replay_execution",
    "segment_distance",
]

#: Names that moved to their task's folder (issue 32: the generic scene machinery imports no
#: task), kept here for one release as deprecated aliases: name -> the module that holds it now.
_MOVED_TO_TASKS = {
    "HandFinishingScene": "torchhrc.tasks.hand_finishing.scene",
    "MoveResult": "torchhrc.tasks.hand_finishing.scene",
    "ReplayResult": "torchhrc.tasks.hand_finishing.replay",
    "box_moves": "torchhrc.tasks.hand_finishing.replay",
    "replay_box_moves": "torchhrc.tasks.hand_finishing.replay",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED_TO_TASKS)
