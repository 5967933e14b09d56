"""SAPIEN 3 scenes of the tasks (the ``sim`` extra: ``pip install torchhrc[sim]``): the scene
machinery the tasks' scenes share (:mod:`.scene`) and the capsule geometry of the separation
measure (:mod:`.capsules`). Each task's scene and its replay live with their task
(:mod:`torchhrc.tasks.place_and_drill.workbench`, :mod:`torchhrc.tasks.place_and_drill.replay`,
:mod:`torchhrc.tasks.hand_finishing.scene`, :mod:`torchhrc.tasks.hand_finishing.replay`).

SAPIEN is imported only when a scene is built, so ``import torchhrc.sim`` works without it.

Example:
    >>> from torchhrc.sim import RenderUnavailableError
    >>> issubclass(RenderUnavailableError, RuntimeError)
    True
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute
from torchhrc.sim.capsules import Capsule, capsule_separation, segment_distance
from torchhrc.sim.scene import RenderUnavailableError, check_render_device

__all__ = [
    "Capsule",
    "RenderUnavailableError",
    "capsule_separation",
    "check_render_device",
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
    "DrillResult": "torchhrc.tasks.place_and_drill.workbench",
    "PlaceAndDrillScene": "torchhrc.tasks.place_and_drill.workbench",
    "WorkbenchLayout": "torchhrc.tasks.place_and_drill.workbench",
    "ExecutionReplay": "torchhrc.tasks.place_and_drill.replay",
    "execution_steps": "torchhrc.tasks.place_and_drill.replay",
    "replay_execution": "torchhrc.tasks.place_and_drill.replay",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED_TO_TASKS)
