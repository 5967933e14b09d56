"""The hand-finishing task through the task interface (:mod:`torchhrc.tasks.interface`).

:class:`HandFinishingCollaborativeTask` states the hand-finishing mechanics of
:class:`~torchhrc.tasks.hand_finishing.model.HandFinishingTask` in the interface's terms, so
that :func:`torchhrc.tasks.pipeline.build_model` builds its MOMDP like any other task's:

* ``x = c * P + p`` (configuration, progress), the robot's actions move the box
  (``robot_effect[a, x] = neighbour[a, c] * P + p``), the one human action ``work``
  completes a unit (``p -> p + 1``), the task is done at ``p = P - 1`` (terminal);
* the types come from the clusters: each cluster's chain says which side that person works
  first (:func:`first_sides_from_chains`, paper: the clusters are the preference types), and
  the type's behaviour is the task's: it works with probability ``work_probability`` when the
  box presents the side it works on next;
* the reward is the task's (:meth:`~CollaborativeTask.known_reward`; no IRL: the
  demonstrations are at the level of sides, not box configurations, and are used for the
  clustering only, so :meth:`read_steps` reads none);
* the robot observes the person through a noisy hand-position signal: ``observation`` gives
  ``Z (A, X, Y, O)`` for the model without it (e.g. a learned
  :class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation`).

Example:
    >>> import torch
    >>> from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
    >>> geometry = BoxGeometry(horizontal=(0.0,), vertical=(0.2, 0.4), tilt=(-0.5, 0.0, 0.5))
    >>> base = HandFinishingTask.build(feasible=torch.ones(1, 2, 3, 2, dtype=torch.bool),
    ...                                geometry=geometry, work_units=2)
    >>> task = HandFinishingCollaborativeTask(base)
    >>> task.num_states, task.num_actions, task.human_actions
    (30, 7, ('work',))
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.hand_finishing.model import _MOVES, ACTIONS, HandFinishingTask
from torchhrc.tasks.interface import CollaborativeTask, TaskSteps, TypeEvidence

if TYPE_CHECKING:
    from torchhrc.pomdp import MOMDP

__all__ = ["HandFinishingCollaborativeTask", "first_sides_from_chains"]


def first_sides_from_chains(
    chains: torch.Tensor, vocabulary: Sequence[tuple[str, str]]
) -> tuple[str, ...]:
    """The side each cluster works first, from its Markov chain over the demonstrations.

    A left-first person goes from working the left side to the robot presenting the right
    one; a right-first person the other way round. Cluster ``k`` is ``"left"``-first when
    ``T[k, work_left, present_right] + T[k, work_left, work_right] >
    T[k, work_right, present_left] + T[k, work_right, work_left]``.

    Args:
        chains: ``(K, V, V)`` chains.
        vocabulary: ``(V,)`` symbols, with ``human:work_left``, ``human:work_right``,
            ``robot:present_left``, ``robot:present_right``.

    Raises:
        ModelError: a symbol is missing.

    Example:
        >>> v = [("human", "work_left"), ("human", "work_right"), ("robot", "present_left"),
        ...      ("robot", "present_right")]
        >>> T = torch.zeros(1, 4, 4); T[0, 0, 3] = 1.0
        >>> first_sides_from_chains(T, v)
        ('left',)
    """
    idx = {tuple(step): i for i, step in enumerate(vocabulary)}
    need = [("human", "work_left"), ("human", "work_right"), ("robot", "present_left"),
            ("robot", "present_right")]  # fmt: skip
    missing = [f"{a}:{b}" for a, b in need if (a, b) not in idx]
    if missing:
        raise ModelError(f"the demonstrations' vocabulary lacks {', '.join(missing)}")
    wl, wr, pl, pr = (idx[s] for s in need)
    T = chains
    score = T[:, wl, pr] + T[:, wl, wr] - T[:, wr, pl] - T[:, wr, wl]
    return tuple("left" if float(s) > 0 else "right" for s in score)


@dataclass(frozen=True, eq=False)
class HandFinishingCollaborativeTask(CollaborativeTask):
    """Hand-finishing as a :class:`~torchhrc.tasks.interface.CollaborativeTask`.

    Args:
        base: the task's configurations and constants (its ``first_sides`` are ignored: the
            types come from the clusters).
        observation_model: ``observation_model(model) -> Z (A, X, Y, O)`` for the learned
            model without an observation (``None``: the trivial observation).
    """

    base: HandFinishingTask
    observation_model: Callable[[MOMDP], torch.Tensor] | None = None

    human_actions = ("work",)
    robot_actions = ACTIONS
    feature_names = ("move", "presents_a_side")

    @property
    def discount(self) -> float:  # type: ignore[override]
        return self.base.rewards.discount

    @property
    def initial_state(self) -> int:
        return self.base.x0

    @cached_property
    def state_names(self) -> tuple[str, ...]:  # type: ignore[override]
        P = self.base.num_progress
        return tuple(
            f"c{int(c)}(h{h},v{v},t{t})/p{p}"
            for c, (h, v, t) in enumerate(self.base.kept.tolist())
            for p in range(P)
        )

    @cached_property
    def _cp(self) -> tuple[torch.Tensor, torch.Tensor]:
        C, P = self.base.num_configurations, self.base.num_progress
        c = torch.arange(C).view(C, 1).expand(C, P).reshape(-1)
        p = torch.arange(P).view(1, P).expand(C, P).reshape(-1)
        return c, p

    @cached_property
    def robot_effect(self) -> torch.Tensor:  # type: ignore[override]
        c, p = self._cp
        return self.base.neighbour[:, c] * self.base.num_progress + p

    @cached_property
    def human_effect(self) -> torch.Tensor:  # type: ignore[override]
        c, p = self._cp
        x = torch.arange(c.shape[0])
        return torch.where(p < self.base.num_progress - 1, x + 1, x).view(-1, 1)

    @property
    def terminal(self) -> torch.Tensor:
        return self._cp[1] == self.base.num_progress - 1

    def features(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """``(A, X, 2)``: the action is a move; the box presents a side after it (not done)."""
        c = self._cp[0]
        move = torch.tensor([d != 0 for _, d in _MOVES], dtype=dtype).view(-1, 1)
        c2 = self.base.neighbour[:, c]
        presents = self.base.presents[c2].any(-1) & ~self.terminal
        phi = torch.stack([move.expand_as(presents.to(dtype)), presents.to(dtype)], -1)
        return (phi * (~self.terminal).to(dtype).view(1, -1, 1)).to(device)

    def read_steps(self, demonstrations: object) -> TaskSteps | None:  # type: ignore[override]
        """None: the demonstrations (sides, not configurations) serve the clustering only."""
        return None

    def typed(self, evidence: TypeEvidence) -> HandFinishingTask:
        """The base task with the clusters' first sides."""
        return replace(
            self.base, first_sides=first_sides_from_chains(evidence.chains, evidence.vocabulary)
        )

    def human_policy(self, evidence: TypeEvidence) -> torch.Tensor:
        """``(Y, A, X, 2)``: work with ``work_probability`` when the box presents the side
        type ``y`` works on next (after the robot's move), else let the step pass."""
        task = self.typed(evidence)
        c, p = self._cp
        done = p == task.num_progress - 1
        side = task.side_next(p)  # (X, Y)
        c2 = task.neighbour[:, c]  # (A, X)
        presented = task.presents[c2.unsqueeze(-1), side.unsqueeze(0)]  # (A, X, Y)
        work = presented & ~done.view(1, -1, 1)
        dtype = evidence.chains.dtype
        prob = task.rewards.work_probability * work.to(dtype)
        return torch.stack([prob, 1.0 - prob], -1).permute(2, 0, 1, 3)

    def known_reward(self, evidence: TypeEvidence) -> torch.Tensor:
        """The task's reward ``(A, X, Y)`` for the clusters' sides."""
        return self.typed(evidence)._tensors(evidence.chains.dtype)[1]

    def type_names(self, evidence: TypeEvidence) -> tuple[str, ...]:
        """``"left-first"`` / ``"right-first"`` per cluster."""
        return tuple(
            f"{s}-first" for s in first_sides_from_chains(evidence.chains, evidence.vocabulary)
        )

    def observation(self, model: MOMDP) -> torch.Tensor | None:
        """The hand-position signal's ``Z`` (``observation_model(model)``), or None."""
        return None if self.observation_model is None else self.observation_model(model)

    def learned_momdp(
        self,
        demonstrations: object,
        chains: torch.Tensor,
        assignments: torch.Tensor,
        observation: Callable[[], torch.Tensor] | None = None,
    ) -> MOMDP:
        """The robot's MOMDP by :func:`torchhrc.tasks.pipeline.build_model` from the clusters
        (``chains (K, V, V)``, ``assignments (N,)``), with ``Z = observation()`` (e.g. a
        :class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation`, detached) or the
        trivial observation."""
        from torchhrc.tasks.pipeline import build_model

        task = self
        if observation is not None:
            task = replace(self, observation_model=lambda m: observation().detach().to(m.Tx.dtype))
        return build_model(task, demonstrations, chains, assignments).momdp
