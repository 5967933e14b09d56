"""Old module path of :mod:`torchhrc.pomdp.belief` (issue 32: the models package).

This module re-exports its names for one release.

Every name here is a deprecated alias (a ``DeprecationWarning`` naming its new place); import
from :mod:`torchhrc.pomdp` instead.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

#: Every name of this old path and the module that holds it now.
_MOVED = {
    "BeliefUpdate": "torchhrc.pomdp.belief",
    "correct": "torchhrc.pomdp.belief",
    "log_matmul_exp": "torchhrc.pomdp.belief",
    "log_update": "torchhrc.pomdp.belief",
    "log_update_all": "torchhrc.pomdp.belief",
    "momdp_correct": "torchhrc.pomdp.belief",
    "momdp_log_update": "torchhrc.pomdp.belief",
    "momdp_log_update_all": "torchhrc.pomdp.belief",
    "momdp_predict": "torchhrc.pomdp.belief",
    "momdp_predict_all": "torchhrc.pomdp.belief",
    "momdp_update": "torchhrc.pomdp.belief",
    "momdp_update_all": "torchhrc.pomdp.belief",
    "predict": "torchhrc.pomdp.belief",
    "predict_all": "torchhrc.pomdp.belief",
    "update": "torchhrc.pomdp.belief",
    "update_all": "torchhrc.pomdp.belief",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
