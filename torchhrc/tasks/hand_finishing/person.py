"""Simulated persons of the hand-finishing task: demonstrations and closed-loop episodes.

A person works one side of the box first (``"left"`` or ``"right"``), then the other. Their
hand, seen from above, walks towards the surface they work on next (plus a personal offset):
the mean of
:meth:`~torchhrc.tasks.hand_finishing.model.HandFinishingTask.observation_model`, the hand's
*target*. The hand does not jump there: it starts where the person stands
(:attr:`HandMotion.start`, in front of the box) and covers a fraction
:attr:`HandMotion.approach` of the remaining distance at every step, a first-order (exponential)
approach, ``h_t = h_t-1 + approach * (target(x_t, y) - h_t-1)``, so that a left-first person's
hand traces a path to the left surface, then, once that side is finished, across to the right
one (the paper's Fig. 4(b)). The robot's sensor sees ``h_t`` plus Gaussian noise of the
observation model's covariance. The robot's model (a Gaussian around the target, the paper's
form) therefore does not know about the lag: it is learned from such tracks
(:func:`simulate_hand_tracks`) and absorbs it in its fitted mean and spread.

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

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.approach_observation import ApproachObservation
from torchhrc.pomdp.belief import momdp_update
from torchhrc.pomdp.observation import (
    DiscretizedGaussianObservation,
    discretize_positions,
    sample_positions,
)
from torchhrc.pomdp.observation_fit import HandTracks, simulate_tracks

__all__ = [
    "Episodes",
    "HandMotion",
    "demonstration_vocabulary",
    "hand_trajectories",
    "simulate_demonstrations",
    "simulate_episodes",
    "simulate_hand_tracks",
]


@dataclass(frozen=True, kw_only=True)
class HandMotion:
    """How the simulated person's hand moves (see the module docstring).

    Attributes:
        approach: fraction of the remaining distance to the target the hand covers per step,
            in ``(0, 1]`` (``1``: the hand is at its target at every step, no trajectory).
        start: ``(x, y)`` hand position before the first step, in the robot base frame (m):
            where the person stands, in front of the box (default 1.2 m from the robot, on
            the centre line).

    Example:
        >>> HandMotion(approach=0.5).approach
        0.5
    """

    approach: float = 0.8
    start: tuple[float, float] = (1.2, 0.0)

    def __post_init__(self) -> None:
        if not (isinstance(self.approach, (int, float)) and 0.0 < self.approach <= 1.0):
            raise ModelError(f"expected approach in (0, 1], got {self.approach!r}")
        if len(self.start) != 2 or not all(math.isfinite(float(v)) for v in self.start):
            raise ModelError(f"expected start to be two finite numbers (x, y), got {self.start!r}")
        object.__setattr__(self, "start", (float(self.start[0]), float(self.start[1])))
        object.__setattr__(self, "approach", float(self.approach))

    def step(self, hand: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """One step of the approach: ``hand (..., 2) + approach * (target (..., 2) - hand)``."""
        return hand + self.approach * (target - hand)

    def start_like(self, reference: torch.Tensor) -> torch.Tensor:
        """``(2,)`` the start position on ``reference``'s device and dtype."""
        return reference.new_tensor(self.start)


def hand_trajectories(targets: torch.Tensor, motion: HandMotion) -> torch.Tensor:
    """The hand's path ``(..., L, 2)`` towards the targets ``(..., L, 2)`` of steps ``0 .. L-1``.

    The recursion ``h_t = (1 - a) h_t-1 + a g_t`` from ``h_-1 = start`` in closed form, all
    steps at once: ``h_t = (1 - a)^(t+1) start + sum_k<=t a (1 - a)^(t-k) g_k`` (a lower
    triangular ``(L, L)`` weight matrix applied to the targets).

    Example:
        >>> g = torch.tensor([[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]], dtype=torch.float64)
        >>> hand_trajectories(g, HandMotion(approach=0.5, start=(0.0, 0.0)))[:, 1].tolist()
        [0.5, 0.75, 0.875]
    """
    if targets.dim() < 2 or targets.shape[-1] != 2:
        raise ModelError(
            f"expected targets to have shape (..., L, 2), actual shape = {tuple(targets.shape)}"
        )
    L = targets.shape[-2]
    a = motion.approach
    t = torch.arange(L, device=targets.device, dtype=targets.dtype)
    lag = t.unsqueeze(-1) - t  # (L, L) t - k
    keep = 1.0 - a
    weights = torch.where(lag >= 0, a * keep ** lag.clamp(min=0), torch.zeros_like(lag))
    from_start = (keep ** (t + 1)).unsqueeze(-1) * motion.start_like(targets)  # (L, 2)
    return weights @ targets + from_start


