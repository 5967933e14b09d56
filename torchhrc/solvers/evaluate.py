"""Monte Carlo evaluation of a policy: many episodes simulated in parallel tensors.

Each step advances every episode at once: the policy picks ``a = pi(b)`` for all beliefs,
the successor state and observation are sampled, and the beliefs are updated in one batched
call (:meth:`~torchhrc.solvers.forms.base.SolverModel.step` of the model's form, so dense,
MOMDP and sparse models are all simulated the same way). The
discounted return of episode ``e`` is ``sum_t discount^t R(a_t, s_t)``, truncated at a
horizon ``H`` whose tail ``discount^H max|R| / (1 - discount)`` is below ``tail_tolerance``.
An episode that reaches an absorbing state (every action stays, reward 0: APPL's terminal
states) is finished; the loop stops when all are (its return is unchanged by that).

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
from typing import Any, NamedTuple

import torch

from torchhrc.errors import ModelError
from torchhrc.solvers.forms import as_solver_model
from torchhrc.solvers.forms.base import SolverModel
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import (
    SPARSE_BELIEF_STATES,
    mostly_zero,
    sample_categorical,
    to_csr,
)

__all__ = ["EvaluationResult", "SimulationStep", "evaluate_policy"]

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


class SimulationStep(NamedTuple):
    """One step of the ``E`` episodes of :func:`evaluate_policy`, given to ``on_step``.

    A flat model has one observed value (``x`` all 0) and its hidden value is the state.
    The tensors are valid during the call only (the beliefs are then updated in place).

    Attributes:
        step: the time step ``t`` (0 first).
        active: ``(E,)`` bool, the episodes not yet finished (absorbed) before this step.
        x: ``(E,)`` observed value before the step; y: ``(E,)`` the true hidden value.
        belief: ``(E, Y)`` the belief the action was chosen at.
        action: ``(E,)`` the action taken.
        reward: ``(E,)`` ``R(a, x, y)`` (0 for finished episodes).
        observation: ``(E,)`` the observation received.
        next_x: ``(E,)`` the observed value after the step.
    """

    step: int
    active: torch.Tensor
    x: torch.Tensor
    y: torch.Tensor
    belief: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    observation: torch.Tensor
    next_x: torch.Tensor


def _horizon(discount: float, max_reward: float, tail_tolerance: float) -> int:
    if discount >= 1.0:
        raise ModelError("evaluate_policy needs discount < 1 or an explicit horizon")
    if max_reward <= 0:
        return 1
    # discount^H * max_reward / (1 - discount) <= tail_tolerance
    h = math.log(tail_tolerance * (1.0 - discount) / max_reward) / math.log(discount)
    return max(1, math.ceil(h))


def _form_and_chooser(model: Any, policy: PolicyLike) -> tuple[SolverModel, Callable[..., Any]]:
    """The model's solver form and ``choose(x (E,), beliefs (E, Y)) -> actions (E,)``."""
    if len(getattr(model, "batch_shape", ())):
        raise ModelError(
            f"evaluate_policy takes one model, got batch_shape {tuple(model.batch_shape)}"
        )
    form = as_solver_model(model)
    if isinstance(policy, AlphaVectorPolicy):
        if form.factored and not policy.is_momdp:
            form = form.flattened()  # a flat policy of a MOMDP acts on its to_pomdp()
        if not form.factored and policy.is_momdp:
            raise ModelError("a MOMDP policy (observed set) cannot act in a flat POMDP")
        size = form.num_hidden
        if policy.alphas.shape[1] != size:
            raise ModelError(
                f"expected policy alphas with {size} columns, got {tuple(policy.alphas.shape)}"
            )
        if policy.num_vectors and int(policy.actions.max()) >= form.num_actions:
            raise ModelError(
                f"expected policy actions < A={form.num_actions}, got {int(policy.actions.max())}"
            )
        if policy.is_momdp:
            assert policy.observed is not None
            if policy.num_vectors and int(policy.observed.max()) >= form.num_observed:
                raise ModelError(
                    f"expected policy observed values < X={form.num_observed}, "
                    f"got {int(policy.observed.max())}"
                )
            return form, policy.action
        if size >= SPARSE_BELIEF_STATES:
            table = policy.alphas.T.contiguous()  # (S, N), once
            return form, lambda x, b: _sparse_action(policy, table, b)
        return form, lambda x, b: policy.action(b)
    if callable(policy):
        if form.factored:
            return form, policy
        return form, lambda x, b: policy(b)
    raise TypeError(f"expected an AlphaVectorPolicy or a callable, got {type(policy).__name__}")


