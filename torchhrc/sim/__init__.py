"""SAPIEN 3 scenes of the tasks (the ``sim`` extra: ``pip install torchhrc[sim]``).

SAPIEN is imported only when a scene is built, so ``import torchhrc.sim`` works without it.

Example:
    >>> from torchhrc.sim import HandFinishingScene, RenderUnavailableError
    >>> issubclass(RenderUnavailableError, RuntimeError)
    True
"""

from __future__ import annotations

from torchhrc.sim.replay import ReplayResult, box_moves, replay_box_moves
from torchhrc.sim.scene import (
    HandFinishingScene,
    MoveResult,
    RenderUnavailableError,
    check_render_device,
)

__all__ = [
    "HandFinishingScene",
    "MoveResult",
    "RenderUnavailableError",
    "ReplayResult",
    "box_moves",
    "check_render_device",
    "replay_box_moves",
]
