"""The two-sided task of tests/tasks/test_evaluation.py and test_true_model.py, and a
TaskEvaluation written by hand.

The person first walks to side "a" (type "left") or "b" (type "right"), then to the middle;
there the robot hands over left or right (+1 for the type that wants it, -1 for the other) and
the task ends. In the middle the state no longer shows the type.
"""

from __future__ import annotations

import functools
import warnings

import torch

from torchhrc.tasks import CollaborativeTask
from torchhrc.tasks.evaluation import TaskEvaluation
from torchhrc.tasks.people import TabularPeople, TaskWithPeople

G = 0.9  # discount


class Sides(CollaborativeTask):
    state_names = ("start", "a", "b", "middle", "end")
    robot_actions = ("wait", "hand_left", "hand_right")
    human_actions = ("go_a", "go_b", "to_middle")
    robot_effect = torch.tensor([[0, 1, 2, 3, 4], [0, 1, 2, 4, 4], [0, 1, 2, 4, 4]])
    human_effect = torch.tensor([[1, 2, 0], [1, 1, 3], [2, 2, 3], [3, 3, 3], [4, 4, 4]])
    discount = G

    @property
    def terminal(self) -> torch.Tensor:
        return torch.tensor([False, False, False, False, True])


def world() -> TaskWithPeople:
    task = Sides()
    Y, X, A, H = 2, 5, 3, 3
    policy = torch.zeros(Y, 1, X, A, H + 1, dtype=torch.float64)
    policy[..., H] = 1.0  # no action where nothing is legal (middle, end)
    for y, first in ((0, 0), (1, 1)):
        policy[y, 0, 0, :, :] = torch.nn.functional.one_hot(torch.tensor(first), H + 1)
        policy[y, 0, 1:3, :, :] = torch.nn.functional.one_hot(torch.tensor(2), H + 1)
    people = TabularPeople(("left", "right"), policy, task.human_legal)
    reward = torch.zeros(A, X, Y, dtype=torch.float64)
    reward[1, 3] = torch.tensor([1.0, -1.0])
    reward[2, 3] = torch.tensor([-1.0, 1.0])
    return TaskWithPeople(task, people, reward, horizon=6, observed=False)


@functools.cache
def learned():
    """``(world, demos, aware, agnostic)``: 12 subjects x 3 demonstrations of :func:`world`
    (noise 0.05, seed 0), the type-aware model (k = 2) and the type-agnostic one (k = 1), both
    solved for 1 s; learned once per test process."""
    import torchhrc

    task_world = world()
    demos, _ = task_world.demonstrations(subjects=12, per_subject=3, noise=0.05, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        aware = torchhrc.learn(task_world.task, demos, k=2, solver_time=1.0, seed=0)
        agnostic = torchhrc.learn(task_world.task, demos, k=1, solver_time=1.0, seed=0)
    return task_world, demos, aware, agnostic


def by_hand(overall_mean, status=("identified", "identified"), robots=None):
    """A TaskEvaluation of 2 types x 2 episodes whose robot ``r`` returns
    ``overall_mean[r] +- 0.1 r`` (episode 0 +, episode 1 -, in both types): the paired
    difference of robots ``i`` and ``j`` is ``m_i - m_j +- 0.1 (i - j)``, whose overall 95%
    half-width is ``1.96 * 0.1 |i - j| / sqrt(2)`` (0.139 for neighbours)."""
    robots = robots or ("type-aware", "type-agnostic", "told the type")
    R = len(robots)
    sign = torch.tensor([1.0, -1.0], dtype=torch.float64)
    returns = (torch.tensor(overall_mean, dtype=torch.float64).view(R, 1, 1)
               + 0.1 * torch.arange(R, dtype=torch.float64).view(R, 1, 1) * sign)  # fmt: skip
    return TaskEvaluation(
        robots=robots, type_names=("a", "b"), returns=returns.expand(R, 2, 2).clone(),
        mean=torch.zeros(R, 2), ci=torch.zeros(R, 2),
        overall_mean=torch.tensor(overall_mean, dtype=torch.float64),
        overall_ci=torch.full((R,), 0.1, dtype=torch.float64), steps=torch.zeros(R, 2),
        belief_steps=(3,), type_map=torch.tensor([0, 1]), map_source="assignments",
        belief_accuracy=torch.ones(2, 1), belief_max=torch.ones(2, 1), belief_status=status,
        split_threshold=0.8, episodes=2, noise=0.05, seed=0, discount=0.9, horizon=5,
    )  # fmt: skip
