"""Deprecated package (issue 32): the baselines of the paper's evaluation are specific to the
place-and-drill task and live with it, in :mod:`torchhrc.tasks.place_and_drill.hand_coded` (the
hand-coded expert MOMDP) and :mod:`torchhrc.tasks.place_and_drill.cross_training` (human-robot
cross-training). This package forwards their names for one release with a
``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute
from torchhrc.baselines import cross_training as _cross_training
from torchhrc.baselines import hand_coded as _hand_coded

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

# the old modules' tables (importing them imports nothing of the task)
_MOVED = {**_cross_training._MOVED, **_hand_coded._MOVED}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
