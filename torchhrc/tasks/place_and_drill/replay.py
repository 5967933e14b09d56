"""Replay place-and-drill executions in the SAPIEN workbench and measure human-robot separation.

An execution of the task (:func:`torchhrc.tasks.place_and_drill.simulate.run_executions`) is a
sequence of bench states ``x_0 .. x_H`` and robot actions ``a_0 .. a_{H-1}``. Each step is one
joint step: the robot drills position ``p`` (or waits at home) while the person places the
screw at ``q`` (or rests), as in the task's turn: the robot acts on ``x_t``, the person places
into the bench the robot leaves. The two move at once (the hazard the "safe" type wants
avoided): both reach (robot above ``p``, hand above ``q``), work (drill on ``p``, palm on
``q``), withdraw and return (robot home, arm at rest), in ``phase_steps`` physics steps per
phase. Per step the replay records the minimum separation between any robot capsule (the
drill included) and any of the person's, sampled along the motion, and the robot-person
contact points SAPIEN reports. Steps after the last screw is drilled are not replayed.

Example:
    >>> import torch
    >>> from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
    >>> task = PlaceAndDrillTask(2)
    >>> x1 = int(task.place_effect[task.initial_state, 0])           # the person places A
    >>> x2 = int(task.place_effect[task.robot_effect[1, x1], 1])     # drill A, place B
    >>> drill, place = execution_steps(task, torch.tensor([task.initial_state, x1, x2]),
    ...                                torch.tensor([0, 1]))
    >>> drill.tolist(), place.tolist()
    ([-1, 0], [0, 1])
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.place_and_drill.model import DRILLED, EMPTY, PLACED

__all__ = ["ExecutionReplay", "execution_steps", "replay_execution"]


@dataclass(frozen=True)
class ExecutionReplay:
    """What :func:`replay_execution` measured over the ``T`` replayed steps.

    Attributes:
        drill: ``(T,)`` int64 position the robot drilled (``-1``: it waited).
        place: ``(T,)`` int64 position the person placed (``-1``: none).
        separation: ``(T,)`` float64 minimum robot-person separation of each step (m).
        contacts: ``(T,)`` int64 robot-person contact points of each step.
    """

    drill: torch.Tensor
    place: torch.Tensor
    separation: torch.Tensor
    contacts: torch.Tensor


def execution_steps(
    task: object, states: torch.Tensor, actions: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per step, the position drilled and the position placed (``-1`` for none), up to the
    step that drills the last screw.

    Args:
        task: a :class:`~torchhrc.tasks.place_and_drill.model.PlaceAndDrillTask`.
        states: ``(H + 1,)`` int64 bench states; actions: ``(H,)`` int64 robot actions
            (``0`` waits, ``1 + p`` drills ``p``).

    Returns:
        ``(drill (T,), place (T,))`` int64, ``T <= H``.

    Raises:
        ModelError: the shapes disagree or a transition is not one of the task's.
    """
    if states.dim() != 1 or actions.shape != (states.shape[0] - 1,):
        raise ModelError(
            f"expected states (H + 1,) and actions (H,), got {tuple(states.shape)} and "
            f"{tuple(actions.shape)}"
        )
    status = task.status  # type: ignore[attr-defined]  # (X, n)
    x, a = states[:-1], actions
    mid = task.robot_effect[a, x]  # type: ignore[attr-defined]  # (H,)
    drilled_now = (status[x] == PLACED) & (status[mid] == DRILLED)  # (H, n)
    placed_now = (status[mid] == EMPTY) & (status[states[1:]] == PLACED)
    if (drilled_now.sum(-1) > 1).any() or (placed_now.sum(-1) > 1).any():
        raise ModelError("a step drills or places more than one screw: not a task execution")
    none = torch.full_like(x, -1)
    drill = torch.where(drilled_now.any(-1), drilled_now.long().argmax(-1), none)
    place = torch.where(placed_now.any(-1), placed_now.long().argmax(-1), none)
    done = (status[states[1:]] == DRILLED).all(-1)  # (H,)
    last = int(torch.nonzero(done)[0]) + 1 if bool(done.any()) else len(done)
    return drill[:last], place[:last]


def replay_execution(
    scene: object,
    drill: torch.Tensor,
    place: torch.Tensor,
    *,
    phase_steps: tuple[int, int, int, int] = (40, 40, 25, 40),
    sample_every: int = 5,
) -> ExecutionReplay:
    """Replay the steps of :func:`execution_steps` in a
    :class:`~torchhrc.tasks.place_and_drill.workbench.PlaceAndDrillScene` (reset first) and
    measure them.

    Args:
        scene: the scene.
        drill, place: ``(T,)`` int64 positions per step (``-1``: none).
        phase_steps: physics steps of the reach, work, withdraw and return phases.
        sample_every: physics steps between separation samples.
    """
    scene.reset()  # type: ignore[attr-defined]
    s = scene
    seps, contacts = [], []
    reach, work, withdraw, back = phase_steps
    for p, q in zip(drill.tolist(), place.tolist(), strict=True):
        if p < 0 and q < 0:  # nobody moves: the separation of the resting poses
            seps.append(s.separation())  # type: ignore[attr-defined]
            contacts.append(0)
            continue
        rest = s.human_rest  # type: ignore[attr-defined]
        above = s.human_above[q] if q >= 0 else rest  # type: ignore[attr-defined]
        on = s.human_place[q] if q >= 0 else rest  # type: ignore[attr-defined]
        hover = s.robot_hover[p] if p >= 0 else None  # type: ignore[attr-defined]
        on_screw = s.robot_drill[p] if p >= 0 else None  # type: ignore[attr-defined]
        home = s.robot_home if p >= 0 else None  # type: ignore[attr-defined]
        phases = (
            (hover, (rest, above), reach),
            (on_screw, (above, on), work),
            (hover, (on, above), withdraw),
            (home, (above, rest), back),
        )
        low, touching = float("inf"), 0
        for robot, human, steps in phases:
            sep, c = s.move(robot, human, steps, sample_every=sample_every)  # type: ignore[attr-defined]
            low, touching = min(low, sep), touching + c
        seps.append(low)
        contacts.append(touching)
    return ExecutionReplay(
        drill=drill.clone(),
        place=place.clone(),
        separation=torch.tensor(seps, dtype=torch.float64),
        contacts=torch.tensor(contacts, dtype=torch.long),
    )
