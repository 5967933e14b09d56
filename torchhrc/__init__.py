"""torchhrc: learn human types from joint-action demonstrations and plan robot policies.

Implements Nikolaidis, Gu, Ramakrishnan, Shah, "Efficient Model Learning for Human-Robot
Collaborative Tasks": clustering of demonstrations into human types (mixture of Markov
chains, :mod:`torchhrc.mixture`), a reward per type by inverse reinforcement learning
(:mod:`torchhrc.irl`), and a MOMDP (:mod:`torchhrc.pomdp`) solved with point-based solvers
(:mod:`torchhrc.solvers`: PBVI, SARSOP), all batched on PyTorch tensors. ``import torchhrc``
loads only torch and numpy; optional dependencies load when a function needs them.

Example:
    >>> import torchhrc
    >>> demos = torchhrc.simulate_study(n_subjects=4, n_demos=2, seed=0)
    >>> demos.sequences.shape[0]
    8
"""

from __future__ import annotations

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError, ParseError, TorchHRCError
from torchhrc.experiments.sweep import sweep
from torchhrc.io import load_policy, read_pomdp, read_pomdpx, save_policy, write_pomdp
from torchhrc.irl import apprenticeship_learning, learn_type_rewards, maxent_irl
from torchhrc.metrics import adjusted_rand_index, match_clusters
from torchhrc.mixture import (
    MarkovChainMixture,
    MixtureFit,
    fit_mixture,
    infer_type,
    sequence_log_likelihood,
)
from torchhrc.pomdp import MOMDP, POMDP, SparsePOMDP
from torchhrc.pomdp.belief import (
    BeliefUpdate,
    log_update,
    momdp_log_update,
    momdp_update,
    momdp_update_all,
    update,
    update_all,
)
from torchhrc.pomdp.observation import DiscretizedGaussianObservation
from torchhrc.pomdp.observation_fit import fit_observation_model
from torchhrc.resources import shipped_path
from torchhrc.solvers import (
    AlphaVectorPolicy,
    FIBConfig,
    PBVIConfig,
    QMDPConfig,
    SARSOPConfig,
    Solution,
    evaluate_policy,
    solve,
    value_iteration,
)
from torchhrc.tasks import CollaborativeTask, Controller, LearnedModel, learn
from torchhrc.tasks.evaluation import TaskEvaluation, evaluate_task
from torchhrc.tasks.place_and_drill import simulate_study

__version__ = "0.1.0"

__all__ = [
    "MOMDP",
    "POMDP",
    "AlphaVectorPolicy",
    "BeliefUpdate",
    "CollaborativeTask",
    "Controller",
    "Demonstrations",
    "DiscretizedGaussianObservation",
    "FIBConfig",
    "LearnedModel",
    "MarkovChainMixture",
    "MixtureFit",
    "ModelError",
    "PBVIConfig",
    "ParseError",
    "QMDPConfig",
    "SARSOPConfig",
    "Solution",
    "SparsePOMDP",
    "TaskEvaluation",
    "TorchHRCError",
    "__version__",
    "adjusted_rand_index",
    "apprenticeship_learning",
    "evaluate_policy",
    "evaluate_task",
    "fit_mixture",
    "fit_observation_model",
    "infer_type",
    "learn",
    "learn_type_rewards",
    "load_policy",
    "log_update",
    "match_clusters",
    "maxent_irl",
    "momdp_log_update",
    "momdp_update",
    "momdp_update_all",
    "read_pomdp",
    "read_pomdpx",
    "save_policy",
    "sequence_log_likelihood",
    "shipped_path",
    "simulate_study",
    "solve",
    "sweep",
    "update",
    "update_all",
    "value_iteration",
    "write_pomdp",
]
