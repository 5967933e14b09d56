"""Maximum-entropy IRL (Ziebart et al. 2008; the discounted, causal form of Ziebart 2010).

Soft value iteration (S states, A actions, F features; batch dims ``...`` first)::

    Q(a, s) = R(a, s) + discount * sum_s2 T(a, s, s2) V(s2)
    V(s)    = log sum_a exp Q(a, s)              pi(a | s) = exp(Q(a, s) - V(s))

With a linear reward ``R = theta . phi`` the MaxEnt IRL dual (Ziebart 2010, Ch. 9) is the
concave function::

    g(theta) = theta . mu_hat - D . V_theta - l2 / 2 ||theta||^2
    grad g   = mu_hat - mu(pi_theta) - l2 theta

whose gradient is the gap between the expert's feature expectations and those of the
soft-optimal policy (``dV(s0) / dR(a, s)`` is the discounted occupancy of ``(s, a)``).
:func:`soft_value_iteration` is differentiable by the implicit function theorem at the fixed
point (one linear solve in the backward pass, exact, no unrolled iterations), so ``g`` and its
gradient come from autograd; the maximisation uses L-BFGS, batched over several reward
hypotheses ``theta (H, F)`` (e.g. several starts, several MDPs).

Example:
    >>> import torch
    >>> T = torch.eye(2, dtype=torch.float64).expand(2, 2, 2)     # two actions, both stay
    >>> R = torch.zeros(2, 2, dtype=torch.float64)
    >>> soft_value_iteration(T, R, 0.5).values                   # log(2) / (1 - 0.5)
    tensor([1.3863, 1.3863], dtype=torch.float64)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from torchhrc._checks import broadcast_shapes, check_probabilities, check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.irl.features import (
    check_features,
    empirical_feature_expectations,
    feature_expectations,
    reward_from_weights,
    start_distribution,
)
from torchhrc.irl.trajectories import Trajectories, check_trajectories

__all__ = [
    "MaxEntResult",
    "SoftSolution",
    "maxent_irl",
    "maxent_irl_types",
    "maxent_objective",
    "soft_value_iteration",
]


@dataclass(frozen=True)
class SoftSolution:
    """The result of :func:`soft_value_iteration`.

    Attributes:
        values: ``(..., S)`` soft values ``V(s)``.
        q_values: ``(..., A, S)`` soft action values ``Q(a, s)``.
        policy: ``(..., S, A)`` the soft-optimal policy ``pi(a | s) = exp(Q - V)``.
        iterations: number of soft Bellman backups of the forward pass.
    """

    values: torch.Tensor
    q_values: torch.Tensor
    policy: torch.Tensor
    iterations: int


_NEWTON_MAX_STATES = 2000
"""Up to this many states the forward pass takes Newton steps (one ``S x S`` solve each,
quadratic convergence); beyond it, plain soft value iteration sweeps."""


def _soft_backup(
    T: torch.Tensor, R: torch.Tensor, V: torch.Tensor, discount: float
) -> torch.Tensor:
    """``Q (..., A, S)`` from ``V (..., S)``."""
    return R + discount * (T @ V.unsqueeze(-2).unsqueeze(-1)).squeeze(-1)


def _sum_to_shape(grad: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    """Sum a broadcast gradient back to an input's ``shape``."""
    extra = grad.dim() - len(shape)
    if extra:
        grad = grad.sum(dim=tuple(range(extra)))
    dims = tuple(i for i, n in enumerate(shape) if n == 1 and grad.shape[i] != 1)
    return grad.sum(dim=dims, keepdim=True) if dims else grad


