"""Old module path: :mod:`torchhrc.observation` moved to the models package :mod:`torchhrc.pomdp`
(issue 32), split in two: the discretized Gaussian model and its grid in
:mod:`torchhrc.pomdp.observation`, the hand tracks and the learning in
:mod:`torchhrc.pomdp.observation_fit`; this module re-exports their names for one release.
"""

from __future__ import annotations

from torchhrc.pomdp.observation import (
    DiscretizedGaussianObservation,
    ObservationGrid,
    bivariate_normal_cdf,
    discretize_positions,
    discretized_gaussian,
    log_discretized_gaussian,
    sample_positions,
)
from torchhrc.pomdp.observation_fit import (
    HandTracks,
    ObservationFit,
    fit_observation_model,
    simulate_tracks,
    track_log_likelihood,
)

# private helpers that modules imported from here before the move
from torchhrc.pomdp.observation_fit import _safe_log as _safe_log
from torchhrc.pomdp.observation_fit import _unpack_transition as _unpack_transition

__all__ = [
    "DiscretizedGaussianObservation",
    "HandTracks",
    "ObservationFit",
    "ObservationGrid",
    "bivariate_normal_cdf",
    "discretize_positions",
    "discretized_gaussian",
    "fit_observation_model",
    "log_discretized_gaussian",
    "sample_positions",
    "simulate_tracks",
    "track_log_likelihood",
]
