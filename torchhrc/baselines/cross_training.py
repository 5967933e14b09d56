"""Deprecated module path (issue 32): cross-training on the place-and-drill task lives with its
task, in :mod:`torchhrc.tasks.place_and_drill.cross_training`; this module forwards its names
for one release with a ``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_MOVED = {
    name: "torchhrc.tasks.place_and_drill.cross_training"
    for name in (
        "CrossTrainingPolicy",
        "fit_cross_training",
    )
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
