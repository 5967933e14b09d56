"""A reward per human type: one IRL problem per cluster, solved as one batch (paper Sec. IRL).

For a fixed human type ``y`` the MOMDP reduces to an MDP over the observed task states
(paper: "For a fixed human type y, we can reduce the MOMDP into a Markov Decision Process
(X, A_r, T_x, R, gamma)"), with transitions ``Tx[:, :, y, :]``. Each cluster's
demonstrations give that type's expert feature expectations, IRL gives weights ``w_y`` and::

    R[a, x, y] = w_y . phi(x[, a])            R: (A, X, Y), the MOMDP's reward layout

Shapes (shared/DESIGN.md): ``Tx: (A, X, Y, X)``; per-type MDPs ``(Y, A, X, X)``; features
``(X, F)`` over task states or ``(X, A, F)`` over task state and robot action.

Example:
    >>> import torch
    >>> from torchhrc.irl.trajectories import Trajectories
    >>> T = torch.tensor([[[1.0, 0.0], [1.0, 0.0]], [[0.0, 1.0], [0.0, 1.0]]],
    ...                  dtype=torch.float64).expand(2, 2, 2, 2)   # (Y, A, X, X): a -> x = a
    >>> demos = [Trajectories.from_pairs([[(0, y), (y, y), (y, y)]]) for y in range(2)]
    >>> out = learn_type_rewards(T, demos, torch.eye(2, dtype=torch.float64), discount=0.5,
    ...                          horizon=3, epsilon=1e-6)
    >>> out.reward.shape, out.policies.tolist()
    (torch.Size([2, 2, 2]), [[0, 0], [1, 1]])
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch

from torchhrc._checks import check_tensor
from torchhrc.errors import ModelError
from torchhrc.irl.features import reward_from_weights
from torchhrc.irl.maxent import MaxEntResult, _maxent_batched
from torchhrc.irl.projection import (
    REWARD_RULES,
    ApprenticeshipResult,
    _prepare,
    _run_batched,
    _standard_errors,
)
from torchhrc.irl.trajectories import Trajectories
from torchhrc.pomdp import MOMDP
from torchhrc.solvers.value_iteration import value_iteration

__all__ = ["TypeRewards", "learn_type_rewards", "type_transitions"]


@dataclass(frozen=True)
class TypeRewards:
    """The result of :func:`learn_type_rewards` (Y types, F features).

    Attributes:
        reward: ``(A, X, Y)`` ``R[a, x, y] = w_y . phi(x[, a])``, ready for ``MOMDP.R``.
        weights: ``(Y, F)`` the reward weights of each type (unit norm for the
            Abbeel-Ng methods' individual ``w^(i)``; their second-half mean may be shorter).
        policies: ``(Y, X)`` int64, an optimal policy of each type's MDP under its learned
            reward (value iteration).
        results: one :class:`~torchhrc.irl.projection.ApprenticeshipResult` (methods
            ``"projection"``, ``"qp"``) or :class:`~torchhrc.irl.maxent.MaxEntResult`
            (``"maxent"``) per type, with the margins, policies and mixture weights.
        method: the IRL method used.
    """

    reward: torch.Tensor
    weights: torch.Tensor
    policies: torch.Tensor
    results: tuple[ApprenticeshipResult | MaxEntResult, ...]
    method: str


def type_transitions(model: MOMDP) -> torch.Tensor:
    """The per-type MDP transitions ``(Y, A, X, X)``: ``T[y, a, x, x2] = Tx[a, x, y, x2]``.

    Example:
        >>> m = MOMDP(Tx=torch.ones(1, 1, 2, 1, dtype=torch.float64), Ty=None,
        ...           Z=torch.ones(1, 1, 2, 1, dtype=torch.float64),
        ...           R=torch.zeros(1, 1, 2, dtype=torch.float64), x0=0,
        ...           b0=torch.tensor([0.5, 0.5], dtype=torch.float64), discount=0.9)
        >>> type_transitions(m).shape
        torch.Size([2, 1, 1, 1])
    """
    if model.Tx.dim() != 4:
        raise ModelError(
            f"expected an unbatched MOMDP with Tx of shape (A, X, Y, X), "
            f"actual shape = {tuple(model.Tx.shape)}"
        )
    return model.Tx.permute(2, 0, 1, 3)


def learn_type_rewards(
    mdp_per_type: MOMDP | torch.Tensor,
    demonstrations_by_cluster: Sequence[Trajectories],
    features: torch.Tensor,
    *,
    discount: float | None = None,
    method: Literal["projection", "qp", "maxent"] = "projection",
    reward_rule: Literal["closest", "paper", "last", "dominant"] = "closest",
    epsilon: float = 1e-2,
    max_iterations: int = 50,
    horizon: int | None = None,
    start: torch.Tensor | None = None,
    monte_carlo: int | None = None,
    l2: float = 1e-3,
    seed: int = 0,
    qp_solver: str = "CLARABEL",
    qp_options: dict[str, Any] | None = None,
) -> TypeRewards:
    """Learn one reward per human type from each cluster's demonstrations (paper Sec. IRL).

    All types run as one batch: value iteration, feature expectations (and, for MaxEnt,
    soft value iteration and L-BFGS) are tensor programs over the Y problems; a type that
    has converged stops while the others go on.

    Args:
        mdp_per_type: a :class:`~torchhrc.pomdp.MOMDP` (its ``Tx`` and ``discount`` are
            used) or the per-type transitions ``(Y, A, X, X)``, ``T[y] = Tx[:, :, y, :]``.
        demonstrations_by_cluster: Y sets of ``(x, a)`` trajectories, cluster ``y``'s
            demonstrations in the task's observed states and robot actions.
        features: ``(X, F)`` task-state features or ``(X, A, F)`` state-action features.
        discount: discount of the feature expectations (default the MOMDP's).
        method: ``"projection"`` / ``"qp"`` (Abbeel & Ng 2004, as in the paper) or
            ``"maxent"`` (Ziebart et al. 2008).
        reward_rule: which Abbeel-Ng weights make the reward (the ``rule`` of
            :func:`~torchhrc.irl.projection.apprenticeship_learning`): ``"closest"``
            (default) the ``w^(i)`` whose policy's feature expectations are nearest the
            expert's, ``"paper"`` the mean of ``w^(i)`` over the second half of the
            iterations, ``"last"`` ``w^(M)``, ``"dominant"`` the ``w^(i)`` of the policy with
            the largest mixture weight.
        epsilon: Abbeel-Ng stopping margin; for MaxEnt the gradient-norm tolerance.
        max_iterations: Abbeel-Ng RL steps, or L-BFGS iterations for MaxEnt.
        horizon: finite horizon of the feature expectations (Abbeel-Ng only): use the
            demonstrations' length when they all end at the task's completion.
        start: ``(X,)`` initial distribution; default each cluster's empirical first states.
        monte_carlo: Abbeel-Ng ``mu(pi)`` from this many sampled rollouts (the paper's
            choice); None = exact.
        l2: MaxEnt ridge penalty.
        seed: seed of the random start policies / sampling.
        qp_solver, qp_options: cvxpy solver of ``method="qp"``.

    Returns:
        :class:`TypeRewards` with ``reward (A, X, Y)`` (use it as
        ``dataclasses.replace(momdp, R=result.reward)``), ``weights (Y, F)`` and per-type
        results.

    Raises:
        ModelError: a different number of clusters and types, features that do not match
            the task's sizes, an empty cluster, a demonstration with an impossible
            transition (the message names the cluster), a QP failure.
    """
    if isinstance(mdp_per_type, MOMDP):
        T = type_transitions(mdp_per_type)
        if discount is None:
            discount = mdp_per_type.discount
    else:
        T = check_tensor("mdp_per_type", mdp_per_type)
        if T.dim() != 4 or T.shape[-1] != T.shape[-2]:
            raise ModelError(
                "expected mdp_per_type to be a MOMDP or per-type transitions of shape "
                f"(Y, A, X, X), actual shape = {tuple(T.shape)}"
            )
    if discount is None:
        raise TypeError("learn_type_rewards() needs discount= when given transitions")
    if method not in ("projection", "qp", "maxent"):
        raise ValueError(f"expected method 'projection', 'qp' or 'maxent', got {method!r}")
    if reward_rule not in REWARD_RULES:
        raise ValueError(f"expected reward_rule in {REWARD_RULES}, got {reward_rule!r}")
    demonstrations_by_cluster = list(demonstrations_by_cluster)
    Y, A = T.shape[0], T.shape[1]
    if len(demonstrations_by_cluster) != Y:
        raise ModelError(
            f"expected one set of demonstrations per type: {Y} types, got "
            f"{len(demonstrations_by_cluster)} clusters"
        )
    names = [f"demonstrations_by_cluster[{y}]" for y in range(Y)]
    T, phi, mu_hat, d0, _ = _prepare(
        T,
        features,
        demonstrations_by_cluster,
        discount=discount,
        start=start,
        method="projection" if method == "maxent" else method,
        epsilon=epsilon,
        max_iterations=max_iterations,
        horizon=horizon if method != "maxent" else None,
        monte_carlo=monte_carlo,
        initial_policy=None,
        names=names,
    )
    results: tuple[ApprenticeshipResult | MaxEntResult, ...]
    if method == "maxent":
        if horizon is not None:
            raise ValueError(
                "method='maxent' uses infinite-horizon feature expectations; leave horizon=None"
            )
        weights, policy, mu, objective, gradient_norm, iterations = _maxent_batched(
            T,
            phi,
            mu_hat,
            d0,
            torch.zeros_like(mu_hat),
            discount=discount,
            l2=l2,
            tol=epsilon,
            max_iterations=max_iterations,
        )
        results = tuple(
            MaxEntResult(
                weights=weights[y],
                policy=policy[y],
                feature_expectations=mu[y],
                expert_feature_expectations=mu_hat[y],
                objective=objective[y],
                gradient_norm=gradient_norm[y],
                iterations=iterations,
                converged=bool(gradient_norm[y] <= epsilon),
            )
            for y in range(Y)
        )
    else:
        generator = torch.Generator(device=T.device).manual_seed(seed)
        results = tuple(
            _run_batched(
                T,
                phi,
                mu_hat,
                d0,
                discount=discount,
                method=method,
                epsilon=epsilon,
                max_iterations=max_iterations,
                horizon=horizon,
                monte_carlo=monte_carlo,
                initial_policy=None,
                generator=generator,
                vi_tol=1e-8,
                qp_solver=qp_solver,
                qp_options=qp_options,
                standard_error=_standard_errors(phi, demonstrations_by_cluster, discount),
                rule=reward_rule,
            )
        )
        weights = torch.stack([r.weights for r in results])
    R = reward_from_weights(phi, weights, A)  # (Y, A, X)
    policies = value_iteration(T, R, discount).policy  # (Y, X)
    return TypeRewards(
        reward=R.permute(1, 2, 0).contiguous(),
        weights=weights,
        policies=policies,
        results=results,
        method=method,
    )
