"""Bring your own task: a kitchen where the robot helps a cook of one of three hidden types.

The cook does four sub-tasks (chop, stir, season, plate), each once, in the order of their
type; the type also decides what they want from the robot meanwhile: the "fetcher" wants
the ingredient of their next sub-task fetched, the "wiper" wants the counter wiped, the
"loner" wants to be left alone. We describe the task (torchhrc.tasks.CollaborativeTask),
simulate demonstrations, learn a solved model with one call, and compare the type-aware
robot with a type-agnostic one (an MDP fit to all demonstrations pooled) over simulated
episodes. Walk-through: docs/your_own_task.md.
"""

from __future__ import annotations

import math
import random

import torch

from torchhrc import Demonstrations
from torchhrc.tasks import CollaborativeTask, Controller, learn

SUBTASKS = ("chop", "stir", "season", "plate")
ORDERS = {"fetcher": (0, 1, 2, 3), "wiper": (1, 0, 2, 3), "loner": (0, 2, 1, 3)}
TYPES = tuple(ORDERS)
S = len(SUBTASKS)
FULL = 2**S - 1  # every sub-task done


class Kitchen(CollaborativeTask):
    """x = fetched * 16 + done: ``done`` a bit mask of finished sub-tasks, ``fetched`` 0 for
    nothing or 1 + the sub-task whose ingredient the robot has put on the counter."""

    robot_actions = ("wait", *(f"fetch_{s}" for s in SUBTASKS), "wipe")
    human_actions = tuple(f"do_{s}" for s in SUBTASKS)
    human_model = "state"  # the cook's next sub-task depends on what is done, not on the robot

    def __init__(self) -> None:
        x = torch.arange((S + 1) * 2**S)
        done, fetched = x % 2**S, x // 2**S
        self.state_names = tuple(
            "+".join(s for i, s in enumerate(SUBTASKS) if d >> i & 1) + f"|{f}"
            for d, f in zip(done.tolist(), fetched.tolist())
        )
        bit = 2 ** torch.arange(S).view(S, 1)  # (S, 1)
        is_done = (done & bit) > 0  # (S, X)
        fetch = torch.where(is_done, x, (torch.arange(S).view(S, 1) + 1) * 2**S + done)
        self.robot_effect = torch.cat([x.view(1, -1), fetch, x.view(1, -1)])  # (A, X)
        used = fetched == torch.arange(S).view(S, 1) + 1  # the cook uses what was fetched
        after = torch.where(used, 0, fetched) * 2**S + (done | bit)
        self.human_effect = torch.where(is_done, x, after).T  # (X, H)

    @property
    def terminal(self) -> torch.Tensor:
        return torch.arange(self.num_states) % 2**S == FULL


def next_subtask(kind: str, done: int) -> int:
    return next(i for i in ORDERS[kind] if not done >> i & 1)


def wanted(kind: str, x: int) -> int:
    """The robot action a cook of this type wants in state x."""
    done, fetched = x % 2**S, x // 2**S
    if kind == "fetcher":
        i = next_subtask(kind, done)
        return 0 if fetched == i + 1 else 1 + i
    return 1 + S if kind == "wiper" else 0


def score(kind: str, x: int, a: int) -> float:
    """The cook's own reward: +1 for what they want, 0 for waiting, -1 for anything else."""
    return 1.0 if a == wanted(kind, x) and a != 0 else (0.0 if a == 0 else -1.0)


def human_turn(task: Kitchen, kind: str, x: int, rng: random.Random, slip: float) -> int:
    done = x % 2**S
    legal = [i for i in range(S) if not done >> i & 1]
    return rng.choice(legal) if rng.random() < slip else next_subtask(kind, done)


def demonstrations(task: Kitchen, subjects: int, demos: int, seed: int) -> Demonstrations:
    rng = random.Random(seed)
    seqs, who, kinds = [], [], []
    for s in range(subjects):
        kind = TYPES[s % len(TYPES)]
        for _ in range(demos):
            x, seq = task.initial_state, []
            while x % 2**S != FULL:
                a = wanted(kind, x) if rng.random() > 0.1 else rng.randrange(task.num_actions)
                h = human_turn(task, kind, int(task.robot_effect[a, x]), rng, slip=0.05)
                seq += [("robot", task.robot_actions[a]), ("human", task.human_actions[h])]
                x = int(task.step(torch.tensor(x), torch.tensor(h), torch.tensor(a)))
            seqs.append(seq), who.append(f"s{s}"), kinds.append(kind)
    return Demonstrations.from_lists(seqs, subjects=who, types=kinds)


def episodes(task: Kitchen, controller: Controller, n: int, seed: int) -> torch.Tensor:
    """Accumulated reward of ``n`` episodes against simulated cooks (types in turn)."""
    rng, totals = random.Random(seed), []
    for e in range(n):
        kind, x, total = TYPES[e % len(TYPES)], task.initial_state, 0.0
        controller.reset()
        for _ in range(2 * S):  # a cook may slip; the episode ends when all is done
            a = controller.act(x)
            total += score(kind, x, a)
            h = human_turn(task, kind, int(task.robot_effect[a, x]), rng, slip=0.1)
            x = int(task.step(torch.tensor(x), torch.tensor(h), torch.tensor(a)))
            if x % 2**S == FULL:
                break
        totals.append(total)
    return torch.tensor(totals, dtype=torch.float64)


def mean_ci95(r: torch.Tensor) -> tuple[float, float]:
    return float(r.mean()), 1.96 * float(r.std()) / math.sqrt(r.numel())


def main(seed: int = 0, runs: int = 300) -> dict[str, tuple[float, float]]:
    task = Kitchen()
    demos = demonstrations(task, subjects=18, demos=3, seed=seed)
    aware = learn(task, demos, k_min=1, k_max=4, restarts=5, seed=seed, solver_time=10.0)
    agnostic = learn(task, demos, k=1, seed=seed, solver_time=10.0)  # pooled: an MDP
    print(f"types found: {aware.num_types} ({aware.info['k']} by BIC); bounds "
          f"[{aware.lower:.3f}, {aware.upper:.3f}]")  # fmt: skip
    results = {}
    for name, model in (("type-aware", aware), ("type-agnostic", agnostic)):
        mean, half = mean_ci95(episodes(task, Controller.from_model(model), runs, seed + 1))
        results[name] = (mean, half)
        print(f"{name:14s} mean reward {mean:6.3f} +- {half:.3f} (95% CI, {runs} episodes)")
    return results


if __name__ == "__main__":
    main()
