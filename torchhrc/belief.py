"""Old module path of :mod:`torchhrc.pomdp.belief` (issue 32: the models package).

This module re-exports its names for one release.
"""

from __future__ import annotations

from torchhrc.pomdp.belief import (
    BeliefUpdate,
    correct,
    log_matmul_exp,
    log_update,
    log_update_all,
    momdp_correct,
    momdp_log_update,
    momdp_log_update_all,
    momdp_predict,
    momdp_predict_all,
    momdp_update,
    momdp_update_all,
    predict,
    predict_all,
    update,
    update_all,
)

__all__ = [
    "BeliefUpdate",
    "correct",
    "log_matmul_exp",
    "log_update",
    "log_update_all",
    "momdp_correct",
    "momdp_log_update",
    "momdp_log_update_all",
    "momdp_predict",
    "momdp_predict_all",
    "momdp_update",
    "momdp_update_all",
    "predict",
    "predict_all",
    "update",
    "update_all",
]
