"""``N`` place-and-drill episodes stepped as one tensor batch (a ``gymnasium.vector.VectorEnv``).

Each call to :meth:`PlaceAndDrillVectorEnv.step` advances every episode with one batched
call of :meth:`PlaceAndDrillHuman.step <torchhrc.tasks.place_and_drill.env.PlaceAndDrillHuman.step>`
(about twenty tensor operations for the whole batch), instead of ``N`` Python calls of a single
environment as gymnasium's ``SyncVectorEnv`` makes. The dynamics, spaces and rewards are those
of :class:`~torchhrc.tasks.place_and_drill.env.PlaceAndDrillEnv`.

Autoreset follows gymnasium's default (``AutoresetMode.NEXT_STEP``): the step after an
episode terminated or was truncated resets that episode and returns its first observation
(``{"x": 0, "observation": 1}``) with reward 0 and ``terminated = truncated = False``; the
action given for it is ignored.

Shapes (``N = num_envs``)::

    observations: {"x": (N,) int64, "observation": (N,) int64}
    rewards: (N,) float64;  terminations, truncations: (N,) bool
    infos: {"y": (N,) int64 true types (evaluation only), "t": (N,) steps taken}

Example:
    >>> import numpy as np
    >>> envs = PlaceAndDrillVectorEnv(4, epsilon=0.0)
    >>> obs, info = envs.reset(seed=0)
    >>> obs["x"].tolist()
    [0, 0, 0, 0]
    >>> obs, reward, terminated, truncated, info = envs.step(np.zeros(4, dtype=np.int64))
    >>> reward.shape, (obs["x"] > 0).all()
    ((4,), np.True_)
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from torchhrc.envs._base import torch_generator
from torchhrc.tasks.place_and_drill.env import _attach_human

__all__ = ["PlaceAndDrillVectorEnv"]


class PlaceAndDrillVectorEnv(VectorEnv):
    """``num_envs`` place-and-drill episodes as one batch (module docstring).

    Args:
        num_envs: ``N``.
        epsilon, noise, horizon, type_probabilities, expert_path: as
            :class:`~torchhrc.tasks.place_and_drill.env.PlaceAndDrillEnv`.

    Raises:
        ValueError: ``num_envs < 1`` or an option out of range.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": [],
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int,
        *,
        epsilon: float = 0.1,
        noise: float = 0.0,
        horizon: int | None = None,
        type_probabilities: Sequence[float] | None = None,
        expert_path: str | os.PathLike[str] | None = None,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"expected num_envs to be a positive int, got {num_envs!r}")
        _attach_human(self, epsilon=epsilon, noise=noise, horizon=horizon,
                      type_probabilities=type_probabilities, expert_path=expert_path)  # fmt: skip
        n = self.task.n_positions
        self.num_envs = num_envs
        self.single_action_space = gym.spaces.Discrete(self.task.num_actions)
        self.single_observation_space = gym.spaces.Dict(
            {
                "x": gym.spaces.Discrete(self.task.num_states),
                "observation": gym.spaces.Discrete(2),
            }
        )
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._generator: torch.Generator | None = None
        self._x = torch.zeros(num_envs, dtype=torch.long)
        self._y = torch.zeros(num_envs, dtype=torch.long)
        self._order = torch.arange(n).expand(num_envs, n).clone()
        self._t = torch.zeros(num_envs, dtype=torch.long)
        self._needs_reset = torch.zeros(num_envs, dtype=torch.bool)
        self._zero_obs = torch.zeros(num_envs, dtype=torch.long)

    def _observations(self, start: torch.Tensor) -> dict[str, np.ndarray]:
        return {"x": self._x.numpy().copy(), "observation": start.long().numpy()}

    def reset(
        self,
        *,
        seed: int | list[int] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset every episode (an int ``seed`` seeds the whole batch)."""
        if isinstance(seed, list):
            seed = seed[0]
        super().reset(seed=seed)
        if seed is not None or self._generator is None:
            self._generator = torch_generator(self.np_random)
        self._x, self._y, self._order = self.human.initial(self.num_envs, self._generator)
        self._t.zero_()
        self._needs_reset.zero_()
        ones = torch.ones(self.num_envs, dtype=torch.long)
        return self._observations(ones), {"y": self._y.numpy().copy(), "t": self._t.numpy().copy()}

    def step(
        self, actions: np.ndarray | torch.Tensor
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Advance every episode by one step (``actions (N,)`` ints in ``[0, A)``)."""
        if self._generator is None:
            raise RuntimeError("call reset() before step()")
        a = torch.as_tensor(np.asarray(actions), dtype=torch.long)
        A = self.task.num_actions
        if a.shape != (self.num_envs,):
            raise ValueError(
                f"expected actions of shape (num_envs={self.num_envs},), got {tuple(a.shape)}"
            )
        if bool(((a < 0) | (a >= A)).any()):
            raise ValueError(f"expected actions in [0, {A}), got {a.tolist()}")
        restart = self._needs_reset
        a = a.masked_fill(restart, 0)
        x2, reward = self.human.step(self._x, self._y, self._order, a, self._generator)
        t2 = self._t + 1
        if bool(restart.any()):
            x0, y0, order0 = self.human.initial(self.num_envs, self._generator)
            x2 = torch.where(restart, x0, x2)
            self._y = torch.where(restart, y0, self._y)
            self._order = torch.where(restart.unsqueeze(-1), order0, self._order)
            reward = reward.masked_fill(restart, 0.0)
            t2 = t2.masked_fill(restart, 0)
        terminated = (x2 == self.task.terminal_state) & ~restart
        truncated = (t2 >= self.horizon) & ~terminated & ~restart
        self._x, self._t = x2, t2
        self._needs_reset = terminated | truncated
        obs = self._observations(restart)
        info = {"y": self._y.numpy().copy(), "t": t2.numpy().copy()}
        return obs, reward.numpy(), terminated.numpy(), truncated.numpy(), info
