"""An agent adapter: a solved :class:`~torchhrc.solvers.policy.AlphaVectorPolicy` and its belief
filter acting in a torchhrc environment.

The agent keeps the belief a planning robot keeps (:mod:`torchhrc.pomdp.belief`; paper Eq. 3 for a
MOMDP) and acts greedily on it::

    reset:  b = b0                                 (the start observation carries nothing)
    act:    a = policy.action(b)  or  policy.action(x, b_y)
    observe(a, o'):  b = update(model, b, a, o')   or  momdp_update(model, x, b_y, a, x', o')

An observation the model gives probability zero (the environment's human may do what the
robot's model does not foresee) leaves the belief unchanged instead of failing. The agent is
batched: with a vector environment's observations (arrays of ``N``) it keeps ``N`` beliefs; an
observation equal to the environments' start observation ``O`` (an episode that a vector
environment has just reset) restarts that belief at ``b0``, as does :meth:`BeliefAgent.reset`
with a ``mask``.

:func:`rollout` runs episodes of a single environment with any agent and returns their
returns.

Example:
    >>> from torchhrc.envs.pomdp_env import POMDPEnv
    >>> from torchhrc.solvers import SARSOPConfig, solve
    >>> from torchhrc.tasks.classic import tiger
    >>> policy = solve(tiger(), SARSOPConfig(time_limit=5.0, precision=0.1, seed=0)).policy
    >>> returns = rollout(POMDPEnv(tiger(), horizon=20), BeliefAgent(tiger(), policy),
    ...                   episodes=20, seed=0)
    >>> returns.shape, bool(returns.mean() > 0)
    ((20,), True)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
import torch

from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.belief import momdp_update, update
from torchhrc.solvers.policy import AlphaVectorPolicy

__all__ = ["Agent", "BeliefAgent", "RandomAgent", "rollout"]


class Agent(Protocol):
    """What :func:`rollout` asks of an agent."""

    def reset(self, observation: Any, *, mask: np.ndarray | None = None) -> None: ...

    def act(self, observation: Any) -> Any: ...

    def observe(self, action: Any, observation: Any) -> None: ...


def _as_batch(value: Any) -> tuple[torch.Tensor, bool]:
    """``(B,)`` int64 tensor of ``value`` and whether it was a scalar."""
    array = np.asarray(value)
    return torch.as_tensor(array.reshape(-1), dtype=torch.long), array.ndim == 0


class BeliefAgent:
    """A solved policy with its belief filter (module docstring).

    Args:
        model: the :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.MOMDP` the policy
            was solved for (its belief update is the filter). A flat policy of a MOMDP acts
            on ``model.to_pomdp()`` with the flat observation ``x' * O + o``.
        policy: the :class:`~torchhrc.solvers.policy.AlphaVectorPolicy`.
        b0: initial belief, ``(S,)`` or ``(Y,)`` (default the model's ``b0``).

    Raises:
        TypeError: ``model`` or ``policy`` has the wrong type.
        ValueError: the policy does not fit the model.
    """

    def __init__(
        self,
        model: POMDP | MOMDP,
        policy: AlphaVectorPolicy,
        *,
        b0: torch.Tensor | None = None,
    ) -> None:
        if not isinstance(model, (POMDP, MOMDP)):
            raise TypeError(f"expected model to be a POMDP or MOMDP, got {type(model).__name__}")
        if not isinstance(policy, AlphaVectorPolicy):
            raise TypeError(f"expected an AlphaVectorPolicy, got {type(policy).__name__}")
        self._flat_of_momdp = isinstance(model, MOMDP) and not policy.is_momdp
        self._momdp = isinstance(model, MOMDP) and policy.is_momdp
        if isinstance(model, POMDP) and policy.is_momdp:
            raise ValueError("a MOMDP policy (observed set) cannot act on a flat POMDP")
        self.source = model
        self.model = model.to_pomdp() if self._flat_of_momdp else model
        self.policy = policy
        size = self.model.num_hidden if self._momdp else self.model.num_states  # type: ignore[union-attr]
        if policy.alphas.shape[1] != size:
            raise ValueError(
                f"expected policy alphas with {size} columns, got {tuple(policy.alphas.shape)}"
            )
        start = self.model.b0 if b0 is None else torch.as_tensor(b0)
        if start.shape != (size,):
            raise ValueError(f"expected b0 of shape ({size},), got {tuple(start.shape)}")
        self.b0 = start.to(policy.alphas.dtype)
        self.belief = self.b0.unsqueeze(0).clone()
        self._x = torch.zeros(1, dtype=torch.long)
        self._scalar = True

    def _split(self, observation: Any) -> tuple[torch.Tensor | None, torch.Tensor]:
        if isinstance(observation, Mapping):
            x, self._scalar = _as_batch(observation["x"])
            o, _ = _as_batch(observation["observation"])
            return x, o
        o, self._scalar = _as_batch(observation)
        return None, o

    def reset(self, observation: Any, *, mask: np.ndarray | None = None) -> None:
        """Restart the beliefs (all, or where ``mask (B,)`` is True) at a reset observation."""
        x, o = self._split(observation)
        B = o.shape[0]
        fresh = self.b0.expand(B, -1)
        if mask is None or self.belief.shape[0] != B:
            self.belief = fresh.clone()
        else:
            m = torch.as_tensor(np.asarray(mask, dtype=bool).reshape(-1))
            self.belief = torch.where(m.unsqueeze(-1), fresh, self.belief)
        if x is not None:
            self._x = x

    def act(self, observation: Any) -> np.ndarray | int:
        """The policy's action at the current beliefs (and the observed ``x`` of a MOMDP)."""
        x, _ = self._split(observation)
        if self._momdp:
            action = self.policy.action(x, self.belief)
        else:  # a flat belief (over the flat states s = x * Y + y of a MOMDP)
            action = self.policy.action(self.belief)
        out = action.cpu().numpy()
        return int(out[0]) if self._scalar else out

    def observe(self, action: Any, observation: Any) -> None:
        """Update the beliefs with the action taken and the observation received."""
        a, _ = _as_batch(action)
        x2, o = self._split(observation)
        start = o >= self.source.num_observations  # an autoreset episode's first observation
        o = o.masked_fill(start, 0)
        if self._momdp:
            result = momdp_update(self.model, self._x, self.belief, a, x2, o, on_zero="ninf")
        elif self._flat_of_momdp:
            flat = x2 * self.source.num_observations + o  # type: ignore[union-attr]
            result = update(self.model, self.belief, a, flat, on_zero="ninf")
        else:
            result = update(self.model, self.belief, a, o, on_zero="ninf")
        possible = torch.isfinite(result.log_normalizer).unsqueeze(-1)
        belief = torch.where(possible, result.belief, self.belief)
        self.belief = torch.where(start.unsqueeze(-1), self.b0, belief)
        if x2 is not None:
            self._x = x2


class RandomAgent:
    """Uniformly random actions from an action space (seeded), the baseline robot.

    Args:
        action_space: a gymnasium ``Discrete`` space (or a batched ``MultiDiscrete``).
        seed: seed of the space's sampler.
    """

    def __init__(self, action_space: Any, *, seed: int | None = None) -> None:
        self.action_space = action_space
        self.action_space.seed(seed)

    def reset(self, observation: Any, *, mask: np.ndarray | None = None) -> None:
        return None

    def act(self, observation: Any) -> Any:
        return self.action_space.sample()

    def observe(self, action: Any, observation: Any) -> None:
        return None


def rollout(
    env: Any,
    agent: Agent,
    *,
    episodes: int,
    seed: int | None = 0,
    discount: float = 1.0,
) -> np.ndarray:
    """Run ``episodes`` episodes of a single environment; return their returns.

    Args:
        env: a gymnasium environment.
        agent: an :class:`Agent` (e.g. :class:`BeliefAgent`).
        episodes: number of episodes ``E``.
        seed: seed of the first reset (the following episodes continue its stream).
        discount: the return is ``sum_t discount^t r_t`` (1: undiscounted, gymnasium's).

    Returns:
        ``(E,)`` float64 returns.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"expected episodes to be a positive int, got {episodes!r}")
    returns = np.zeros(episodes)
    for e in range(episodes):
        obs, _ = env.reset(seed=seed if e == 0 else None)
        agent.reset(obs)
        total, weight, done = 0.0, 1.0, False
        while not done:
            action = agent.act(obs)
            obs, reward, terminated, truncated, _ = env.step(action)
            agent.observe(action, obs)
            total += weight * float(reward)
            weight *= discount
            done = terminated or truncated
        returns[e] = total
    return returns
