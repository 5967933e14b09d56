"""A gymnasium environment simulating any flat POMDP of the library (dense or sparse).

One step from the hidden state ``s`` under action ``a`` samples, from the model's tensors::

    reward = R[a, s]                  (the model's expected immediate reward)
    s2    ~ T[a, s, :]                 next state
    o     ~ Z[a, s2, :]                observation

Spaces: ``action_space = Discrete(A)``; ``observation_space = Discrete(O + 1)``, where
``0 .. O - 1`` are the model's observations and ``O`` stands for "no observation yet", the
observation :meth:`POMDPEnv.reset` returns (a POMDP has no observation before its first
action). ``info["state"]`` carries the true state, for evaluation only: an agent that reads it
is not solving the POMDP. The episode is truncated after ``horizon`` steps and terminates on
entering one of ``terminal_states``. Rewards are undiscounted, as gymnasium's; the model's
``discount`` is :attr:`POMDPEnv.discount` for agents that discount.

Randomness is gymnasium's ``np_random``, seeded by ``reset(seed=...)``: the same seed and the
same actions give the same episode.

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> env = POMDPEnv(tiger(), horizon=10)
    >>> obs, info = env.reset(seed=0)
    >>> obs, int(env.observation_space.n), info["state"] in (0, 1)
    (2, 3, True)
    >>> obs, reward, terminated, truncated, info = env.step(0)  # listen
    >>> reward, obs in (0, 1)
    (-1.0, True)
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
from torchhrc.pomdp import POMDP, SparsePOMDP

__all__ = ["POMDPEnv"]


def _flat_tables(model: POMDP | SparsePOMDP) -> tuple[CategoricalRows, CategoricalRows]:
    """``(T, Z)`` as compressed rows ``a * S + s``; the one place the two forms differ."""
    if isinstance(model, SparsePOMDP):
        A, S = model.num_actions, model.num_states
        (ti, tp), (zi, zp) = model.transitions, model.observations_
        ti, zi = ti.cpu().numpy(), zi.cpu().numpy()
        T = CategoricalRows(ti[:, 0] * S + ti[:, 1], ti[:, 2], tp.cpu().numpy(), A * S)
        Z = CategoricalRows(zi[:, 0] * S + zi[:, 1], zi[:, 2], zp.cpu().numpy(), A * S)
        return T, Z
    return CategoricalRows.from_dense(model.T), CategoricalRows.from_dense(model.Z)


class POMDPEnv(gym.Env):
    """A flat POMDP (:class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.SparsePOMDP`)
    as a gymnasium environment (see the module docstring).

    Args:
        model: an unbatched POMDP, dense or sparse.
        horizon: steps after which an episode is truncated (``None``: never).
        terminal_states: states whose entry terminates the episode (default none).
        render_mode: ``None`` or ``"ansi"`` (a one-line text of the last step).

    Raises:
        TypeError: ``model`` is not a POMDP.
        ValueError: the model is batched, or an option is out of range.

    Attributes:
        model: the POMDP simulated.
        discount: the model's discount factor.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        model: POMDP | SparsePOMDP,
        *,
        horizon: int | None = None,
        terminal_states: Sequence[int] = (),
        render_mode: str | None = None,
    ) -> None:
        if not isinstance(model, (POMDP, SparsePOMDP)):
            raise TypeError(
                f"expected model to be a POMDP or SparsePOMDP, got {type(model).__name__}"
            )
        check_unbatched(model)
        self.render_mode = check_render_mode(render_mode)
        self.model = model
        self.discount = float(model.discount)
        self.horizon = check_horizon(horizon)
        A, S, O = model.num_actions, model.num_states, model.num_observations
        self._S, self._O = S, O
        self._T, self._Z = _flat_tables(model)
        self._b0 = CategoricalRows.from_dense(model.b0.reshape(1, S))
        self._R = model.R.detach().cpu().numpy().astype(np.float64).reshape(A, S)
        terminal = np.zeros(S, dtype=bool)
        for s in terminal_states:
            if not 0 <= int(s) < S:
                raise ValueError(f"expected terminal_states in [0, {S}), got {s!r}")
            terminal[int(s)] = True
        self._terminal = terminal
        self.action_space = gym.spaces.Discrete(A)
        self.observation_space = gym.spaces.Discrete(O + 1)
        self._state = 0
        self._t = 0
        self._last: tuple[int, int, float] | None = None

    @property
    def start_observation(self) -> int:
        """``O``, the observation returned by :meth:`reset` ("no observation yet")."""
        return self._O

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[int, dict[str, Any]]:
        """Start an episode: ``s ~ b0``; returns ``(O, {"state": s})``."""
        super().reset(seed=seed)
        self._state = int(self._b0.sample(np.zeros(1), self.np_random.random(1))[0])
        self._t = 0
        self._last = None
        return self._O, {"state": self._state}

    def step(self, action: int) -> tuple[int, float, bool, bool, dict[str, Any]]:
        """Apply ``action``; returns ``(o, R[a, s], terminated, truncated, {"state": s2})``."""
        a = check_action(action, self._R.shape[0])
        s = self._state
        u = self.np_random.random(2)
        reward = float(self._R[a, s])
        s2 = int(self._T.sample(np.array(a * self._S + s), u[0]))
        o = int(self._Z.sample(np.array(a * self._S + s2), u[1]))
        self._state = s2
        self._t += 1
        self._last = (a, o, reward)
        terminated = bool(self._terminal[s2])
        truncated = not terminated and self.horizon is not None and self._t >= self.horizon
        return o, reward, terminated, truncated, {"state": s2}

    def render(self) -> str | None:
        """``"ansi"``: ``"t=<step> a=<action> o=<observation> r=<reward>"``."""
        if self.render_mode != "ansi":
            return None
        if self._last is None:
            return f"t={self._t} start"
        a, o, r = self._last
        return f"t={self._t} a={a} o={o} r={r:g}"