@torch.no_grad()
def simulate_hand_tracks(
    truth: MOMDP,
    person: DiscretizedGaussianObservation,
    *,
    num_tracks: int,
    length: int,
    motion: HandMotion | None = None,
    actions: torch.Tensor | None = None,
    seed: int = 0,
) -> HandTracks:
    """Recorded hand tracks of simulated persons, for learning the observation model.

    The task's states and the persons' types are drawn as in
    :func:`torchhrc.pomdp.observation_fit.simulate_tracks` (type ``y ~ b0``, robot actions
    uniform at random unless given, ``x_t+1 ~ Tx[a_t, x_t, y]``); the hand follows ``motion``
    towards ``person``'s mean for ``(x_t+1, y)`` (:func:`hand_trajectories`), and the sensor adds
    ``person``'s Gaussian noise.

    Args:
        truth: the task MOMDP (``Tx``, ``b0``, ``x0``).
        person: the true hand model (its means are the targets, its covariances the noise).
        num_tracks: ``N``.
        length: ``L`` steps per track.
        motion: the hand's motion (default :class:`HandMotion`).
        actions: ``(N, L)`` int64 robot actions (default uniform random).
        seed: seed.

    Returns:
        :class:`~torchhrc.pomdp.observation_fit.HandTracks` with ``positions`` (the sensed
        positions) and ``types`` filled.
    """
    motion = HandMotion() if motion is None else motion
    base = simulate_tracks(person, truth, num_tracks=num_tracks, length=length,
                           actions=actions, seed=seed)  # fmt: skip
    x2, y = base.observed[:, 1:], base.types.unsqueeze(-1)  # (N, L), (N, 1)
    targets = person.mean()[x2, y]  # (N, L, 2)
    hands = hand_trajectories(targets, motion)
    rho = person.correlation()
    gen = torch.Generator(device=targets.device).manual_seed(int(seed) + 1)
    sensed = sample_positions(hands, scale=person.scale()[x2, y],
                              correlation=None if rho is None else rho[x2, y],
                              generator=gen)  # fmt: skip
    return HandTracks(
        observed=base.observed,
        actions=base.actions,
        cells=discretize_positions(person.grid, sensed),
        lengths=base.lengths,
        positions=sensed,
        types=base.types,
    )


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
        positions: ``(N, L, 2)`` sensed hand positions (hand plus sensor noise).
        beliefs: ``(N, L + 1, Y)`` the robot's belief over the type before each step.
        types: ``(N,)`` int64 true type values.
        rewards: ``(N, L)`` rewards received.
        hands: ``(N, L + 1, 2)`` the hand's true path, from its start (``None`` when not
            recorded).
    """

    observed: torch.Tensor
    actions: torch.Tensor
    cells: torch.Tensor
    positions: torch.Tensor
    beliefs: torch.Tensor
    types: torch.Tensor
    rewards: torch.Tensor
    hands: torch.Tensor | None = None

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
    motion: HandMotion | None = None,
    seed: int = 0,
    observer: ApproachObservation | None = None,
) -> Episodes:
    """Run the robot's policy against simulated persons, all episodes batched.

    The person of true type ``types[n]`` moves the task (``x2 ~ truth.Tx[a, x, y]``); their
    hand moves towards ``person``'s mean for ``(x2, y)`` (``motion``, see the module
    docstring) and the sensor adds ``person``'s noise (the TRUE observation model); the robot
    sees the grid cell of the sensed position, updates its belief with ``model`` (its own,
    possibly learned, observation model; paper Eq. 3) and acts by ``policy.action(x, belief)``.

    Args:
        model: the robot's MOMDP (``Tx``, ``Z``, ``b0``, ``x0``), its type values those of
            the clusters it learned.
        truth: the true task MOMDP (``Tx``, ``R``), indexed by the true types.
        policy: an object with ``action(x (N,), belief (N, Y)) -> (N,)``.
        person: the true hand-position model (its ``Y`` true types index ``types``).
        types: ``(N,)`` int64 true type of each episode.
        steps: ``L``.
        motion: the hand's motion (default :class:`HandMotion`; ``HandMotion(approach=1)``
            puts the hand at its target at every step).
        seed: seed.
        observer: when given, the robot's belief filter uses this approach model of the
            hand (:meth:`~torchhrc.pomdp.approach_observation.ApproachObservation.filter_update`)
            instead of ``model.Z``; the policy is still ``policy``.

    Raises:
        ModelError: a hand cell has probability zero under the robot's model.

    Example:
        >>> from torchhrc.solvers import AlphaVectorPolicy
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 4, seed=0)
        >>> from torchhrc.pomdp.observation import ObservationGrid
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
    motion = HandMotion() if motion is None else motion
    means, scales, rho = person.mean(), person.scale(), person.correlation()
    hand = motion.start_like(means).expand(n, 2)
    observed, actions, cells, positions, beliefs, rewards = [x], [], [], [], [b], []
    hands = [hand]
    tracked = None if observer is None else observer.filter_start(n)
    for _ in range(steps):  # a closed loop is sequential in time
        a = policy.action(x, b)  # type: ignore[attr-defined]
        rewards.append(truth.R[a, x, types])
        x2 = torch.multinomial(truth.Tx[a, x, types], 1, generator=gen).squeeze(-1)
        hand = motion.step(hand, means[x2, types])
        pos = sample_positions(hand, scale=scales[x2, types],
                               correlation=None if rho is None else rho[x2, types],
                               generator=gen)  # fmt: skip
        cell = discretize_positions(person.grid, pos)
        if observer is None:
            b = momdp_update(model, x, b, a, x2, cell).belief
        else:
            b, tracked = observer.filter_update(model, x, b, a, x2, cell, tracked)
        x = x2
        for lst, v in ((observed, x), (actions, a), (cells, cell), (positions, pos), (beliefs, b),
                       (hands, hand)):  # fmt: skip
            lst.append(v)
    return Episodes(
        observed=torch.stack(observed, 1),
        actions=torch.stack(actions, 1),
        cells=torch.stack(cells, 1),
        positions=torch.stack(positions, 1),
        beliefs=torch.stack(beliefs, 1),
        types=types,
        rewards=torch.stack(rewards, 1),
        hands=torch.stack(hands, 1),
    )
