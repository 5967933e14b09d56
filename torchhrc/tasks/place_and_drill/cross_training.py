"""Human-robot cross-training (Nikolaidis & Shah 2013) as the paper's baseline.

Paper (section "Robustness of Computed Policy"): "We used the demonstrated sequences of the
testing subject as input for the cross-training algorithm, which learns a user model by
updating the transition and reward function of a Markov Decision Process. The algorithm then
computes a policy based on the learned model". Our reading (docs/cross_training.md) on the
task's MDP over the bench configuration ``x`` (no human type)::

    counts[a, x, x2] = number of demonstrated steps (x, a, x2)            (forward phase)
    T[a, x, x2]      = (counts[a, x, x2] + prior * M[a, x, x2]) / (sum_x2 counts[a, x, x2] + prior)
    R[a, x]          = reward_per_step * [a is the action demonstrated most often in x]
                       + goal_reward * T[a, x, done]        (rotation phase; the task's goal)

Only demonstrated steps that change the bench count for the reward: a robot wait at a full
bench (the human cannot act, nothing happens) is a pause, not a preference; counted, it would
make the robot wait forever for a reward it collects at every step.
    Q = value_iteration(T, R, discount).q_values                           (the policy)

``M`` is the task's mechanics with a uniformly random human placement (what the robot knows
before training): the transition prior. The reward is zero outside the demonstrated
state-action pairs, so in parts of the state space the subject never showed the robot, several
actions have the same value; the robot then has no preference and picks uniformly at random
among the best actions (ties within ``tie_tol``). Every subject gets its own MDP, all solved
in one batched call.

Shapes (``S`` subjects, ``A`` robot actions, ``X`` bench states)::

    T: (S, A, X, X)   R: (S, A, X)   q_values: (S, A, X)   best: (S, X, A) bool

Example:
    >>> from torchhrc.data import Demonstrations
    >>> from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
    >>> demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "drill_A")]])
    >>> ct = fit_cross_training(PlaceAndDrillTask(1), demos)
    >>> ct.best[0, 1].tolist()  # in state "P" the subject drilled
    [False, True]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.solvers.value_iteration import value_iteration
from torchhrc.tasks.interface import behaviour_from_preferences
from torchhrc.tasks.pipeline import transition_from_behaviour
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask

__all__ = ["CrossTrainingPolicy", "fit_cross_training"]


@dataclass(frozen=True)
class CrossTrainingPolicy:
    """Per-subject cross-training MDPs and their greedy policies.

    Attributes:
        subjects: ``(S,)`` subject ids, in the order of the batch dim.
        T: ``(S, A, X, X)`` learned transitions.
        R: ``(S, A, X)`` learned rewards.
        q_values: ``(S, A, X)`` optimal action values of the learned MDP.
        best: ``(S, X, A)`` bool, the actions within ``tie_tol`` of the best in each state.
        visited: ``(S, X)`` bool, states the subject's demonstrations visited.
    """

    subjects: tuple[str, ...]
    T: torch.Tensor
    R: torch.Tensor
    q_values: torch.Tensor
    best: torch.Tensor
    visited: torch.Tensor

    def action(
        self, subject: torch.Tensor | int, x: torch.Tensor, uniform: torch.Tensor
    ) -> torch.Tensor:
        """Pick an action: uniformly among the best actions of ``x`` for the subject.

        Args:
            subject: int or int64 ``(...)`` index into :attr:`subjects`.
            x: ``(...)`` int64 bench states.
            uniform: ``(...)`` floats in ``[0, 1)`` (one random number per decision).

        Returns:
            ``(...)`` int64 actions.
        """
        best = self.best[subject, x]  # (..., A)
        count = best.sum(-1)  # (...)
        k = (uniform * count).floor().long().clamp_max(count - 1)  # which of the tied ones
        rank = best.long().cumsum(-1) - 1  # (..., A)
        choice = best & (rank == k.unsqueeze(-1))
        return choice.long().argmax(-1)


def fit_cross_training(
    task: PlaceAndDrillTask,
    demonstrations: Demonstrations,
    *,
    prior: float = 1.0,
    reward_per_step: float = 1.0,
    goal_reward: float = 1.0,
    reward: Literal["mode", "count"] = "mode",
    discount: float = 0.95,
    tie_tol: float = 1e-9,
) -> CrossTrainingPolicy:
    """Learn one cross-training MDP per subject from its own demonstrations and solve it.

    Args:
        task: the task.
        demonstrations: the subjects' demonstrations (only their own are used for each).
        prior: Dirichlet pseudo-count of the mechanics prior ``M`` per ``(a, x)``.
        reward_per_step: reward added for every demonstrated ``(x, a)``.
        goal_reward: reward of completing the task (the step into the all-drilled state).
        reward: ``"mode"`` (default): ``reward_per_step`` for the action(s) the subject
            demonstrated most often in ``x``; ``"count"``: ``reward_per_step`` times the
            number of times ``(x, a)`` was demonstrated (the literal additive update, which
            with a discounted infinite horizon makes a demonstrated slip such as one extra
            wait at a full bench an endless reward loop).
        discount: discount factor of the MDP.
        tie_tol: actions within ``tie_tol * max(1, |Q|)`` of the best are tied.

    Returns:
        :class:`CrossTrainingPolicy` over ``demonstrations.unique_subjects``.

    Raises:
        ModelError: ``prior <= 0`` or ``reward_per_step <= 0``.
    """
    if not prior > 0:
        raise ModelError(f"expected prior > 0, got {prior}")
    if not reward_per_step > 0:
        raise ModelError(f"expected reward_per_step > 0, got {reward_per_step}")
    steps = task.read_steps(demonstrations)
    subjects = demonstrations.unique_subjects
    S, A, X = len(subjects), task.num_actions, task.num_states
    sid = demonstrations.subject_index.cpu()[:, None].expand_as(steps.states)  # (N, H)
    m = steps.mask.cpu()
    s, x, a, x2 = sid[m], steps.states.cpu()[m], steps.actions.cpu()[m], steps.next_states.cpu()[m]
    dt = torch.float64
    flat = ((s * A + a) * X + x) * X + x2
    counts = torch.bincount(flat, minlength=S * A * X * X).to(dt).view(S, A, X, X)
    uniform = torch.ones(1, A, 1, task.n_positions, dtype=dt)  # a uniformly random placement
    mechanics = transition_from_behaviour(task, behaviour_from_preferences(task, uniform))
    mechanics = mechanics[:, :, 0, :]  # (A, X, X)
    T = (counts + prior * mechanics) / (counts.sum(-1, keepdim=True) + prior)
    moved = x2 != x  # a pause (nothing changed: a wait at a full bench) shows no preference
    visits = torch.bincount(((s * A + a) * X + x)[moved], minlength=S * A * X).to(dt).view(S, A, X)
    if reward == "count":
        R = reward_per_step * visits
    elif reward == "mode":
        top = visits.amax(-2, keepdim=True)  # (S, 1, X)
        R = reward_per_step * ((visits == top) & (visits > 0)).to(dt)
    else:
        raise ValueError(f"expected reward 'mode' or 'count', got {reward!r}")
    # the task's goal: reward for the step that completes it (expected under T)
    done = T[..., task.terminal_state].clone()  # (S, A, X)
    done[..., task.terminal_state] = 0.0
    R = R + goal_reward * done
    solution = value_iteration(T, R, discount, tol=1e-8)
    Q = solution.q_values  # (S, A, X)
    top = Q.amax(-2, keepdim=True)
    best = (Q >= top - tie_tol * top.abs().clamp_min(1.0)).transpose(-1, -2)  # (S, X, A)
    visited = torch.zeros(S, X, dtype=torch.bool)
    visited[s, x] = True
    visited[s, x2] = True
    return CrossTrainingPolicy(
        subjects=subjects, T=T, R=R, q_values=Q, best=best.contiguous(), visited=visited
    )