class _SoftValueFixedPoint(torch.autograd.Function):
    """``V = logsumexp_a(R + discount T V)`` solved forward, differentiated implicitly.

    The forward pass is Newton's method on ``V - f(V) = 0`` (soft policy iteration,
    globally convergent like policy iteration, quadratic near the fixed point) for up to
    ``_NEWTON_MAX_STATES`` states, soft value iteration beyond.
    """

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: torch.autograd.function.FunctionCtx,
        T: torch.Tensor,
        R: torch.Tensor,
        discount: float,
        tol: float,
        max_iterations: int,
        initial: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        batch = broadcast_shapes(T.shape[:-3], R.shape[:-2])
        S = T.shape[-1]
        V = R.new_zeros(*batch, S) if initial is None else initial.expand(*batch, S).clone()
        eye = torch.eye(S, dtype=R.dtype, device=R.device)
        iterations = 0
        eps = torch.finfo(R.dtype).eps
        previous = math.inf
        for iterations in range(1, max_iterations + 1):  # noqa: B007 -- reported
            Q = _soft_backup(T, R, V, discount)
            V_backup = torch.logsumexp(Q, dim=-2)
            residual = float((V_backup - V).abs().max()) if V.numel() else 0.0
            # ``tol``, but no finer than the values' own rounding: with large values (a large
            # reward scale) the residual stalls at a few ulps of |V| above a tight ``tol``,
            # and Newton's steps then only add rounding; stop there too (it used to run to
            # max_iterations, minutes per call)
            scale = float(V_backup.abs().max()) if V.numel() else 0.0
            floor = 64.0 * eps * max(1.0, scale)
            if residual <= max(tol, floor) or (residual >= previous and residual <= 1e6 * floor):
                V = V_backup
                break
            previous = residual
            if S <= _NEWTON_MAX_STATES:
                # Newton step on V - f(V) = 0 (soft policy iteration): the Jacobian of the
                # soft backup f is discount * P_pi, so V <- V - (I - discount P_pi)^-1 (V - f(V)).
                pi = torch.softmax(Q, dim=-2).transpose(-1, -2)
                P = torch.einsum("...sa,...ast->...st", pi, T)
                step = torch.linalg.solve(eye - discount * P, (V - V_backup).unsqueeze(-1))
                V = V - step.squeeze(-1)
            else:
                V = V_backup
        Q = _soft_backup(T, R, V, discount)
        pi = torch.softmax(Q, dim=-2).transpose(-1, -2)  # (..., S, A)
        ctx.save_for_backward(T, R, V, pi)
        ctx.discount = discount
        count = V.new_tensor(float(iterations))
        ctx.mark_non_differentiable(count)
        return V, count

    @staticmethod
    def backward(  # type: ignore[override]
        ctx: torch.autograd.function.FunctionCtx,
        grad_V: torch.Tensor,
        _grad_iterations: torch.Tensor,
    ) -> tuple[torch.Tensor | None, ...]:
        T, R, V, pi = ctx.saved_tensors  # type: ignore[attr-defined]
        g = ctx.discount  # type: ignore[attr-defined]
        S = V.shape[-1]
        # P[..., s, s2] = sum_a pi[..., s, a] T[..., a, s, s2]; dV = (I - g P)^-1 (pi . dR + ...)
        P = torch.einsum("...sa,...ast->...st", pi, T)
        eye = torch.eye(S, dtype=V.dtype, device=V.device)
        u = torch.linalg.solve((eye - g * P).transpose(-1, -2), grad_V.unsqueeze(-1)).squeeze(-1)
        weighted = pi * u.unsqueeze(-1)  # (..., S, A): u[s] pi(a | s)
        grad_R = grad_T = None
        if ctx.needs_input_grad[1]:
            grad_R = _sum_to_shape(weighted.transpose(-1, -2), R.shape)
        if ctx.needs_input_grad[0]:
            # dV / dT[a, s, s2] = g pi(a | s) V(s2), propagated through (I - g P)^-T
            full = g * weighted.transpose(-1, -2).unsqueeze(-1) * V.unsqueeze(-2).unsqueeze(-2)
            grad_T = _sum_to_shape(full, T.shape)
        return grad_T, grad_R, None, None, None, None


