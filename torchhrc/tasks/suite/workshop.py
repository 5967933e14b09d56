"""A five-type workshop: division of labour, hands-off and turn taking mixed (243 states).

Five parts ``A..E``, each to do, done by the person or done by the robot (``3^5 = 243``
states). Five types:

* ``left_worker``: does ``A, B``; the robot does ``C, D, E``;
* ``right_worker``: does ``E, D``; the robot does ``A, B, C``;
* ``middle_worker``: does ``C``; the robot does the rest;
* ``soloist``: does everything in order ``A..E`` and wants the robot hands-off;
* ``turn_taker``: does the first part left, but only on a turn where the robot has just
  done one (it waits while the robot waits): one for you, one for me.

The task gives compact reward features (12 instead of ``A * X = 1458``): doing part ``p``,
doing the first part left, waiting while part ``p`` is left, a useless move. Behaviour
depends on the state and on the robot's move. No observation of the human.

Example:
    >>> twp = workshop_five()
    >>> twp.task.num_states, twp.num_types, twp.task.features().shape
    (243, 5, torch.Size([6, 243, 12]))
"""

from __future__ import annotations

from torchhrc.tasks.people import TaskWithPeople
from torchhrc.tasks.suite.builder import TaskSpec, build

__all__ = ["workshop_five"]

OPEN, HUMAN, ROBOT = 0, 1, 2
PARTS = "ABCDE"
OWN = {
    "left_worker": (0, 1),
    "right_worker": (4, 3),
    "middle_worker": (2,),
    "soloist": (0, 1, 2, 3, 4),
    "turn_taker": (),
}
TYPES = tuple(OWN)


def _robot(s: tuple[int, ...], a: int) -> tuple[int, ...]:
    p = a - 1
    return s if p < 0 or s[p] != OPEN else (*s[:p], ROBOT, *s[p + 1 :])


def _human(s: tuple[int, ...], h: int) -> tuple[int, ...] | None:
    return (*s[:h], HUMAN, *s[h + 1 :]) if s[h] == OPEN else None


def _first(s: tuple[int, ...]) -> int:
    return next((p for p, v in enumerate(s) if v == OPEN), -1)


def _behaviour(y: int, m: int, s: tuple[int, ...], a: int) -> dict[int, float]:
    if TYPES[y] == "turn_taker":
        just = a > 0 and s[a - 1] == ROBOT  # the robot's move did a part (s: after it)
        return {_first(s): 1.0} if just else {-1: 1.0}
    nxt = next((p for p in OWN[TYPES[y]] if s[p] == OPEN), -1)
    return {nxt: 1.0}


def _features(s: tuple[int, ...], a: int) -> dict[str, float]:
    f = {f"do_{p}": 0.0 for p in PARTS}
    f.update(do_first=0.0, **{f"wait_while_{p}": 0.0 for p in PARTS}, useless=0.0)
    if a == 0:
        for p in range(len(PARTS)):
            f[f"wait_while_{PARTS[p]}"] = float(s[p] == OPEN)
    elif s[a - 1] != OPEN:
        f["useless"] = 1.0
    else:
        f[f"do_{PARTS[a - 1]}"] = 1.0
        f["do_first"] = float(a - 1 == _first(s))
    return f


def _weights(y: int) -> dict[str, float]:
    kind = TYPES[y]
    w = {"useless": -0.2, "do_first": 0.0}
    for p in range(len(PARTS)):
        robot_part = p not in OWN[kind] and kind != "soloist"
        w[f"do_{PARTS[p]}"] = 1.0 if robot_part else -1.0
        w[f"wait_while_{PARTS[p]}"] = -0.1 if robot_part else 0.0
    if kind == "turn_taker":
        w.update({f"do_{p}": 0.3 for p in PARTS}, do_first=0.7)
    return w


def _reward(y: int, s: tuple[int, ...], a: int) -> float:
    w = _weights(y)
    return sum(w[k] * v for k, v in _features(s, a).items())


def workshop_five() -> TaskWithPeople:
    """The five-type workshop (243 states, 5 types, state- and action-dependent)."""
    return build(
        TaskSpec(
            name="workshop_five",
            description="who does which part, whether the robot may help, and turn taking",
            initial=(OPEN,) * len(PARTS),
            robot_actions=("wait", *(f"do_{p}" for p in PARTS)),
            human_actions=tuple(f"do_{p}" for p in PARTS),
            robot_step=_robot,
            human_step=_human,
            terminal=lambda s: OPEN not in s,
            state_name=lambda s: "".join("-hr"[v] for v in s),
            type_names=TYPES,
            behaviour=_behaviour,
            reward=_reward,
            horizon=12,
            features=_features,
        )
    )
