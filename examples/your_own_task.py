"""Bring your own task: a kitchen where the robot helps a cook of one of three hidden types.

The cook does four sub-tasks (chop, stir, season, plate), each once, in the order of their
type; the type also decides what they want from the robot meanwhile: the "fetcher" wants
the ingredient of their next sub-task fetched, the "wiper" wants the counter wiped, the
"loner" wants to be left alone. We describe the task (torchhrc.tasks.CollaborativeTask) and
its simulated cooks (TaskWithPeople: who they are, what each type is paid), generate
demonstrations, learn a solved model with one call, and compare the type-aware robot with a
type-agnostic one (an MDP fit to all demonstrations pooled) with torchhrc.evaluate_task.
Walk-through: docs/your_own_task.md.
"""

from __future__ import annotations

import torch

from torchhrc import Demonstrations, evaluate_task
from torchhrc.tasks import CollaborativeTask, TabularPeople, TaskWithPeople, learn

SUBTASKS = ("chop", "stir", "season", "plate")
ORDERS = {"fetcher": (0, 1, 2, 3), "wiper": (1, 0, 2, 3), "loner": (0, 2, 1, 3)}
TYPES = tuple(ORDERS)
S = len(SUBTASKS)
FULL = 2**S - 1  # every sub-task done
# a state: (done, fetched): a bit mask of finished sub-tasks, and 0 for nothing on the counter
# or 1 + the sub-task whose ingredient the robot put there (never one already done)
STATES = [(d, f) for f in range(S + 1) for d in range(2**S) if f == 0 or not d >> (f - 1) & 1]
INDEX = {s: i for i, s in enumerate(STATES)}


class Kitchen(CollaborativeTask):
    """48 states ``(done, fetched)``; the robot waits, fetches an ingredient or wipes."""

    state_names = tuple(
        "+".join(s for i, s in enumerate(SUBTASKS) if d >> i & 1) + f"|{f}" for d, f in STATES
    )
    robot_actions = ("wait", *(f"fetch_{s}" for s in SUBTASKS), "wipe")
    human_actions = tuple(f"do_{s}" for s in SUBTASKS)
    human_model = "state"  # the cook's next sub-task depends on what is done, not on the robot

    def __init__(self) -> None:
        robot, human = [], []
        for d, f in STATES:
            fetch = [INDEX[(d, f)] if d >> i & 1 else INDEX[(d, i + 1)] for i in range(S)]
            robot.append([INDEX[(d, f)], *fetch, INDEX[(d, f)]])
            # a done sub-task: no effect; else done, and its ingredient used up
            after = [INDEX[(d | 1 << i, 0 if f == i + 1 else f)] for i in range(S)]
            human.append([INDEX[(d, f)] if d >> i & 1 else after[i] for i in range(S)])
        self.robot_effect = torch.tensor(robot).T  # (A, X)
        self.human_effect = torch.tensor(human)  # (X, H)

    @property
    def terminal(self) -> torch.Tensor:
        return torch.tensor([d == FULL for d, _ in STATES])


def next_subtask(kind: str, done: int) -> int:
    return next(i for i in ORDERS[kind] if not done >> i & 1)


def wanted(kind: str, x: int) -> int:
    """The robot action a cook of this type wants in state x."""
    done, fetched = STATES[x]
    if kind == "fetcher":
        i = next_subtask(kind, done)
        return 0 if fetched == i + 1 else 1 + i
    return 1 + S if kind == "wiper" else 0


def score(kind: str, x: int, a: int) -> float:
    """The cook's own reward: +1 for what they want, 0 for waiting, -1 for anything else."""
    return 1.0 if a == wanted(kind, x) and a != 0 else (0.0 if a == 0 else -1.0)


def kitchen_with_cooks(task: Kitchen) -> TaskWithPeople:
    """The task with its simulated cooks of known types and their true rewards."""
    X, A, H = task.num_states, task.num_actions, task.num_human_actions
    policy = torch.zeros(len(TYPES), 1, X, A, H + 1, dtype=torch.float64)  # (Y, M, X, A, H+1)
    reward = torch.zeros(A, X, len(TYPES), dtype=torch.float64)  # (A, X, Y)
    for y, kind in enumerate(TYPES):
        for x, (done, _) in enumerate(STATES):
            if done == FULL:  # the end: no action, no reward
                policy[y, 0, x, :, H] = 1.0
                continue
            policy[y, 0, x, :, next_subtask(kind, done)] = 1.0
            reward[:, x, y] = torch.tensor([score(kind, x, a) for a in range(A)])
    people = TabularPeople(TYPES, policy, task.human_legal, task=task)
    return TaskWithPeople(task, people, reward, horizon=2 * S, observed=False)


def demonstrations(task: Kitchen, subjects: int, demos: int, seed: int) -> Demonstrations:
    """``subjects`` cooks (types in turn, named in ``.types``), ``demos`` sequences each, with a
    partner doing what they want; the robot and the cook slip 1 time in 20."""
    world = kitchen_with_cooks(task)
    return world.demonstrations(subjects=subjects, per_subject=demos, noise=0.05, seed=seed)[0]


def main(seed: int = 0, runs: int = 300) -> dict[str, tuple[float, float]]:
    world = kitchen_with_cooks(Kitchen())
    demos = demonstrations(world.task, subjects=18, demos=3, seed=seed)
    aware = learn(world.task, demos, k_min=1, k_max=4, restarts=5, seed=seed, solver_time=5.0)
    agnostic = learn(world.task, demos, k=1, seed=seed, solver_time=5.0)  # pooled: an MDP
    print(f"types found: {aware.num_types} (by {aware.info.get('criterion', 'BIC')}); "
          f"human model {aware.info.get('human_model', {}).get('used', 'state')}; "
          f"bounds [{aware.lower:.3f}, {aware.upper:.3f}]")  # fmt: skip
    # against the simulated cooks (slipping 1 time in 10), scored by each cook's own reward;
    # "true model": a robot planning on the cooks' true behaviour and rewards (what finding
    # the type online can gain at all)
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic,
                           episodes=runs // len(TYPES), noise=0.1, belief_steps=(1, 2, 4),
                           true_model=True, seed=seed + 1)  # fmt: skip
    print(result.table())
    print(result.summary())  # ahead/level/behind, what can be gained, types not found
    results = {}
    for r, name in enumerate(result.robots):
        mean, half = float(result.overall_mean[r]), float(result.overall_ci[r])
        results[name] = (mean, half)
        print(f"{name:14s} mean reward {mean:6.3f} +- {half:.3f} (95% CI, {runs} episodes)")
    return results


if __name__ == "__main__":
    main()
