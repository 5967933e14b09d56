"""Deprecated module path (issue 32): the hand-coded expert MOMDP of place-and-drill lives with
its task, in :mod:`torchhrc.tasks.place_and_drill.hand_coded`; this module forwards its names
for one release with a ``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_MOVED = {
    name: "torchhrc.tasks.place_and_drill.hand_coded"
    for name in (
        "DEFAULT_EXPERT_PATH",
        "ExpertModel",
        "build_expert_momdp",
        "expert_initial_belief",
        "load_expert_model",
        "parse_expert_model",
    )
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
