"""Following or leading, alone and mixed with pace.

Stations are idle, prepared by the robot, or finished by the person (``3^P`` states). The
robot prepares stations; the person finishes them (a prepared station is quicker, but the
person may finish an idle one too). Types:

* ``leader``: finishes the stations in a fixed order (``A, B, ...``) whatever the robot
  does; the robot should prepare the leader's next station;
* ``follower``: finishes the station the robot prepared on the previous turn (a reaction
  one turn behind: history, one memory value), else the first station prepared earlier,
  and waits when there is none; the robot should keep preparing;
* ``lagging_*``: the same, but acts only every other turn (a phase bit of memory).

* :func:`lead_or_follow` (4 stations, 81 states, 2 types: ``leader``, ``follower``);
* :func:`lead_and_pace` (3 stations, 27 states, 4 types: ``leader``, ``lagging_leader``,
  ``follower``, ``lagging_follower``).

No observation of the human; behaviour depends on history.

Example:
    >>> lead_or_follow().task.num_states, lead_and_pace().type_names[1]
    (81, 'lagging_leader')
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["lead_and_pace", "lead_or_follow"]

IDLE, PREPPED, DONE = 0, 1, 2
NAMES = "ABCD"


def _spec(name: str, description: str, stations: int, types: tuple[str, ...]) -> TaskSpec:
    P = stations
    lag = any(t.startswith("lagging") for t in types)
    # memory: last prepared station + 1 (0: none), times the phase bit when someone lags
    M = (P + 1) * (2 if lag else 1)

    def split(m: int) -> tuple[int, int]:
        return m % (P + 1), m // (P + 1)

    def robot_step(s: tuple[int, ...], a: int) -> tuple[int, ...]:
        p = a - 1
        return s if p < 0 or s[p] != IDLE else (*s[:p], PREPPED, *s[p + 1 :])

    def human_step(s: tuple[int, ...], h: int) -> tuple[int, ...] | None:
        return (*s[:h], DONE, *s[h + 1 :]) if s[h] != DONE else None

    def leads(y: int) -> bool:
        return types[y].endswith("leader")

    def behaviour(y: int, m: int, s: tuple[int, ...], a: int) -> dict[int, float]:
        last, phase = split(m)
        if types[y].startswith("lagging") and phase == 1:
            return {-1: 1.0}  # resting this turn
        if leads(y):
            nxt = next((p for p in range(P) if s[p] != DONE), -1)
            return {nxt: 1.0}
        if last > 0 and s[last - 1] != DONE:
            return {last - 1: 1.0}
        just = a - 1 if a > 0 else -1  # prepared this turn: its turn comes next time
        older = [p for p in range(P) if s[p] == PREPPED and p != just]
        return {older[0]: 1.0} if older else {-1: 1.0}

    def memory(y: int, m: int, s: tuple[int, ...], a: int, h: int) -> int:
        last, phase = split(m)
        if a > 0 and s[a - 1] == PREPPED:
            last = a  # the robot just prepared station a - 1 (or it still waits)
        elif last > 0 and (s[last - 1] == DONE or h == last - 1):
            last = 0
        if last > 0 and h == last - 1:
            last = 0
        return last + (P + 1) * ((1 - phase) if lag else 0)

    def reward(y: int, s: tuple[int, ...], a: int) -> float:
        idle = [p for p in range(P) if s[p] == IDLE]
        if leads(y):
            nxt = next((p for p in range(P) if s[p] != DONE), -1)
            if a == 0:
                return 0.0 if nxt < 0 or s[nxt] == PREPPED else -0.2
            if s[a - 1] != IDLE:
                return -0.2
            return 1.0 if a - 1 == nxt else -0.5
        if a == 0:
            return -0.5 if idle else 0.0
        return 1.0 if s[a - 1] == IDLE else -0.2

    return TaskSpec(
        name=name,
        description=description,
        initial=(IDLE,) * P,
        robot_actions=("wait", *(f"prepare_{NAMES[p]}" for p in range(P))),
        human_actions=tuple(f"finish_{NAMES[p]}" for p in range(P)),
        robot_step=robot_step,
        human_step=human_step,
        terminal=lambda s: all(v == DONE for v in s),
        state_name=lambda s: "".join("-pf"[v] for v in s),
        type_names=types,
        behaviour=behaviour,
        reward=reward,
        horizon=4 * P,
        memory_size=M,
        memory_update=memory,
    )


def lead_or_follow() -> TaskWithPeople:
    """Leader or follower (81 states, 2 types, history-dependent)."""
    return build(_spec("lead_or_follow", "who leads: the person's order or the robot's",
                       4, ("leader", "follower")))  # fmt: skip


def lead_and_pace() -> TaskWithPeople:
    """Leading/following mixed with pace (27 states, 4 types, history-dependent)."""
    types = ("leader", "lagging_leader", "follower", "lagging_follower")
    return build(_spec("lead_and_pace", "who leads, and whether the person acts every turn",
                       3, types))  # fmt: skip
