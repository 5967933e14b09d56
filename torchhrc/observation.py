"""Old module path: :mod:`torchhrc.observation` moved to the models package :mod:`torchhrc.pomdp`
(issue 32), split in two: the discretized Gaussian model and its grid in
:mod:`torchhrc.pomdp.observation`, the hand tracks and the learning in
:mod:`torchhrc.pomdp.observation_fit`; this module re-exports their names for one release.

Every name here is a deprecated alias (a ``DeprecationWarning`` naming its new place); import
from :mod:`torchhrc.pomdp` instead.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

#: Every name of this old path and the module that holds it now.
_MOVED = {
    "DiscretizedGaussianObservation": "torchhrc.pomdp.observation",
    "HandTracks": "torchhrc.pomdp.observation_fit",
    "ObservationFit": "torchhrc.pomdp.observation_fit",
    "ObservationGrid": "torchhrc.pomdp.observation",
    "_safe_log": "torchhrc.pomdp.observation_fit",
    "_unpack_transition": "torchhrc.pomdp.observation_fit",
    "bivariate_normal_cdf": "torchhrc.pomdp.observation",
    "discretize_positions": "torchhrc.pomdp.observation",
    "discretized_gaussian": "torchhrc.pomdp.observation",
    "fit_observation_model": "torchhrc.pomdp.observation_fit",
    "log_discretized_gaussian": "torchhrc.pomdp.observation",
    "sample_positions": "torchhrc.pomdp.observation",
    "simulate_tracks": "torchhrc.pomdp.observation_fit",
    "track_log_likelihood": "torchhrc.pomdp.observation_fit",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
