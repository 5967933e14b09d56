"""A user's own task with simulated people, for tests/experiments/test_task_sweep.py (imported
by its path, as ``torchhrc sweep path/sweep_world.py:assembly`` imports it).

``assembly`` is a factory: no argument, returns a :class:`~torchhrc.tasks.people.TaskWithPeople`
built with the suite's builder. Three parts go into a fixture; an ``eager`` person places the
next part whatever the robot does (the robot should wait), a ``cautious`` one only while the
robot holds the fixture (the robot should hold). 4 states, 2 types.
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

TYPES = ("eager", "cautious")
WAIT, HOLD = 0, 1
PLACE = 0


def _behaviour(y: int, m: int, placed: int, a: int) -> dict[int, float]:
    if TYPES[y] == "eager" or a == HOLD:
        return {PLACE: 1.0}
    return {-1: 1.0}  # the cautious person waits for the robot to hold


def _reward(y: int, placed: int, a: int) -> float:
    if TYPES[y] == "eager":
        return 0.5 if a == WAIT else -0.5
    return 1.0 if a == HOLD else -0.2


def assembly() -> TaskWithPeople:
    """The assembly task (4 states, 2 types)."""
    return build(
        TaskSpec(
            name="assembly",
            description="whether the person needs the fixture held",
            initial=0,
            robot_actions=("wait", "hold"),
            human_actions=("place",),
            robot_step=lambda placed, a: placed,
            human_step=lambda placed, h: placed + 1 if placed < 3 else None,
            terminal=lambda placed: placed == 3,
            state_name=lambda placed: f"placed{placed}",
            type_names=TYPES,
            behaviour=_behaviour,
            reward=_reward,
            horizon=8,
        )
    )


def not_a_world():  # unannotated on purpose: the sweep must call it to know
    """Takes no seed, so it reads as a factory; returns a mapping, not a task."""
    return {"k": 1}


def needs_size(size: int) -> TaskWithPeople:
    """Neither a factory (it needs an argument) nor a metrics function (no seed)."""
    raise AssertionError("never called")
