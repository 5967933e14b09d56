"""A suite of generated collaborative tasks with simulated people of known types.

Each entry builds a :class:`~torchhrc.tasks.people.TaskWithPeople`: a
:class:`~torchhrc.tasks.CollaborativeTask`, its simulated people (true types with readable
names), the true reward of the robot's actions per type, an episode horizon, and seeded
demonstrations at a given size and noise. The types differ in structurally different ways
(order preference, division of labour, following or leading, hands-off or waiting, pace,
mixtures); across the suite there are 2 to 5 types, 21 to 243 states, behaviour that
depends on the state and behaviour that depends on history, with and without a noisy
observation of the human. What each task is: docs/task_suite.md.

=======================  ====  =====  ===========  ========  ==================================
name                     X     types  depends on   observed  types differ in
=======================  ====  =====  ===========  ========  ==================================
``screws_hands_off``     27    3      history      no        hands-off / eager / pairs
``fetch_order``          48    3      state        no        order preference
``division_of_labour``   81    3      state        no        who does which part
``kitting_observed``     64    4      state        yes       division x order
``lead_or_follow``       81    2      history      no        leading or following
``lead_and_pace``        27    4      history      no        leading/following x pace
``pace``                 24    3      history      no        pace (lagging)
``tool_handover``        21    2      state        yes       hands-off (fetch own tools)
``workshop_five``        243   5      state        no        division x hands-off x turns
=======================  ====  =====  ===========  ========  ==================================

Example:
    >>> from torchhrc.tasks.suite import make_task, suite_tasks
    >>> len(suite_tasks()) >= 8
    True
    >>> demos, types = make_task("pace").demonstrations(subjects=3, per_subject=2, seed=0)
    >>> demos.types[:2], types.tolist()
    (('steady', 'steady'), [0, 0, 1, 1, 2, 2])
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import SuiteTask, TaskSpec, build
from torchhrc.tasks.suite.division import division_of_labour, kitting_observed
from torchhrc.tasks.suite.hands_off import screws_hands_off
from torchhrc.tasks.suite.lead import lead_and_pace, lead_or_follow
from torchhrc.tasks.suite.order import fetch_order
from torchhrc.tasks.suite.pace import pace
from torchhrc.tasks.suite.tools import tool_handover
from torchhrc.tasks.suite.workshop import workshop_five

__all__ = [
    "SUITE",
    "SuiteTask",
    "TaskSpec",
    "build",
    "make_task",
    "suite_tasks",
]

#: Every suite task by name: ``SUITE[name]() -> TaskWithPeople``.
SUITE: dict[str, Callable[..., TaskWithPeople]] = {
    "screws_hands_off": screws_hands_off,
    "fetch_order": fetch_order,
    "division_of_labour": division_of_labour,
    "kitting_observed": kitting_observed,
    "lead_or_follow": lead_or_follow,
    "lead_and_pace": lead_and_pace,
    "pace": pace,
    "tool_handover": tool_handover,
    "workshop_five": workshop_five,
}


def make_task(name: str, **kwargs: Any) -> TaskWithPeople:
    """Build the suite task ``name`` (keyword arguments go to its builder).

    Raises:
        ValueError: an unknown name (the message lists the suite).

    Example:
        >>> make_task("fetch_order").type_names
        ('left_to_right', 'right_to_left', 'inside_out')
    """
    if name not in SUITE:
        raise ValueError(f"unknown suite task {name!r}; expected one of {', '.join(SUITE)}")
    return SUITE[name](**kwargs)


def suite_tasks() -> tuple[str, ...]:
    """The names of the suite's tasks, in a fixed order.

    Example:
        >>> suite_tasks()[0]
        'screws_hands_off'
    """
    return tuple(SUITE)
