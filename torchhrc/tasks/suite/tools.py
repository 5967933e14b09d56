"""Hands-off with a reach signal: tools handed over, or fetched by the person.

Five jobs in a fixed order, each needing a tool (``drill, saw, glue, saw, drill``). The robot
may put a tool on the bench; the person does the job when its tool is there, and a person
of the ``self_server`` type fetches a missing tool themselves. State: (jobs done, tool on the
bench) (21 states). Types:

* ``receiver``: waits for the robot to hand the right tool;
* ``self_server``: wants the robot hands-off and fetches their own tools.

After each step the robot sees where the person reaches next (the next human action or
none), right with probability 0.75. Behaviour depends on the state only.

Example:
    >>> twp = tool_handover()
    >>> twp.task.num_states, twp.observed, twp.true_observation.shape
    (21, True, torch.Size([4, 21, 2, 3]))
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["tool_handover"]

TOOLS = ("drill", "saw", "glue")
JOBS = (0, 1, 2, 1, 0)  # the tool each job needs
TYPES = ("receiver", "self_server")
DO, FETCH = 0, 1


def _hand(s: tuple[int, int], a: int) -> tuple[int, int]:
    return s if a == 0 else (s[0], a - 1)


def _human(s: tuple[int, int], h: int) -> tuple[int, int] | None:
    done, tool = s
    need = JOBS[done]
    if h == DO:
        return (done + 1, -1) if tool == need else None
    return (done, need) if tool != need else None


def _behaviour(y: int, m: int, s: tuple[int, int], a: int) -> dict[int, float]:
    if s[1] == JOBS[s[0]]:
        return {DO: 1.0}
    return {FETCH: 1.0} if TYPES[y] == "self_server" else {-1: 1.0}


def _reward(y: int, s: tuple[int, int], a: int) -> float:
    need, tool = JOBS[s[0]], s[1]
    if TYPES[y] == "receiver":
        if a == 0:
            return 0.0 if tool == need else -0.5
        return 1.0 if a - 1 == need and tool != need else -1.0
    if a == 0:
        return 0.2
    return -0.3 if a - 1 == need else -1.0


def tool_handover() -> TaskWithPeople:
    """The tool hand-over task (21 states, 2 types, state-dependent, observed)."""
    return build(
        TaskSpec(
            name="tool_handover",
            description="whether the person waits for tools or fetches their own",
            initial=(0, -1),
            robot_actions=("wait", *(f"hand_{t}" for t in TOOLS)),
            human_actions=("do_job", "fetch_tool"),
            robot_step=_hand,
            human_step=_human,
            terminal=lambda s: s[0] == len(JOBS),
            state_name=lambda s: f"job{s[0]}|" + ("empty" if s[1] < 0 else TOOLS[s[1]]),
            type_names=TYPES,
            behaviour=_behaviour,
            reward=_reward,
            horizon=15,
            intent_accuracy=0.75,
        )
    )