def soft_value_iteration(
    transition: torch.Tensor,
    reward: torch.Tensor,
    discount: float,
    *,
    tol: float = 1e-10,
    max_iterations: int = 100_000,
    initial_values: torch.Tensor | None = None,
) -> SoftSolution:
    """Soft (maximum-entropy) value iteration, batched and differentiable.

    Args:
        transition: ``(..., A, S, S)`` transition probabilities.
        reward: ``(..., A, S)`` rewards (batch dims broadcast with ``transition``'s, e.g.
            ``(H, A, S)`` rewards of H hypotheses with one ``(A, S, S)`` transition).
        discount: in (0, 1).
        tol: stop when the soft Bellman residual ``max |f(V) - V| <= tol`` (then
            ``|V - V*| <= tol / (1 - discount)``).
        max_iterations: cap on the number of Newton steps / backups.
        initial_values: ``(..., S)`` warm start (default zeros).

    Returns:
        :class:`SoftSolution`; ``values`` and ``q_values`` are differentiable in ``reward``
        and ``transition`` (implicit differentiation of the fixed point).

    Raises:
        ModelError: shapes disagree, ``transition`` is not a probability tensor, or the
            discount is not in (0, 1).

    Example:
        >>> T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]], dtype=torch.float64)
        >>> R = torch.tensor([[0.0, 1.0]], dtype=torch.float64)
        >>> soft_value_iteration(T, R, 0.5).values.round(decimals=6)
        tensor([1., 2.], dtype=torch.float64)
    """
    T = check_tensor("transition", transition)
    check_shape("transition", T, (None, None, None), "(..., A, S, S)")
    A, S = T.shape[-3], T.shape[-1]
    if T.shape[-2] != S:
        raise ModelError(f"expected transition of shape (..., A, S, S), got {tuple(T.shape)}")
    R = check_tensor("reward", reward)
    check_shape("reward", R, (A, S), f"(..., A={A}, S={S})")
    check_probabilities("transition", T.detach())
    if not 0.0 < discount < 1.0:
        raise ModelError(f"expected discount in (0, 1) for soft value iteration, got {discount}")
    dtype = torch.promote_types(T.dtype, R.dtype)
    T, R = T.to(dtype), R.to(dtype)
    initial = None if initial_values is None else initial_values.detach().to(dtype)
    V, iterations = _SoftValueFixedPoint.apply(T, R, discount, tol, max_iterations, initial)
    Q = _soft_backup(T, R, V, discount)
    policy = torch.softmax(Q, dim=-2).transpose(-1, -2)
    return SoftSolution(values=V, q_values=Q, policy=policy, iterations=int(iterations))


def maxent_objective(
    weights: torch.Tensor,
    transition: torch.Tensor,
    features: torch.Tensor,
    expert_feature_expectations: torch.Tensor,
    start: torch.Tensor,
    discount: float,
    *,
    l2: float = 0.0,
    tol: float = 1e-10,
) -> torch.Tensor:
    """The MaxEnt IRL dual ``g(theta) = theta . mu_hat - D . V_theta - l2/2 ||theta||^2``.

    Its gradient (by autograd) is ``mu_hat - mu(pi_theta) - l2 theta``.

    Args:
        weights: ``(..., F)`` reward weights ``theta`` (one row per hypothesis).
        transition: ``(..., A, S, S)``.
        features: ``(S, F)`` or ``(S, A, F)``.
        expert_feature_expectations: ``(..., F)`` ``mu_hat``.
        start: ``(..., S)`` initial distribution D.
        discount: in (0, 1).
        l2: ridge penalty (keeps ``theta`` finite for deterministic experts).
        tol: soft value iteration tolerance.

    Returns:
        ``(...)`` objective values (to maximise).

    Example:
        >>> T = torch.eye(2, dtype=torch.float64).expand(2, 2, 2)
        >>> theta = torch.zeros(2, dtype=torch.float64, requires_grad=True)
        >>> g = maxent_objective(theta, T, torch.eye(2, dtype=torch.float64),
        ...                      torch.tensor([2.0, 0.0], dtype=torch.float64),
        ...                      torch.tensor([1.0, 0.0], dtype=torch.float64), 0.5)
        >>> torch.autograd.grad(g, theta)[0]                   # mu_hat - mu(uniform policy)
        tensor([0., 0.], dtype=torch.float64)
    """
    A = transition.shape[-3]
    R = reward_from_weights(features, weights, A)
    V = soft_value_iteration(transition, R, discount, tol=tol).values
    value = (V * start.to(V.dtype)).sum(-1)
    return (
        (weights * expert_feature_expectations.to(weights.dtype)).sum(-1)
        - value
        - 0.5 * l2 * (weights * weights).sum(-1)
    )


