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
    PlaceAndDrillTask,
    interpret_clusters,
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
    "ExecutionController",
    "ExecutionTrace",
    "MOMDPController",
    "PlaceAndDrillTask",
    "demonstrated_orders",
    "interpret_clusters",
    "run_executions",
    "step_human",
]


def __getattr__(name: str) -> object:
    # the task's old copy of the pipeline (issue 32): deprecated names of .model, one release
    from torchhrc.tasks.place_and_drill import model

    if name not in model._RENAMED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return model.__getattr__(name)