def _sparse_action(
    policy: AlphaVectorPolicy, table: torch.Tensor, beliefs: torch.Tensor
) -> torch.Tensor:
    """``policy.action(beliefs)``, as a product over the beliefs' support when they are
    sparse (:func:`~torchhrc.solvers.sampling.mostly_zero`); ``table`` is ``alphas.T``."""
    if not mostly_zero(beliefs):
        return policy.action(beliefs)
    scores = to_csr(beliefs.to(table.dtype)) @ table  # (E, N)
    return policy.actions[scores.argmax(-1)]


def _start(form: SolverModel, episodes: int, generator: torch.Generator
           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
    """``x (E,)``, ``y (E,)`` and the belief ``(E, Y)`` of the first step: one of the
    form's roots (its random first ``x``), then ``y`` from the belief there."""
    xs, beliefs, weights = form.roots
    device = beliefs.device
    if len(xs) == 1:
        x = torch.full((episodes,), int(xs[0]), dtype=torch.long, device=device)
        belief = beliefs[0].expand(episodes, -1).clone()
        return x, sample_categorical(belief, generator), belief
    w = torch.from_numpy(weights).to(device=device, dtype=beliefs.dtype)
    joint = (w[:, None] * beliefs).reshape(1, -1).expand(episodes, -1)
    pick = sample_categorical(joint, generator)
    Y = beliefs.shape[-1]
    root = pick // Y
    x = torch.from_numpy(xs).to(device)[root]
    return x, pick % Y, beliefs[root].clone()


def evaluate_policy(
    model: Any,
    policy: PolicyLike,
    *,
    episodes: int = 1000,
    horizon: int | None = None,
    tail_tolerance: float = 1e-3,
    seed: int | None = 0,
    generator: torch.Generator | None = None,
    on_step: Callable[[SimulationStep], None] | None = None,
) -> EvaluationResult:
    """Simulate ``episodes`` episodes in parallel and average their discounted returns.

    Args:
        model: an unbatched :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.MOMDP`,
            or a :class:`~torchhrc.pomdp.SparsePOMDP` or
            :class:`~torchhrc.pomdp.SparseMOMDP`: whatever
            :func:`~torchhrc.solvers.forms.as_solver_model` takes (a solver form too). A flat
            policy of a MOMDP (solved through ``to_pomdp()``) is evaluated on the flat model.
        policy: an :class:`AlphaVectorPolicy`, or a callable ``belief (E, S) -> actions (E,)``
            (flat) / ``(x (E,), belief_y (E, Y)) -> actions (E,)`` (MOMDP).
        episodes: number of episodes ``E``.
        horizon: steps per episode (default: enough for a tail below ``tail_tolerance``).
        tail_tolerance: bound on the truncated discounted tail when ``horizon`` is None.
        seed: seed of a fresh generator (ignored when ``generator`` is given).
        generator: the randomness.
        on_step: called with a :class:`SimulationStep` after every step (a trace).

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
    if episodes < 2:
        raise ValueError(f"expected episodes >= 2, got {episodes}")
    form, choose = _form_and_chooser(model, policy)
    g = form.discount
    R = form.R  # (A, X, Y)
    max_reward = float(R.abs().max())
    H = _horizon(g, max_reward, tail_tolerance) if horizon is None else int(horizon)
    if H < 1:
        raise ValueError(f"expected horizon >= 1, got {horizon}")
    truncation = g**H * max_reward / (1.0 - g) if g < 1.0 else float("inf")
    device = R.device
    if generator is None:
        generator = torch.Generator(device=device).manual_seed(0 if seed is None else seed)
    E = int(episodes)
    returns = R.new_zeros(E)
    absorbing = form.absorbing()
    x, y, belief = _start(form, E, generator)
    active = torch.ones(E, dtype=torch.bool, device=device)
    weight = 1.0
    for t in range(H):
        if absorbing is not None:
            active = active & ~absorbing[x, y]
            if not bool(active.any()):
                break
        live = active.nonzero().squeeze(-1) if absorbing is not None else None
        if live is None or live.numel() == E:
            action = choose(x, belief)
            step = form.step(x, y, belief, action, generator)
            reward = R[action, x, y]
            nx, ny, obs, nb = step
        else:  # only the episodes still running
            action = torch.zeros_like(x)
            action[live] = choose(x[live], belief[live])
            step = form.step(x[live], y[live], belief[live], action[live], generator)
            reward = torch.where(active, R[action, x, y], R.new_zeros(()))
            nx, ny, obs = x.clone(), y.clone(), torch.zeros_like(x)
            nx[live], ny[live], obs[live] = step.x, step.y, step.observation
            nb = belief  # updated in place below, after on_step has seen it

        returns += weight * reward
        if on_step is not None:
            on_step(SimulationStep(t, active, x, y, belief, action, reward, obs, nx))
        if nb is belief:
            belief = belief.index_copy_(0, live, step.belief.to(belief.dtype))
        else:
            belief = nb.to(belief.dtype)
        x, y = nx, ny
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