@dataclass(frozen=True)
class MaxEntResult:
    """The result of :func:`maxent_irl` (``...`` = the hypotheses' batch shape).

    Attributes:
        weights: ``(..., F)`` the learned ``theta``; the reward is ``theta . phi``.
        policy: ``(..., S, A)`` the soft-optimal policy of the learned reward.
        feature_expectations: ``(..., F)`` ``mu(pi_theta)``.
        expert_feature_expectations: ``(F,)`` ``mu_hat``.
        objective: ``(...)`` the final dual value ``g(theta)``.
        gradient_norm: ``(...)`` ``||mu_hat - mu(pi_theta) - l2 theta||_2`` at the end.
        iterations: number of L-BFGS iterations.
        converged: whether every hypothesis' gradient norm is ``<= tol``.
    """

    weights: torch.Tensor
    policy: torch.Tensor
    feature_expectations: torch.Tensor
    expert_feature_expectations: torch.Tensor
    objective: torch.Tensor
    gradient_norm: torch.Tensor
    iterations: int
    converged: bool

    def reward(self, features: torch.Tensor, num_actions: int) -> torch.Tensor:
        """The learned reward ``(..., A, S)``."""
        return reward_from_weights(features, self.weights, num_actions)


def _result(
    weights: torch.Tensor,
    policy: torch.Tensor,
    mu: torch.Tensor,
    mu_hat: torch.Tensor,
    objective: torch.Tensor,
    gradient_norm: torch.Tensor,
    iterations: int,
    tol: float,
) -> MaxEntResult:
    """A :class:`MaxEntResult`, converged where every gradient norm is ``<= tol``."""
    return MaxEntResult(
        weights=weights,
        policy=policy,
        feature_expectations=mu,
        expert_feature_expectations=mu_hat,
        objective=objective,
        gradient_norm=gradient_norm,
        iterations=iterations,
        converged=bool((gradient_norm <= tol).all()),
    )


def _maximise_dual(
    T: torch.Tensor,
    phi: torch.Tensor,
    mu_hat: torch.Tensor,
    d0: torch.Tensor,
    parameters: list[torch.Tensor],
    theta: Callable[[], torch.Tensor],
    penalty: Callable[[], torch.Tensor],
    *,
    discount: float,
    tol: float,
    max_iterations: int,
) -> int:
    """L-BFGS on ``sum_b [theta_b . mu_hat_b - d0_b . V_theta_b - penalty_b]`` over
    ``parameters`` (updated in place): ``theta()`` gives the ``(B, F)`` weights from them,
    ``penalty()`` the ``(B,)`` ridge terms. Returns the iterations taken."""
    A = T.shape[-3]
    optimizer = torch.optim.LBFGS(
        parameters,
        lr=1.0,
        max_iter=max_iterations,
        tolerance_grad=tol * 1e-2,
        tolerance_change=1e-14,
        history_size=20,
        line_search_fn="strong_wolfe",
    )
    warm: dict[str, torch.Tensor] = {}

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        weights = theta()
        R = reward_from_weights(phi, weights, A)
        solution = soft_value_iteration(T, R, discount, tol=1e-12, initial_values=warm.get("V"))
        warm["V"] = solution.values.detach()
        value = (solution.values * d0).sum(-1)
        g = (weights * mu_hat).sum(-1) - value - penalty()
        loss = -g.sum()
        loss.backward()
        return loss

    optimizer.step(closure)
    return int(optimizer.state[parameters[0]].get("n_iter", 0))


