"""Division of labour: who does which part (with and without a reach signal).

Each part is to do, done by the person or done by the robot (``3^P`` states, or ``2^P`` when
the state only tells whether a part is done). A person does their own parts, in the order of
their type, and leaves the rest to the robot (they wait once their own parts are done); the
robot should let the person start, then do the other parts and keep off the person's. (The
common first move matters: a mixture of Markov chains merges at no cost types whose
sequences share no symbol.)

* :func:`division_of_labour` (4 parts, 81 states, 3 types): ``left_half`` (the person does
  ``A, B``), ``right_half`` (``C, D``), ``outer`` (``A, D``). No observation of the human.
* :func:`kitting_observed` (6 parts, the state tells only which are done: 64 states, 4
  types): a mixture of division and order: ``left_in_order`` (the person does ``A, B, C``,
  the robot should do ``D, E, F``), ``left_mixed`` (the person ``C, A, B``, the robot
  ``F, E, D``), ``right_in_order`` (``D, E, F``; ``A, B, C``), ``right_mixed`` (``F, D, E``;
  ``C, B, A``). The robot sees where the person reaches next (right with probability 0.8).

Behaviour depends on the state only.

Example:
    >>> division_of_labour().task.num_states, kitting_observed().task.num_states
    (81, 64)
"""

from __future__ import annotations

from collections.abc import Sequence

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["division_of_labour", "kitting_observed"]

OPEN, HUMAN, ROBOT = 0, 1, 2
PARTS = ("A", "B", "C", "D", "E", "F")


def _spec(
    name: str,
    description: str,
    own: dict[str, Sequence[int]],
    robot_order: dict[str, Sequence[int]],
    *,
    parts: int,
    record_who: bool = True,
    intent_accuracy: float | None = None,
) -> TaskSpec:
    """``own[type]``: the person's parts in their order; ``robot_order[type]``: the order in
    which the type wants the robot's parts done; ``record_who``: the state tells who did a
    part (``3^parts`` states) or only that it is done (``2^parts``)."""
    types = tuple(own)
    P = parts
    by_robot = ROBOT if record_who else HUMAN

    def robot_step(s: tuple[int, ...], a: int) -> tuple[int, ...]:
        p = a - 1
        return s if p < 0 or s[p] != OPEN else (*s[:p], by_robot, *s[p + 1 :])

    def human_step(s: tuple[int, ...], h: int) -> tuple[int, ...] | None:
        return (*s[:h], HUMAN, *s[h + 1 :]) if s[h] == OPEN else None

    def behaviour(y: int, m: int, s: tuple[int, ...], a: int) -> dict[int, float]:
        nxt = next((p for p in own[types[y]] if s[p] == OPEN), -1)
        return {nxt: 1.0}

    def reward(y: int, s: tuple[int, ...], a: int) -> float:
        if all(v == OPEN for v in s):  # the person starts; the robot joins after
            return 0.5 if a == 0 else -0.5
        mine = [p for p in robot_order[types[y]] if s[p] == OPEN]
        if a == 0:
            return -0.3 if mine else 0.0
        p = a - 1
        if s[p] != OPEN:
            return -0.2  # nothing to do there
        if p not in robot_order[types[y]]:
            return -1.0  # the person's part
        return 1.0 if p == mine[0] else 0.3

    return TaskSpec(
        name=name,
        description=description,
        initial=(OPEN,) * P,
        robot_actions=("wait", *(f"do_{p}" for p in PARTS[:P])),
        human_actions=tuple(f"do_{p}" for p in PARTS[:P]),
        robot_step=robot_step,
        human_step=human_step,
        terminal=lambda s: OPEN not in s,
        state_name=lambda s: "".join(("-hr" if record_who else "-x")[v] for v in s),
        type_names=types,
        behaviour=behaviour,
        reward=reward,
        horizon=8,
        intent_accuracy=intent_accuracy,
    )


def division_of_labour() -> TaskWithPeople:
    """Which parts the person does (81 states, 3 types, state-dependent, unobserved)."""
    own = {"left_half": (0, 1), "right_half": (2, 3), "outer": (0, 3)}
    rest = {"left_half": (2, 3), "right_half": (0, 1), "outer": (1, 2)}
    return build(_spec("division_of_labour", "which parts the person does", own, rest, parts=4))


def kitting_observed() -> TaskWithPeople:
    """Division x order with a reach signal (64 states, 4 types, state-dependent, observed)."""
    own = {
        "left_in_order": (0, 1, 2),
        "left_mixed": (2, 0, 1),
        "right_in_order": (3, 4, 5),
        "right_mixed": (5, 3, 4),
    }
    rest = {
        "left_in_order": (3, 4, 5),
        "left_mixed": (5, 4, 3),
        "right_in_order": (0, 1, 2),
        "right_mixed": (2, 1, 0),
    }
    spec = _spec("kitting_observed", "which half the person does and in which order", own,
                 rest, parts=6, record_who=False, intent_accuracy=0.8)  # fmt: skip
    return build(spec)
