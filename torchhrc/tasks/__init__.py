"""torchhrc.tasks: the task interface, the pipeline from demonstrations to a solved model, and
the online controller (any user's task and the paper's two go through the same code).

Example:
    >>> from torchhrc.tasks import CollaborativeTask, Controller, LearnedModel, learn
    >>> issubclass(CollaborativeTask, object)
    True
"""

from torchhrc.tasks.controller import Controller
from torchhrc.tasks.evaluation import TaskEvaluation, evaluate_task, told_type_controller
from torchhrc.tasks.interface import (
    CollaborativeTask,
    TaskSteps,
    TypeEvidence,
    chain_preferences,
    check_task,
    reachable_states,
    tabular_features,
    wasted_move_feature,
)
from torchhrc.tasks.people import SimulatedPeople, TabularPeople, TaskWithPeople
from torchhrc.tasks.pipeline import IRLConfig, LearnedModel, build_model, learn, solve_model
from torchhrc.tasks.suite import make_task, suite_tasks
from torchhrc.tasks.true_model import (
    true_behaviour_controller,
    true_model_controller,
    true_momdp,
    true_reward_controller,
)

__all__ = [
    "CollaborativeTask",
    "Controller",
    "IRLConfig",
    "LearnedModel",
    "SimulatedPeople",
    "TabularPeople",
    "TaskEvaluation",
    "TaskSteps",
    "TaskWithPeople",
    "TypeEvidence",
    "build_model",
    "chain_preferences",
    "check_task",
    "evaluate_task",
    "learn",
    "make_task",
    "reachable_states",
    "solve_model",
    "suite_tasks",
    "tabular_features",
    "told_type_controller",
    "true_behaviour_controller",
    "true_model_controller",
    "true_momdp",
    "true_reward_controller",
    "wasted_move_feature",
]
