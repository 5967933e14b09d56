"""Deprecated package (issue 32): the baselines of the paper's evaluation are specific to the
place-and-drill task and live with it, in :mod:`torchhrc.tasks.place_and_drill.hand_coded` (the
hand-coded expert MOMDP) and :mod:`torchhrc.tasks.place_and_drill.cross_training` (human-robot
cross-training). This package forwards their names for one release with a
``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_MOVED = {
    "CrossTrainingPolicy": "torchhrc.tasks.place_and_drill.cross_training",
    "fit_cross_training": "torchhrc.tasks.place_and_drill.cross_training",
    **{
        name: "torchhrc.tasks.place_and_drill.hand_coded"
        for name in (
            "DEFAULT_EXPERT_PATH",
            "ExpertModel",
            "build_expert_momdp",
            "expert_initial_belief",
            "load_expert_model",
            "parse_expert_model",
        )
    },
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