def _maxent_batched(
    T: torch.Tensor,
    phi: torch.Tensor,
    mu_hat: torch.Tensor,
    d0: torch.Tensor,
    theta0: torch.Tensor,
    *,
    discount: float,
    l2: float,
    tol: float,
    max_iterations: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """L-BFGS on ``sum_b g_b(theta_b)`` (separable): ``T (B, A, S, S)``, ``mu_hat (B, F)``,
    ``d0 (B, S)``, ``theta0 (B, F)``. Returns weights, policy, mu, objective, grad norm, iters."""
    A = T.shape[-3]
    theta = theta0.clone().requires_grad_(True)
    iterations = _maximise_dual(
        T, phi, mu_hat, d0, [theta], lambda: theta,
        lambda: 0.5 * l2 * (theta * theta).sum(-1),
        discount=discount, tol=tol, max_iterations=max_iterations,
    )  # fmt: skip
    with torch.no_grad():
        weights = theta.detach()
        R = reward_from_weights(phi, weights, A)
        solution = soft_value_iteration(T, R, discount, tol=1e-12)
        mu = feature_expectations(T, solution.policy, phi, discount, d0)
        value = (solution.values * d0).sum(-1)
        objective = (weights * mu_hat).sum(-1) - value - 0.5 * l2 * (weights * weights).sum(-1)
        gradient_norm = torch.linalg.vector_norm(mu_hat - mu - l2 * weights, dim=-1)
    return weights, solution.policy, mu, objective, gradient_norm, iterations


def maxent_irl(
    transition: torch.Tensor,
    features: torch.Tensor,
    demonstrations: Trajectories,
    *,
    discount: float,
    start: torch.Tensor | None = None,
    initial_weights: torch.Tensor | None = None,
    num_hypotheses: int = 1,
    l2: float = 1e-3,
    tol: float = 1e-6,
    max_iterations: int = 200,
    seed: int = 0,
    expert_feature_expectations: torch.Tensor | None = None,
) -> MaxEntResult:
    """Maximum-entropy IRL: maximise the dual ``g(theta)`` by L-BFGS, all hypotheses at once.

    Args:
        transition: ``(A, S, S)`` or a batch ``(H, A, S, S)`` (one MDP per hypothesis).
        features: ``(S, F)`` or ``(S, A, F)``.
        demonstrations: the expert's trajectories (unequal lengths allowed); they should be
            long enough that ``discount^L`` is small (infinite-horizon feature expectations).
        discount: in (0, 1).
        start: ``(S,)`` initial distribution; default the demonstrations' first states.
        initial_weights: ``(H, F)`` starting ``theta`` of H hypotheses (default: zeros for
            the first and seeded normal draws for the others).
        num_hypotheses: H when ``initial_weights`` is not given.
        l2: ridge penalty on ``theta``.
        tol: stop when the gradient norm of every hypothesis is ``<= tol``.
        max_iterations: L-BFGS iteration cap.
        seed: seed of the random initial hypotheses.
        expert_feature_expectations: ``(F,)`` ``mu_hat`` to use instead of the
            demonstrations' estimate (e.g. exact ones; ``demonstrations`` still give D).

    Returns:
        :class:`MaxEntResult` with batch shape ``(H,)`` when ``H > 1`` or ``transition`` is
        batched, else ``()``.

    Raises:
        ModelError: features and MDP of different sizes, empty demonstrations, an
            impossible transition in a demonstration, bad arguments.

    Example:
        >>> from torchhrc.tasks.gridworld import Gridworld
        >>> world = Gridworld(size=4, goal=(3, 3), hazards=((1, 2),), slip=0.0)
        >>> res = maxent_irl(world.transition, world.features(),
        ...                  world.demonstrations(20, 40, seed=0), discount=0.9)
        >>> bool(res.gradient_norm < 1e-3)
        True
    """
    T = check_tensor("transition", transition)
    check_shape("transition", T, (None, None, None), "(..., A, S, S)")
    if T.dim() > 4:
        raise ModelError(f"expected transition (A, S, S) or (H, A, S, S), got {tuple(T.shape)}")
    A, S = T.shape[-3], T.shape[-1]
    check_probabilities("transition", T)
    if not 0.0 < discount < 1.0:
        raise ModelError(f"expected discount in (0, 1), got {discount}")
    if l2 < 0 or tol <= 0 or max_iterations < 1:
        raise ValueError(
            f"expected l2 >= 0, tol > 0, max_iterations >= 1, got {l2}, {tol}, {max_iterations}"
        )
    phi = check_features(features, S, A).to(T.dtype)
    if not isinstance(demonstrations, Trajectories):
        raise TypeError(
            f"expected demonstrations to be Trajectories, got {type(demonstrations).__name__}"
        )
    if demonstrations.num_trajectories == 0:
        raise ModelError("demonstrations is empty: IRL needs at least one demonstration")
    demonstrations = demonstrations.to(T.device)
    for b in range(T.shape[0] if T.dim() == 4 else 1):
        check_trajectories(demonstrations, T[b] if T.dim() == 4 else T)
    if expert_feature_expectations is None:
        mu_hat = empirical_feature_expectations(phi, demonstrations, discount)
    else:
        mu_hat = check_tensor("expert_feature_expectations", expert_feature_expectations)
        check_shape("expert_feature_expectations", mu_hat, (phi.shape[-1],), "(F,)")
        mu_hat = mu_hat.to(T.dtype)
    if start is None:
        d0 = start_distribution(demonstrations, S, dtype=T.dtype).to(T.device)
    else:
        d0 = check_tensor("start", start).to(T.dtype)
        check_shape("start", d0, (S,), f"(S={S},)")
        check_probabilities("start", d0)
    F = phi.shape[-1]
    batched = T.dim() == 4 or num_hypotheses > 1 or initial_weights is not None
    if initial_weights is None:
        H = T.shape[0] if T.dim() == 4 else num_hypotheses
        if H < 1:
            raise ValueError(f"expected num_hypotheses >= 1, got {num_hypotheses}")
        generator = torch.Generator().manual_seed(seed)
        theta0 = torch.randn(H, F, generator=generator, dtype=T.dtype).to(T.device)
        theta0[0] = 0.0
    else:
        theta0 = check_tensor("initial_weights", initial_weights).to(T.dtype)
        check_shape("initial_weights", theta0, (F,), f"(H, F={F})")
        theta0 = theta0.reshape(-1, F)
    H = theta0.shape[0]
    T = T.expand(H, A, S, S) if T.dim() == 3 else T
    if T.shape[0] != H:
        raise ModelError(f"expected {T.shape[0]} initial weight rows (one per MDP), got {H}")
    weights, policy, mu, objective, gradient_norm, iterations = _maxent_batched(
        T,
        phi,
        mu_hat.expand(H, F),
        d0.expand(H, S),
        theta0,
        discount=discount,
        l2=l2,
        tol=tol,
        max_iterations=max_iterations,
    )
    if not batched:
        weights, policy, mu = weights[0], policy[0], mu[0]
        objective, gradient_norm = objective[0], gradient_norm[0]
    return _result(weights, policy, mu, mu_hat, objective, gradient_norm, iterations, tol)


def maxent_irl_types(
    transition: torch.Tensor,
    features: torch.Tensor,
    demonstrations: list[Trajectories],
    *,
    discount: float,
    l2: float = 1e-3,
    pooling: float = 0.0,
    tol: float = 1e-6,
    max_iterations: int = 200,
) -> MaxEntResult:
    """MaxEnt IRL of K related experts at once, their rewards partly pooled.

    Each expert ``k`` (a type of people) has its own MDP ``transition[k]`` and reward
    ``theta_k = theta_0 + delta_k``: a part shared by all and a part of its own. The prior is
    Gaussian, ``theta_0 ~ N(0, pooling / l2)`` and ``delta_k ~ N(0, (1 - pooling) / l2)``, so
    each ``theta_k`` has the ridge :func:`maxent_irl` gives it alone (variance ``1 / l2``)
    and two experts' rewards a prior correlation ``pooling``. The objective maximised is::

        sum_k [ g_k(theta_0 + delta_k) - l2 / (1 - pooling) ||delta_k||^2 / 2 ]
            - K l2 / pooling ||theta_0||^2 / 2

    (``g_k`` the dual of :func:`maxent_objective` without its ridge, on expert ``k``'s own
    demonstrations). ``pooling = 0`` is K separate :func:`maxent_irl` fits; towards 1, one
    reward for all. What it is for: a pair ``(s, a)`` that expert ``k``'s demonstrations
    never reach gets its reward from the experts whose demonstrations do, instead of 0.
    This is the hierarchical prior of multi-task Bayesian IRL (Dimitrakakis and Rothkopf,
    "Bayesian multitask inverse reinforcement learning", EWRL 2011), here at its MAP point.

    Args:
        transition: ``(K, A, S, S)`` one MDP per expert.
        features: ``(S, F)`` or ``(S, A, F)``.
        demonstrations: K trajectory sets, one per expert, each non-empty.
        discount: in (0, 1).
        l2: the ridge of each ``theta_k`` (its prior precision).
        pooling: in [0, 1): the prior correlation of two experts' rewards.
        tol: stop when the gradient norm is ``<= tol``.
        max_iterations: L-BFGS iteration cap.

    Returns:
        :class:`MaxEntResult` with batch shape ``(K,)`` (``expert_feature_expectations``
        ``(K, F)``; ``gradient_norm`` per expert, of its own objective's gradient).

    Raises:
        ValueError: ``pooling`` outside [0, 1), ``l2 <= 0`` with ``pooling > 0``, a count
            of trajectory sets other than K.
        ModelError: as :func:`maxent_irl`.

    Example:
        >>> from torchhrc.tasks.gridworld import Gridworld
        >>> world = Gridworld(size=3, goal=(2, 2), slip=0.0)
        >>> T = world.transition.expand(2, *world.transition.shape)
        >>> demos = [world.demonstrations(5, 10, seed=s) for s in (0, 1)]
        >>> fit = maxent_irl_types(T, world.features(), demos, discount=0.9, l2=0.1,
        ...                        pooling=0.5)
        >>> tuple(fit.weights.shape)                      # (K experts, F features)
        (2, 3)
    """
    T = check_tensor("transition", transition)
    check_shape("transition", T, (None, None, None, None), "(K, A, S, S)")
    K, A, S = T.shape[0], T.shape[1], T.shape[-1]
    check_probabilities("transition", T)
    if not 0.0 < discount < 1.0:
        raise ModelError(f"expected discount in (0, 1), got {discount}")
    if not 0.0 <= pooling < 1.0:
        raise ValueError(f"expected pooling in [0, 1), got {pooling!r}")
    if l2 < 0 or (pooling > 0 and l2 <= 0) or tol <= 0 or max_iterations < 1:
        raise ValueError(
            f"expected l2 >= 0 (> 0 with pooling), tol > 0, max_iterations >= 1, got "
            f"{l2}, {tol}, {max_iterations}"
        )
    if len(demonstrations) != K:
        raise ValueError(
            f"expected {K} trajectory sets (one per MDP of transition), got {len(demonstrations)}"
        )
    phi = check_features(features, S, A).to(T.dtype)
    F = phi.shape[-1]
    mu_hat = T.new_zeros(K, F)
    d0 = T.new_zeros(K, S)
    for k, demos in enumerate(demonstrations):  # K sets (a handful of types)
        if not isinstance(demos, Trajectories):
            raise TypeError(
                f"expected demonstrations[{k}] to be Trajectories, got {type(demos).__name__}"
            )
        if demos.num_trajectories == 0:
            raise ModelError(f"demonstrations[{k}] is empty: IRL needs a demonstration")
        demos = demos.to(T.device)
        check_trajectories(demos, T[k])
        mu_hat[k] = empirical_feature_expectations(phi, demos, discount)
        d0[k] = start_distribution(demos, S, dtype=T.dtype).to(T.device)
    if pooling == 0.0 or K == 1:  # K separate problems, each solved alone (as maxent_irl);
        # one expert: the split prior's MAP is theta's ridge l2 alone
        parts = [
            _maxent_batched(T[k : k + 1], phi, mu_hat[k : k + 1], d0[k : k + 1],
                            T.new_zeros(1, F), discount=discount, l2=l2, tol=tol,
                            max_iterations=max_iterations)
            for k in range(K)
        ]  # fmt: skip
        weights, policy, mu, objective, gradient_norm = (
            torch.cat([part[i] for part in parts]) for i in range(5)
        )
        iterations = max(part[5] for part in parts)
    else:
        l2_own, l2_shared = l2 / (1.0 - pooling), K * l2 / pooling
        shared = T.new_zeros(F, requires_grad=True)
        own = T.new_zeros(K, F, requires_grad=True)
        iterations = _maximise_dual(
            T, phi, mu_hat, d0, [shared, own], lambda: shared + own,
            lambda: 0.5 * l2_own * (own * own).sum(-1)
            + 0.5 * l2_shared / K * (shared * shared).sum(),
            discount=discount, tol=tol, max_iterations=max_iterations,
        )  # fmt: skip
        with torch.no_grad():
            delta = own.detach()
            weights = shared.detach() + delta
            R = reward_from_weights(phi, weights, A)
            solution = soft_value_iteration(T, R, discount, tol=1e-12)
            policy = solution.policy
            mu = feature_expectations(T, policy, phi, discount, d0)
            objective = (weights * mu_hat).sum(-1) - (solution.values * d0).sum(-1)
            objective = objective - 0.5 * l2_own * (delta * delta).sum(-1)
            gradient_norm = torch.linalg.vector_norm(mu_hat - mu - l2_own * delta, dim=-1)
    return _result(weights, policy, mu, mu_hat, objective, gradient_norm, iterations, tol)
