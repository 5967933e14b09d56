"""Deprecated module path (issue 32): the replay of box moves lives with the hand-finishing task,
in :mod:`torchhrc.tasks.hand_finishing.replay`; this module forwards its names for one release
with a ``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_MOVED = {
    name: "torchhrc.tasks.hand_finishing.replay"
    for name in (
        "ReplayResult",
        "box_moves",
        "replay_box_moves",
    )
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
