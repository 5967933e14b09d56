"""Baselines of the paper's evaluation: the hand-coded expert MOMDP and human-robot cross-training.

Example:
    >>> from torchhrc.baselines import load_expert_model
    >>> load_expert_model().type_names
    ('safe', 'efficient')
"""

from __future__ import annotations

from torchhrc.baselines.cross_training import CrossTrainingPolicy, fit_cross_training
from torchhrc.baselines.hand_coded import (
    DEFAULT_EXPERT_PATH,
    ExpertModel,
    build_expert_momdp,
    expert_initial_belief,
    load_expert_model,
    parse_expert_model,
)

__all__ = [
    "DEFAULT_EXPERT_PATH",
    "CrossTrainingPolicy",
    "ExpertModel",
    "build_expert_momdp",
    "expert_initial_belief",
    "fit_cross_training",
    "load_expert_model",
    "parse_expert_model",
]
