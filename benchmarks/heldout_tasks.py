"""Held-out collaborative tasks: our stand-in for the tasks issue 31's author runs and we never see.

None of these is in :mod:`torchhrc.tasks.suite`, none was used to tune anything, and each is
written as a user would write their own task: against the public API only
(:class:`~torchhrc.tasks.CollaborativeTask`, :class:`~torchhrc.tasks.TabularPeople`,
:class:`~torchhrc.tasks.TaskWithPeople`, ``TaskWithPeople.rollout``), through a small rule
tabulator of our own (:func:`tabulate`), not the suite's builder. They vary what the suite
holds fixed:

=====================  ===  =====  ============  ===============================================
name                   X    types  depends on    what is unusual
=====================  ===  =====  ============  ===============================================
``finish_late``        31   3      state         the types act alike for 4 of 6 stages and
                                                 differ only in the finishing stage
``twins``              22   2      state         two types identical except in one state
``sorting_moody``      112  3      state         a type with a stochastic preference (a random
                                                 remaining item); 6 robot and 5 human actions
``tool_rhythm``        27   4      history       the person's next tool follows their own
                                                 rhythm (memory), which the state does not show
``crew_70_20_10``      64   3      state         types of 70 / 20 / 10 % of the subjects
``five_parts``         243  5      state         5 types, 6 robot and 10 human actions
``slow_sanding``       9    2      state         two types alike but for the pace of one
                                                 sub-step (the careful one lingers there)
``paint_crews``        27   4      state         2 x 2 factorial types (order x who primes),
                                                 shares 40 / 30 / 20 / 10 %
``shelf_kitting``      97   3      state         a kitting step and one tool: order x who
                                                 kits; a robot move good for every type
                                                 (hand the tool) that no partner makes first
``station_glance``     81   3      state         observed: after each step the robot sees which
                                                 station the person turns to (L, R, neither;
                                                 right 80 %), coarser than her move
``lead_follow_phase``  31   3      state         one type leads (acts first, picks the halves),
                                                 one follows (waits for the robot), one leads
                                                 in stages 0-2 and follows after; 50 / 30 / 20 %
``pace_split``         189  4      state         2 x 2 types, who does which parts x pace (the
                                                 careful ones linger and want the robot still);
                                                 shares 40 / 30 / 20 / 10 %
``side_reactive``      40   3      robot's move  reactive types: one mirrors the robot's move of
                                                 the turn (side L or R; waits when it waits),
                                                 one takes the other side, one ignores it
``inspect_last``       256  2      state         observed (a 75 % glance at what the person
                                                 reaches for); 4 parts x place, fix, check; the
                                                 types differ only in who fixes the last part
``parcel_hands``       112  5      history       one-slot hand-over tray; 3 orders x handed,
                                                 hands-off, and a type alternating hands from a
                                                 random first hand (not in the state); shares
                                                 35 / 25 / 20 / 12 / 8 %
``arm_clearance``      25   3      state         observed, and sharper with the arm near her
                                                 (90 %, 60 % from home); hand over, set down
                                                 or keep clear of her side; 40 / 35 / 25 %
``glue_cure``          81   3      history       glue sets for two robot moves: one type joins
                                                 only joints the robot's last two moves did not
                                                 glue (memory); 40 / 35 / 25 %
``handover_timing``    37   4      history       when to hand over: as soon as ready, on cue
                                                 (she asks by pausing once: memory) or never;
                                                 a rare type turns from on cue to early for
                                                 the last two parts; 40 / 30 / 20 / 10 %
``panel_wiring``       27   2      state         wire three terminals, then fasten each: one
                                                 type wants the robot to fasten, one fastens
                                                 her own wires right away
``tool_slot``          48   4      state         one hand-over slot for the next tool; a type
                                                 that returns any tool handed (20 %) and a
                                                 rare one that cleans first; 40 / 30 / 20 / 10 %
``heavy_lifts``        20   3      history       heavy and light boxes; a fatigued type never
                                                 lifts two heavy ones in a row (memory)
``kit_batch``          81   3      state         parts fed one at a time or the whole kit at
                                                 once; two types differ only in how they take
                                                 the whole kit (one freezes a turn)
``check_timing``       244  3      state         when the robot should inspect the person's
                                                 work: after each part, at the end, or never
``fixture_height``     21   2      state         a fixture the robot raises or lowers; 85 % tall,
                                                 15 % short; each undoes a wrong adjustment
``harness_branch``     152  3      state         long (16+ robot turns, 8 stations): the types
                                                 differ only at the 3 branch stations in the
                                                 middle (tape, tie, or the robot holds it)
``dish_rack``          95   4      state         two types want the same robot moves (one
                                                 rinses each item first); a rare type hands
                                                 back whatever is handed; 45 / 30 / 15 / 10 %
``rivet_reach``        70   3      history       safety: one type wants the robot stopped while
                                                 her hand is in the shared fixture (flinches
                                                 out), one reaches in only when it pauses;
                                                 brackets per reach in memory; 45 / 35 / 20 %
``press_block``        91   3      state         the robot's own jobs take a shared press from
                                                 her: one type waits for it, one works around
                                                 (sands first), one always sands first;
                                                 40 / 35 / 25 %
``driver_pick``        21   3      state         two types differ only in which of two
                                                 equivalent drivers they want handed; a third
                                                 picks one at random and wants the robot to wait
``cabinet_glue``       208  5      history       3 sub-assemblies in 3 orders; two settlers
                                                 pause once (memory) while the frame's glue
                                                 sets and want the robot still then; shares
                                                 30 / 25 / 20 / 15 / 10 %
``defect_rework``      26   2      state         a random defect (a quarter of the parts): the
                                                 types differ only in handling a flagged part
                                                 (hold it to repair, or scrap it); 87 / 13 %
``shelf_build``        26   4      state         two types want the same robot moves and differ
                                                 only in pace throughout; one wants the driver,
                                                 one wants the robot still; 35 / 25 / 25 / 15 %
``leaky_tubes``        31   3      history       a type changes gloves only after a tube that
                                                 leaked (a pause, memory): same state, wants
                                                 gloves or the tube by history; 40 / 35 / 25 %
``tile_crack``         38   3      state         a random crack (a fifth of the tiles laid; a
                                                 quarter of the episodes see none): the types
                                                 differ only in recovering (remove it herself,
                                                 wait for the robot to, or skip it and go on);
                                                 40 / 35 / 25 %
``polish_passes``      37   3      state         a count on every panel: two polishing passes,
                                                 one, or one and a robot inspection (without
                                                 it she often polishes twice); 40 / 35 / 25 %
``bento_line``         247  4      state         large: 4 compartments x fill, garnish and a
                                                 one-slot tray (sauce or lid); two types alike
                                                 until the box is full (sauce, then lid, or the
                                                 lid alone); 30 / 25 / 25 / 20 %
``jar_slip``           42   3      state         the robot's own random mistake (a sixth of its
                                                 hand-overs slip): the types differ only in
                                                 taking it (pick the jar up, wait for the robot
                                                 to, or no more hand-overs); 40 / 35 / 25 %
``pad_sides``          25   3      state         which hand (pad) on some components only: all
                                                 right, the large ones left, or the last half
                                                 left; 45 / 35 / 20 %
``tote_pack``          145  5      state         5 types, two rare (9 % each): two orders, the
                                                 label first, fragile items fetched herself,
                                                 and a wish that changes with the items left
                                                 (the last two staged at once)
=====================  ===  =====  ============  ===============================================

``slow_sanding`` and ``paint_crews`` were added after the selection rule of 6701614 and
kept out of every later tuning (evaluated only as a final check). ``shelf_kitting`` was
written by the issue-31 audit from the docs alone (/work/helpers/AUDIT31.md): 30 x 4 seeds
0-9 k = 3 with ARI 1 (goal 2 holds), but with the default features the type-aware robot is
worse than the pooled one overall on seed 1 (goal 3: the hedge move leaves every type's
demonstrated path, where the learned reward is flat); keep it out of tuning too.
``station_glance``, ``lead_follow_phase`` and ``pace_split`` were written by the audit of
2026-12-05 (session 23) from the docs alone, to cover what the others lack (a noisy
observation of the human; leading against following; a larger crossed task with a rare
type), and kept out of tuning. ``side_reactive``, ``inspect_last`` and ``parcel_hands`` were
written by the audit of session 24 from the docs alone (reactive types; a large observed task
whose types differ late; five unequal types, one history-dependent),
and are kept out of tuning. ``arm_clearance``, ``glue_cure`` and ``handover_timing`` were
written by the audit of session 26 from the docs alone (a comfort zone, with a glance whose
accuracy depends on the state; the robot's previous move in the person's memory; the timing
of hand-overs, with a rare type that differs late), and are kept out of tuning too.
``panel_wiring``, ``tool_slot`` and ``heavy_lifts`` were written by the audit of session 27
from the docs alone. ``tool_slot`` (the type-aware robot behind the pooled one on 4 seeds:
the robot kept handing tools to the type that hands them back) led to the state model's
reaction (``torchhrc.tasks.interface._reaction``), so it is no longer held out;
``panel_wiring`` and ``heavy_lifts`` are. ``kit_batch``, ``check_timing`` and
``fixture_height`` were written by a second audit of session 27 from the docs alone, after
that change, and are kept out of tuning. ``harness_branch``, ``dish_rack`` and
``rivet_reach`` were written by the audit of session 29 from the docs alone (a long task
whose types differ only in the middle; two types with one best response beside a rare
type that hands items back; a safety stop while the person reaches into the shared space),
and are kept out of tuning.
``press_block``, ``driver_pick`` and ``cabinet_glue`` were written by the second audit of
session 29 from the docs alone (a robot move that blocks the person's station; types that
differ only in the object handed, beside an indecisive one; five unequal types with a
memory-driven pause), and are kept out of tuning.
``defect_rework``, ``shelf_build`` and ``leaky_tubes`` were written by the audit of session
30 from the docs alone (types that differ only where a chance event leads, with a rare one;
a pair that differs only in pace beside types with other wants; a want that depends on the
person's hidden history), and are kept out of tuning.
``tile_crack``, ``polish_passes`` and ``bento_line`` were written by the audit of session
32 from the docs alone (types that differ only in recovering from a random mistake; types
that differ in how many times they repeat a step; a larger task with four near-even types,
two of which differ only at the end). ``bento_line`` (7/10 at 30 x 4: the split of divided
types left people of its two late-differing types in the wrong half) led to the split's
settling by the person's own moves (``torchhrc.tasks.divided_types._settle``), so it is no
longer held out for the number of types; ``tile_crack`` and ``polish_passes`` are.
``jar_slip``, ``pad_sides`` and ``tote_pack`` were written by the audit of session 33 from
the docs alone (types that differ only in taking the robot's own random mistake, one of
them for the rest of the task; types that differ in which hand they use on some parts only;
a larger task with five types, two of them rare, one whose wish changes with how many items
are left), and are kept out of tuning.

``HELDOUT[name]() -> HeldoutWorld`` (a ``TaskWithPeople``), whose ``shares`` (None:
balanced) split the demonstrating subjects between the types and weigh them over the
population in ``evaluate_task``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable, Mapping, Sequence
from typing import Any

import torch

from torchhrc.tasks import CollaborativeTask, TabularPeople, TaskWithPeople

__all__ = ["HELDOUT", "HeldoutWorld", "tabulate"]


# ------------------------------------------------------------------------------ the tabulator
class RuleTask(CollaborativeTask):
    """A task given by tables (built by :func:`tabulate`)."""

    def __init__(self, name, state_names, robot_actions, human_actions, robot_effect,
                 human_effect, legal, terminal) -> None:  # fmt: skip
        self.name = name
        self.state_names = tuple(state_names)
        self.robot_actions = tuple(robot_actions)
        self.human_actions = tuple(human_actions)
        self.robot_effect = robot_effect  # (A, X)
        self.human_effect = human_effect  # (X, H)
        self._legal, self._terminal = legal, terminal

    @property
    def human_legal(self) -> torch.Tensor:
        return self._legal

    @property
    def terminal(self) -> torch.Tensor:
        return self._terminal


def tabulate(
    name: str,
    *,
    initial: Hashable,
    robot_actions: Sequence[str],
    human_actions: Sequence[str],
    robot_step: Callable[[Any, int], Any],
    human_step: Callable[[Any, int], Any],
    terminal: Callable[[Any], bool],
    type_names: Sequence[str],
    behaviour: Callable[[int, int, Any, int], Mapping[int, float]],
    reward: Callable[[int, Any, int], float],
    horizon: int,
    memory: int = 1,
    memory_update: Callable[[int, int, Any, int, int], int] | None = None,
    shares: tuple[float, ...] | None = None,
) -> HeldoutWorld:
    """Rules over Python states -> a TaskWithPeople. ``robot_actions[0]`` is "wait";
    ``human_step(s, h)`` is None where ``h`` cannot happen; ``behaviour(y, m, s_mid, a_r)``
    gives ``{a_h: p}`` (``-1``: no action); ``memory_update(y, m, s_mid, a_r, h)`` the
    person's memory after her action ``h`` (``-1``: none), read like ``behaviour`` in the
    state after the robot's move; ``reward(y, s, a_r)`` the true reward of robot action
    ``a_r`` in state ``s``, the state *before* the robot's move (as
    ``TaskWithPeople.true_reward[a_r, x, y]``)."""
    states, i = [initial], 0
    seen = {initial}
    while i < len(states):  # the states reachable from the initial one
        s, i = states[i], i + 1
        if terminal(s):
            continue
        for a in range(len(robot_actions)):
            mid = robot_step(s, a)
            for t in [mid, *(human_step(mid, h) for h in range(len(human_actions)))]:
                if t is not None and t not in seen:
                    seen.add(t)
                    states.append(t)
    index = {s: x for x, s in enumerate(states)}
    X, A, H, Y = len(states), len(robot_actions), len(human_actions), len(type_names)
    end = torch.tensor([bool(terminal(s)) for s in states])
    robot_effect = torch.tensor([[x if end[x] else index[robot_step(s, a)] for x, s in
                                  enumerate(states)] for a in range(A)])  # fmt: skip
    nxt = [[None if end[x] else human_step(s, h) for h in range(H)] for x, s in enumerate(states)]
    legal = torch.tensor([[t is not None and t != s for t in row] for row, s in zip(nxt, states)])
    human_effect = torch.tensor([[index[t] if ok else x for t, ok in zip(row, legal[x].tolist())]
                                 for x, row in enumerate(nxt)])  # fmt: skip
    policy = torch.zeros(Y, memory, X, A, H + 1, dtype=torch.float64)
    update = torch.zeros(Y, memory, X, A, H + 1, dtype=torch.long)
    true_reward = torch.zeros(A, X, Y, dtype=torch.float64)
    for x, s in enumerate(states):
        if end[x]:
            policy[..., x, :, H] = 1.0
            update[:, :, x] = torch.arange(memory).view(memory, 1, 1)
            continue
        for y in range(Y):
            for a in range(A):
                true_reward[a, x, y] = float(reward(y, s, a))
                for m in range(memory):
                    rule = behaviour(y, m, s, a)
                    total = sum(rule.values())
                    for h, p in rule.items():
                        policy[y, m, x, a, h] = p / total  # h = -1: the last column
                    for h in range(-1, H):
                        if h < 0 or legal[x, h]:
                            nm = 0 if memory_update is None else memory_update(y, m, s, a, h)
                            update[y, m, x, a, h] = nm
    task = RuleTask(name, [str(s) for s in states], robot_actions, human_actions, robot_effect,
                    human_effect, legal, end)  # fmt: skip
    people = TabularPeople(type_names, policy, legal, update=update)
    return HeldoutWorld(task, people, true_reward, horizon=horizon, observed=False, shares=shares)


#: What every held-out task returns: a TaskWithPeople, its ``shares`` (None: balanced) splitting
#: the demonstrating subjects between the types (``TaskWithPeople.demonstrations``) and
#: weighing them in ``evaluate_task``. (Until session 24 a subclass here held the shares.)
HeldoutWorld = TaskWithPeople


def _set(s: tuple, i: int, v: Any) -> tuple:
    """The tuple ``s`` with entry ``i`` replaced by ``v`` (a state of the tabulated tasks)."""
    return (*s[:i], v, *s[i + 1 :])


def _pick(best: int, a: int, good: float = 1.0, idle: float = 0.0, bad: float = -1.0) -> float:
    """+good for the wanted action, idle for waiting (action 0), bad for anything else."""
    return good if a == best else (idle if a == 0 else bad)


# ------------------------------------------------------------------------------ finish_late
# stages 0-3: the person fits a part while the robot holds the frame (everyone alike);
# stage 4: each type finishes in its own way (glue, screws or tape), wanting that item passed;
# stage 5: the person inspects alone. State: (stage, what the robot has out).
_ITEMS = ("none", "hold", "glue", "screws", "tape")


def finish_late() -> HeldoutWorld:
    types = ("glue", "screws", "tape")

    def robot_step(s, a):
        return s if a == 0 else (s[0], a)

    def human_step(s, h):
        stage = s[0]
        ok = (h == 0 and stage < 4) or (1 <= h <= 3 and stage == 4) or (h == 4 and stage == 5)
        return (stage + 1, 0) if ok else None

    def behaviour(y, m, s, a):
        stage = s[0]
        if stage < 4:
            return {0: 1.0} if s[1] == 1 else {0: 0.5, -1: 0.5}  # fits sooner when held
        return {1 + y: 1.0} if stage == 4 else {4: 1.0}

    def reward(y, s, a):
        stage, item = s
        if stage < 4:
            return 0.2 if (a == 0 and item == 1) else _pick(1, a)
        if stage == 4:
            return 0.2 if (a == 0 and item == 2 + y) else _pick(2 + y, a)
        return _pick(0, a, good=0.5, bad=-0.5)

    return tabulate(
        "finish_late", initial=(0, 0),
        robot_actions=("wait", "hold", "pass_glue", "pass_screws", "pass_tape"),
        human_actions=("fit", "glue", "screw", "tape", "inspect"),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s[0] == 6,
        type_names=types, behaviour=behaviour, reward=reward, horizon=14,
    )  # fmt: skip


# ------------------------------------------------------------------------------ twins
# five panels placed in order; a placed panel is bolted by the robot (bolt: all placed ones)
# or by the person. Both types want each panel bolted at once by the robot, except at one
# state, 3 placed and 2 bolted, where the "twin_self" person bolts the third panel herself
# (and wants the robot to wait). State: (placed, bolted).
def twins() -> HeldoutWorld:
    panels, odd = 5, (3, 2)

    def robot_step(s, a):
        return (s[0], s[0]) if a == 1 else s

    def human_step(s, h):
        placed, bolted = s
        if h == 0:
            return (placed + 1, bolted) if placed < panels else None
        if h == 1:
            return (placed, bolted + 1) if bolted < placed else None
        return ("done", "done") if placed == bolted == panels else None

    def behaviour(y, m, s, a):
        placed, bolted = s
        if s == odd and y == 1:
            return {1: 1.0}
        if placed == bolted == panels:
            return {2: 1.0}
        if placed - bolted >= 2:
            return {1: 1.0}  # too many loose panels: bolts one herself
        return {0: 1.0} if placed < panels else {-1: 1.0}

    def reward(y, s, a):
        placed, bolted = s
        if s == odd:
            return _pick(1, a, idle=-0.5) if y == 0 else _pick(0, a, good=0.5)
        return _pick(1, a) if bolted < placed else _pick(0, a, good=0.2, bad=-0.5)

    return tabulate(
        "twins", initial=(0, 0), robot_actions=("wait", "bolt"),
        human_actions=("place", "bolt_self", "finish"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == "done",
        type_names=("twin_robot", "twin_self"), behaviour=behaviour, reward=reward, horizon=16,
    )  # fmt: skip


# ------------------------------------------------------------------------------ sorting_moody
# five items A-E sorted into bins; the robot may present one item. "by_size" sorts A..E,
# "by_colour" C, E, A, D, B; "moody" sorts a presented item half the time, else a random
# remaining one, and dislikes being presented items. State: (sorted mask, presented or -1).
_SORT_ORDERS = {"by_size": (0, 1, 2, 3, 4), "by_colour": (2, 4, 0, 3, 1)}


def sorting_moody() -> HeldoutWorld:
    types = ("by_size", "by_colour", "moody")

    def robot_step(s, a):
        mask, _ = s
        return s if a == 0 or mask >> (a - 1) & 1 else (mask, a - 1)

    def human_step(s, h):
        mask, shown = s
        return None if mask >> h & 1 else (mask | 1 << h, -1 if shown == h else shown)

    def remaining(mask):
        return [i for i in range(5) if not mask >> i & 1]

    def nxt(y, mask):
        return next(i for i in _SORT_ORDERS[types[y]] if not mask >> i & 1)

    def behaviour(y, m, s, a):
        mask, shown = s
        if types[y] != "moody":
            return {nxt(y, mask): 1.0}
        rest = remaining(mask)
        out = {i: (0.5 if shown >= 0 else 1.0) / len(rest) for i in rest}
        if shown >= 0:
            out[shown] += 0.5
        return out

    def reward(y, s, a):
        mask, shown = s
        if types[y] == "moody":
            return _pick(0, a, good=0.3, bad=-0.3)
        want = nxt(y, mask)
        return 0.2 if (a == 0 and shown == want) else _pick(1 + want, a)

    return tabulate(
        "sorting_moody", initial=(0, -1),
        robot_actions=("wait", *(f"present_{c}" for c in "ABCDE")),
        human_actions=tuple(f"sort_{c}" for c in "ABCDE"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == 31, type_names=types,
        behaviour=behaviour, reward=reward, horizon=12,
    )  # fmt: skip


# ------------------------------------------------------------------------------ tool_rhythm
# eight operations, each with the drill or the saw; the robot lays a tool out. The person's
# next tool follows their own rhythm, kept in memory (a slip shifts it), not in the state:
# "alternate" drill, saw, drill, ...; "pairs" drill, drill, saw, saw, ...; "drills_first"
# four drills, then four saws; "follower" uses whatever tool lies out (else the drill).
# State: (operations done, tool out: 0 none, 1 drill, 2 saw).
def tool_rhythm() -> HeldoutWorld:
    types, ops = ("alternate", "pairs", "drills_first", "follower"), 8

    def phase_tool(y, m):  # 0 drill, 1 saw, from the memory m (a counter mod 4 or 8)
        return {0: m % 2, 1: (m // 2) % 2, 2: int(m >= 4), 3: 0}[y]

    def robot_step(s, a):
        return s if a == 0 or s[0] == ops else (s[0], a)

    def human_step(s, h):
        done, out = s
        return None if done == ops else (done + 1, 0 if out == h + 1 else out)

    def behaviour(y, m, s, a):
        if types[y] == "follower":
            return {s[1] - 1 if s[1] else 0: 1.0}
        return {phase_tool(y, m): 1.0}

    def memory_update(y, m, s, a, h):
        return m if h < 0 else (m + 1) % 8

    def reward(y, s, a):
        done, out = s
        if types[y] == "follower":
            return _pick(0, a, good=0.3, bad=-0.3)
        want = 1 + phase_tool(y, done % 8)  # the tool of the rhythm at this count
        return 0.2 if (a == 0 and out == want) else _pick(want, a)

    return tabulate(
        "tool_rhythm", initial=(0, 0), robot_actions=("wait", "lay_drill", "lay_saw"),
        human_actions=("drill", "saw"), robot_step=robot_step, human_step=human_step,
        terminal=lambda s: s[0] == ops, type_names=types, behaviour=behaviour, reward=reward,
        horizon=12, memory=8, memory_update=memory_update,
    )  # fmt: skip


# ------------------------------------------------------------------------------ crew_70_20_10
# three tools T1-T3 on the shelf; the person uses each once, in order. The robot can hand a
# tool to the right or the left hand (it lies on that side until used). "right_handed"
# (70 % of the subjects) wants each tool handed to the right; "left_handed" (20 %) to the
# left; "fetcher" (10 %) fetches their own tools and wants the robot to wait. State: per tool
# 0 shelf, 1 right, 2 left, 3 used.
def crew_70_20_10() -> HeldoutWorld:
    types = ("right_handed", "left_handed", "fetcher")

    def robot_step(s, a):
        if a == 0:
            return s
        t, side = (a - 1) // 2, 1 + (a - 1) % 2
        return s if s[t] != 0 else (*s[:t], side, *s[t + 1 :])

    def human_step(s, h):  # h < 3: use tool h (from a hand); h >= 3: fetch tool h - 3 and use it
        t = h % 3
        if s[t] == 3 or (h < 3) != (s[t] in (1, 2)):
            return None
        return (*s[:t], 3, *s[t + 1 :])

    def current(s):
        return next(t for t in range(3) if s[t] != 3)

    def behaviour(y, m, s, a):
        t = current(s)
        if s[t] in (1, 2):
            return {t: 1.0} if (s[t] == 1) == (y != 1) or y == 2 else {t: 0.5, -1: 0.5}
        return {3 + t: 1.0} if y == 2 else {-1: 1.0}  # waits for the robot, unless a fetcher

    def reward(y, s, a):
        t = current(s)
        if y == 2:
            return _pick(0, a, good=0.3, bad=-0.5)
        want = 1 + 2 * t + (0 if y == 0 else 1)
        return 0.2 if (a == 0 and s[t] == 1 + (y == 1)) else _pick(want, a)

    return tabulate(
        "crew_70_20_10", initial=(0, 0, 0),
        robot_actions=("wait", *(f"hand_T{t}_{side}" for t in (1, 2, 3)
                                 for side in ("right", "left"))),
        human_actions=(*(f"use_T{t}" for t in (1, 2, 3)), *(f"fetch_T{t}" for t in (1, 2, 3))),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s == (3, 3, 3),
        type_names=types, behaviour=behaviour, reward=reward, horizon=12, shares=(0.7, 0.2, 0.1),
    )  # fmt: skip


# ------------------------------------------------------------------------------ five_parts
# five parts, each mounted by the person and then fastened (by the robot or the person).
# "all_then_fasten": mounts all 1..5, wants them fastened after; "fasten_each": mount i, robot
# fastens i at once; "self": mounts and fastens every part herself; "reverse": mounts 5..1,
# robot fastens at once; "split": the robot fastens the even parts, she the odd ones.
# State: per part 0 loose, 1 mounted, 2 fastened (243 states).
def five_parts() -> HeldoutWorld:
    types = ("all_then_fasten", "fasten_each", "self", "reverse", "split")
    n = 5

    def robot_step(s, a):
        return _set(s, a - 1, 2) if a > 0 and s[a - 1] == 1 else s

    def human_step(s, h):
        i, op = h % n, h // n  # op 0 mount, 1 fasten
        return _set(s, i, 1 + op) if s[i] == op else None

    def plan(y, s):
        """(the person's next action or -1, the robot action the type wants)."""
        order = range(n - 1, -1, -1) if types[y] == "reverse" else range(n)
        mounted = [i for i in order if s[i] == 1]
        loose = [i for i in order if s[i] == 0]
        if types[y] == "all_then_fasten":
            return (loose[0], 0) if loose else (-1, 1 + mounted[0])
        if types[y] == "self":
            return (n + mounted[0] if mounted else loose[0], 0)
        mine = [i for i in mounted if types[y] == "split" and i % 2 == 0]  # parts 1, 3, 5
        if mine:
            return n + mine[0], 0
        if mounted:
            return -1, 1 + mounted[0]
        return loose[0], 0

    def behaviour(y, m, s, a):
        return {plan(y, s)[0]: 1.0}

    def reward(y, s, a):
        want = plan(y, s)[1]
        return _pick(want, a, good=0.2 if want == 0 else 1.0, idle=-0.2, bad=-0.5)

    return tabulate(
        "five_parts", initial=(0,) * n,
        robot_actions=("wait", *(f"fasten_{i + 1}" for i in range(n))),
        human_actions=(*(f"mount_{i + 1}" for i in range(n)),
                       *(f"fasten_{i + 1}" for i in range(n))),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s == (2,) * n,
        type_names=types, behaviour=behaviour, reward=reward, horizon=16,
    )  # fmt: skip


# ------------------------------------------------------------------------------ slow_sanding
# four steps (cut, sand, drill, finish), each done by the person; the robot holds the piece
# or waits. "brisk" does each step at once when the piece is held; "careful" does the same,
# except that at the sanding step she lingers (sands again, no progress) 2 turns in 3. Both
# want the piece held (the same true reward): only the pace differs. State: (step, held).
def slow_sanding() -> HeldoutWorld:
    types, steps = ("brisk", "careful"), 4

    def robot_step(s, a):
        return s if s[0] == steps else (s[0], int(a == 1))

    def human_step(s, h):
        return (s[0] + 1, 0) if h == s[0] < steps else None

    def behaviour(y, m, s, a):
        step, held = s
        if step == 1 and y == 1:
            return {1: 1.0 / 3.0, -1: 2.0 / 3.0}
        return {step: 1.0} if held else {step: 0.5, -1: 0.5}

    def reward(y, s, a):  # the same for both: only the pace differs
        return 0.2 if (a == 0 and s[1]) else _pick(1, a)

    return tabulate(
        "slow_sanding", initial=(0, 0), robot_actions=("wait", "hold"),
        human_actions=("cut", "sand", "drill", "finish"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == steps, type_names=types,
        behaviour=behaviour, reward=reward, horizon=14,
    )  # fmt: skip


# ------------------------------------------------------------------------------ paint_crews
# three boards, each primed and then painted. Types cross two choices: the order of the boards
# (1, 2, 3 or 3, 2, 1) and who primes (the robot, the person waiting for it, or the person
# herself, wanting the robot to wait); the person always paints. Shares 40 / 30 / 20 / 10 %.
# State: per board 0 raw, 1 primed, 2 painted (27 states).
def paint_crews() -> HeldoutWorld:
    types = ("up_robot", "up_self", "down_robot", "down_self")
    n = 3

    def robot_step(s, a):
        return _set(s, a - 1, 1) if a > 0 and s[a - 1] == 0 else s

    def human_step(s, h):
        i, op = h % n, h // n  # op 0 prime, 1 paint
        return _set(s, i, 1 + op) if s[i] == op else None

    def board(y, s):
        order = range(n) if y < 2 else range(n - 1, -1, -1)
        return next(i for i in order if s[i] != 2)

    def behaviour(y, m, s, a):
        i = board(y, s)
        if s[i] == 1:
            return {n + i: 1.0}
        return {i: 1.0} if y % 2 else {-1: 1.0}

    def reward(y, s, a):
        i = board(y, s)
        if s[i] == 0 and y % 2 == 0:
            return _pick(1 + i, a)
        return _pick(0, a, good=0.2, idle=0.0, bad=-0.5)

    return tabulate(
        "paint_crews", initial=(0,) * n,
        robot_actions=("wait", *(f"prime_{i + 1}" for i in range(n))),
        human_actions=(*(f"prime_{i + 1}" for i in range(n)),
                       *(f"paint_{i + 1}" for i in range(n))),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s == (2,) * n,
        type_names=types, behaviour=behaviour, reward=reward, horizon=14,
        shares=(0.4, 0.3, 0.2, 0.1),
    )  # fmt: skip


# ------------------------------------------------------------------------------ shelf_kitting
# four parts A-D, each in storage (0), kitted on the bench (1) or mounted (2), and one
# screwdriver on the rack or in the person's hand; mounting needs the part kitted and the
# tool in hand. "ab" and "dc" want the robot to kit, in the order A-D or D-A, and mount as
# the parts come (waiting when theirs is not on the bench); "self" kits everything first,
# then mounts A-D, and wants only the tool handed over. State: (parts, tool).
def shelf_kitting() -> HeldoutWorld:
    types = ("ab", "dc", "self")
    orders = ((0, 1, 2, 3), (3, 2, 1, 0), (0, 1, 2, 3))
    n = 4

    def robot_step(s, a):
        parts, tool = s
        if 1 <= a <= n and parts[a - 1] == 0:
            return (_set(parts, a - 1, 1), tool)
        return (parts, 1) if a == n + 1 else s

    def human_step(s, h):
        parts, tool = s
        if h < n:
            return (_set(parts, h, 1), tool) if parts[h] == 0 else None
        if h == n:
            return None if tool else (parts, 1)
        i = h - n - 1
        return (_set(parts, i, 2), tool) if parts[i] == 1 and tool else None

    def behaviour(y, m, s, a):
        parts, tool = s
        if y == 2 and 0 in parts:
            return {next(i for i in orders[y] if parts[i] == 0): 1.0}
        if not tool:
            return {n: 1.0}
        i = next(i for i in orders[y] if parts[i] != 2)
        return {n + 1 + i: 1.0} if parts[i] == 1 else {-1: 1.0}

    def reward(y, s, a):
        parts, tool = s
        if a == 0:
            return 0.0
        if a == n + 1:
            return (1.0 if y == 2 else 0.5) if not tool else -1.0
        if parts[a - 1] != 0 or y == 2:
            return -1.0
        return 1.0 if a - 1 == next(i for i in orders[y] if parts[i] == 0) else -0.5

    return tabulate(
        "shelf_kitting", initial=((0,) * n, 0),
        robot_actions=("wait", *(f"kit_{p}" for p in "ABCD"), "hand_tool"),
        human_actions=(*(f"kit_{p}" for p in "ABCD"), "get_tool",
                       *(f"mount_{p}" for p in "ABCD")),
        robot_step=robot_step, human_step=human_step,
        terminal=lambda s: s[0] == (2,) * n, type_names=types, behaviour=behaviour,
        reward=reward, horizon=12,
    )  # fmt: skip


# ------------------------------------------------------------------------------ station_glance
# two stations, L and R, four builds each. The robot brings a kit of parts to a station (at
# most one kit there); the person builds at a station from its kit, or fetches a kit herself
# and builds (one move). "left_first" builds at L four times, then at R; "alternate" builds
# at the station with fewer builds (L on ties); both wait for the robot's kit. "right_self"
# builds at R first, then L, fetching her own kits, and wants the robot to wait. After each
# step the robot sees which station the person turns to next (L, R or neither), right with
# probability 0.8: coarser than her move (a build and a fetch look alike).
# State: (builds at L, builds at R, kit at L, kit at R).
class GlanceTask(RuleTask):
    """A RuleTask whose robot sees where the person turns next (``zones (H + 1, O)``)."""

    zones: torch.Tensor
    accuracy: float

    def glance(self, intent: torch.Tensor, num_actions: int) -> torch.Tensor:
        """``(X, Y, H + 1)`` next-move weights -> ``Z (A, X, Y, O)``."""
        p = intent @ self.zones.to(intent)
        p = p / p.sum(-1, keepdim=True).clamp_min(1e-300)
        z = self.accuracy * p + (1.0 - self.accuracy) / p.shape[-1]
        return z.unsqueeze(0).expand(num_actions, *z.shape).contiguous()

    def observation(self, model):  # the learned people's next move, the robot waiting
        row = model.Tx[0]  # (X, Y, X')
        X, Y = row.shape[:2]
        after = torch.as_tensor(self.human_effect).to(row.device).unsqueeze(1).expand(X, Y, -1)
        p_h = row.gather(-1, after) * self.human_legal.to(row.device).unsqueeze(1)
        p_none = row.gather(-1, torch.arange(X, device=row.device).view(X, 1, 1).expand(X, Y, 1))
        return self.glance(torch.cat([p_h, p_none], -1), self.num_actions)


def station_glance() -> HeldoutWorld:
    types, n = ("left_first", "alternate", "right_self"), 4

    def robot_step(s, a):
        side = a - 1
        if a == 0 or s[side] == n or s[2 + side]:
            return s
        return (*s[:2], *(1 if i == side else k for i, k in enumerate(s[2:])))

    def human_step(s, h):
        side, fetch = h % 2, h >= 2
        if s[side] == n or s[2 + side] == int(fetch):  # a build needs a kit, a fetch none
            return None
        done = tuple(d + (i == side) for i, d in enumerate(s[:2]))
        return (*done, *(0 if i == side else k for i, k in enumerate(s[2:])))

    def station(y, s):
        left, right = s[:2]
        if y == 0:
            return 0 if left < n else 1
        if y == 1:
            return 0 if (left <= right and left < n) or right == n else 1
        return 1 if right < n else 0

    def behaviour(y, m, s, a):
        st = station(y, s)
        if s[2 + st]:
            return {st: 1.0}
        return {2 + st: 1.0} if y == 2 else {-1: 1.0}

    def reward(y, s, a):
        st = station(y, s)
        if y == 2 or s[2 + st]:
            return _pick(0, a, good=0.3 if y == 2 else 0.2, bad=-0.5)
        return _pick(1 + st, a, idle=-0.5, bad=-0.5)

    world = tabulate(
        "station_glance", initial=(0, 0, 0, 0), robot_actions=("wait", "kit_L", "kit_R"),
        human_actions=("build_L", "build_R", "fetch_build_L", "fetch_build_R"),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s[:2] == (n, n),
        type_names=types, behaviour=behaviour, reward=reward, horizon=14,
    )  # fmt: skip
    t = world.task
    task = GlanceTask(t.name, t.state_names, t.robot_actions, t.human_actions, t.robot_effect,
                      t.human_effect, t.human_legal, t.terminal)  # fmt: skip
    task.zones = torch.tensor([[1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                              dtype=torch.float64)  # fmt: skip
    task.accuracy = 0.8
    intent = world.people.policy[:, 0, :, 0, :].permute(1, 0, 2)  # (X, Y, H + 1), robot waits
    return dataclasses.replace(world, task=task, observed=True,
                               true_observation=task.glance(intent, t.num_actions))  # fmt: skip


# ------------------------------------------------------------------------------ lead_follow_phase
# six stages, each with a left and a right half: one half is the person's, the other the
# robot's, and whoever moves first picks. "leader" starts every stage before the robot (the
# left half in even stages, the right one in odd stages) and wants the robot to wait, then
# take the other half; "follower" waits until the robot has taken a half (the left one, she
# prefers), then does the other; "phased" leads in stages 0-2 and follows in stages 3-5.
# No memory. Shares 50 / 30 / 20 %. State: (stage, left, right), a half 0 open, 1 done by
# the person, 2 by the robot; a stage with both halves done closes.
def lead_follow_phase() -> HeldoutWorld:
    types, stages = ("leader", "follower", "phased"), 6

    def close(s):
        return (s[0] + 1, 0, 0) if s[1] and s[2] else s

    def robot_step(s, a):
        return s if a == 0 or s[a] else close(tuple(2 if i == a else v for i, v in enumerate(s)))

    def human_step(s, h):
        if s[0] == stages or s[1 + h]:
            return None
        return close(tuple(1 if i == 1 + h else v for i, v in enumerate(s)))

    def leads(y, stage):
        return y == 0 or (y == 2 and stage < 3)

    def behaviour(y, m, s, a):
        stage, left, right = s
        if left == right == 0:
            return {stage % 2: 1.0} if leads(y, stage) else {-1: 1.0}
        if 1 in (left, right):
            return {-1: 1.0}  # her half is done; the other is the robot's
        return {0 if left == 0 else 1: 1.0}

    def reward(y, s, a):
        stage, left, right = s
        if left == right == 0:
            if leads(y, stage):
                return _pick(0, a, good=0.2, bad=-0.5)
            return _pick(1, a, idle=-0.3, bad=0.5)
        if 1 in (left, right):
            return _pick(1 if left == 0 else 2, a, idle=-0.3)
        return _pick(0, a, good=0.2, bad=-0.5)

    return tabulate(
        "lead_follow_phase", initial=(0, 0, 0), robot_actions=("wait", "take_left", "take_right"),
        human_actions=("do_left", "do_right"), robot_step=robot_step, human_step=human_step,
        terminal=lambda s: s[0] == stages, type_names=types, behaviour=behaviour,
        reward=reward, horizon=12, shares=(0.5, 0.3, 0.2),
    )  # fmt: skip


# ------------------------------------------------------------------------------ pace_split
# four parts A-D; the robot does a part in one move, the person in two (start it, then finish
# it; one part at a time). The types cross who does what (the person does A, B or C, D; the
# robot should do the other two, and never hers) with pace: a "brisk" person finishes a
# started part at once and wants the robot to work meanwhile; a "careful" one lingers on it
# 2 turns in 3 and wants the robot still while she works. Shares 40 / 30 / 20 / 10 %.
# State: per part 0 open, 1 started, 2 done by the person, 3 done by the robot.
def pace_split() -> HeldoutWorld:
    types = ("left_brisk", "right_brisk", "left_careful", "right_careful")
    n = 4

    def robot_step(s, a):
        return _set(s, a - 1, 3) if a > 0 and s[a - 1] == 0 else s

    def human_step(s, h):
        if h < n:
            return _set(s, h, 1) if s[h] == 0 and 1 not in s else None
        return _set(s, h - n, 2) if s[h - n] == 1 else None

    def own(y):
        return (0, 1) if y % 2 == 0 else (2, 3)

    def behaviour(y, m, s, a):
        if 1 in s:
            finish = n + s.index(1)
            return {finish: 1.0 / 3.0, -1: 2.0 / 3.0} if y >= 2 else {finish: 1.0}
        mine = [p for p in own(y) if s[p] == 0]
        return {mine[0]: 1.0} if mine else {-1: 1.0}

    def reward(y, s, a):
        robots = [p for p in range(n) if p not in own(y) and s[p] == 0]
        if (1 in s and y >= 2) or not robots:
            return _pick(0, a, good=0.3, bad=-0.5)
        if a == 0:
            return -0.3
        return 1.0 if a - 1 in robots else -1.0

    return tabulate(
        "pace_split", initial=(0,) * n, robot_actions=("wait", *(f"do_{p}" for p in "ABCD")),
        human_actions=(*(f"start_{p}" for p in "ABCD"), *(f"finish_{p}" for p in "ABCD")),
        robot_step=robot_step, human_step=human_step,
        terminal=lambda s: all(v >= 2 for v in s), type_names=types, behaviour=behaviour,
        reward=reward, horizon=16, shares=(0.4, 0.3, 0.2, 0.1),
    )  # fmt: skip


# ------------------------------------------------------------------------------ side_reactive
# a fixture with a left and a right side, three parts each; the robot or the person mounts
# the next part of a side; the fixture stays turned to the side the robot last worked on
# (jig: 0 none yet, 1 L, 2 R). The types react to the robot's move of the turn: "mirror"
# mounts on the side the robot just worked on (and waits when the robot waits), wanting the
# robot to lead the left side, then the right; "complement" mounts on the other side (when
# the robot waits: the side opposite the jig; waits at the start), wanting the robot to
# start left and stay on its side; "ignorer" mounts L, L, L, R, R, R whatever the robot does,
# wanting the robot on the other side (and to wait when only hers is left).
# State: (left mounted, right mounted, jig): 48 combinations, 40 reachable. (Audit of session 24.)
def side_reactive() -> HeldoutWorld:
    types, n = ("mirror", "complement", "ignorer"), 3

    def robot_step(s, a):
        if a == 0 or s[a - 1] == n:
            return s
        return (*(c + (i == a - 1) for i, c in enumerate(s[:2])), a)

    def human_step(s, h):
        return None if s[h] == n else (*(c + (i == h) for i, c in enumerate(s[:2])), s[2])

    def side_or_other(s, side):
        if s[side] < n:
            return {side: 1.0}
        return {1 - side: 1.0} if s[1 - side] < n else {-1: 1.0}

    def behaviour(y, m, s, a):
        if y == 0:
            return {-1: 1.0} if a == 0 else side_or_other(s, a - 1)
        if y == 1:
            if a == 0:
                return {-1: 1.0} if s[2] == 0 else side_or_other(s, 2 - s[2])
            return side_or_other(s, 2 - a)
        return side_or_other(s, 0)

    def reward(y, s, a):
        if a > 0 and s[a - 1] == n:
            return -1.0  # a side that is full: a wasted move
        if y == 0:
            return _pick(1 if s[0] < n else 2, a, idle=-0.5, bad=-0.5)
        if y == 1:
            jig = s[2]
            best = 1 if jig == 0 else (jig if s[jig - 1] < n else 3 - jig)
            return _pick(best, a, idle=-0.3, bad=-1.0)
        other = 1 if s[0] < n else 0  # the side she is not on
        if s[other] < n:
            return _pick(1 + other, a, idle=-0.3, bad=-1.0)
        return _pick(0, a, good=0.3, bad=-1.0)

    return tabulate(
        "side_reactive", initial=(0, 0, 0), robot_actions=("wait", "mount_L", "mount_R"),
        human_actions=("mount_L", "mount_R"), robot_step=robot_step, human_step=human_step,
        terminal=lambda s: s[:2] == (n, n), type_names=types, behaviour=behaviour,
        reward=reward, horizon=10,
    )  # fmt: skip


# ------------------------------------------------------------------------------ inspect_last
# four parts, each placed by the person, fixed (by the robot or the person) and then checked
# by the person, one part at a time in the order 1-4 (any order is possible: 4^4 = 256
# states). Both types place, wait for the robot to fix and check parts 1-3 alike;
# "robot_fixes" does part 4 the same way, "self_last" fixes part 4 herself and wants the
# robot to keep still for it. After each step the robot glances at what the person reaches
# for next (parts tray, driver, gauge, nothing), right 75 % of the time.
# State: per part 0 loose, 1 placed, 2 fixed, 3 checked. (Audit of session 24.)
def inspect_last() -> HeldoutWorld:
    types, n = ("robot_fixes", "self_last"), 4

    def robot_step(s, a):
        return s if a == 0 or s[a - 1] != 1 else (*s[: a - 1], 2, *s[a:])

    def human_step(s, h):
        i, op = h % n, h // n  # op 0 place, 1 fix, 2 check
        return (*s[:i], op + 1, *s[i + 1 :]) if s[i] == op else None

    def current(s):
        return next(i for i in range(n) if s[i] != 3)

    def behaviour(y, m, s, a):
        i = current(s)
        if s[i] == 0:
            return {i: 1.0}
        if s[i] == 1:
            return {n + i: 1.0} if (y == 1 and i == n - 1) else {-1: 1.0}
        return {2 * n + i: 1.0}

    def reward(y, s, a):
        i = current(s)
        if y == 1 and i == n - 1:
            return _pick(0, a, good=0.3, bad=-1.0)
        if s[i] == 1:
            return _pick(1 + i, a, idle=-0.3, bad=-0.5)
        return _pick(0, a, good=0.2, bad=-0.5)

    world = tabulate(
        "inspect_last", initial=(0,) * n,
        robot_actions=("wait", *(f"fix_{i + 1}" for i in range(n))),
        human_actions=(*(f"place_{i + 1}" for i in range(n)), *(f"fix_{i + 1}" for i in range(n)),
                       *(f"check_{i + 1}" for i in range(n))),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s == (3,) * n,
        type_names=types, behaviour=behaviour, reward=reward, horizon=14,
    )  # fmt: skip
    t = world.task
    task = GlanceTask(t.name, t.state_names, t.robot_actions, t.human_actions, t.robot_effect,
                      t.human_effect, t.human_legal, t.terminal)  # fmt: skip
    zones = torch.zeros(3 * n + 1, 4, dtype=torch.float64)
    for h in range(3 * n):
        zones[h, h // n] = 1.0
    zones[3 * n, 3] = 1.0
    task.zones, task.accuracy = zones, 0.75
    intent = world.people.policy[:, 0, :, 0, :].permute(1, 0, 2)  # (X, Y, H + 1), robot waits
    return dataclasses.replace(world, task=task, observed=True,
                               true_observation=task.glance(intent, t.num_actions))  # fmt: skip


# ------------------------------------------------------------------------------ parcel_hands
# five items A-E packed into a box; the robot can put one item on the hand-over tray (one at
# a time); the person packs an item from the tray or fetches it from the shelf (one move).
# "in_order" (35 %) packs A-E, "reverse" (25 %) E-A and "heavy_first" (12 %) C, E, A, D, B,
# each wanting their next item handed (they take it from the tray; when it is not there,
# they fetch it half the time and wait for it otherwise); "hands_off" (20 %) packs A-E from
# the shelf whatever the robot does and wants the robot to wait; "two_hands" (8 %) alternates
# hands, which the state does not show: the right hand takes whatever lies on the tray
# (waiting for it when the tray is empty), the left one fetches the first unpacked item in
# A-E order; the first hand is random per episode. She wants the robot to hand from the back
# (the last unpacked item), so the hands do not collide. State: (packed mask, item on the
# tray or -1), 112 states. (Audit of session 24.)
def parcel_hands() -> HeldoutWorld:
    types = ("in_order", "reverse", "hands_off", "heavy_first", "two_hands")
    orders = ((0, 1, 2, 3, 4), (4, 3, 2, 1, 0), (0, 1, 2, 3, 4), (2, 4, 0, 3, 1), None)
    n = 5

    def left(mask):
        return [i for i in range(n) if not mask >> i & 1]

    def robot_step(s, a):
        mask, tray = s
        return s if a == 0 or tray >= 0 or mask >> (a - 1) & 1 else (mask, a - 1)

    def human_step(s, h):
        mask, tray = s
        return None if mask >> h & 1 else (mask | 1 << h, -1 if tray == h else tray)

    def nxt(y, mask):
        return next(i for i in orders[y] if not mask >> i & 1)

    def behaviour(y, m, s, a):
        mask, tray = s
        if y == 4:
            if m == 0:  # right hand: the tray
                return {tray: 1.0} if tray >= 0 else {-1: 1.0}
            return {next(i for i in left(mask) if i != tray): 1.0} if left(mask) != [tray] \
                else {tray: 1.0}  # fmt: skip
        i = nxt(y, mask)
        if y == 2 or tray == i:
            return {i: 1.0}
        return {i: 0.5, -1: 0.5}

    def memory_update(y, m, s, a, h):
        return m if (y != 4 or h < 0) else 1 - m

    def reward(y, s, a):
        mask, tray = s
        if a > 0 and (tray >= 0 or mask >> (a - 1) & 1):
            return -0.5  # the tray is taken or the item packed: a wasted move
        if y == 2:
            return _pick(0, a, good=0.3, bad=-0.5)
        if y == 4:
            return _pick(1 + left(mask)[-1], a, idle=-0.2, bad=0.1) if tray < 0 else \
                _pick(0, a, good=0.2)  # fmt: skip
        want = nxt(y, mask)
        if tray == want:
            return _pick(0, a, good=0.2)
        return _pick(1 + want, a, idle=-0.3, bad=-0.5)

    world = tabulate(
        "parcel_hands", initial=(0, -1),
        robot_actions=("wait", *(f"hand_{c}" for c in "ABCDE")),
        human_actions=tuple(f"pack_{c}" for c in "ABCDE"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == 2**n - 1, type_names=types,
        behaviour=behaviour, reward=reward, horizon=12, memory=2,
        memory_update=memory_update, shares=(0.35, 0.25, 0.20, 0.12, 0.08),
    )  # fmt: skip
    p = world.people
    initial = torch.tensor([[1.0, 0.0]] * 4 + [[0.5, 0.5]], dtype=torch.float64)
    people = TabularPeople(p.type_names, p.policy, p.legal, update=p.update, initial=initial)
    return dataclasses.replace(world, people=people)


# ------------------------------------------------------------------------------ arm_clearance
# a shared bench: the person assembles six parts, each from the robot or from her own bin.
# The robot can hand a part into her hand (its arm comes near and stays there), set one down
# on the bench from its home position, or retreat home. "hand_to_hand" (40 %) wants each
# part handed and does not mind the arm near; "keep_clear" (35 %) fetches from her bin and
# stops working whenever the arm is near her (she wants it home and still); "set_down"
# (25 %) wants her parts set down from a distance (from the arm near her she takes one
# half the time, and does nothing else while it is there).
# When waiting for a part, hand_to_hand and set_down fetch their own a quarter of the time.
# After each step the robot glances at where the person reaches next (bench, bin, nothing):
# right 90 % of the time with the arm near her, 60 % from home (the wrist camera), so the
# sharp view costs keep_clear and set_down their comfort.
# State: (parts done, arm 0 home / 1 near, a part handed or set down and not yet used),
# 25 states. (Audit of session 26.)
class ReachGlanceTask(GlanceTask):
    """A GlanceTask whose glance is right with a probability that depends on the state
    ``x'`` after the step: ``accuracy (X,)``."""

    def glance(self, intent: torch.Tensor, num_actions: int) -> torch.Tensor:
        p = intent @ self.zones.to(intent)
        p = p / p.sum(-1, keepdim=True).clamp_min(1e-300)
        acc = torch.as_tensor(self.accuracy).to(intent).view(-1, 1, 1)  # (X, 1, 1)
        z = acc * p + (1.0 - acc) / p.shape[-1]
        return z.unsqueeze(0).expand(num_actions, *z.shape).contiguous()


def arm_clearance() -> HeldoutWorld:
    types, n = ("hand_to_hand", "keep_clear", "set_down"), 6

    def robot_step(s, a):
        done, _, bench = s
        if a == 3:
            return (done, 0, bench)  # retreat
        if a in (1, 2) and not bench and done < n:
            return (done, int(a == 1), 1)  # hand (arm near) or set down (arm home)
        return s

    def human_step(s, h):
        done, arm, bench = s
        if done == n or bench != (h == 0):  # assemble needs a part on the bench, a fetch none
            return None
        return (done + 1, arm, 0)

    def behaviour(y, m, s, a):
        _, arm, bench = s
        if y == 0:
            if bench:
                return {0: 1.0} if arm else {0: 0.5, -1: 0.5}  # reaches over, slower
            return {-1: 1.0} if arm else {1: 0.25, -1: 0.75}
        if arm:  # keep_clear stops while the arm is near; set_down takes a part held out
            return {0: 0.5, -1: 0.5} if (y == 2 and bench) else {-1: 1.0}  # half the time
        if bench:
            return {0: 1.0}
        return {1: 1.0} if y == 1 else {1: 0.25, -1: 0.75}

    def reward(y, s, a):
        _, arm, bench = s
        if (a == 3 and not arm) or (a in (1, 2) and bench):
            return -0.5  # retreating from home, or a part when one lies there: wasted
        if y == 0:
            if bench:
                return _pick(0, a, good=0.2, bad=-0.5)
            return {0: -0.3, 1: 1.0, 2: 0.0, 3: -0.5}[a]
        if arm:
            return {0: -0.5, 1: -1.0, 2: 1.0 if y == 2 else -0.5, 3: 0.5}[a]  # set_down: home
        if y == 1:
            return _pick(0, a, good=0.3, bad=-1.0)
        return _pick(2 if not bench else 0, a, good=1.0 if not bench else 0.2, idle=-0.3,
                     bad=-1.0)  # fmt: skip

    world = tabulate(
        "arm_clearance", initial=(0, 0, 0),
        robot_actions=("wait", "hand", "set_down", "retreat"),
        human_actions=("assemble", "fetch_assemble"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == n, type_names=types,
        behaviour=behaviour, reward=reward, horizon=12, shares=(0.4, 0.35, 0.25),
    )  # fmt: skip
    t = world.task
    task = ReachGlanceTask(t.name, t.state_names, t.robot_actions, t.human_actions,
                           t.robot_effect, t.human_effect, t.human_legal, t.terminal)  # fmt: skip
    task.zones = torch.tensor([[1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64)
    near = torch.tensor([name.split(", ")[1] == "1" for name in t.state_names])
    task.accuracy = torch.where(near, 0.9, 0.6).to(torch.float64)
    intent = world.people.policy[:, 0, :, 0, :].permute(1, 0, 2)  # (X, Y, H + 1), robot waits
    return dataclasses.replace(world, task=task, observed=True,
                               true_observation=task.glance(intent, t.num_actions))  # fmt: skip


# ------------------------------------------------------------------------------ glue_cure
# four joints, each open (0), glued by the robot (1) or joined by the person (2); the robot
# glues any open joint (a fresh coat on a glued one wets it again). "quick" (40 %) joins the
# glued joint at once (7 times in 10; else the next turn) and wants one joint glued at a
# time (glue ahead skins over: the robot should wait while one is waiting); "patient" (35 %)
# joins a glued joint only once the glue has set, when neither the robot's move of this
# turn nor that of the turn before glued it (memory: the robot's previous move), and wants
# the robot to glue ahead, A-D; "pairs" (25 %) joins the joints of a pair (A-B, C-D) only
# once both are glued, and wants the pair glued, then the robot still while she joins.
# State: per joint 0 open, 1 glued, 2 joined (81 states). (Audit of session 26.)
def glue_cure() -> HeldoutWorld:
    types, n = ("quick", "patient", "pairs"), 4

    def robot_step(s, a):
        return _set(s, a - 1, 1) if a > 0 and s[a - 1] == 0 else s

    def human_step(s, h):
        return _set(s, h, 2) if s[h] == 1 else None

    def behaviour(y, m, s, a):
        glued = [j for j in range(n) if s[j] == 1]
        if y == 0:
            return {glued[0]: 0.7, -1: 0.3} if glued else {-1: 1.0}
        if y == 1:
            wet = {a - 1, m - 1}  # glued by this turn's move or by the previous one
            ready = [j for j in glued if j not in wet]
        else:
            ready = [j for j in glued if s[j ^ 1] != 0]  # the pair's other joint not open
        return {ready[0]: 1.0} if ready else {-1: 1.0}

    def memory_update(y, m, s, a, h):
        return a if a > 0 and s[a - 1] == 1 else 0  # the joint this move glued, 1-4, or 0

    def reward(y, s, a):
        open_ = [j for j in range(n) if s[j] == 0]
        glued = [j for j in range(n) if s[j] == 1]
        if a > 0 and s[a - 1] != 0:
            return -0.5  # a joint already glued or joined: wasted (and wet again)
        if y == 1:
            return _pick(1 + open_[0], a, idle=-0.3, bad=-0.5) if open_ else \
                _pick(0, a, good=0.2)  # fmt: skip
        if y == 2:
            pending = [j for j in glued if s[j ^ 1] == 0]
            if pending:
                return _pick(1 + (pending[0] ^ 1), a, idle=-0.3, bad=-0.5)
        if glued:
            return _pick(0, a, good=0.2, bad=-0.5)
        return _pick(1 + open_[0], a, idle=-0.3, bad=-0.5)

    return tabulate(
        "glue_cure", initial=(0,) * n,
        robot_actions=("wait", *(f"glue_{c}" for c in "ABCD")),
        human_actions=tuple(f"join_{c}" for c in "ABCD"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s == (2,) * n, type_names=types,
        behaviour=behaviour, reward=reward, horizon=12, memory=n + 1,
        memory_update=memory_update, shares=(0.4, 0.35, 0.25),
    )  # fmt: skip


# ------------------------------------------------------------------------------ handover_timing
# four parts: the robot machines each (one move; it then lies ready in the robot's fixture)
# and may hand it over (into the person's tray); the person preps the base in two moves,
# then mounts the part from her tray, or fetches it from the fixture and mounts it (one
# move). The types differ in when they want the hand-over: "early" (40 %) as soon as the
# part is ready (she waits for it, fetching it a fifth of the time); "on_cue" (30 %) only
# once her base is prepped (a part handed sooner is in her way: she preps at half speed),
# and she asks by pausing once (memory), then fetches it herself; "self_fetch" (20 %) fetches
# every part herself (a hand-over is in her way too); "cue_then_early" (10 %) is on_cue for
# parts 1-2 and early for parts 3-4 (she differs from on_cue only late).
# State: (parts mounted, part 0 not machined / 1 ready / 2 handed, base prepped 0-2), 37
# states. (Audit of session 26.)
def handover_timing() -> HeldoutWorld:
    types, n = ("early", "on_cue", "self_fetch", "cue_then_early"), 4

    def robot_step(s, a):
        k, part, base = s
        if (a == 1 and part == 0) or (a == 2 and part == 1):
            return (k, part + 1, base)
        return s

    def human_step(s, h):
        k, part, base = s
        if k == n:
            return None
        if h == 0:
            return (k, part, base + 1) if base < 2 else None
        return (k + 1, 0, 0) if base == 2 and part == 3 - h else None  # mount 2, fetch 1

    def mode(y, k):  # 0 early, 1 on_cue, 2 self_fetch
        return (1 if k < 2 else 0) if y == 3 else y

    def behaviour(y, m, s, a):
        k, part, base = s
        md = mode(y, k)
        if base < 2:
            return {0: 0.5, -1: 0.5} if part == 2 and md else {0: 1.0}
        if part == 2:
            return {1: 1.0}
        if part == 0:
            return {-1: 1.0}
        if md == 0:
            return {2: 0.2, -1: 0.8}
        return {2: 1.0} if md == 2 or m == 1 else {-1: 1.0}  # on_cue: pauses once first

    def memory_update(y, m, s, a, h):
        k, part, base = s
        return int(mode(y, k) == 1 and part == 1 and base == 2 and h < 0)

    def reward(y, s, a):
        k, part, base = s
        md = mode(y, k)
        if (a == 1 and part != 0) or (a == 2 and part != 1):
            return -0.5  # machining a part already machined, handing none: wasted
        if part == 0:
            return _pick(1, a, idle=-0.3)
        if part == 2 or md == 2 or (md == 1 and base < 2):
            return _pick(0, a, good=0.3 if part == 1 else 0.2, bad=-0.5)
        return _pick(2, a, idle=-0.3)

    return tabulate(
        "handover_timing", initial=(0, 0, 0), robot_actions=("wait", "machine", "hand"),
        human_actions=("prep_base", "mount", "fetch_mount"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == n, type_names=types,
        behaviour=behaviour, reward=reward, horizon=16, memory=2,
        memory_update=memory_update, shares=(0.4, 0.3, 0.2, 0.1),
    )  # fmt: skip


# ====================================================================== the session-27 audit
# panel_wiring, tool_slot and heavy_lifts: written by the audit of session 27 from the docs
# alone (held out: run once as a final check, kept out of tuning).
_NO_ACTION = -1  # "no human action" in a behaviour rule (heavy_lifts)


# ------------------------------------------------------------------------------ panel_wiring
# A technician wires three terminals (L, M, R) of a control panel, left to right; each wire
# must then be fastened (screwed down), by the person or by the robot's screwdriver.
# "delegator" wants the robot to fasten every loose wire while they keep wiring; "self_checker"
# fastens each wire themselves right after placing it (they check the torque) and wants the
# robot's screwdriver out of the panel.
_TERMS = ("L", "M", "R")
_EMPTY, _LOOSE, _FAST = 0, 1, 2


def panel_wiring() -> HeldoutWorld:
    robot_actions = ("wait", "fasten_L", "fasten_M", "fasten_R")
    human_actions = ("wire_L", "wire_M", "wire_R", "screw_L", "screw_M", "screw_R")
    types = ("delegator", "self_checker")

    def robot_step(s, a):
        if a == 0:
            return s
        i = a - 1
        if s[i] != _LOOSE:
            return s  # nothing to fasten there: a wasted move
        return tuple(_FAST if j == i else v for j, v in enumerate(s))

    def human_step(s, h):
        if terminal(s):
            return None
        i, kind = h % 3, h // 3  # 0: wire, 1: screw
        need, to = (_EMPTY, _LOOSE) if kind == 0 else (_LOOSE, _FAST)
        if s[i] != need:
            return None
        return tuple(to if j == i else v for j, v in enumerate(s))

    def terminal(s):
        return all(v == _FAST for v in s)

    def first(s, v):
        return next((i for i, w in enumerate(s) if w == v), None)

    def behaviour(y, m, s, a):
        empty, loose = first(s, _EMPTY), first(s, _LOOSE)
        if types[y] == "delegator":  # keeps wiring; fastens only when nothing is left to wire
            if empty is not None:
                return {empty: 1.0}
            return {3 + loose: 1.0}
        if loose is not None:  # self_checker: fasten what is loose first, then wire the next
            return {3 + loose: 1.0}
        return {empty: 1.0}

    def reward(y, s, a):
        loose = [i for i, v in enumerate(s) if v == _LOOSE]
        if a == 0:  # an idle robot while wires wait costs the delegator time, nobody else
            return -0.3 if (types[y] == "delegator" and loose) else 0.0
        if s[a - 1] != _LOOSE:
            return -0.5  # the screwdriver into the panel for nothing
        # fastening a loose wire: saves the delegator a screwing turn; the self_checker
        # has to undo and re-torque it, with the robot's tool in their hands' way
        return 1.0 if types[y] == "delegator" else -1.0

    return tabulate(
        "panel_wiring", initial=(_EMPTY, _EMPTY, _EMPTY), robot_actions=robot_actions,
        human_actions=human_actions, robot_step=robot_step, human_step=human_step,
        terminal=terminal, type_names=types, behaviour=behaviour, reward=reward, horizon=8,
    )  # fmt: skip


# ------------------------------------------------------------------------------ tool_slot
# A gearbox is assembled in steps (clean the housing - optional, press the bearing, place the
# gear, screw the cover; the cover needs bearing and gear, cleaning is only possible before the
# bearing); the robot can put one tool into a shared hand-over slot (brush, press, tweezers,
# driver). Types: "standard" (40 %, bearing-gear-cover, wants the next tool handed),
# "gear_first" (30 %, gear-bearing-cover, wants the next tool handed), "own_tools" (20 %,
# bearing-gear-cover, fetches their own tools and spends a turn putting any handed tool back)
# and the rare "cleaner" (10 %, cleans the housing first, wants the brush and then each tool).
_STEPS = ("clean", "bearing", "gear", "cover")  # tool of step i is tool i + 1
_TOOLS = ("none", "brush", "press", "tweezers", "driver")


def tool_slot() -> HeldoutWorld:
    robot_actions = ("wait", "hand_brush", "hand_press", "hand_tweezers", "hand_driver")
    human_actions = ("do_clean", "do_bearing", "do_gear", "do_cover", "return_tool")
    types = ("standard", "gear_first", "own_tools", "cleaner")
    orders = {"standard": (1, 2, 3), "gear_first": (2, 1, 3), "own_tools": (1, 2, 3),
              "cleaner": (0, 1, 2, 3)}  # fmt: skip

    def terminal(s):
        return s[0][3] == 1

    def can_do(s, i):
        done = s[0]
        if done[i]:
            return False
        if i == 0:
            return not done[1]  # the housing can be cleaned only before the bearing is in
        if i == 3:
            return bool(done[1] and done[2])
        return True

    def robot_step(s, a):
        return s if a == 0 else (s[0], a)  # the robot's tool replaces the slot's content

    def human_step(s, h):
        if terminal(s):
            return None
        done, slot = s
        if h == 4:  # put the slot's tool back on the rack
            return (done, 0) if slot else None
        if not can_do(s, h):
            return None
        done = tuple(1 if j == h else v for j, v in enumerate(done))
        return (done, 0 if slot == h + 1 else slot)  # the matching tool is used and racked

    def next_step(y, s):
        return next(i for i in orders[types[y]] if can_do(s, i))

    def behaviour(y, m, s, a):
        if types[y] == "own_tools" and s[1]:
            return {4: 1.0}
        return {next_step(y, s): 1.0}

    def reward(y, s, a):
        slot = s[1]
        if types[y] == "own_tools":  # every handed tool costs them a turn to put back
            return 0.0 if a == 0 else (-0.5 if a == slot else -1.0)
        if a == 0:
            return 0.0
        if a == slot:
            return -0.2  # re-placing the tool already there: pointless motion
        need = next_step(y, s) + 1
        return 1.0 if a == need else -0.5  # saves a walk to the rack / clutters the slot

    return tabulate(
        "tool_slot", initial=((0, 0, 0, 0), 0), robot_actions=robot_actions,
        human_actions=human_actions, robot_step=robot_step, human_step=human_step,
        terminal=terminal, type_names=types, behaviour=behaviour, reward=reward, horizon=8,
        shares=(0.4, 0.3, 0.2, 0.1),
    )  # fmt: skip


# ------------------------------------------------------------------------------ heavy_lifts
# A person and a robot move 4 heavy and 3 light boxes from a cart onto a pallet, one box each
# per turn at most. "strong" lifts the heavy boxes, then the light ones, and wants the robot on
# the light pile (two at the heavy pile crowd each other); "fatigued" never lifts two heavy
# boxes in a row (memory of their own last lift: after a heavy one they take a light one or
# rest) and wants the robot to take heavy boxes; "light_only" (a back problem) lifts only light
# boxes and wants the robot to take the heavy ones and leave the light ones to them.
def heavy_lifts() -> HeldoutWorld:
    robot_actions = ("wait", "lift_heavy", "lift_light")
    human_actions = ("lift_heavy", "lift_light")
    types = ("strong", "fatigued", "light_only")

    def take(s, k):  # k = 0: heavy, 1: light
        if s[k] == 0:
            return None
        return (s[0] - 1, s[1]) if k == 0 else (s[0], s[1] - 1)

    def robot_step(s, a):
        return s if a == 0 else (take(s, a - 1) or s)

    def human_step(s, h):
        return None if terminal(s) else take(s, h)

    def terminal(s):
        return s == (0, 0)

    def behaviour(y, m, s, a):
        heavy, light = s
        kind = types[y]
        if kind == "strong":
            return {0: 1.0} if heavy else {1: 1.0}
        if kind == "fatigued":
            if m == 0 and heavy:
                return {0: 1.0}
            # just lifted a heavy one: light or rest
            return {1: 1.0} if light else {_NO_ACTION: 1.0}
        return {1: 1.0} if light else {_NO_ACTION: 1.0}  # light_only

    def memory_update(y, m, s, a, h):
        return 1 if (types[y] == "fatigued" and h == 0) else 0

    def reward(y, s, a):
        heavy, light = s
        if a == 0:
            return 0.0
        if s[a - 1] == 0:
            return -0.3  # reaching into an empty pile
        robot_heavy = a == 1
        if types[y] == "strong":
            if robot_heavy:  # crowds them at the heavy pile, unless only heavy ones are left
                return 0.5 if light == 0 else -0.5
            return 1.0
        if robot_heavy:  # fatigued and light_only: the robot takes the strain off them
            return 1.0
        if heavy == 0:
            return 0.5  # only light boxes left: finishing sooner helps
        return -0.5 if types[y] == "fatigued" else -1.0  # takes their (only) light work

    return tabulate(
        "heavy_lifts", initial=(4, 3), robot_actions=robot_actions,
        human_actions=human_actions, robot_step=robot_step, human_step=human_step,
        terminal=terminal, type_names=types, behaviour=behaviour, reward=reward, horizon=10,
        memory=2, memory_update=memory_update,
    )  # fmt: skip


# ====================================================================== the second session-27 audit
# kit_batch, check_timing and fixture_height: written by a second audit of session 27 from the
# docs alone, after the state model's reaction (held out: run once, kept out of tuning).
# ------------------------------------------------------------------------------ kit_batch
# The person fits four parts; the robot feeds parts into a tray one at a time or the whole
# remaining kit at once. "kit_lover" and "startled" fit in the same order and want the same
# single feeds; they differ only in the kit move: the kit lover loves it, the startled person
# freezes for a turn and hates it. "reverse" fits in the opposite order.
def kit_batch() -> HeldoutWorld:
    P = 4
    ALL = (1 << P) - 1
    types = ("kit_lover", "startled", "reverse")
    orders = {0: (0, 1, 2, 3), 1: (0, 1, 2, 3), 2: (3, 2, 1, 0)}
    FEED_ALL = P + 1  # robot actions: wait, feed_0..feed_3, feed_all

    def robot_step(s, a):
        done, tray = s
        if a == 0:
            return s
        if a == FEED_ALL:
            return (done, ALL & ~done)
        i = a - 1
        if done >> i & 1 or tray >> i & 1:
            return s  # a part already fitted or already in the tray: nothing changes
        return (done, tray | 1 << i)

    def human_step(s, h):
        done, tray = s
        if done >> h & 1:
            return None
        return (done | 1 << h, tray & ~(1 << h))

    def terminal(s):
        return s[0] == ALL

    def nxt(y, done):
        return next(i for i in orders[y] if not done >> i & 1)

    def behaviour(y, m, s, a):
        if y == 1 and a == FEED_ALL:
            return {-1: 1.0}  # startled: freezes for the turn
        return {nxt(y, s[0]): 1.0}

    def reward(y, s, a):
        done, tray = s
        mid = robot_step(s, a)
        if a == 0:
            return 0.0
        if mid == s:
            return -0.5  # a wasted move (the robot reaches over for nothing)
        n = nxt(y, done)
        if a == FEED_ALL:
            added = [i for i in range(P) if mid[1] >> i & 1 and not tray >> i & 1]
            if y == 0:  # the kit lover: everything at hand, the next part most of all
                return sum(1.0 if i == n else 0.8 for i in added)
            return -2.0 if y == 1 else -1.0  # startled: a scare; reverse: a tray to sort
        return 1.0 if a - 1 == n else -1.0  # the next part: a saved trip; another: clutter

    return tabulate(
        "kit_batch",
        initial=(0, 0),
        robot_actions=("wait", *(f"feed_{i}" for i in range(P)), "feed_all"),
        human_actions=tuple(f"fit_{i}" for i in range(P)),
        robot_step=robot_step,
        human_step=human_step,
        terminal=terminal,
        type_names=types,
        behaviour=behaviour,
        reward=reward,
        horizon=8,
    )


# ------------------------------------------------------------------------------ check_timing
# The person fits five parts (lowest first) and then submits; the robot may inspect a fitted
# part. "check_each" wants every part inspected right after it is fitted and waits until it
# is; "check_at_end" wants no interruption while fitting, then every part inspected before
# submitting; "no_check" never wants an inspection and submits as soon as all are fitted.
def check_timing() -> HeldoutWorld:
    P = 5
    DONE = "submitted"
    types = ("check_each", "check_at_end", "no_check")

    def robot_step(s, a):
        if s == DONE or a == 0:
            return s
        i = a - 1
        return (*s[:i], 2, *s[i + 1 :]) if s[i] == 1 else s  # status 0 open, 1 fitted, 2 checked

    def human_step(s, h):
        if s == DONE:
            return None
        if h < P:
            return (*s[:h], 1, *s[h + 1 :]) if s[h] == 0 else None
        return DONE if all(v >= 1 for v in s) else None  # submit

    def terminal(s):
        return s == DONE

    def behaviour(y, m, s, a):
        open_ = [i for i in range(P) if s[i] == 0]
        unchecked = any(v == 1 for v in s)
        if y == 0 and unchecked:
            return {-1: 1.0}  # waits for the inspection
        if open_:
            return {open_[0]: 1.0}
        if y == 1 and unchecked:
            return {-1: 1.0}
        return {P: 1.0}  # submit

    def reward(y, s, a):
        open_ = any(v == 0 for v in s)
        unchecked = any(v == 1 for v in s)
        if a == 0:
            if y == 0 and unchecked:
                return -0.5  # the person stands waiting for the robot
            if y == 1 and unchecked and not open_:
                return -0.5
            return 0.0
        if robot_step(s, a) == s:
            return -0.5  # inspecting nothing: a wasted move
        if y == 0:
            return 1.0
        if y == 1:
            return -1.0 if open_ else 1.0  # an interruption while fitting; wanted at the end
        return -1.0  # no_check: micromanaged

    return tabulate(
        "check_timing",
        initial=(0,) * P,
        robot_actions=("wait", *(f"inspect_{i}" for i in range(P))),
        human_actions=(*(f"fit_{i}" for i in range(P)), "submit"),
        robot_step=robot_step,
        human_step=human_step,
        terminal=terminal,
        type_names=types,
        behaviour=behaviour,
        reward=reward,
        horizon=14,
    )


# ------------------------------------------------------------------------------ fixture_height
# The person does six units of work at a fixture the robot can raise or lower (low, mid, high;
# it starts at mid). 85 % are "tall" (comfortable high), 15 % "short" (comfortable low); both
# work at mid, and each undoes a robot adjustment to the far end (adjusting it back themselves).
def fixture_height() -> HeldoutWorld:
    WORK = 6
    types = ("tall", "short")
    comfort = (2, 0)

    def robot_step(s, a):
        h, p = s
        if a == 1:
            return (min(h + 1, 2), p)
        if a == 2:
            return (max(h - 1, 0), p)
        return s

    def human_step(s, h_):
        h, p = s
        if h_ == 0:
            return (h, p + 1) if p < WORK else None  # work
        if h_ == 1:
            return (h + 1, p) if h < 2 else None  # adjust_up
        return (h - 1, p) if h > 0 else None  # adjust_down

    def terminal(s):
        return s[1] == WORK

    def behaviour(y, m, s, a):
        h = s[0]
        if y == 0 and h == 0:
            return {1: 1.0}  # tall, at low: puts it back up
        if y == 1 and h == 2:
            return {2: 1.0}  # short, at high: puts it back down
        return {0: 1.0}

    def reward(y, s, a):
        c = comfort[y]
        h2 = robot_step(s, a)[0]
        r = (abs(s[0] - c) - abs(h2 - c)) - 0.3 * abs(h2 - c)  # the move's help, the strain left
        if a != 0 and h2 == s[0]:
            r -= 0.5  # a wasted move
        return r

    return tabulate(
        "fixture_height",
        initial=(1, 0),
        robot_actions=("wait", "raise", "lower"),
        human_actions=("work", "adjust_up", "adjust_down"),
        robot_step=robot_step,
        human_step=human_step,
        terminal=terminal,
        type_names=types,
        behaviour=behaviour,
        reward=reward,
        horizon=10,
        shares=(0.85, 0.15),
    )


# ====================================================================== the session-29 audit
# harness_branch, dish_rack and rivet_reach: written by the audit of session 29 from the docs
# alone (held out: run once, kept out of tuning).
# ------------------------------------------------------------------------------ harness_branch
# A technician builds a wiring harness on a board, eight stations in a fixed order: at each
# she routes a wire (from a length the robot cut, or she cuts her own, slower), then secures
# it. The trunk stations (0-2 and 6-7) are clipped by everyone; the three branch stations in
# the middle (3-5) are where the types differ: "taper" tapes the branch, "tier" cable-ties
# it, "holder" clips it but wants the robot to hold the branch while she does (and fumbles
# without). The robot cuts the next wire, puts a clip, tape or a tie in the tray (one slot) or
# holds the routed branch. State: (station, routed, wire cut, tray: 0 none, 1 clip, 2 tape,
# 3 tie, 4 the robot holding the branch); 16+ robot turns.
def harness_branch() -> HeldoutWorld:
    K, BRANCH = 8, (3, 4, 5)
    types = ("taper", "tier", "holder")
    HOLD = 4

    def secure(y, k):  # the person's securing action at station k: 1 clip, 2 tape, 3 tie
        return 2 + y if (k in BRANCH and y < 2) else 1

    def need(y, k):  # what the person wants from the robot once routed: an item or the hold
        return HOLD if (k in BRANCH and y == 2) else secure(y, k)

    def robot_step(s, a):
        k, routed, wire, tray = s
        if a == 1:  # cut_wire
            return (k, routed, 1, tray) if wire == 0 else s
        if 2 <= a <= 4:  # hand_clip, hand_tape, hand_tie (replaces what is in the tray)
            return s if tray == a - 1 else (k, routed, wire, a - 1)
        if a == 5:  # hold_branch: only a routed wire can be held
            return (k, routed, wire, HOLD) if routed and tray != HOLD else s
        return s

    def human_step(s, h):
        k, routed, wire, tray = s
        if k == K:
            return None
        if h == 0:  # route: uses the cut wire, or she cuts her own
            return (k, 1, 0, tray) if not routed else None
        if not routed:
            return None
        return (k + 1, 0, wire, 0 if tray in (h, HOLD) else tray)  # clip, tape or tie

    def behaviour(y, m, s, a):
        k, routed, wire, tray = s
        if not routed:
            return {0: 1.0} if wire else {0: 0.5, -1: 0.5}
        sec, want = secure(y, k), need(y, k)
        return {sec: 1.0} if tray == want else {sec: 0.4 if want == HOLD else 0.6,
                                                   -1: 0.6 if want == HOLD else 0.4}  # fmt: skip

    def reward(y, s, a):
        k, routed = s[:2]
        if a == 0:
            return 0.0
        if robot_step(s, a) == s:
            return -0.5  # a wasted move
        if a == 1:  # a wire for this station, or pre-cut for the next one
            return 1.0 if not routed else (0.3 if k < K - 1 else -0.5)
        want = need(y, k)
        if a == 5:
            return 1.0 if want == HOLD else -1.0  # the arm in her way
        return 1.0 if a - 1 == want else -1.0  # the item she needs next; another: clutter

    return tabulate(
        "harness_branch", initial=(0, 0, 0, 0),
        robot_actions=("wait", "cut_wire", "hand_clip", "hand_tape", "hand_tie", "hold_branch"),
        human_actions=("route", "clip", "tape", "tie"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == K, type_names=types,
        behaviour=behaviour, reward=reward, horizon=26,
    )  # fmt: skip


# ------------------------------------------------------------------------------ dish_rack
# A person loads four kinds of dishes (plates, cups, cutlery, pots) into a dishwasher; the robot
# can hand one from the sink into the rack's hand-over slot (handing another swaps it). The
# person loads the handed one at once, else fetches hers from the sink (slower). "plates_first"
# (45 %) and "rinser" (15 %) load in the same order and want the same thing from the robot (the
# next kind handed) but the rinser rinses every item before loading it; "cups_first" (30 %) has
# another order; "self_loader" (10 %) loads in the plates-first order by herself and hands back
# anything handed to her. State: (loaded mask, slot: -1 or a kind, next item rinsed).
def dish_rack() -> HeldoutWorld:
    N, ALL = 4, 15
    types = ("plates_first", "cups_first", "rinser", "self_loader")
    orders = ((0, 1, 2, 3), (1, 0, 3, 2), (0, 1, 2, 3), (0, 1, 2, 3))

    def robot_step(s, a):
        mask, slot, rinsed = s
        if a == 0 or mask >> (a - 1) & 1 or slot == a - 1:
            return s
        return (mask, a - 1, rinsed)

    def human_step(s, h):
        mask, slot, rinsed = s
        if mask == ALL:
            return None
        if h < N:  # load_<kind>
            return None if mask >> h & 1 else (mask | 1 << h, -1 if slot == h else slot, 0)
        if h == N:  # rinse the next item
            return (mask, slot, 1) if not rinsed else None
        return (mask, -1, rinsed) if slot >= 0 else None  # decline: back into the sink

    def nxt(y, mask):
        return next(i for i in orders[y] if not mask >> i & 1)

    def behaviour(y, m, s, a):
        mask, slot, rinsed = s
        i = nxt(y, mask)
        if y == 3:
            return {N + 1: 1.0} if slot >= 0 else {i: 1.0}
        if y == 2 and not rinsed:
            return {N: 1.0} if slot == i else {N: 0.7, -1: 0.3}
        return {i: 1.0} if slot == i or y == 2 else {i: 0.7, -1: 0.3}

    def reward(y, s, a):
        mask, slot = s[:2]
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # handing a loaded kind or the one in the slot: a wasted move
        if y == 3:
            return _pick(0, a, good=0.2)
        want = nxt(y, mask)
        if slot == want:
            return _pick(0, a, good=0.2)
        return _pick(1 + want, a)

    return tabulate(
        "dish_rack", initial=(0, -1, 0),
        robot_actions=("wait", "hand_plates", "hand_cups", "hand_cutlery", "hand_pots"),
        human_actions=("load_plates", "load_cups", "load_cutlery", "load_pots", "rinse",
                       "decline"),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s[0] == ALL,
        type_names=types, behaviour=behaviour, reward=reward, horizon=16,
        shares=(0.45, 0.30, 0.15, 0.10),
    )  # fmt: skip


# ------------------------------------------------------------------------------ rivet_reach
# A shared fixture: the robot sets six rivets, the person places four brackets into the same
# fixture, reaching in (reach, place, withdraw). "steady" (45 %) places two brackets per reach
# and wants the robot to keep riveting whatever she does; "stop_me" (35 %) places one per reach
# and wants the robot stopped whenever her hand is in the fixture (a rivet then makes her
# flinch out, bracket unplaced); "yielder" (20 %) reaches in only on a turn the robot pauses,
# wants it to pause for her until her brackets are in, and flinches out like stop_me. How many
# brackets she placed in this reach is her memory, not in the state. State: (brackets placed,
# rivets set, hand in the fixture).
def rivet_reach() -> HeldoutWorld:
    P, R = 4, 6
    types = ("steady", "stop_me", "yielder")

    def robot_step(s, a):
        p, r, hand = s
        return (p, r + 1, hand) if a == 1 and r < R else s

    def human_step(s, h):
        p, r, hand = s
        if h == 0:  # reach
            return (p, r, 1) if not hand and p < P else None
        if h == 1:  # place
            return (p + 1, r, 1) if hand and p < P else None
        return (p, r, 0) if hand else None  # withdraw

    def terminal(s):
        return s == (P, R, 0)

    def behaviour(y, m, s, a):
        p, r, hand = s
        if not hand:
            if p == P or (y == 2 and a == 1 and r < R):
                return {-1: 1.0}  # done, or the yielder waits for the robot to pause
            return {0: 1.0}
        if y > 0 and a == 1:
            return {2: 1.0}  # flinches out
        per_reach = 2 if y == 0 else 1
        return {1: 1.0} if (m < per_reach and p < P) else {2: 1.0}

    def memory_update(y, m, s, a, h):
        return min(m + 1, 2) if h == 1 else (m if h < 0 else 0)

    def reward(y, s, a):
        p, r, hand = s
        if a == 1 and r == R:
            return -0.5  # riveting with every rivet set: a wasted move
        busy = -0.2 if r < R else 0.0  # the robot idle with work left
        if y == 0:
            return 1.0 if a == 1 else busy
        if hand:
            return (-2.0 if y == 1 else -1.5) if a == 1 else 0.3
        if y == 2 and p < P:
            return -0.3 if a == 1 else 0.5  # she wants the fixture to herself first
        return 1.0 if a == 1 else busy

    return tabulate(
        "rivet_reach", initial=(0, 0, 0), robot_actions=("wait", "rivet"),
        human_actions=("reach", "place", "withdraw"), robot_step=robot_step,
        human_step=human_step, terminal=terminal, type_names=types, behaviour=behaviour,
        reward=reward, horizon=22, memory=3, memory_update=memory_update,
        shares=(0.45, 0.35, 0.20),
    )  # fmt: skip


# ------------------------------------------------------------------------------ press_block
# A shared press: the person works four parts, each pressed and sanded (either order) at her
# bench; the robot has three jobs of its own at the press (start: it takes the press; finish:
# the job done, the press free again). While the robot holds the press she cannot press.
# "waiter" (40 %) presses first and, finding the press taken, waits for it; "work_around"
# (35 %) presses first but, finding it taken, sands first instead; "sand_first" (25 %) always
# sands first. Everyone wants the robot's jobs done while she works on something else, never
# while she needs the press. State: (parts finished, stage of the current part: 0 fresh,
# 1 pressed, 2 sanded; robot jobs done, robot at the press).
def press_block() -> HeldoutWorld:
    P, J = 4, 3
    types = ("waiter", "work_around", "sand_first")

    def robot_step(s, a):
        k, stage, j, b = s
        if a == 1:  # start_job: take the press
            return (k, stage, j, 1) if (b == 0 and j < J) else s
        if a == 2:  # finish_job: the job done, the press free
            return (k, stage, j + 1, 0) if b == 1 else s
        return s

    def human_step(s, h):
        k, stage, j, b = s
        if k == P:
            return None
        if h == 0:  # press
            if b == 1 or stage == 1:
                return None
            return (k, 1, j, b) if stage == 0 else (k + 1, 0, j, b)
        if stage == 2:  # sand
            return None
        return (k, 2, j, b) if stage == 0 else (k + 1, 0, j, b)

    def intended(y, s):  # what she does in state s (after the robot's move); -1: waits
        k, stage, _, b = s
        if k == P:
            return -1
        if stage == 1:
            return 1
        if stage == 2:
            return -1 if b else 0
        if y == 2 or (y == 1 and b):
            return 1  # sands first (always, or while the press is taken)
        return -1 if b else 0

    def behaviour(y, m, s, a):
        return {intended(y, s): 1.0}

    def reward(y, s, a):
        k, b = s[0], s[3]
        mid = robot_step(s, a)
        if a == 0:
            return -0.5 if b else 0.0  # holding the press and doing nothing
        if mid == s:
            return -0.5  # a wasted move
        if a == 2:
            return 0.5
        if k == P:
            return 0.2  # a job with nobody to work beside: progress, but nothing in parallel
        return -1.0 if intended(y, mid) < 0 else 1.0  # she stands idle / works in parallel

    return tabulate(
        "press_block", initial=(0, 0, 0, 0),
        robot_actions=("wait", "start_job", "finish_job"), human_actions=("press", "sand"),
        robot_step=robot_step, human_step=human_step,
        terminal=lambda s: s[0] == P and s[2] == J and s[3] == 0, type_names=types,
        behaviour=behaviour, reward=reward, horizon=18, shares=(0.40, 0.35, 0.25),
    )  # fmt: skip


# ------------------------------------------------------------------------------ driver_pick
# The person drives six screws; for each the robot can hand her one of two equivalent drivers
# with the screw loaded (a ratchet or a power driver), put in her hand-over slot (handing the
# other swaps it). She drives with the handed one at once if it is hers, else fetches her own
# (slower). "ratchet" and "power" differ only in which driver they use and want handed;
# "chooser" picks one at random each time, uses whatever is handed but would rather choose
# herself (she wants the robot to wait). State: (screws driven, slot: 0 empty, 1 ratchet,
# 2 power).
def driver_pick() -> HeldoutWorld:
    N = 6
    types = ("ratchet", "power", "chooser")

    def robot_step(s, a):
        n, slot = s
        return s if (a == 0 or slot == a) else (n, a)

    def human_step(s, h):
        n, slot = s
        if n == N:
            return None
        return (n + 1, 0 if slot == h + 1 else slot)  # drive_ratchet (h 0), drive_power (h 1)

    def behaviour(y, m, s, a):
        n, slot = s
        if n == N:
            return {-1: 1.0}
        if y == 2:
            return {slot - 1: 1.0} if slot else {0: 0.3, 1: 0.3, -1: 0.4}
        return {y: 1.0} if slot == y + 1 else {y: 0.6, -1: 0.4}  # fetching her own: slower

    def reward(y, s, a):
        slot = s[1]
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # handing the driver already in the slot
        if y == 2:
            return _pick(0, a, good=0.3, bad=-0.3)  # she would rather choose herself
        if slot == y + 1:
            return _pick(0, a, good=0.2)  # hers is there: leave it
        return _pick(y + 1, a, idle=-0.2 if slot else 0.0)  # the wrong one there: swap it

    return tabulate(
        "driver_pick", initial=(0, 0), robot_actions=("wait", "hand_ratchet", "hand_power"),
        human_actions=("drive_ratchet", "drive_power"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=14,
    )  # fmt: skip


# ------------------------------------------------------------------------------ cabinet_glue
# A cabinet from three sub-assemblies (drawer, frame, top), three steps each; the robot can
# put the next part of one sub-assembly in the hand-over tray (one slot; handing another swaps
# it); she builds with the tray's part at once if it is the one she needs, else fetches hers
# (slower). Five types: "drawer_first" (30 %) D, F, T; "frame_first" (25 %) F, D, T;
# "alternator" (20 %) D, F, D, F, D, F, T; and two "settlers" who let the frame's glue set
# before its last step: "drawer_settler" (15 %, D, F, T) and "frame_settler" (10 %, F, D, T)
# pause one turn there (memory: whether she has paused) and want the robot to wait, not hand
# anything, while the frame's last step is next. State: (drawer, frame, top steps done,
# tray: -1 empty or a sub-assembly).
def cabinet_glue() -> HeldoutWorld:
    S = 3
    types = ("drawer_first", "frame_first", "alternator", "drawer_settler", "frame_settler")
    first = (0, 1, 0, 0, 1)  # the sub-assembly each type starts with

    def robot_step(s, a):
        *done, tray = s
        i = a - 1
        if a == 0 or done[i] == S or tray == i:
            return s
        return (*done, i)

    def human_step(s, h):
        *done, tray = s
        if done[h] == S:
            return None
        return (*_set(tuple(done), h, done[h] + 1), -1 if tray == h else tray)

    def nxt(y, s):
        d, f = s[:2]
        if y == 2:
            return 0 if (d <= f and d < S) else (1 if f < S else 2)
        one, two = (0, 1) if first[y] == 0 else (1, 0)
        return one if s[one] < S else (two if s[two] < S else 2)

    def glue_moment(y, s):  # a settler with the frame's last step next
        return y >= 3 and s[1] == S - 1 and nxt(y, s) == 1

    def behaviour(y, m, s, a):
        if s[:3] == (S, S, S):
            return {-1: 1.0}
        if glue_moment(y, s) and m == 0:
            return {-1: 1.0}  # lets the glue set
        i = nxt(y, s)
        return {i: 1.0} if s[3] == i else {i: 0.6, -1: 0.4}

    def memory_update(y, m, s, a, h):
        return 1 if (m == 1 or (glue_moment(y, s) and h < 0)) else 0

    def reward(y, s, a):
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a wasted move
        if glue_moment(y, s):
            return _pick(0, a, good=0.3)  # hands off the frame while the glue sets
        i = nxt(y, s)
        if s[3] == i:
            return _pick(0, a, good=0.2)  # her part is in the tray: leave it
        return _pick(1 + i, a)

    return tabulate(
        "cabinet_glue", initial=(0, 0, 0, -1),
        robot_actions=("wait", "hand_drawer", "hand_frame", "hand_top"),
        human_actions=("build_drawer", "build_frame", "build_top"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[:3] == (S, S, S), type_names=types,
        behaviour=behaviour, reward=reward, horizon=22, memory=2, memory_update=memory_update,
        shares=(0.30, 0.25, 0.20, 0.15, 0.10),
    )  # fmt: skip


# ====================================================================== the session-30 audit
# defect_rework, shelf_build and leaky_tubes: written by the audit of session 30 from the docs
# alone (held out: run once, kept out of tuning).
# ------------------------------------------------------------------------------ defect_rework
# An inspection bench: five parts, one at a time. The robot can feed the next part onto the
# bench (else she fetches it herself, slower); she inspects it: it passes (75 %) or she flags
# a defect (25 %, at random). A flagged part is either repaired (the robot can hold it steady
# for her) and then passes, or scrapped (the robot can carry it to the scrap bin, or she
# discards it herself). "repairer" (87 %) repairs flagged parts and wants them held (without
# the hold she repairs slowly); "scrapper" (13 %) never repairs: she wants a flagged part
# scrapped by the robot (a hold is in her way). Everywhere else both want the same: the next
# part fed, the robot still while she inspects. The types differ only in the flagged-part
# states, which a quarter of the parts reach. State: (parts finished, bench: 0 empty,
# 1 unchecked part, 2 flagged, 3 flagged and held by the robot, 4 repaired), 26 states.
def defect_rework() -> HeldoutWorld:
    N = 5
    types = ("repairer", "scrapper")

    def robot_step(s, a):
        k, b = s
        if a == 1 and b == 0:
            return (k, 1)  # feed the next part
        if a == 2 and b == 2:
            return (k, 3)  # hold the flagged part steady
        if a == 3 and b in (2, 3):
            return (k + 1, 0)  # carry it to the scrap bin
        return s

    def human_step(s, h):
        k, b = s
        if k == N:
            return None
        if h == 0:  # fetch a part herself
            return (k, 1) if b == 0 else None
        if h == 1:  # pass: the part is good (or repaired)
            return (k + 1, 0) if b in (1, 4) else None
        if h == 2:  # flag a defect
            return (k, 2) if b == 1 else None
        if h == 3:  # repair
            return (k, 4) if b in (2, 3) else None
        return (k + 1, 0) if b in (2, 3) else None  # discard

    def behaviour(y, m, s, a):
        k, b = s
        if k == N:
            return {-1: 1.0}
        if b == 0:
            return {0: 0.5, -1: 0.5}  # fetching her own part is slower
        if b == 1:
            return {1: 0.75, 2: 0.25}
        if b == 4:
            return {1: 1.0}
        if y == 0:
            return {3: 1.0} if b == 3 else {3: 0.4, -1: 0.6}  # repairs slowly unheld
        return {4: 0.5, -1: 0.5}  # the scrapper discards it herself, held or not

    def reward(y, s, a):
        _k, b = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        if b == 0:
            return _pick(1, a)
        if b == 2:
            if y == 0:
                return _pick(2, a)  # scrapping a repairable part: -1
            return 1.0 if a == 3 else (-0.5 if a == 2 else 0.0)
        if b == 3:
            if y == 0:
                return _pick(0, a, good=0.2)  # keep holding; scrapping it: -1
            return 1.0 if a == 3 else -0.2
        return _pick(0, a, good=0.2)

    return tabulate(
        "defect_rework", initial=(0, 0), robot_actions=("wait", "feed", "hold", "scrap"),
        human_actions=("fetch", "pass", "flag", "repair", "discard"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=24, shares=(0.87, 0.13),
    )  # fmt: skip


# ------------------------------------------------------------------------------ shelf_build
# A bookshelf: four boards, each placed by the person, then screwed. The robot has one
# gripper: it can put the next board in her hand-over slot, put the screwdriver there
# (it stays there until the robot uses the gripper again) or hold the placed board level
# (released once it is screwed). "holdme" (35 %) wants the board handed, then held while she
# screws with her own driver; "holdme_slow" (25 %) wants exactly the same robot moves but
# works at about half the pace (a first-time builder); "driver" (25 %) wants the board
# handed, then the screwdriver handed (she holds the board herself); "solo" (15 %) fetches
# her own boards and tools, wants the robot to wait and slows down while it holds a board.
# Each helped step goes faster (fast types 90 % a turn with the help, 50 % without; the slow
# one 50 % and 25 %). State: (boards done, stage 0 to place / 1 to screw, gripper: 0 free,
# 1 board in the slot, 2 driver in the slot, 3 holding), 26 states.
def shelf_build() -> HeldoutWorld:
    N = 4
    types = ("holdme", "holdme_slow", "driver", "solo")

    def robot_step(s, a):
        k, stage, out = s
        if k == N or out == a:
            return s
        if a == 1:  # hand_board
            return (k, stage, 1) if stage == 0 else s
        if a == 2:  # hand_driver
            return (k, stage, 2)
        if a == 3:  # hold the placed board level
            return (k, stage, 3) if stage == 1 else s
        return s

    def human_step(s, h):
        k, stage, out = s
        if k == N or stage != h:
            return None
        if h == 0:  # place the next board (the one in the slot, if any)
            return (k, 1, 0 if out == 1 else out)
        return (k + 1, 0, 0 if out == 3 else out)  # screw it (the hold released)

    def helped(y, s):
        stage, out = s[1:]
        if stage == 0:
            return out == 1
        return out == (2 if y == 2 else 3)

    def behaviour(y, m, s, a):
        k, stage, out = s
        if k == N:
            return {-1: 1.0}
        if y == 3:
            p = 0.4 if out == 3 else 0.8
        elif y == 1:
            p = 0.5 if helped(y, s) else 0.25
        else:
            p = 0.9 if helped(y, s) else 0.5
        return {stage: p, -1: 1.0 - p}

    def reward(y, s, a):
        _k, stage, out = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        if y == 3:
            return _pick(0, a, good=0.3, bad=-0.3)
        want = 1 if stage == 0 else (2 if y == 2 else 3)
        if out == want:
            return _pick(0, a, good=0.2)  # her help is there: leave it
        return _pick(want, a)

    return tabulate(
        "shelf_build", initial=(0, 0, 0),
        robot_actions=("wait", "hand_board", "hand_driver", "hold"),
        human_actions=("place", "screw"), robot_step=robot_step, human_step=human_step,
        terminal=lambda s: s[0] == N, type_names=types, behaviour=behaviour, reward=reward,
        horizon=24, shares=(0.35, 0.25, 0.25, 0.15),
    )  # fmt: skip


# ------------------------------------------------------------------------------ leaky_tubes
# A lab bench: five sample tubes, each brought from the fridge by the robot into her tray
# (she does not fetch them). She inspects each tube before processing it; a quarter of them
# leak, which she notices with a pause (a turn without a move), and then processes it
# anyway. Whether the last tube leaked is her memory, not in the state. The robot can bring
# the next tube or hand fresh gloves (one tray: either replaces the other); she can change
# gloves (from the tray, or her own box, slower). "careful" (40 %) changes gloves only after
# processing a leaky tube: she wants gloves then, the next tube otherwise, so in the same
# state (a sample just done, tray empty) her wanted move depends on what happened earlier
# (scored by the true reward as the state's average over her memory, a quarter gloves);
# "always_gloves" (35 %) changes gloves before every tube and wants them handed first;
# "no_change" (25 %) never changes gloves and wants the tube. State: (samples done, tray:
# 0 empty, 1 tube, 2 gloves; fresh gloves on since the last sample), 31 states.
def leaky_tubes() -> HeldoutWorld:
    N, LEAK = 5, 0.25
    types = ("careful", "always_gloves", "no_change")

    def robot_step(s, a):
        k, tray, g = s
        return s if (a == 0 or tray == a) else (k, a, g)

    def human_step(s, h):
        k, tray, g = s
        if k == N:
            return None
        if h == 0:  # process the tube in the tray
            return (k + 1, 0, 0) if tray == 1 else None
        return (k, 0 if tray == 2 else tray, 1) if g == 0 else None  # change gloves

    def change(tray):
        return {1: 1.0} if tray == 2 else {1: 0.5, -1: 0.5}  # her own box: slower

    def process(m):  # m 0: inspects (a leak: a pause); m 1: noticed the leak, processes
        return {0: 1.0} if m == 1 else {0: 1.0 - LEAK, -1: LEAK}

    def behaviour(y, m, s, a):
        k, tray, g = s
        if k == N:
            return {-1: 1.0}
        if g == 0 and (y == 1 or (y == 0 and m == 2)):
            return change(tray)
        return process(m) if tray == 1 else {-1: 1.0}

    def memory_update(y, m, s, a, h):
        tray = s[1]
        if m == 0 and h < 0 and tray == 1 and not (y == 1 and s[2] == 0):
            return 1  # paused over the tube: it leaks
        if m == 1 and h == 0:
            return 2 if y == 0 else 0  # processed the leaky tube (only careful minds)
        if m == 2 and h == 1:
            return 0  # fresh gloves
        return m

    def serve(want, tray, a):  # want 1: the tube, 2: gloves
        return _pick(0, a, good=0.2) if tray == want else _pick(want, a)

    def reward(y, s, a):
        k, tray, g = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        if y == 2:
            return serve(1, tray, a)
        if y == 1:
            return serve(2 if g == 0 else 1, tray, a)
        if k > 0 and g == 0:  # she may have processed a leaky tube: the average over that
            return LEAK * serve(2, tray, a) + (1 - LEAK) * serve(1, tray, a)
        return serve(1, tray, a)

    return tabulate(
        "leaky_tubes", initial=(0, 0, 0), robot_actions=("wait", "bring_tube", "hand_gloves"),
        human_actions=("process", "change_gloves"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=20, memory=3, memory_update=memory_update,
        shares=(0.40, 0.35, 0.25),
    )  # fmt: skip


# ====================================================================== the session-32 audit
# tile_crack, polish_passes and bento_line: written by the audit of session 32 from the docs
# alone (held out: run once, kept out of tuning).
# ------------------------------------------------------------------------------ tile_crack
# A tiler sets six tiles in a row. The robot can feed the next tile into her tray (else she
# fetches one herself, slower). Laying a tile cracks it a fifth of the time, at random (about
# a quarter of the episodes see no crack at all). The types differ only in how they recover
# from a cracked tile: "redo_self" (40 %) pries it off herself at once and wants the robot
# to keep out of her wall space (it waits; a fresh tile fed after is welcome); "ask_robot"
# (35 %) steps back and waits for the robot to remove it (she does it herself a quarter of
# the turns); "skip_mark" (25 %) marks it for later and goes on to the next tile, wanting
# that tile fed (a removal undoes her mark). Everywhere else all three want the same: the
# next tile fed, the robot still while she lays it. State: (tiles done, tray: 0 empty,
# 1 tile, crack: 0 none, 1 cracked tile on the wall, 2 cracked tile removed), 38 states.
def tile_crack() -> HeldoutWorld:
    N, CRACK = 6, 0.2
    types = ("redo_self", "ask_robot", "skip_mark")

    def robot_step(s, a):
        k, tray, crack = s
        if a == 1 and tray == 0:
            return (k, 1, crack)  # feed the next tile
        if a == 2 and crack == 1:
            return (k, tray, 2)  # remove the cracked tile
        return s

    def human_step(s, h):
        k, tray, crack = s
        if k == N:
            return None
        if h == 0:  # fetch a tile herself
            return (k, 1, crack) if tray == 0 and crack != 1 else None
        if h in (1, 2):  # lay the tile from the tray: it sits (1) or it cracks (2)
            if tray == 0 or crack == 1:
                return None
            return (k + 1, 0, 0) if h == 1 else (k, 0, 1)
        if h == 3:  # remove the cracked tile herself
            return (k, tray, 2) if crack == 1 else None
        return (k + 1, tray, 0) if crack == 1 else None  # skip: mark it, go on

    def behaviour(y, m, s, a):
        k, tray, crack = s
        if k == N:
            return {-1: 1.0}
        if crack == 1:
            return ({3: 1.0}, {-1: 0.75, 3: 0.25}, {4: 1.0})[y]
        if tray == 0:
            return {0: 0.5, -1: 0.5}  # fetching her own tile is slower
        return {1: 1.0 - CRACK, 2: CRACK}

    def reward(y, s, a):
        _k, tray, crack = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        if crack == 1:
            if y == 0:
                return 0.3 if a == 0 else (-0.3 if a == 1 else -1.0)
            if y == 1:
                return 1.0 if a == 2 else (-0.3 if a == 0 else -0.5)
            if a == 2:
                return -1.0
            return _pick(1, a) if tray == 0 else 0.2
        return _pick(1, a) if tray == 0 else _pick(0, a, good=0.2)

    return tabulate(
        "tile_crack", initial=(0, 0, 0), robot_actions=("wait", "feed", "remove"),
        human_actions=("fetch", "lay", "crack", "remove", "skip"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=24, shares=(0.40, 0.35, 0.25),
    )  # fmt: skip


# ------------------------------------------------------------------------------ polish_passes
# A finishing cell: six panels, one at a time on a stand. The robot mounts a panel on the
# empty stand (else she fetches one, slower), takes a finished panel to the rack (mounting
# the next one in the same move) or inspects the panel on the stand; she polishes it (one
# pass a move, at most two) or racks it herself (slower). The types differ in a count, on
# every panel: "two_pass" (40 %) always polishes twice and wants the robot still after the
# first pass (taking the panel then ruins her second pass), then wants it taken; "one_pass"
# (35 %) polishes once and wants it taken right away; "pass_inspect" (25 %) polishes once
# and wants the robot to inspect it before it is taken; uninspected, she polishes a second
# pass half the turns, so a robot that only waits sees her act much like "two_pass". After
# one pass, the three want three different robot moves (wait, take, inspect).
# State: (panels done, stand: 0 empty, 1 panel, passes 0-2, inspected), 37 states.
def polish_passes() -> HeldoutWorld:
    N = 6
    types = ("two_pass", "one_pass", "pass_inspect")

    def robot_step(s, a):
        k, stand, p, insp = s
        if a == 1 and stand == 0:
            return (k, 1, 0, 0)  # mount a panel
        if a == 2 and stand == 1 and p >= 1:
            return (k + 1, int(k + 1 < N), 0, 0)  # take it to the rack, mount the next
        if a == 3 and stand == 1 and p >= 1 and not insp:
            return (k, 1, p, 1)  # inspect it
        return s

    def human_step(s, h):
        k, stand, p, insp = s
        if k == N:
            return None
        if h == 0:  # fetch a panel herself
            return (k, 1, 0, 0) if stand == 0 else None
        if h == 1:  # one polishing pass
            return (k, 1, p + 1, insp) if stand == 1 and p < 2 else None
        return (k + 1, 0, 0, 0) if stand == 1 and p >= 1 else None  # rack it herself

    def behaviour(y, m, s, a):
        k, stand, p, insp = s
        if k == N:
            return {-1: 1.0}
        if stand == 0:
            return {0: 0.5, -1: 0.5}
        if p == 0 or (y == 0 and p == 1):
            return {1: 1.0}
        if y == 2 and p == 1 and not insp:
            return {1: 0.5, -1: 0.5}  # waits for the inspection, or polishes again
        return {2: 0.5, -1: 0.5}  # waits for the robot to take it, or racks it herself

    def reward(y, s, a):
        _k, stand, p, insp = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        if stand == 0:
            return _pick(1, a)
        if p == 0:
            return _pick(0, a, good=0.2)
        if y == 0 and p == 1:
            return 0.3 if a == 0 else (-1.0 if a == 2 else -0.5)
        if y == 2 and not insp:
            return 1.0 if a == 3 else (-1.0 if a == 2 else 0.0)
        return 1.0 if a == 2 else (-0.3 if a == 3 else 0.0)

    return tabulate(
        "polish_passes", initial=(0, 0, 0, 0),
        robot_actions=("wait", "mount", "take", "inspect"),
        human_actions=("fetch", "polish", "rack"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=30, shares=(0.40, 0.35, 0.25),
    )  # fmt: skip


# ------------------------------------------------------------------------------ bento_line
# A kitchen line packs a bento box: four compartments (rice, fish, veg, pickle), each filled
# by the cook and then garnished (by the robot or by her); once all four are garnished she
# may pour sauce, and closes the box with a lid. The robot can garnish a filled compartment
# or put the sauce or the lid in her hand-over tray (one slot: either replaces the other);
# without it she fetches her own, slower. "lid_only" (30 %) fills in order and wants each
# compartment garnished by the robot as soon as it is filled (else she waits, or garnishes
# it herself half the turns), then the lid; "sauce_first" (25 %) is the same until the box
# is full, then wants the sauce, then the lid: the two differ only in the last two robot
# moves; "self_garnish" (25 %) fills in reverse order and garnishes each compartment
# herself at once, wanting the robot still until the lid; "batch" (20 %) fills all four
# first, then wants them garnished in order by the robot, then the sauce, then the lid.
# Early sauce or lids are in the way. State: (compartments: 0 empty, 1 filled, 2 garnished;
# tray: 0 empty, 1 sauce, 2 lid; sauced), 247 states.
_BENTO = ("rice", "fish", "veg", "pickle")


def bento_line() -> HeldoutWorld:
    n = len(_BENTO)
    types = ("lid_only", "sauce_first", "self_garnish", "batch")
    orders = (tuple(range(n)), tuple(range(n)), tuple(range(n - 1, -1, -1)), tuple(range(n)))
    SAUCE, LID = n + 1, n + 2  # the robot's hand_sauce and hand_lid

    def full(cs):
        return all(c == 2 for c in cs)

    def robot_step(s, a):
        cs, tray, sauced = s
        if 1 <= a <= n and cs[a - 1] == 1:
            return (_set(cs, a - 1, 2), tray, sauced)  # garnish it
        if a in (SAUCE, LID) and tray != a - n:
            return (cs, a - n, sauced)  # put the sauce (1) or the lid (2) in her tray
        return s

    def human_step(s, h):
        cs, tray, sauced = s
        if cs == "done":
            return None
        if h < 2 * n:  # fill (h < n) or garnish compartment h % n
            i, op = h % n, h // n
            return (_set(cs, i, op + 1), tray, sauced) if cs[i] == op else None
        if not full(cs):
            return None
        if h in (2 * n, 2 * n + 1):  # pour the sauce from the tray / fetched herself
            if sauced or (tray == 1) != (h == 2 * n):
                return None
            return (cs, 0 if tray == 1 else tray, 1)
        if (tray == 2) != (h == 2 * n + 2):  # close with the lid from the tray / her own
            return None
        return ("done", 0, 0)

    def todo(y, cs):
        """(the next compartment to fill or None, the next one to garnish or None)."""
        empty = [i for i in orders[y] if cs[i] == 0]
        filled = [i for i in orders[y] if cs[i] == 1]
        return (empty[0] if empty else None), (filled[0] if filled else None)

    def wants_sauce(y, sauced):
        return y in (1, 3) and not sauced

    def behaviour(y, m, s, a):
        cs, tray, sauced = s
        if cs == "done":
            return {-1: 1.0}
        if not full(cs):
            fill, garnish = todo(y, cs)
            if y == 2 and garnish is not None:
                return {n + garnish: 1.0}
            if garnish is None or (y == 3 and fill is not None):
                return {fill: 1.0}
            return {-1: 0.5 if y < 2 else 0.7, n + garnish: 0.5 if y < 2 else 0.3}
        if wants_sauce(y, sauced):
            return {2 * n: 1.0} if tray == 1 else {2 * n + 1: 0.5, -1: 0.5}
        return {2 * n + 2: 1.0} if tray == 2 else {2 * n + 3: 0.5, -1: 0.5}

    def wanted(y, s):  # the robot move the type wants in the state before it
        cs, tray, sauced = s
        if not full(cs):
            fill, garnish = todo(y, cs)
            if y == 2 or garnish is None or (y == 3 and fill is not None):
                return 0
            return 1 + garnish
        if wants_sauce(y, sauced):
            return 0 if tray == 1 else SAUCE
        return 0 if tray == 2 else LID

    def reward(y, s, a):
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        want = wanted(y, s)
        if want == 0:
            return 0.2 if a == 0 else (-0.5 if a in (SAUCE, LID) else -1.0)
        return _pick(want, a, idle=-0.2)

    return tabulate(
        "bento_line", initial=((0,) * n, 0, 0),
        robot_actions=("wait", *(f"garnish_{c}" for c in _BENTO), "hand_sauce", "hand_lid"),
        human_actions=(*(f"fill_{c}" for c in _BENTO), *(f"garnish_{c}" for c in _BENTO),
                       "pour_sauce", "fetch_sauce", "close", "fetch_lid"),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s[0] == "done",
        type_names=types, behaviour=behaviour, reward=reward, horizon=24,
        shares=(0.30, 0.25, 0.25, 0.20),
    )  # fmt: skip


# ====================================================================== the session-33 audit
# jar_slip, pad_sides and tote_pack: written by the audit of session 33 from the docs alone
# (held out: run once, kept out of tuning).
# ------------------------------------------------------------------------------ jar_slip
# A packing station: the robot takes six jars off a conveyor, one at a time, and either
# hands each to the packer (she grabs it from the gripper) or sets it on her bench (she
# collects it from there, a little slower). A hand-over slips a sixth of the time, at random:
# the robot's mistake, the jar falls on the mat (unbroken), which the robot sees. From then
# on the state remembers that a jar has slipped. The types differ only in how they take the
# robot's mistake: "pickup_self" (40 %) picks the jar off the mat herself at once and wants
# the robot out of her way (it waits), then hand-overs as before; "robot_fetch" (35 %) steps
# back and waits for the robot to retrieve it to the bench (picks it up herself a fifth of
# the turns); "lost_trust" (25 %) picks it up herself like "pickup_self", but after the
# first slip no longer wants hand-overs: she wants every later jar set on the bench (an
# offered jar she mostly leaves in the gripper, so the robot should set it down). Without a
# slip (a third of the episodes) the three act and want alike. State: (jars packed, jar:
# 0 none out, 1 offered in the gripper, 2 on the bench, 3 on the mat; a jar has slipped),
# 48 states.
def jar_slip() -> HeldoutWorld:
    N, SLIP = 6, 1 / 6
    types = ("pickup_self", "robot_fetch", "lost_trust")

    def robot_step(s, a):
        k, jar, slipped = s
        if a == 1 and jar == 0:
            return (k, 1, slipped)  # take the next jar off the conveyor and offer it
        if a == 2 and jar in (0, 1):
            return (k, 2, slipped)  # set the next (or the offered) jar on her bench
        if a == 3 and jar == 3:
            return (k, 2, slipped)  # retrieve the slipped jar from the mat to the bench
        return s

    def human_step(s, h):
        k, jar, slipped = s
        if k == N:
            return None
        if h in (0, 1):  # grab the offered jar and pack it (0), or it slips (1)
            return None if jar != 1 else ((k + 1, 0, slipped) if h == 0 else (k, 3, 1))
        if h == 2:  # collect the jar from the bench and pack it
            return (k + 1, 0, slipped) if jar == 2 else None
        return (k + 1, 0, slipped) if jar == 3 else None  # pick it up off the mat, pack it

    def behaviour(y, m, s, a):
        k, jar, slipped = s
        if k == N or jar == 0:
            return {-1: 1.0}
        if jar == 1:
            if y == 2 and slipped:
                return {-1: 0.7, 0: 0.3 * (1 - SLIP), 1: 0.3 * SLIP}  # would rather not
            return {0: 1.0 - SLIP, 1: SLIP}
        if jar == 2:
            return {2: 1.0} if (y == 2 and slipped) else {2: 0.7, -1: 0.3}
        return {-1: 0.8, 3: 0.2} if y == 1 else {3: 1.0}

    def reward(y, s, a):
        _k, jar, slipped = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        bench_only = y == 2 and slipped
        if jar == 0:
            if bench_only:
                return 1.0 if a == 2 else (-1.0 if a == 1 else -0.2)
            return 1.0 if a == 1 else (0.3 if a == 2 else -0.2)
        if jar == 1:  # she let the offered jar be
            if bench_only:
                return 1.0 if a == 2 else -0.5
            return 0.2 if a == 0 else -0.3
        if jar == 2:
            return 0.2 if a == 0 else -0.5
        if y == 1:  # the jar on the mat
            return 1.0 if a == 3 else -0.3
        return 0.3 if a == 0 else -0.5  # she reaches for it: the robot keeps clear

    return tabulate(
        "jar_slip", initial=(0, 0, 0), robot_actions=("wait", "hand", "bench", "retrieve"),
        human_actions=("grab", "slip", "collect", "pickup"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=24, shares=(0.40, 0.35, 0.25),
    )  # fmt: skip


# ------------------------------------------------------------------------------ pad_sides
# An assembler fits eight components on a board, in a fixed order (small, small, large,
# small, large, small, small, large). The robot stages the next component on the left or the
# right pad of her station (staging on the other pad moves it there); she takes it from the
# pad with that hand and fits it at once if it is on the side she wants, else she reaches
# across for it two turns in five and waits for the robot to move it otherwise. The types
# differ in which hand they use, on some components only: "righty" (45 %) takes every
# component with her right hand; "big_left" (35 %) takes the three large ones with her left
# hand (she steadies the board with the right), the small ones with the right; "left_finish"
# (20 %) moves to the other side of the board after the first four and takes the last four
# with her left hand. The three want the same pad on components 0, 1 and 3 only. State:
# (components fitted, pad: 0 empty, 1 left, 2 right), 25 states.
_PAD_LARGE = (False, False, True, False, True, False, False, True)


def pad_sides() -> HeldoutWorld:
    N = len(_PAD_LARGE)
    types = ("righty", "big_left", "left_finish")

    def side(y, k):  # 1: left, 2: right
        if y == 1:
            return 1 if _PAD_LARGE[k] else 2
        if y == 2:
            return 1 if k >= N // 2 else 2
        return 2

    def robot_step(s, a):
        k, pad = s
        return s if (a == 0 or pad == a) else (k, a)

    def human_step(s, h):
        k, pad = s
        if k == N:
            return None
        return (k + 1, 0) if pad == h + 1 else None  # take_left (h 0), take_right (h 1)

    def behaviour(y, m, s, a):
        k, pad = s
        if k == N or pad == 0:
            return {-1: 1.0}
        if pad == side(y, k):
            return {pad - 1: 1.0}
        return {pad - 1: 0.4, -1: 0.6}  # reaching across is awkward: she mostly waits

    def reward(y, s, a):
        k, pad = s
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # staging it where it already is
        want = side(y, k)
        if pad == want:
            return _pick(0, a, good=0.2)
        return _pick(want, a, idle=-0.3 if pad else -0.2, bad=-0.5)

    return tabulate(
        "pad_sides", initial=(0, 0), robot_actions=("wait", "stage_left", "stage_right"),
        human_actions=("take_left", "take_right"), robot_step=robot_step,
        human_step=human_step, terminal=lambda s: s[0] == N, type_names=types,
        behaviour=behaviour, reward=reward, horizon=24, shares=(0.45, 0.35, 0.20),
    )  # fmt: skip


# ------------------------------------------------------------------------------ tote_pack
# A warehouse packing station: an order of four items (book, mug, towel, candle) goes into a
# box. The robot can bring an item from the shelf into her staging bin (it holds two) or
# print the shipping label; she packs a staged item, fetches one from the shelf herself
# (slower), and closes the box once all four are in, with the printed label or one she
# writes herself (slower). Five types, two of them rare: "in_order" (30 %) packs book, mug,
# towel, candle and wants each brought when she needs it, then the label; "reverse" (28 %)
# the same in the reverse order; "batch_end" (24 %) is "in_order" until two items are left,
# then wants both of them staged at once (she hesitates over the third while the fourth is
# not there): her wish changes with how many items are left; "label_first" (9 %) wants the
# label printed before anything is packed (she mostly waits for it), then is "in_order";
# "self_fragile" (9 %) fetches the fragile items (mug, candle) herself at once and does not
# want them brought (a brought one she packs anyway), "in_order" otherwise. A wrong item in
# the bin she packs out of order a third of the time. State: (per item: 0 on the shelf,
# 1 staged, 2 packed; label printed), 145 states.
_TOTE = ("book", "mug", "towel", "candle")


def tote_pack() -> HeldoutWorld:
    n = len(_TOTE)
    types = ("in_order", "reverse", "batch_end", "label_first", "self_fragile")
    orders = (
        tuple(range(n)), tuple(range(n - 1, -1, -1)), tuple(range(n)), tuple(range(n)),
        tuple(range(n)),
    )  # fmt: skip
    FRAGILE = (1, 3)
    LABEL = n + 1  # the robot's print_label
    PACK, FETCH, CLOSE, WRITE = 0, n, 2 * n, 2 * n + 1  # the person's actions

    def robot_step(s, a):
        items, label = s
        if 1 <= a <= n and items[a - 1] == 0 and items.count(1) < 2:
            return (_set(items, a - 1, 1), label)  # bring it to the bin
        if a == LABEL and not label:
            return (items, 1)
        return s

    def human_step(s, h):
        items, label = s
        if items == "done":
            return None
        if h < 2 * n:  # pack a staged item (h < n), or fetch one from the shelf and pack it
            i, need = h % n, (1 if h < n else 0)
            return (_set(items, i, 2), label) if items[i] == need else None
        if any(v != 2 for v in items) or (h == CLOSE) != bool(label):
            return None
        return ("done", 0)  # close with the printed label (CLOSE) or a written one (WRITE)

    def nxt(y, items):
        return next(i for i in orders[y] if items[i] != 2)

    def behaviour(y, m, s, a):
        items, label = s
        if items == "done":
            return {-1: 1.0}
        if all(v == 2 for v in items):
            return {CLOSE: 1.0} if label else {WRITE: 0.5, -1: 0.5}
        i = nxt(y, items)
        if y == 3 and not label:
            return {-1: 0.7, (PACK + i) if items[i] == 1 else (FETCH + i): 0.3}
        if y == 4 and i in FRAGILE and items[i] == 0:
            return {FETCH + i: 1.0}
        if items[i] == 1:
            left = sum(v != 2 for v in items)
            if y == 2 and left == 2 and 0 in items:
                return {PACK + i: 0.5, -1: 0.5}  # waits for the last item too
            return {PACK + i: 1.0}
        wrong = [j for j in range(n) if items[j] == 1]
        if wrong:
            return {PACK + wrong[0]: 1 / 3, FETCH + i: 1 / 3, -1: 1 / 3}
        return {FETCH + i: 0.4, -1: 0.6}

    def wanted(y, s):  # the robot move the type wants in the state before it
        items, label = s
        if all(v == 2 for v in items) or (y == 3 and not label):
            return 0 if label else LABEL
        i = nxt(y, items)
        if y == 2 and sum(v != 2 for v in items) <= 2:
            rest = [j for j in orders[y] if items[j] == 0]
            return 1 + rest[0] if rest else 0
        if items[i] == 1 or (y == 4 and i in FRAGILE):
            return 0
        return 1 + i

    def reward(y, s, a):
        if a != 0 and robot_step(s, a) == s:
            return -0.5  # a move that changes nothing
        want = wanted(y, s)
        if a == want:
            return 1.0 if a else 0.2
        if a == 0:
            return -0.2
        return -0.3 if a == LABEL else -1.0  # a wrong item clutters the bin

    return tabulate(
        "tote_pack", initial=((0,) * n, 0),
        robot_actions=("wait", *(f"bring_{i}" for i in _TOTE), "print_label"),
        human_actions=(*(f"pack_{i}" for i in _TOTE), *(f"fetch_{i}" for i in _TOTE),
                       "close", "write_label"),
        robot_step=robot_step, human_step=human_step, terminal=lambda s: s[0] == "done",
        type_names=types, behaviour=behaviour, reward=reward, horizon=20,
        shares=(0.30, 0.28, 0.24, 0.09, 0.09),
    )  # fmt: skip


#: Every held-out task by name: ``HELDOUT[name]() -> HeldoutWorld``.
HELDOUT: dict[str, Callable[[], HeldoutWorld]] = {
    "finish_late": finish_late,
    "twins": twins,
    "sorting_moody": sorting_moody,
    "tool_rhythm": tool_rhythm,
    "crew_70_20_10": crew_70_20_10,
    "five_parts": five_parts,
    "slow_sanding": slow_sanding,
    "paint_crews": paint_crews,
    "shelf_kitting": shelf_kitting,
    "station_glance": station_glance,
    "lead_follow_phase": lead_follow_phase,
    "pace_split": pace_split,
    "side_reactive": side_reactive,
    "inspect_last": inspect_last,
    "parcel_hands": parcel_hands,
    "arm_clearance": arm_clearance,
    "glue_cure": glue_cure,
    "handover_timing": handover_timing,
    "panel_wiring": panel_wiring,
    "tool_slot": tool_slot,
    "heavy_lifts": heavy_lifts,
    "kit_batch": kit_batch,
    "check_timing": check_timing,
    "fixture_height": fixture_height,
    "harness_branch": harness_branch,
    "dish_rack": dish_rack,
    "rivet_reach": rivet_reach,
    "press_block": press_block,
    "driver_pick": driver_pick,
    "cabinet_glue": cabinet_glue,
    "defect_rework": defect_rework,
    "shelf_build": shelf_build,
    "leaky_tubes": leaky_tubes,
    "tile_crack": tile_crack,
    "polish_passes": polish_passes,
    "bento_line": bento_line,
    "jar_slip": jar_slip,
    "pad_sides": pad_sides,
    "tote_pack": tote_pack,
}
