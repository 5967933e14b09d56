"""A gymnasium environment simulating any MOMDP of the library.

One step from ``(x, y)`` under action ``a`` samples, from the model's tensors (paper Eq. 3's
generative model; Ong et al. 2010)::

    reward = R[a, x, y]
    x2    ~ Tx[a, x, y, :]                  observed part
    y2    ~ Ty[a, x, y, x2, :]              hidden part (y2 = y when Ty is None, a static type)
    o     ~ Z[a, x2, y2, :]                 observation

Spaces: ``action_space = Discrete(A)``; ``observation_space = Dict(x=Discrete(X),
observation=Discrete(O + 1))``: the agent sees the observed part ``x`` exactly and the
observation ``o``; ``o = O`` stands for "no observation yet" and is returned by
:meth:`MOMDPEnv.reset` only. ``info`` carries the true hidden value (``"y"``) and the flat
state ``"state" = x * Y + y`` for evaluation only. The episode is truncated after ``horizon``
steps and terminates when ``x2`` is one of ``terminal_observed``. Rewards are undiscounted;
:attr:`MOMDPEnv.discount` is the model's. Seeded through ``reset(seed=...)``.

Example:
    >>> from torchhrc.testing import random_momdp
    >>> env = MOMDPEnv(random_momdp(3, 2, 2, 2, seed=0), horizon=5)
    >>> obs, info = env.reset(seed=0)
    >>> obs["observation"], sorted(info)
    (2, ['state', 'x', 'y'])
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from torchhrc.envs._base import (
    check_action,
    check_horizon,
    check_render_mode,
    check_unbatched,
)
from torchhrc.envs._tables import CategoricalRows
from torchhrc.pomdp import MOMDP

__all__ = ["MOMDPEnv"]


class MOMDPEnv(gym.Env):
    """A :class:`~torchhrc.pomdp.MOMDP` as a gymnasium environment (module docstring).

    Args:
        model: an unbatched MOMDP.
        horizon: steps after which an episode is truncated (``None``: never).
        terminal_observed: observed values whose entry terminates the episode.
        render_mode: ``None`` or ``"ansi"``.

    Raises:
        TypeError: ``model`` is not a MOMDP.
        ValueError: the model is batched, or an option is out of range.

    Attributes:
        model: the MOMDP simulated.
        discount: its discount factor.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        model: MOMDP,
        *,
        horizon: int | None = None,
        terminal_observed: Sequence[int] = (),
        render_mode: str | None = None,
    ) -> None:
        if not isinstance(model, MOMDP):
            raise TypeError(f"expected model to be a MOMDP, got {type(model).__name__}")
        check_unbatched(model)
        self.render_mode = check_render_mode(render_mode)
        self.model = model
        self.discount = float(model.discount)
        self.horizon = check_horizon(horizon)
        A, X, Y, O = model.num_actions, model.num_observed, model.num_hidden, model.num_observations
        self._X, self._Y, self._O = X, Y, O
        self._Tx = CategoricalRows.from_dense(model.Tx)  # rows (a, x, y)
        self._Ty = None if model.Ty is None else CategoricalRows.from_dense(model.Ty)
        self._Z = CategoricalRows.from_dense(model.Z)  # rows (a, x2, y2)
        self._b0 = CategoricalRows.from_dense(model.b0.reshape(1, Y))
        # a random first x (model.initial): (x, y) drawn from the joint
        start = model.initial
        self._start = None if start is None else CategoricalRows.from_dense(start.reshape(1, -1))
        self._R = model.R.detach().cpu().numpy().astype(np.float64).reshape(A, X, Y)
        terminal = np.zeros(X, dtype=bool)
        for x in terminal_observed:
            if not 0 <= int(x) < X:
                raise ValueError(f"expected terminal_observed in [0, {X}), got {x!r}")
            terminal[int(x)] = True
        self._terminal = terminal
        self.action_space = gym.spaces.Discrete(A)
        self.observation_space = gym.spaces.Dict(
            {"x": gym.spaces.Discrete(X), "observation": gym.spaces.Discrete(O + 1)}
        )
        self._x = model.x0
        self._y = 0
        self._t = 0
        self._last: tuple[int, int, int, float] | None = None

    @property
    def start_observation(self) -> int:
        """``O``, the ``"observation"`` returned by :meth:`reset` ("no observation yet")."""
        return self._O

    def _info(self) -> dict[str, Any]:
        return {"x": self._x, "y": self._y, "state": self._x * self._Y + self._y}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, int], dict[str, Any]]:
        """Start an episode at ``x0`` with ``y ~ b0`` (or at ``(x, y)`` drawn from
        ``model.initial``, a random start); returns ``({"x": x, "observation": O}, info)``."""
        super().reset(seed=seed)
        if self._start is None:
            self._x = self.model.x0
            self._y = int(self._b0.sample(np.zeros(1), self.np_random.random(1))[0])
        else:
            s = int(self._start.sample(np.zeros(1), self.np_random.random(1))[0])
            self._x, self._y = divmod(s, self._Y)
        self._t = 0
        self._last = None
        return {"x": self._x, "observation": self._O}, self._info()

    def step(self, action: int) -> tuple[dict[str, int], float, bool, bool, dict[str, Any]]:
        """Apply ``action``; returns ``({"x": x2, "observation": o}, R[a, x, y], terminated,
        truncated, info)``."""
        X, Y = self._X, self._Y
        a = check_action(action, self._R.shape[0])
        x, y = self._x, self._y
        u = self.np_random.random(3)
        reward = float(self._R[a, x, y])
        row = (a * X + x) * Y + y
        x2 = int(self._Tx.sample(np.array(row), u[0]))
        y2 = y if self._Ty is None else int(self._Ty.sample(np.array(row * X + x2), u[1]))
        o = int(self._Z.sample(np.array((a * X + x2) * Y + y2), u[2]))
        self._x, self._y = x2, y2
        self._t += 1
        self._last = (a, x2, o, reward)
        terminated = bool(self._terminal[x2])
        truncated = not terminated and self.horizon is not None and self._t >= self.horizon
        return {"x": x2, "observation": o}, reward, terminated, truncated, self._info()

    def render(self) -> str | None:
        """``"ansi"``: ``"t=<step> a=<action> x=<x> o=<observation> r=<reward>"``."""
        if self.render_mode != "ansi":
            return None
        if self._last is None:
            return f"t={self._t} start x={self._x}"
        a, x, o, r = self._last
        return f"t={self._t} a={a} x={x} o={o} r={r:g}"
