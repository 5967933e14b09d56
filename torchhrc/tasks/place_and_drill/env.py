"""The place-and-drill task with its simulated human, as a gymnasium environment.

The robot (the agent) drills screws that a simulated human places (paper, section
"Evaluation"; :mod:`torchhrc.tasks.place_and_drill.model` for the states and actions). The
human is the one of the paper's robustness study (:mod:`torchhrc.experiments.robustness`,
:func:`~torchhrc.tasks.place_and_drill.simulate.step_human`), and every episode is one run::

    at reset:  type y ~ type_probabilities (the expert's types, "safe" / "efficient"),
               placement order ~ a uniformly random permutation of the positions,
               x = 0 (empty bench)
    each step: reward = R_expert[a, x, y]       the hand-coded expert reward of the TRUE type
               m = robot_effect[a, x]           the robot's drill takes effect
               with probability noise the human lets the turn pass (x2 = m); otherwise, if a
               position of m is empty, the human places one: with probability epsilon a
               uniformly random empty position, else the first empty one of its order
    the episode terminates in the all-drilled state and is truncated after ``horizon`` steps.

Rewards are those with which :mod:`~torchhrc.experiments.robustness` scores executions
(undiscounted sum of the true type's expert reward), so the return of an episode is the
paper's Fig. 3 "accumulated reward" of one run.

Spaces are those of a :class:`~torchhrc.envs.momdp_env.MOMDPEnv` of the robot's model
:attr:`PlaceAndDrillEnv.model` (the hand-coded expert MOMDP,
:func:`~torchhrc.tasks.place_and_drill.hand_coded.build_expert_momdp`): ``Dict(x=Discrete(27),
observation=Discrete(2))``, the observation always ``0`` after a step and ``1`` ("no
observation yet") at reset. The model is what a planning robot believes; the human above,
not the model's ``Tx``, moves the episode. ``info`` has the true type (``"y"``, ``"type"``)
for evaluation only.

The dynamics are batched tensors (:class:`PlaceAndDrillHuman`), shared with the vectorised
:class:`~torchhrc.tasks.place_and_drill.vector_env.PlaceAndDrillVectorEnv`; the single
environment is a batch of one. Registered as ``torchhrc/PlaceAndDrill-v0``.

Example:
    >>> env = PlaceAndDrillEnv(epsilon=0.0)
    >>> obs, info = env.reset(seed=0)
    >>> obs, info["type"] in ("safe", "efficient")
    ({'x': 0, 'observation': 1}, True)
    >>> obs, reward, terminated, truncated, info = env.step(0)  # wait: the human places one
    >>> env.task.state_names[obs["x"]].count("P")
    1
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import torch

from torchhrc.envs._base import (
    check_action,
    check_horizon,
    check_probability,
    check_type_probabilities,
    torch_generator,
)
from torchhrc.pomdp import MOMDP
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
from torchhrc.tasks.place_and_drill.simulate import step_human

__all__ = ["PlaceAndDrillEnv", "PlaceAndDrillHuman"]


class PlaceAndDrillHuman:
    """The simulated human and the scoring of the place-and-drill task, batched over runs.

    State of ``N`` runs: ``x (N,)`` int64 bench, ``y (N,)`` int64 type, ``order (N, n)``
    int64 placement order. All methods are tensor programs over the batch.

    Args:
        epsilon: probability of a uniformly random placement (paper Fig. 3's deviation).
        noise: probability that the human skips a turn although a position is empty.
        type_probabilities: ``(Y,)`` probabilities of the expert's types (default uniform).
        expert_path: the hand-coded expert model file (default the shipped one).

    Attributes:
        task: the :class:`~torchhrc.tasks.place_and_drill.model.PlaceAndDrillTask`.
        model: the expert MOMDP (uniform ``b0``), the robot's model.
        type_names: ``(Y,)`` the types.
        score: ``(A, X, Y)`` float64, the reward of each type.

    Example:
        >>> human = PlaceAndDrillHuman(epsilon=0.0)
        >>> g = torch.Generator().manual_seed(0)
        >>> x, y, order = human.initial(3, g)
        >>> x.tolist(), order.sort(-1).values.tolist()[0]
        ([0, 0, 0], [0, 1, 2])
    """

    def __init__(
        self,
        *,
        epsilon: float = 0.1,
        noise: float = 0.0,
        type_probabilities: Sequence[float] | None = None,
        expert_path: str | os.PathLike[str] | None = None,
    ) -> None:
        from torchhrc.tasks.place_and_drill.hand_coded import build_expert_momdp, load_expert_model

        self.epsilon = check_probability("epsilon", epsilon)
        self.noise = check_probability("noise", noise, upper_open=True)
        expert = load_expert_model(expert_path)
        self.task: PlaceAndDrillTask = expert.task
        self.type_names: tuple[str, ...] = expert.type_names
        self.model: MOMDP = build_expert_momdp(expert)
        Y = len(self.type_names)
        probs = check_type_probabilities(type_probabilities, Y)
        self.type_probabilities = probs
        self._type_cdf = probs.cumsum(0)
        self._type_cdf[-1] = 1.0
        self.score = self.model.R.detach().to(torch.float64).contiguous()  # (A, X, Y)
        self._effect = self.task.robot_effect  # (A, X)
        self._status = self.task.status
        self._place = self.task.place_effect

    @property
    def num_types(self) -> int:
        """Y."""
        return len(self.type_names)

    def initial(
        self, n: int, generator: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n`` fresh runs: ``x (n,)`` zeros, ``y (n,)`` drawn types, ``order (n, n_pos)``."""
        u = torch.rand(n, 1 + self.task.n_positions, generator=generator, dtype=torch.float64)
        y = (u[:, :1] >= self._type_cdf).sum(-1).clamp_(max=self.num_types - 1)
        order = u[:, 1:].argsort(-1)
        x = torch.full((n,), self.task.initial_state, dtype=torch.long)
        return x, y, order

    def step(
        self,
        x: torch.Tensor,
        y: torch.Tensor,
        order: torch.Tensor,
        action: torch.Tensor,
        generator: torch.Generator,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of ``N`` runs: ``(x2 (N,), reward (N,))`` for robot actions ``(N,)``."""
        N, n = x.shape[0], self.task.n_positions
        u = torch.rand(N, n + 2, generator=generator, dtype=torch.float64)
        reward = self.score[action, x, y]
        x_mid = self._effect[action, x]
        eps = torch.full((N,), self.epsilon, dtype=torch.float64)
        placed = step_human(self.task, x_mid, order, eps, u[:, 0], u[:, 2:])
        x2 = torch.where(u[:, 1] < self.noise, x_mid, placed)
        return x2, reward


def _attach_human(env: Any, *, epsilon: float, noise: float, horizon: int | None,
                  type_probabilities: Sequence[float] | None,
                  expert_path: str | os.PathLike[str] | None) -> None:  # fmt: skip
    """Give ``env`` (the single or the vector env) its simulated person and what follows from
    it: ``human``, ``task``, ``model``, ``discount`` and ``horizon`` (default 4 steps per
    position)."""
    env.human = PlaceAndDrillHuman(epsilon=epsilon, noise=noise,
                                   type_probabilities=type_probabilities,
                                   expert_path=expert_path)  # fmt: skip
    env.task = env.human.task
    env.model = env.human.model
    env.discount = float(env.model.discount)
    env.horizon = check_horizon(4 * env.task.n_positions if horizon is None else horizon)


class PlaceAndDrillEnv(gym.Env):
    """The place-and-drill task with a simulated human (module docstring).

    Args:
        epsilon: probability of a random placement, in ``[0, 1]`` (default 0.1).
        noise: probability that the human skips a turn, in ``[0, 1)`` (default 0).
        horizon: robot decisions per episode (default ``4 n = 12``, as the robustness study).
        type_probabilities: ``(Y,)`` distribution of the human's type per episode (default
            uniform over the expert's types).
        expert_path: the hand-coded expert model file (default the shipped one).
        render_mode: ``None`` or ``"ansi"`` (the bench, e.g. ``"PDE"``).

    Attributes:
        task: the task's mechanics.
        model: the robot's model, the expert MOMDP (uniform ``b0``).
        discount: the model's discount (rewards are returned undiscounted).
        human: the :class:`PlaceAndDrillHuman`.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        *,
        epsilon: float = 0.1,
        noise: float = 0.0,
        horizon: int | None = None,
        type_probabilities: Sequence[float] | None = None,
        expert_path: str | os.PathLike[str] | None = None,
        render_mode: str | None = None,
    ) -> None:
        if render_mode not in (None, "ansi"):
            raise ValueError(f"expected render_mode None or 'ansi', got {render_mode!r}")
        _attach_human(self, epsilon=epsilon, noise=noise, horizon=horizon,
                      type_probabilities=type_probabilities, expert_path=expert_path)  # fmt: skip
        self.render_mode = render_mode
        self.action_space = gym.spaces.Discrete(self.task.num_actions)
        self.observation_space = gym.spaces.Dict(
            {
                "x": gym.spaces.Discrete(self.task.num_states),
                "observation": gym.spaces.Discrete(2),
            }
        )
        self._generator: torch.Generator | None = None
        self._x, self._y, self._order = self.human.initial(1, torch.Generator().manual_seed(0))
        self._t = 0

    def _info(self) -> dict[str, Any]:
        x, y = int(self._x[0]), int(self._y[0])
        return {
            "x": x,
            "y": y,
            "type": self.human.type_names[y],
            "state": x * self.human.num_types + y,
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, int], dict[str, Any]]:
        """A new run: empty bench, a drawn type and placement order."""
        super().reset(seed=seed)
        if seed is not None or self._generator is None:
            self._generator = torch_generator(self.np_random)
        self._x, self._y, self._order = self.human.initial(1, self._generator)
        self._t = 0
        return {"x": int(self._x[0]), "observation": 1}, self._info()

    def step(self, action: int) -> tuple[dict[str, int], float, bool, bool, dict[str, Any]]:
        """The robot's ``action``, then the human's move."""
        if self._generator is None:
            raise RuntimeError("call reset() before step()")
        a = check_action(action, self.task.num_actions)
        x2, reward = self.human.step(
            self._x, self._y, self._order, torch.tensor([a]), self._generator
        )
        self._x = x2
        self._t += 1
        terminated = int(x2[0]) == self.task.terminal_state
        truncated = not terminated and self.horizon is not None and self._t >= self.horizon
        return (
            {"x": int(x2[0]), "observation": 0},
            float(reward[0]),
            terminated,
            truncated,
            (self._info()),
        )

    def render(self) -> str | None:
        """``"ansi"``: the bench (``E`` empty, ``P`` placed, ``D`` drilled per position)."""
        if self.render_mode != "ansi":
            return None
        return f"t={self._t} {self.task.state_names[int(self._x[0])]}"
