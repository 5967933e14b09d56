"""Pace: the robot hands parts over at the rate the person assembles them.

The person assembles ``8`` parts, one per turn when a part lies in the hand-over buffer
(capacity 2); the robot hands parts over. State: (assembled, buffer) (24 states). The types
differ in pace, which the state does not show (history: a phase bit of memory):

* ``steady``: assembles every turn; wants the buffer stocked (a hand-over at buffer 0 or 1);
* ``lagging``: assembles every other turn; wants one part at a time (no hand-over at
  buffer 1: clutter);
* ``slow_start``: lags for the first half (4 parts), then steady.

No observation of the human.

Example:
    >>> twp = pace()
    >>> twp.task.num_states, twp.type_names
    (24, ('steady', 'lagging', 'slow_start'))
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["pace"]

PARTS, CAPACITY, HALF = 8, 2, 4
TYPES = ("steady", "lagging", "slow_start")


def _hand_over(s: tuple[int, int], a: int) -> tuple[int, int]:
    done, buffer = s
    if a == 1 and buffer < CAPACITY and done + buffer < PARTS:
        return done, buffer + 1
    return s


def _assemble(s: tuple[int, int], h: int) -> tuple[int, int] | None:
    done, buffer = s
    return (done + 1, buffer - 1) if buffer > 0 else None


def _lags(y: int, s: tuple[int, int]) -> bool:
    return TYPES[y] == "lagging" or (TYPES[y] == "slow_start" and s[0] < HALF)


def _behaviour(y: int, m: int, s: tuple[int, int], a: int) -> dict[int, float]:
    if s[1] == 0 or (_lags(y, s) and m == 1):
        return {-1: 1.0}
    return {0: 1.0}


def _memory(y: int, m: int, s: tuple[int, int], a: int, h: int) -> int:
    if not _lags(y, s):
        return 0
    return 1 if h == 0 else 0  # rest the turn after assembling


def _reward(y: int, s: tuple[int, int], a: int) -> float:
    done, buffer = s
    can = buffer < CAPACITY and done + buffer < PARTS
    if a == 1:
        if not can:
            return -0.5
        if buffer == 0:
            return 1.0
        return -0.5 if _lags(y, s) else 0.5
    if buffer == 0 and done + buffer < PARTS:
        return -1.0  # the person has nothing to assemble
    return 0.2 if _lags(y, s) else 0.0


def pace() -> TaskWithPeople:
    """The pace task (24 states, 3 types, history-dependent)."""
    return build(
        TaskSpec(
            name="pace",
            description="how often the person assembles: every turn, every other, or slow start",
            initial=(0, 0),
            robot_actions=("wait", "hand_over"),
            human_actions=("assemble",),
            robot_step=_hand_over,
            human_step=_assemble,
            terminal=lambda s: s[0] == PARTS,
            state_name=lambda s: f"done{s[0]}|buffer{s[1]}",
            type_names=TYPES,
            behaviour=_behaviour,
            reward=_reward,
            horizon=24,
            memory_size=2,
            memory_update=_memory,
        )
    )
