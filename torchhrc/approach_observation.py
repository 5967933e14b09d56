"""Old module path of :mod:`torchhrc.pomdp.approach_observation` (issue 32: the models package).

This module re-exports its names for one release.
"""

from __future__ import annotations

from torchhrc.pomdp.approach_observation import (
    ApproachFit,
    ApproachObservation,
    approach_log_likelihood,
    fit_approach_observation,
)

__all__ = [
    "ApproachFit",
    "ApproachObservation",
    "approach_log_likelihood",
    "fit_approach_observation",
]
