"""Simulated persons of the hand-finishing task: demonstrations and closed-loop episodes.

A person works one side of the box first (``"left"`` or ``"right"``), then the other. Their
hand, seen from above, is at the surface they work on next plus a personal offset, with
Gaussian noise (the generating model of
:meth:`~torchhrc.tasks.hand_finishing.model.HandFinishingTask.observation_model`).

Demonstrations (for clustering into types, as the paper's joint-action sequences): the robot
presents a side, the person works on it for a few units, the robot presents the other side,
the person finishes it. Each subject has a slip probability: at a step the person may work
the other side for a unit, or the robot may wait.

Example:
    >>> d = simulate_demonstrations(["left", "right"], demos_per_subject=2, seed=0)
    >>> d.num_sequences, d.types[:2]
    (4, ('left', 'left'))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from torchhrc.belief import momdp_update
from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.observation import DiscretizedGaussianObservation, discretize_positions
from torchhrc.pomdp import MOMDP

__all__ = ["Episodes", "demonstration_vocabulary", "simulate_demonstrations", "simulate_episodes"]


def demonstration_vocabulary() -> tuple[tuple[str, str], ...]:
    """The demonstrations' symbols: the side the robot presents and the side worked on.

    Example:
        >>> demonstration_vocabulary()[0]
        ('human', 'work_left')
    """
    return (
        ("human", "work_left"),
        ("human", "work_right"),
        ("robot", "present_left"),
        ("robot", "present_right"),
        ("robot", "wait"),
    )


def simulate_demonstrations(
    first_sides: Sequence[str],
    *,
    demos_per_subject: int = 3,
    work_units: int = 4,
    slip: float = 0.1,
    seed: int = 0,
) -> Demonstrations:
    """Demonstrations of simulated subjects, one subject per entry of ``first_sides``.

    Args:
        first_sides: each subject's first side, ``"left"`` or ``"right"`` (their hidden type,
            stored in ``types`` for scoring only).
        demos_per_subject: sequences per subject.
        work_units: work units per side.
        slip: per-step probability of a slip (the robot waits, or the person works a unit of
            the other side).
        seed: seed.

    Returns:
        :class:`~torchhrc.data.Demonstrations` with subjects ``"s0"``, ``"s1"``, ...
    """
    if not 0.0 <= slip < 0.5:
        raise ModelError(f"expected slip in [0, 0.5), got {slip}")
    gen = torch.Generator().manual_seed(int(seed))
    sequences, subjects, types = [], [], []
    for i, first in enumerate(first_sides):
        if first not in ("left", "right"):
            raise ModelError(f"expected first_sides in ('left', 'right'), got {first!r}")
        second = "right" if first == "left" else "left"
        for _ in range(demos_per_subject):
            seq: list[tuple[str, str]] = []
            for side, other in ((first, second), (second, first)):
                seq.append(("robot", f"present_{side}"))
                done = 0
                while done < work_units:
                    u = float(torch.rand((), generator=gen))
                    if u < slip / 2:
                        seq.append(("robot", "wait"))
                    elif u < slip:
                        seq.append(("human", f"work_{other}"))
                    else:
                        seq.append(("human", f"work_{side}"))
                        done += 1
            sequences.append(seq)
            subjects.append(f"s{i}")
            types.append(first)
    return Demonstrations.from_lists(
        sequences, subjects=subjects, types=types, vocabulary=demonstration_vocabulary()
    )


@dataclass(frozen=True)
class Episodes:
    """Closed-loop episodes, ``N`` at once, ``L`` steps.

    Attributes:
        observed: ``(N, L + 1)`` int64 observed states.
        actions: ``(N, L)`` int64 robot actions.
        cells: ``(N, L)`` int64 observed grid cells.
        positions: ``(N, L, 2)`` hand positions.
        beliefs: ``(N, L + 1, Y)`` the robot's belief over the type before each step.
        types: ``(N,)`` int64 true type values.
        rewards: ``(N, L)`` rewards received.
    """

    observed: torch.Tensor
    actions: torch.Tensor
    cells: torch.Tensor
    positions: torch.Tensor
    beliefs: torch.Tensor
    types: torch.Tensor
    rewards: torch.Tensor

    def wait_steps(self) -> torch.Tensor:
        """``(N,)`` steps the robot waited before its first move (``L`` if it never moved)."""
        moved = self.actions != 0
        first = torch.where(moved.any(-1), moved.int().argmax(-1), self.actions.shape[-1])
        return first

    def belief_at_first_move(self) -> torch.Tensor:
        """``(N, Y)`` the belief on which the robot made its first move (or the last one)."""
        idx = self.wait_steps().clamp(max=self.actions.shape[-1])
        return self.beliefs[torch.arange(self.beliefs.shape[0]), idx]


@torch.no_grad()
def simulate_episodes(
    model: MOMDP,
    policy: object,
    truth: MOMDP,
    person: DiscretizedGaussianObservation,
    types: torch.Tensor,
    *,
    steps: int,
    seed: int = 0,
) -> Episodes:
    """Run the robot's policy against simulated persons, all episodes batched.

    The person of true type ``types[n]`` moves the task (``x2 ~ truth.Tx[a, x, y]``) and shows their
    hand (a sample of ``person``, the TRUE observation model); the robot sees the hand's grid
    cell, updates its belief with ``model`` (its own, possibly learned, observation model;
    paper Eq. 3) and acts by ``policy.action(x, belief)``.

    Args:
        model: the robot's MOMDP (``Tx``, ``Z``, ``b0``, ``x0``), its type values those of
            the clusters it learned.
        truth: the true task MOMDP (``Tx``, ``R``), indexed by the true types.
        policy: an object with ``action(x (N,), belief (N, Y)) -> (N,)``.
        person: the true hand-position model (its ``Y`` true types index ``types``).
        types: ``(N,)`` int64 true type of each episode.
        steps: ``L``.
        seed: seed.

    Raises:
        ModelError: a hand cell has probability zero under the robot's model.

    Example:
        >>> from torchhrc.solvers import AlphaVectorPolicy
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 4, seed=0)
        >>> from torchhrc.observation import ObservationGrid
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> hand = DiscretizedGaussianObservation(g, torch.zeros(2, dtype=torch.float64),
        ...     torch.ones(2, dtype=torch.float64), num_observed=3, num_hidden=2, num_actions=2)
        >>> m = MOMDP(Tx=m.Tx, Ty=None, Z=hand().contiguous(), R=m.R, x0=0, b0=m.b0, discount=0.9)
        >>> wait = AlphaVectorPolicy(torch.zeros(3, 2, dtype=torch.float64), torch.zeros(3,
        ...     dtype=torch.long), observed=torch.arange(3))
        >>> simulate_episodes(m, wait, m, hand, torch.tensor([0, 1]), steps=4).wait_steps().tolist()
        [4, 4]
    """
    types = torch.as_tensor(types, dtype=torch.long)
    n = types.shape[0]
    gen = torch.Generator().manual_seed(int(seed))
    x = torch.full((n,), model.x0, dtype=torch.long)
    b = model.b0.expand(n, model.num_hidden).clone()
    observed, actions, cells, positions, beliefs, rewards = [x], [], [], [], [b], []
    for _ in range(steps):  # a closed loop is sequential in time
        a = policy.action(x, b)  # type: ignore[attr-defined]
        rewards.append(truth.R[a, x, types])
        x2 = torch.multinomial(truth.Tx[a, x, types], 1, generator=gen).squeeze(-1)
        pos = person.sample(x2, types, generator=gen)
        cell = discretize_positions(person.grid, pos)
        b = momdp_update(model, x, b, a, x2, cell).belief
        x = x2
        for lst, v in ((observed, x), (actions, a), (cells, cell), (positions, pos), (beliefs, b)):
            lst.append(v)
    return Episodes(
        observed=torch.stack(observed, 1),
        actions=torch.stack(actions, 1),
        cells=torch.stack(cells, 1),
        positions=torch.stack(positions, 1),
        beliefs=torch.stack(beliefs, 1),
        types=types,
        rewards=torch.stack(rewards, 1),
    )
