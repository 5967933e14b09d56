"""The place-and-drill task of the paper's user study.

Re-exports the demonstration simulator (:mod:`~torchhrc.tasks.place_and_drill.demos`).

Example:
    >>> from torchhrc.tasks.place_and_drill import simulate_study
    >>> simulate_study(seed=1).num_sequences
    54
"""

from __future__ import annotations

from torchhrc.tasks.place_and_drill.demos import (
    STRATEGIES,
    demonstration,
    placement_orders,
    position_names,
    scaling_study,
    simulate_demonstrations,
    simulate_study,
    task_vocabulary,
)

__all__ = [
    "STRATEGIES",
    "demonstration",
    "placement_orders",
    "position_names",
    "scaling_study",
    "simulate_demonstrations",
    "simulate_study",
    "task_vocabulary",
]

# The task MOMDP and the execution simulator (torchhrc.tasks.place_and_drill.model / .simulate).
from torchhrc.tasks.place_and_drill.model import (
    FEATURE_NAMES,
    DemonstrationSteps,
    LearnedTaskModel,
    PlaceAndDrillTask,
    build_learned_model,
    build_momdp,
    demonstration_steps,
    interpret_clusters,
    learn_type_weights,
    placement_probabilities,
    placement_transition,
)
from torchhrc.tasks.place_and_drill.simulate import (
    CrossTrainingController,
    ExecutionController,
    ExecutionTrace,
    MOMDPController,
    demonstrated_orders,
    run_executions,
    step_human,
)

__all__ += [
    "FEATURE_NAMES",
    "CrossTrainingController",
    "DemonstrationSteps",
    "ExecutionController",
    "ExecutionTrace",
    "LearnedTaskModel",
    "MOMDPController",
    "PlaceAndDrillTask",
    "build_learned_model",
    "build_momdp",
    "demonstrated_orders",
    "demonstration_steps",
    "interpret_clusters",
    "learn_type_weights",
    "placement_probabilities",
    "placement_transition",
    "run_executions",
    "step_human",
]
