"""Deprecated module path (issue 32): the replay of place-and-drill executions lives with its task,
in :mod:`torchhrc.tasks.place_and_drill.replay`; this module forwards its names for one release
with a ``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_MOVED = {
    name: "torchhrc.tasks.place_and_drill.replay"
    for name in (
        "ExecutionReplay",
        "execution_steps",
        "replay_execution",
    )
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
