"""The hand-finishing task with its simulated person, as a gymnasium environment.

``pip install torchhrc[gym]``: this module imports gymnasium. ``import torchhrc.envs`` registers
it as ``torchhrc/HandFinishing-v0`` (entry point ``torchhrc.tasks.hand_finishing.env:
HandFinishingEnv``; the generic :mod:`torchhrc.envs` imports no task).

The robot (the agent) holds a box whose two sides a person refinishes by hand (paper,
"Online estimation of human type"; :mod:`torchhrc.tasks.hand_finishing.model`). The person is
the one of the reproduction (:func:`~torchhrc.tasks.hand_finishing.person.simulate_episodes`),
and each episode is one closed-loop run::

    at reset:  type y ~ type_probabilities ("left"-first / "right"-first), x = x0 (start
               configuration, no progress), the hand where the person stands
    each step: reward = R[a, x, y]                     the task MOMDP's reward of the TRUE type
               x2 ~ Tx[a, x, y, :]                     the robot's move, the person's work
               the hand moves towards the surface the person works on next (HandMotion), or,
               with probability epsilon, towards the other one (a glance at the other side)
               the sensor sees the hand plus Gaussian noise of std ``noise`` (m, per axis);
               the observation is its cell in the 4 x 12 grid
    the episode terminates when both sides are done, and is truncated after ``horizon`` steps.

Spaces: ``Dict(x=Discrete(X), observation=Discrete(O + 1))`` with ``O = 48`` grid cells; the
observation ``O`` ("no observation yet") is returned by reset only. :attr:`HandFinishingEnv.model`
is the task MOMDP with the generating hand model as ``Z`` (a robot that knows the person's
noise but not the hand's lag). ``info`` has the true type for evaluation only.

The default task is the reproduction's quick instance (3 x 1 x 3 box configurations checked
with pytorch-kinematics, 2 work units per side); pass ``task`` for another. Registered as
``torchhrc/HandFinishing-v0``.

Example:
    >>> env = HandFinishingEnv(noise=0.1)
    >>> obs, info = env.reset(seed=0)
    >>> obs["observation"] == int(env.observation_space["observation"].n) - 1, info["type"]
    (True, 'left')
"""

from __future__ import annotations

import functools
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
from torchhrc.tasks.hand_finishing.model import HandFinishingTask
from torchhrc.tasks.hand_finishing.person import HandMotion
from torchhrc.tasks.hand_finishing.sensing import TRUE_HAND_LOC, observation_grid
from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings

__all__ = ["HandFinishingEnv", "quick_hand_finishing_task"]


@functools.lru_cache(maxsize=4)
def quick_hand_finishing_task(seed: int = 0) -> HandFinishingTask:
    """The reproduction's quick instance (cached): 3 horizontal positions x 1 height x 3
    tilts, kinematic checks with pytorch-kinematics (a few seconds), ``W = 2``.

    Example:
        >>> quick_hand_finishing_task().work_units
        2
    """
    settings = HandFinishingSettings.create(quick=True, seed=seed)
    return HandFinishingTask.build(
        geometry=settings.geometry, work_units=settings.work_units, seed=seed
    )


