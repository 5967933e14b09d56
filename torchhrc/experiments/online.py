"""Online type inference in the place-and-drill study (the paper's "online" case of Fig. 3).

Paper (Introduction and Conclusion): a new user's type "is inferred either offline from prior
demonstrations or online during task execution"; section "Online Estimation of Human Type":
online estimation works "if the human actions are informative of his type". The offline case
(:mod:`.place_and_drill`, Fig. 3) starts every MOMDP run from the type posterior of the
held-out subject's own demonstrations; a robot that knows the type scores a perfect run, so
that curve measures type identification. Here the held-out subject's demonstrations are not
used: every MOMDP starts from the uniform belief over types and updates it from what the
human does while the robot acts (paper Eq. 3,
:class:`~torchhrc.tasks.place_and_drill.simulate.MOMDPController`).

What makes the human's actions informative, and acting early costly (our reading, stated
once here):

* Turn taking. The types' preferences are about the robot's drilling (the expert reward:
  ``drill_early`` is -10 for a safe person and +10 for an efficient one, ``wait_early`` 0 and
  -5). The demonstrations' rule (:mod:`~torchhrc.tasks.place_and_drill.demos`) also fixes
  the human's side: an efficient person alternates, placing the next screw only once the
  previous one is drilled, a safe person places every screw first. In the online runs the
  simulated human follows its type's rule (``human_chunk`` of
  :func:`~torchhrc.tasks.place_and_drill.simulate.run_executions`), deviating with
  probability epsilon to a random placement. So after the first placement the robot must
  either drill (good for efficient, -10 for safe), or wait (free for safe, -5 for efficient)
  and watch: a safe person places the next screw, an efficient one waits for the drill.
  No policy can score the perfect +30 for both types from the uniform prior.
* Learned turn taking. The chains' first-order statistics cannot tell the types' turn taking
  apart (in an efficient demonstration the robot never leaves a screw waiting), so the learned
  model counts it on the demonstrations rewritten as MOMDP steps: for type ``y`` and situation
  ``c`` (``0``: nothing placed waits for drilling after the robot's action, ``1``: a screw
  waits) the probability that the human lets a turn pass although a position is empty,
  ``q[y, c] = (passes[y, c] + prior) / (turns[y, c] + 2 prior)`` (Laplace smoothing, one
  pseudo-count per outcome by default), with each demonstration counted for its cluster.
  What the data do not show (an efficient person facing a waiting screw) stays at the
  prior's 1/2.
* Hand-coded. The expert states the same quantity per type in
  ``models/place_and_drill_expert.json`` (``human.waits_while_pending``).
* Cross-training has no type and, online, no demonstrations of the new user: its MDP is
  learned from the pooled demonstrations of the training subjects
  (:func:`pooled_cross_training`).

Both MOMDPs keep their offline rewards and placement models; the online transition is
``Tx'[a, x, y] = (1 - q[y, c(a, x)]) Tx[a, x, y] + q[y, c(a, x)] onehot(m)`` where
``m = robot_effect[a, x]`` has an empty position (:func:`turn_taking_transition`); the online
MOMDPs are solved by SARSOP from the uniform belief.

Shapes: ``situation (A, X)`` int64 in {0, 1}; ``can_place (A, X)`` bool; ``q (Y, 2)``.

Example:
    >>> from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
    >>> situation, can_place = turn_situations(PlaceAndDrillTask(1))
    >>> situation.tolist(), can_place.tolist()  # wait / drill_A at E, P, D
    ([[0, 1, 0], [0, 0, 0]], [[True, False, False], [True, False, False]])
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.tasks.interface import behaviour_from_preferences
from torchhrc.tasks.pipeline import task_momdp, transition_from_behaviour
from torchhrc.tasks.place_and_drill.cross_training import CrossTrainingPolicy, fit_cross_training
from torchhrc.tasks.place_and_drill.demos import STRATEGIES
from torchhrc.tasks.place_and_drill.hand_coded import ExpertModel
from torchhrc.tasks.place_and_drill.model import EMPTY, PLACED, PlaceAndDrillTask

__all__ = [
    "expert_online_momdp",
    "human_chunk_size",
    "learn_turn_taking",
    "online_momdp",
    "pooled_cross_training",
    "turn_situations",
    "turn_taking_transition",
]


def turn_situations(task: PlaceAndDrillTask) -> tuple[torch.Tensor, torch.Tensor]:
    """The human's situation after each robot action: a screw waiting or not, a free position.

    Returns:
        ``(situation (A, X) int64, can_place (A, X) bool)``: with ``m = robot_effect[a, x]``,
        ``situation = 1`` when ``m`` has a placed, undrilled screw, else ``0``;
        ``can_place`` when ``m`` has an empty position.
    """
    status = task.status[task.robot_effect]  # (A, X, n)
    situation = (status == PLACED).any(-1).long()
    can_place = (status == EMPTY).any(-1)
    return situation, can_place


def learn_turn_taking(
    task: PlaceAndDrillTask,
    demonstrations: Demonstrations,
    assignments: torch.Tensor,
    num_types: int,
    *,
    prior: float = 1.0,
) -> torch.Tensor:
    """Per-type probability that the human lets a turn pass, from the demonstrations.

    ``q[y, c] = (passes + prior) / (turns + 2 prior)`` over the steps ``(x, a, x2)`` of the
    demonstrations of cluster ``y``
    (:meth:`~torchhrc.tasks.interface.CollaborativeTask.read_steps`) whose post-robot
    bench ``m`` has an empty position and is in situation ``c`` (:func:`turn_situations`);
    a pass is ``x2 = m``.

    Args:
        task: the task.
        demonstrations: ``N`` training demonstrations.
        assignments: ``(N,)`` int64 cluster of each demonstration, in ``[0, num_types)``.
        num_types: ``Y``.
        prior: pseudo-count per outcome (> 0).

    Returns:
        ``(Y, 2)`` float64 probabilities.

    Example:
        >>> demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "wait"),
        ...                                     ("human", "place_B"), ("robot", "drill_A")]])
        >>> learn_turn_taking(PlaceAndDrillTask(2), demos, torch.tensor([0]), 1).tolist()
        [[0.3333333333333333, 0.3333333333333333]]
    """
    if not prior > 0:
        raise ModelError(f"expected prior > 0, got {prior}")
    if assignments.shape != (demonstrations.num_sequences,):
        raise ModelError(
            f"expected assignments of shape (N={demonstrations.num_sequences},), "
            f"got {tuple(assignments.shape)}"
        )
    if (
        assignments.numel()
        and not 0 <= int(assignments.min()) <= int(assignments.max()) < num_types
    ):
        raise ModelError(f"expected assignments in [0, {num_types}), got {assignments.tolist()}")
    steps = task.read_steps(demonstrations)
    situation, can_place = turn_situations(task)
    mid = task.robot_effect[steps.actions.cpu(), steps.states.cpu()]  # (N, H)
    c = situation[steps.actions.cpu(), steps.states.cpu()]
    turn = steps.mask.cpu() & can_place[steps.actions.cpu(), steps.states.cpu()]
    passed = (steps.next_states.cpu() == mid) & turn
    y = assignments.cpu()[:, None].expand_as(c)
    cell = (y * 2 + c)[turn]
    turns = torch.bincount(cell, minlength=2 * num_types).double()
    passes = torch.bincount((y * 2 + c)[passed], minlength=2 * num_types).double()
    return ((passes + prior) / (turns + 2 * prior)).view(num_types, 2)


def turn_taking_transition(
    task: PlaceAndDrillTask, Tx: torch.Tensor, wait: torch.Tensor
) -> torch.Tensor:
    """Mix per-type turn passing into a placement transition.

    ``Tx'[a, x, y] = (1 - q[y, c]) Tx[a, x, y] + q[y, c] onehot(m)`` where ``m`` has an empty
    position (``c = situation[a, x]``), ``Tx'[a, x, y] = Tx[a, x, y]`` elsewhere.

    Args:
        task: the task.
        Tx: ``(A, X, Y, X)`` transition in which the human always places when it can
            (:func:`~torchhrc.tasks.pipeline.transition_from_behaviour`, ``pause=0``).
        wait: ``(Y, 2)`` probabilities ``q[y, c]`` in ``[0, 1]``.

    Returns:
        ``(A, X, Y, X)`` transition in ``Tx``'s dtype.

    Example:
        >>> task = PlaceAndDrillTask(1)
        >>> uniform = torch.ones(1, 2, 1, 1, dtype=torch.float64)  # (Y, A, X, H)
        >>> Tx = transition_from_behaviour(task, behaviour_from_preferences(task, uniform))
        >>> turn_taking_transition(task, Tx, torch.tensor([[0.25, 0.5]]))[0, 0, 0].tolist()
        [0.25, 0.75, 0.0]
    """
    A, X = task.num_actions, task.num_states
    Y = Tx.shape[-2]
    if Tx.shape != (A, X, Y, X):
        raise ModelError(f"expected Tx of shape (A={A}, X={X}, Y, X={X}), got {tuple(Tx.shape)}")
    if wait.shape != (Y, 2) or (wait < 0).any() or (wait > 1).any():
        raise ModelError(
            f"expected wait of shape (Y={Y}, 2) with values in [0, 1], got {tuple(wait.shape)}"
        )
    situation, can_place = turn_situations(task)
    situation, can_place = situation.to(Tx.device), can_place.to(Tx.device)
    q = wait.to(Tx).T[situation]  # (A, X, Y)
    q = torch.where(can_place.unsqueeze(-1), q, torch.zeros_like(q))
    stay = torch.nn.functional.one_hot(task.robot_effect.to(Tx.device), X).to(Tx)  # (A, X, X)
    return (1.0 - q).unsqueeze(-1) * Tx + q.unsqueeze(-1) * stay.unsqueeze(-2)


def online_momdp(
    task: PlaceAndDrillTask,
    placement: torch.Tensor,
    R: torch.Tensor,
    wait: torch.Tensor,
    *,
    noise: float = 0.05,
    discount: float = 0.95,
    type_names: Sequence[str] | None = None,
) -> MOMDP:
    """The MOMDP of the online case: placements, turn taking, rewards, uniform initial belief.

    Args:
        task: the task.
        placement: ``(Y, A, n)`` placement preferences per type, the same in every state
            (:func:`~torchhrc.tasks.interface.chain_preferences` of the learned chains;
            :func:`~torchhrc.tasks.interface.behaviour_from_preferences`).
        R: ``(A, X, Y)`` rewards.
        wait: ``(Y, 2)`` turn passing probabilities (:func:`learn_turn_taking`).
        noise: random-placement floor of the placements.
        discount: discount factor.
        type_names: ``(Y,)`` names.

    Returns:
        :class:`~torchhrc.pomdp.MOMDP` with ``b0`` uniform.

    Example:
        >>> task = PlaceAndDrillTask(2)
        >>> m = online_momdp(task, torch.ones(2, 3, 2, dtype=torch.float64),
        ...                  torch.zeros(3, 9, 2, dtype=torch.float64),
        ...                  torch.tensor([[0.0, 0.1], [0.0, 0.9]]))
        >>> m.b0.tolist()
        [0.5, 0.5]
    """
    preferences = placement.to(torch.float64).unsqueeze(-2)  # (Y, A, 1, n)
    behaviour = behaviour_from_preferences(task, preferences, noise=noise)
    Tx = turn_taking_transition(task, transition_from_behaviour(task, behaviour), wait)
    return task_momdp(task, Tx, R, discount=discount, type_names=type_names)


def expert_online_momdp(expert: ExpertModel) -> MOMDP:
    """The hand-coded expert MOMDP with the expert's turn taking, from the uniform belief.

    The expert's ``waits_while_pending[y]`` is ``q[y, 1]``; with nothing waiting for a drill
    the expert's human always places (``q[y, 0] = 0``).

    Raises:
        ModelError: the expert file states no ``human.waits_while_pending``.

    Example:
        >>> from torchhrc.tasks.place_and_drill.hand_coded import load_expert_model
        >>> expert_online_momdp(load_expert_model()).b0.tolist()
        [0.5, 0.5]
    """
    if expert.waits_while_pending is None:
        raise ModelError(
            f"the expert model {expert.path} states no human.waits_while_pending; "
            "the online case needs the expert's turn taking"
        )
    task = expert.task
    Y = len(expert.type_names)
    wait = torch.zeros(Y, 2, dtype=torch.float64)
    wait[:, 1] = torch.tensor(expert.waits_while_pending, dtype=torch.float64)
    placement = torch.ones(Y, task.num_actions, task.n_positions, dtype=torch.float64)
    return online_momdp(
        task,
        placement,
        expert.reward(),
        wait,
        noise=0.0,
        discount=expert.discount,
        type_names=expert.type_names,
    )


def pooled_cross_training(
    task: PlaceAndDrillTask, demonstrations: Demonstrations, *, discount: float = 0.95
) -> CrossTrainingPolicy:
    """Cross-training for a user without demonstrations: one MDP from everyone's (pooled).

    Returns:
        :class:`~torchhrc.tasks.place_and_drill.cross_training.CrossTrainingPolicy` with one
        subject, ``"pooled"`` (use subject index 0).

    Example:
        >>> demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "drill_A")]] * 2)
        >>> pooled_cross_training(PlaceAndDrillTask(1), demos).subjects
        ('pooled',)
    """
    n = demonstrations.num_sequences
    pooled = Demonstrations(
        vocabulary=demonstrations.vocabulary,
        sequences=demonstrations.sequences,
        lengths=demonstrations.lengths,
        subjects=("pooled",) * n,
        sequence_ids=tuple(
            f"{s}/{q}" for s, q in zip(demonstrations.subjects, demonstrations.sequence_ids)
        ),
    )
    return fit_cross_training(task, pooled, discount=discount)


def human_chunk_size(task: PlaceAndDrillTask, type_name: str) -> int:
    """The chunk size of a ground-truth type's turn-taking rule (``n`` safe, ``1`` efficient).

    Example:
        >>> task = PlaceAndDrillTask(3)
        >>> human_chunk_size(task, "safe"), human_chunk_size(task, "efficient")
        (3, 1)
    """
    if type_name not in STRATEGIES:
        raise ModelError(f"unknown type {type_name!r}, expected one of {', '.join(STRATEGIES)}")
    g = STRATEGIES[type_name]
    return task.n_positions if g is None else min(g, task.n_positions)
