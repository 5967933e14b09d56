"""Monte Carlo evaluation of a policy: many episodes simulated in parallel tensors.

Each step advances every episode at once: the policy picks ``a = pi(b)`` for all beliefs,
the successor state and observation are sampled, and the beliefs are updated in one batched
call (the steps of :mod:`torchhrc.solvers.sampling`). The
discounted return of episode ``e`` is ``sum_t discount^t R(a_t, s_t)``, truncated at a
horizon ``H`` whose tail ``discount^H max|R| / (1 - discount)`` is below ``tail_tolerance``.

The result carries the mean, its standard error and a 95% confidence interval
``mean +- 1.96 * std / sqrt(E)``, widened by the truncation bound.

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> from torchhrc.solvers.blind import blind_policy
    >>> r = evaluate_policy(tiger(), blind_policy(tiger()), episodes=100, seed=0)
    >>> round(r.mean, 2)  # always listening: -1 / (1 - 0.95), up to the truncated tail
    -20.0
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import flat_step, momdp_start, momdp_step, sample_categorical

__all__ = ["EvaluationResult", "evaluate_policy"]

#: two-sided 95% normal quantile
_Z95 = 1.959963984540054

PolicyLike = AlphaVectorPolicy | Callable[..., torch.Tensor]


@dataclass(frozen=True)
class EvaluationResult:
    """Monte Carlo estimate of a policy's discounted return from the initial belief.

    Attributes:
        mean: average discounted return over the episodes.
        std_error: standard error of the mean.
        ci_low, ci_high: 95% confidence interval, widened by ``truncation``.
        truncation: bound on the discounted rewards beyond ``horizon``.
        horizon: number of simulated steps.
        returns: ``(E,)`` discounted return of each episode.
    """

    mean: float
    std_error: float
    ci_low: float
    ci_high: float
    truncation: float
    horizon: int
    returns: torch.Tensor


def _horizon(discount: float, max_reward: float, tail_tolerance: float) -> int:
    if discount >= 1.0:
        raise ModelError("evaluate_policy needs discount < 1 or an explicit horizon")
    if max_reward <= 0:
        return 1
    # discount^H * max_reward / (1 - discount) <= tail_tolerance
    h = math.log(tail_tolerance * (1.0 - discount) / max_reward) / math.log(discount)
    return max(1, math.ceil(h))


def evaluate_policy(
    model: POMDP | MOMDP,
    policy: PolicyLike,
    *,
    episodes: int = 1000,
    horizon: int | None = None,
    tail_tolerance: float = 1e-3,
    seed: int | None = 0,
    generator: torch.Generator | None = None,
) -> EvaluationResult:
    """Simulate ``episodes`` episodes in parallel and average their discounted returns.

    Args:
        model: an unbatched :class:`POMDP` or :class:`MOMDP`. A flat policy of a MOMDP
            (solved through ``to_pomdp()``) is evaluated on the flat model.
        policy: an :class:`AlphaVectorPolicy`, or a callable ``belief (E, S) -> actions (E,)``
            (flat) / ``(x (E,), belief_y (E, Y)) -> actions (E,)`` (MOMDP).
        episodes: number of episodes ``E``.
        horizon: steps per episode (default: enough for a tail below ``tail_tolerance``).
        tail_tolerance: bound on the truncated discounted tail when ``horizon`` is None.
        seed: seed of a fresh generator (ignored when ``generator`` is given).
        generator: the randomness.

    Returns:
        :class:`EvaluationResult`.

    Raises:
        ModelError: the model is batched, or the policy does not fit the model.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> from torchhrc.solvers.qmdp import qmdp_policy
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> r = evaluate_policy(m, qmdp_policy(m), episodes=200, seed=1)
        >>> r.ci_low <= r.mean <= r.ci_high
        True
    """
    if not isinstance(model, (POMDP, MOMDP)):
        raise TypeError(f"expected model to be a POMDP or MOMDP, got {type(model).__name__}")
    if len(model.batch_shape):
        raise ModelError(
            f"evaluate_policy takes one model, got batch_shape {tuple(model.batch_shape)}"
        )
    if episodes < 2:
        raise ValueError(f"expected episodes >= 2, got {episodes}")
    if isinstance(policy, AlphaVectorPolicy):
        if isinstance(model, MOMDP) and not policy.is_momdp:
            model = model.to_pomdp()
        if isinstance(model, POMDP) and policy.is_momdp:
            raise ModelError("a MOMDP policy (observed set) cannot act in a flat POMDP")
        size = model.num_hidden if isinstance(model, MOMDP) else model.num_states
        if policy.alphas.shape[1] != size:
            raise ModelError(
                f"expected policy alphas with {size} columns, got {tuple(policy.alphas.shape)}"
            )
        act = policy.action
    elif callable(policy):
        act = policy
    else:
        raise TypeError(f"expected an AlphaVectorPolicy or a callable, got {type(policy).__name__}")
    g = model.discount
    max_reward = float(model.R.abs().max())
    H = _horizon(g, max_reward, tail_tolerance) if horizon is None else int(horizon)
    if H < 1:
        raise ValueError(f"expected horizon >= 1, got {horizon}")
    truncation = g**H * max_reward / (1.0 - g) if g < 1.0 else float("inf")
    device = model.R.device
    if generator is None:
        generator = torch.Generator(device=device).manual_seed(0 if seed is None else seed)
    E = int(episodes)
    returns = model.R.new_zeros(E)
    weight = 1.0
    if isinstance(model, MOMDP):
        x, y, belief = momdp_start(model, E, generator)
        for _ in range(H):
            action = act(x, belief)
            step = momdp_step(model, x, y, belief, action, generator)
            returns += weight * step.reward
            x, y, belief = step.x, step.y, step.belief
            weight *= g
    else:
        belief = model.b0.expand(E, -1).clone()
        s = sample_categorical(belief, generator)
        for _ in range(H):
            action = act(belief)
            step = flat_step(model, s, belief, action, generator)
            returns += weight * step.reward
            s, belief = step.state, step.belief
            weight *= g
    mean = float(returns.mean())
    std_error = float(returns.std(unbiased=True)) / math.sqrt(E)
    half = _Z95 * std_error
    return EvaluationResult(
        mean=mean,
        std_error=std_error,
        ci_low=mean - half - truncation,
        ci_high=mean + half + truncation,
        truncation=truncation,
        horizon=H,
        returns=returns,
    )