class HandFinishingEnv(gym.Env):
    """The hand-finishing task with a simulated person (module docstring).

    Args:
        noise: standard deviation (m) of the sensed hand position per axis (default 0.2, the
            paper's level in the reproduction).
        epsilon: per-step probability that the hand heads for the other side (default 0).
        horizon: steps per episode (default 30).
        task: the task (default :func:`quick_hand_finishing_task`).
        type_probabilities: ``(Y,)`` distribution of the person's type (default uniform).
        render_mode: ``None`` or ``"ansi"``.

    Attributes:
        task: the task.
        model: the task MOMDP with the generating hand model (the robot's model).
        discount: the model's discount (rewards are returned undiscounted).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        *,
        noise: float = 0.2,
        epsilon: float = 0.0,
        horizon: int | None = 30,
        task: HandFinishingTask | None = None,
        type_probabilities: Sequence[float] | None = None,
        render_mode: str | None = None,
    ) -> None:
        if render_mode not in (None, "ansi"):
            raise ValueError(f"expected render_mode None or 'ansi', got {render_mode!r}")
        if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not noise > 0:
            raise ValueError(f"expected noise to be a positive float (m), got {noise!r}")
        self.epsilon = check_probability("epsilon", epsilon)
        self.noise = float(noise)
        self.horizon = check_horizon(horizon)
        self.render_mode = render_mode
        self.task = quick_hand_finishing_task() if task is None else task
        self.grid = observation_grid()
        self.person = self.task.observation_model(
            self.grid,
            loc=torch.tensor(TRUE_HAND_LOC, dtype=torch.float64),
            scale=torch.tensor([self.noise, self.noise], dtype=torch.float64),
        )
        self.model = self.task.momdp(self.person)
        self.discount = float(self.model.discount)
        self.motion = HandMotion()
        Y = self.model.num_hidden
        self._type_probs = check_type_probabilities(type_probabilities, Y)
        with torch.no_grad():
            self._means = self.person.mean().detach()  # (X, Y, 2)
            self._scales = self.person.scale().detach()  # (X, Y, 2)
        self._Tx = self.model.Tx.detach()
        self._R = self.model.R.detach()
        O = self.model.num_observations
        self._O = O
        self.action_space = gym.spaces.Discrete(self.model.num_actions)
        self.observation_space = gym.spaces.Dict(
            {
                "x": gym.spaces.Discrete(self.model.num_observed),
                "observation": gym.spaces.Discrete(O + 1),
            }
        )
        self._generator: torch.Generator | None = None
        self._x, self._y, self._t = self.model.x0, 0, 0
        self._hand = self.motion.start_like(self._means)

    def _info(self) -> dict[str, Any]:
        Y = self.model.num_hidden
        return {
            "x": self._x,
            "y": self._y,
            "type": self.task.first_sides[self._y],
            "state": self._x * Y + self._y,
            "hand": self._hand.tolist(),
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, int], dict[str, Any]]:
        """A new run: start configuration, drawn type, the hand where the person stands."""
        super().reset(seed=seed)
        if seed is not None or self._generator is None:
            self._generator = torch_generator(self.np_random)
        self._y = int(torch.multinomial(self._type_probs, 1, generator=self._generator))
        self._x, self._t = self.model.x0, 0
        self._hand = self.motion.start_like(self._means)
        return {"x": self._x, "observation": self._O}, self._info()

    def step(self, action: int) -> tuple[dict[str, int], float, bool, bool, dict[str, Any]]:
        """The robot's ``action``; the person works and moves the hand; the sensor sees it."""
        from torchhrc.pomdp.observation import discretize_positions

        if self._generator is None:
            raise RuntimeError("call reset() before step()")
        a = check_action(action, self.model.num_actions)
        x, y, g = self._x, self._y, self._generator
        Y = self.model.num_hidden
        reward = float(self._R[a, x, y])
        x2 = int(torch.multinomial(self._Tx[a, x, y], 1, generator=g))
        u = torch.rand(4, generator=g, dtype=torch.float64)
        aim = y
        if Y > 1 and float(u[0]) < self.epsilon:
            aim = (y + 1 + int(float(u[1]) * (Y - 1))) % Y  # another side's surface
        self._hand = self.motion.step(self._hand, self._means[x2, aim])
        noise = torch.randn(2, generator=g, dtype=torch.float64) * self._scales[x2, y]
        cell = int(discretize_positions(self.grid, self._hand + noise))
        self._x = x2
        self._t += 1
        progress = x2 % self.task.num_progress
        terminated = progress == self.task.num_progress - 1
        truncated = not terminated and self.horizon is not None and self._t >= self.horizon
        return {"x": x2, "observation": cell}, reward, bool(terminated), truncated, self._info()

    def render(self) -> str | None:
        """``"ansi"``: configuration, progress and the hand's position."""
        if self.render_mode != "ansi":
            return None
        c, p = self._x // self.task.num_progress, self._x % self.task.num_progress
        h = self._hand.tolist()
        return f"t={self._t} configuration={c} progress={p} hand=({h[0]:.2f}, {h[1]:.2f})"
