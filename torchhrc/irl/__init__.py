"""Inverse reinforcement learning: features, Abbeel-Ng (projection / QP), MaxEnt, type rewards.

The paper learns a reward per human type from that cluster's demonstrations by Abbeel & Ng's
apprenticeship learning (:func:`apprenticeship_learning`); :func:`maxent_irl` is the
maximum-entropy alternative (:func:`maxent_irl_types`: several types at once, their rewards
partly pooled) and :func:`learn_type_rewards` runs one problem per type and
returns the MOMDP reward ``R (A, X, Y)``.

Example:
    >>> from torchhrc.irl import Trajectories, empirical_feature_expectations
    >>> import torch
    >>> demos = Trajectories.from_pairs([[(0, 0), (1, 0)]])
    >>> empirical_feature_expectations(torch.eye(2), demos, 0.9)
    tensor([1.0000, 0.9000])
"""

from torchhrc.irl.features import (
    check_features,
    discounted_occupancy,
    empirical_feature_expectations,
    feature_expectations,
    indicator_features,
    monte_carlo_feature_expectations,
    reward_from_weights,
    start_distribution,
)
from torchhrc.irl.maxent import (
    MaxEntResult,
    SoftSolution,
    maxent_irl,
    maxent_irl_types,
    maxent_objective,
    soft_value_iteration,
)
from torchhrc.irl.metrics import expected_return, normalized_return, policy_agreement
from torchhrc.irl.projection import (
    REWARD_RULES,
    ApprenticeshipResult,
    IRLConvergenceWarning,
    apprenticeship_learning,
)
from torchhrc.irl.qp import QPError, solve_simplex_qp
from torchhrc.irl.trajectories import (
    Trajectories,
    check_trajectories,
    policy_matrix,
    sample_trajectories,
)
from torchhrc.irl.type_rewards import TypeRewards, learn_type_rewards, type_transitions

__all__ = [
    "REWARD_RULES",
    "ApprenticeshipResult",
    "IRLConvergenceWarning",
    "MaxEntResult",
    "QPError",
    "SoftSolution",
    "Trajectories",
    "TypeRewards",
    "apprenticeship_learning",
    "check_features",
    "check_trajectories",
    "discounted_occupancy",
    "empirical_feature_expectations",
    "expected_return",
    "feature_expectations",
    "indicator_features",
    "learn_type_rewards",
    "maxent_irl",
    "maxent_irl_types",
    "maxent_objective",
    "monte_carlo_feature_expectations",
    "normalized_return",
    "policy_agreement",
    "policy_matrix",
    "reward_from_weights",
    "sample_trajectories",
    "soft_value_iteration",
    "solve_simplex_qp",
    "start_distribution",
    "type_transitions",
]
