"""Order preference: the robot fetches the part the person assembles next.

Four parts ``A..D``; the person assembles each once, in the order of their type; the robot
fetches parts to the bench (one at a time; a fetched part is used when the person assembles
it). The types differ only in their order, so the robot's best fetch differs by type in
almost every state:

* ``left_to_right``: ``A, B, C, D``;
* ``right_to_left``: ``D, C, B, A``;
* ``inside_out``: ``B, C, A, D``.

Behaviour depends on the state only (which parts are done). 48 states, 3 types, no
observation of the human.

Example:
    >>> twp = fetch_order()
    >>> twp.task.num_states, twp.num_types
    (48, 3)
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["fetch_order"]

PARTS = ("A", "B", "C", "D")
ORDERS = {
    "left_to_right": (0, 1, 2, 3),
    "right_to_left": (3, 2, 1, 0),
    "inside_out": (1, 2, 0, 3),
}
TYPES = tuple(ORDERS)

State = tuple[tuple[bool, ...], int]  # (done per part, fetched part or -1)


def _fetch(s: State, a: int) -> State:
    done, _ = s
    p = a - 1
    if p < 0 or done[p]:
        return s
    return done, p


def _assemble(s: State, h: int) -> State | None:
    done, fetched = s
    if done[h]:
        return None
    return (*done[:h], True, *done[h + 1 :]), -1 if fetched == h else fetched


def _next(y: int, s: State) -> int:
    return next((p for p in ORDERS[TYPES[y]] if not s[0][p]), -1)


def _behaviour(y: int, m: int, s: State, a: int) -> dict[int, float]:
    nxt = _next(y, s)
    return {-1: 1.0} if nxt < 0 else {nxt: 1.0}


def _reward(y: int, s: State, a: int) -> float:
    nxt = _next(y, s)
    if a == 0:
        return 0.2 if s[1] == nxt else 0.0  # nothing to do once the next part is ready
    if a - 1 == nxt and s[1] != nxt:
        return 1.0
    return -1.0


def fetch_order() -> TaskWithPeople:
    """The order-preference fetching task (48 states, 3 types, state-dependent)."""
    return build(
        TaskSpec(
            name="fetch_order",
            description="the order in which the person assembles the parts",
            initial=((False,) * 4, -1),
            robot_actions=("wait", *(f"fetch_{p}" for p in PARTS)),
            human_actions=tuple(f"assemble_{p}" for p in PARTS),
            robot_step=_fetch,
            human_step=_assemble,
            terminal=lambda s: all(s[0]),
            state_name=lambda s: (
                "".join(p if d else "-" for p, d in zip(PARTS, s[0]))
                + "|"
                + ("." if s[1] < 0 else PARTS[s[1]])
            ),
            type_names=TYPES,
            behaviour=_behaviour,
            reward=_reward,
            horizon=10,
        )
    )
