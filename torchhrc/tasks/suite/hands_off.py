"""Hands-off or waiting: three screws placed by the person and drilled by the robot.

The person places screws ``A, B, C`` (in that order) and the robot drills placed ones. The
three types differ in when they want the robot to act:

* ``hands_off``: places every screw first and wants the robot out of the workspace until
  then; a drill while a position is still empty makes them pull back for this turn and the
  next (history: one memory bit);
* ``eager``: places a screw every turn and wants each drilled right away;
* ``pairs``: places two screws, waits until both are drilled, then places the last one
  (the robot should drill once a pair is placed, not before).

While the robot waits, ``hands_off`` and ``eager`` act the same (they place the next
screw): from the person's actions alone the two cannot be told apart in those states, and
their best responses differ (wait vs drill), so a robot that never drills early keeps its
belief split. 27 states, 3 types, no observation of the human.

Example:
    >>> twp = screws_hands_off()
    >>> twp.task.num_states, twp.type_names
    (27, ('hands_off', 'eager', 'pairs'))
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["screws_hands_off"]

SCREWS = ("A", "B", "C")
EMPTY, PLACED, DRILLED = 0, 1, 2
TYPES = ("hands_off", "eager", "pairs")


def _drill(s: tuple[int, ...], a: int) -> tuple[int, ...]:
    p = a - 1
    if p < 0 or s[p] != PLACED:
        return s
    return (*s[:p], DRILLED, *s[p + 1 :])


def _place(s: tuple[int, ...], h: int) -> tuple[int, ...] | None:
    return (*s[:h], PLACED, *s[h + 1 :]) if s[h] == EMPTY else None


def _next_empty(s: tuple[int, ...]) -> int:
    return next((p for p, v in enumerate(s) if v == EMPTY), -1)


def _started(s: tuple[int, ...]) -> int:
    """Positions placed or drilled."""
    return sum(v != EMPTY for v in s)


def _drill_ok(y: int, s: tuple[int, ...]) -> bool:
    """Whether the type wants a placed screw drilled now."""
    if TYPES[y] == "hands_off":
        return EMPTY not in s
    if TYPES[y] == "pairs":
        return _started(s) >= 2 or EMPTY not in s
    return True


def _intrusion(s_mid: tuple[int, ...], a: int) -> bool:
    """The robot drilled (``a``) while a position is still empty."""
    return a > 0 and s_mid[a - 1] == DRILLED and EMPTY in s_mid


def _behaviour(y: int, m: int, s: tuple[int, ...], a: int) -> dict[int, float]:
    nxt = _next_empty(s)
    if nxt < 0:
        return {-1: 1.0}
    if TYPES[y] == "hands_off" and (m == 1 or _intrusion(s, a)):
        return {-1: 1.0}
    if TYPES[y] == "pairs" and _started(s) % 2 == 0 and PLACED in s:
        return {-1: 1.0}  # a pair is placed: wait until it is drilled
    return {nxt: 1.0}


def _memory(y: int, m: int, s: tuple[int, ...], a: int, h: int) -> int:
    # a fresh intrusion: pull back now and next turn; after a pulled-back turn: back to 0
    return int(TYPES[y] == "hands_off" and m == 0 and _intrusion(s, a))


def _reward(y: int, s: tuple[int, ...], a: int) -> float:
    if a == 0:
        return -0.5 if PLACED in s and _drill_ok(y, s) else 0.0
    if s[a - 1] != PLACED:
        return -0.2  # drilling nothing
    return 1.0 if _drill_ok(y, s) else -1.0


def screws_hands_off() -> TaskWithPeople:
    """The hands-off / eager / pairs screw task (27 states, 3 types, history-dependent)."""
    return build(
        TaskSpec(
            name="screws_hands_off",
            description="when the robot may act: after all is placed, at once, or turn by turn",
            initial=(EMPTY,) * 3,
            robot_actions=("wait", *(f"drill_{p}" for p in SCREWS)),
            human_actions=tuple(f"place_{p}" for p in SCREWS),
            robot_step=_drill,
            human_step=_place,
            terminal=lambda s: all(v == DRILLED for v in s),
            state_name=lambda s: "".join("-pd"[v] for v in s),
            type_names=TYPES,
            behaviour=_behaviour,
            reward=_reward,
            horizon=10,
            memory_size=2,
            memory_update=_memory,
        )
    )
