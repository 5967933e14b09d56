"""Reward features and feature expectations (exact, Monte Carlo, empirical).

Notation (shared/DESIGN.md): S states, A actions, F features; leading batch dims ``...``
(e.g. many policies, or one MDP per human type) come first and broadcast::

    features: (S, F)       phi[s, f]     state features, reward R(s) = w . phi(s)
              (S, A, F)    phi[s, a, f]  state-action features, R(s, a) = w . phi(s, a)
    T:        (..., A, S, S)   T[..., a, s, s2] = P(s2 | s, a)
    policy:   (..., S) int64 actions, or (..., S, A) probabilities pi[..., s, a] = P(a | s)
    start:    (..., S)         initial state distribution D

Feature expectations of a policy (paper Eq. "featureExp"; Abbeel & Ng 2004, Eq. 3)::

    mu(pi) = E[ sum_{t=0}^{H-1} discount^t phi(s_t) | pi, s_0 ~ D ]   (H = inf by default)

computed exactly from the discounted occupancy ``rho = D (I - discount P_pi)^-1`` (one batched
linear solve), or for a finite horizon ``rho = D sum_{t<H} (discount P_pi)^t`` (a geometric
series by repeated squaring). The expert's empirical estimate from n demonstrations (paper
Eq. "expertFeatureExp")::

    mu_hat = 1/n sum_i sum_{t < len_i} discount^t phi(s_t^(i))

Example:
    >>> import torch
    >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)   # one action that stays put
    >>> phi = indicator_features(2, dtype=torch.float64)
    >>> feature_expectations(T, torch.tensor([0, 0]), phi, 0.5, torch.tensor([1.0, 0.0]))
    tensor([2., 0.], dtype=torch.float64)
"""

from __future__ import annotations

from typing import Literal

import torch

from torchhrc._checks import broadcast_shapes, check_probabilities, check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.irl.trajectories import Trajectories, policy_matrix, sample_trajectories

__all__ = [
    "check_features",
    "discounted_occupancy",
    "empirical_feature_expectations",
    "feature_expectations",
    "indicator_features",
    "monte_carlo_feature_expectations",
    "reward_from_weights",
    "start_distribution",
]


def indicator_features(
    num_states: int,
    num_actions: int | None = None,
    *,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """One-hot features: a tabular reward is then ``w`` itself.

    Args:
        num_states: S.
        num_actions: A for state-action indicators; None for state indicators.
        dtype, device: of the result.

    Returns:
        ``(S, S)`` identity, or ``(S, A, S * A)`` with ``phi[s, a, s * A + a] = 1``.

    Example:
        >>> indicator_features(2, 2).shape
        torch.Size([2, 2, 4])
    """
    if num_states < 1 or (num_actions is not None and num_actions < 1):
        raise ModelError(
            f"expected num_states >= 1 and num_actions >= 1, got {num_states}, {num_actions}"
        )
    if num_actions is None:
        return torch.eye(num_states, dtype=dtype, device=device)
    eye = torch.eye(num_states * num_actions, dtype=dtype, device=device)
    return eye.reshape(num_states, num_actions, num_states * num_actions)


def check_features(
    features: object, num_states: int, num_actions: int, *, name: str = "features"
) -> torch.Tensor:
    """Validate user-given features against an MDP's sizes.

    Args:
        features: ``(S, F)`` state features or ``(S, A, F)`` state-action features.
        num_states: the MDP's S.
        num_actions: the MDP's A.
        name: the argument's name, used in messages.

    Returns:
        The features (floating point; integer and bool inputs are cast to float64).

    Raises:
        ModelError: wrong number of dims, a size that differs from the MDP's, or a
            non-finite entry.

    Example:
        >>> check_features(torch.ones(3, 2), 3, 4).shape
        torch.Size([3, 2])
    """
    phi = check_tensor(name, features, floating=False)
    if not phi.is_floating_point():
        phi = phi.to(torch.float64)
    if phi.dim() == 2:
        if phi.shape[0] != num_states:
            raise ModelError(
                f"expected {name} of shape (S={num_states}, F) to match the MDP's {num_states} "
                f"states, actual shape = {tuple(phi.shape)}"
            )
    elif phi.dim() == 3:
        if phi.shape[:2] != (num_states, num_actions):
            raise ModelError(
                f"expected {name} of shape (S={num_states}, A={num_actions}, F) to match the "
                f"MDP's {num_states} states and {num_actions} actions, "
                f"actual shape = {tuple(phi.shape)}"
            )
    else:
        raise ModelError(
            f"expected {name} of shape (S, F) or (S, A, F), actual shape = {tuple(phi.shape)}"
        )
    if phi.shape[-1] < 1:
        raise ModelError(f"expected {name} to have at least one feature, got F = 0")
    if not torch.isfinite(phi).all():
        raise ModelError(f"{name} has non-finite entries")
    return phi


def reward_from_weights(
    features: torch.Tensor, weights: torch.Tensor, num_actions: int
) -> torch.Tensor:
    """The linear reward ``R(a, s) = w . phi(s[, a])`` in the solver layout.

    Args:
        features: ``(S, F)`` or ``(S, A, F)``.
        weights: ``(..., F)`` reward weights (batch dims allowed).
        num_actions: A (state features give the same reward for every action).

    Returns:
        ``(..., A, S)`` rewards, differentiable in ``weights`` and ``features``.

    Example:
        >>> reward_from_weights(torch.eye(2), torch.tensor([1.0, -1.0]), 3).shape
        torch.Size([3, 2])
    """
    if features.dim() == 2:
        r = weights @ features.to(weights.dtype).transpose(-1, -2)  # (..., S)
        return r.unsqueeze(-2).expand(*r.shape[:-1], num_actions, r.shape[-1])
    return torch.einsum("saf,...f->...as", features.to(weights.dtype), weights)


def start_distribution(
    trajectories: Trajectories, num_states: int, *, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """The empirical distribution ``(S,)`` of the trajectories' first states.

    Example:
        >>> start_distribution(Trajectories.from_pairs([[(1, 0)], [(1, 0)]]), 3).tolist()
        [0.0, 1.0, 0.0]
    """
    first = trajectories.states[:, 0]
    counts = torch.bincount(first, minlength=num_states)[:num_states].to(dtype)
    return counts / counts.sum()


def _geometric_series(M: torch.Tensor, horizon: int) -> torch.Tensor:
    """``sum_{t < horizon} M^t`` for ``M (..., S, S)`` by repeated squaring (log2 H matmuls)."""
    S = M.shape[-1]
    eye = torch.eye(S, dtype=M.dtype, device=M.device).expand_as(M)
    total = torch.zeros_like(M)
    offset = eye  # M^(number of terms already in total)
    block_sum, block_pow = eye, M  # sum_{t < 2^k} M^t and M^(2^k)
    h = horizon
    while h:
        if h & 1:
            total = total + offset @ block_sum
            offset = offset @ block_pow
        h >>= 1
        if h:
            block_sum = block_sum + block_pow @ block_sum
            block_pow = block_pow @ block_pow
    return total


def discounted_occupancy(
    transition: torch.Tensor,
    policy: torch.Tensor,
    discount: float,
    start: torch.Tensor,
    *,
    horizon: int | None = None,
) -> torch.Tensor:
    """Discounted state visitation ``rho(s) = sum_t discount^t P(s_t = s | pi, D)``.

    Args:
        transition: ``(..., A, S, S)`` transition probabilities.
        policy: ``(..., S)`` int64 actions or ``(..., S, A)`` probabilities.
        discount: in (0, 1]; 1 needs a finite ``horizon``.
        start: ``(..., S)`` initial state distribution D.
        horizon: number of steps H, or None for the infinite sum.

    Returns:
        ``(..., S)`` occupancy (sums to ``sum_{t<H} discount^t``), differentiable in
        ``transition``, a stochastic ``policy`` and ``start``.

    Example:
        >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)
        >>> discounted_occupancy(T, torch.tensor([0, 0]), 0.5, torch.tensor([0.5, 0.5]))
        tensor([1., 1.], dtype=torch.float64)
    """
    T = check_tensor("transition", transition)
    check_shape("transition", T, (None, None, None), "(..., A, S, S)")
    A, S = T.shape[-3], T.shape[-1]
    pi = policy_matrix(policy, A, T.dtype)
    check_shape("policy", pi, (S, A), f"(..., S={S}) or (..., S={S}, A={A})")
    d0 = check_tensor("start", start).to(T.dtype)
    check_shape("start", d0, (S,), f"(..., S={S})")
    if not 0.0 < discount <= 1.0:
        raise ModelError(f"expected discount in (0, 1], got {discount}")
    if horizon is not None and horizon < 1:
        raise ModelError(f"expected horizon >= 1 or None, got {horizon}")
    if horizon is None and discount >= 1.0:
        raise ModelError("an infinite horizon needs discount < 1; pass a finite horizon")
    # P[..., s, s2] = sum_a pi[..., s, a] T[..., a, s, s2]
    P = torch.einsum("...sa,...ast->...st", pi, T)
    batch = broadcast_shapes(P.shape[:-2], d0.shape[:-1])
    M = (discount * P).expand(*batch, S, S)
    d0 = d0.expand(*batch, S)
    if horizon is None:
        eye = torch.eye(S, dtype=T.dtype, device=T.device)
        # rho (I - discount P) = d0  <=>  (I - discount P)^T rho^T = d0^T
        return torch.linalg.solve((eye - M).transpose(-1, -2), d0.unsqueeze(-1)).squeeze(-1)
    G = _geometric_series(M, horizon)
    return (d0.unsqueeze(-2) @ G).squeeze(-2)


def feature_expectations(
    transition: torch.Tensor,
    policy: torch.Tensor,
    features: torch.Tensor,
    discount: float,
    start: torch.Tensor,
    *,
    horizon: int | None = None,
) -> torch.Tensor:
    """Exact feature expectations ``mu(pi)`` of one or many policies (paper Eq. featureExp).

    Args:
        transition: ``(..., A, S, S)`` transition probabilities.
        policy: ``(..., S)`` int64 or ``(..., S, A)`` stochastic policies; a batch of
            policies is solved in one batched linear solve.
        features: ``(S, F)`` state or ``(S, A, F)`` state-action features.
        discount: in (0, 1]; 1 needs a finite ``horizon``.
        start: ``(..., S)`` initial state distribution.
        horizon: H steps (matching demonstrations of length H), or None for H = inf.

    Returns:
        ``(..., F)`` feature expectations.

    Example:
        >>> T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]], dtype=torch.float64)
        >>> phi = torch.eye(2, dtype=torch.float64)
        >>> feature_expectations(T, torch.tensor([0, 0]), phi, 0.5, phi[0], horizon=3)
        tensor([1.0000, 0.7500], dtype=torch.float64)
    """
    T = check_tensor("transition", transition)
    A, S = T.shape[-3], T.shape[-1]
    phi = check_features(features, S, A).to(T.dtype)
    rho = discounted_occupancy(T, policy, discount, start, horizon=horizon)  # (..., S)
    if phi.dim() == 2:
        return rho @ phi
    pi = policy_matrix(policy, A, T.dtype)  # (..., S, A)
    return torch.einsum("...s,...sa,saf->...f", rho, pi, phi)


def empirical_feature_expectations(
    features: torch.Tensor,
    trajectories: Trajectories,
    discount: float,
    *,
    reduction: Literal["mean", "none"] = "mean",
) -> torch.Tensor:
    """The expert's empirical feature expectations ``mu_hat`` (paper Eq. expertFeatureExp).

    ``mu_hat = 1/n sum_i sum_{t < len_i} discount^t phi(s_t^(i)[, a_t^(i)])``; padded steps
    beyond each trajectory's length count zero.

    Args:
        features: ``(S, F)`` or ``(S, A, F)``.
        trajectories: n trajectories ``(n, L)`` with lengths ``(n,)``.
        discount: in (0, 1].
        reduction: ``"mean"`` for ``mu_hat (F,)``; ``"none"`` for the per-trajectory
            discounted sums ``(n, F)`` (e.g. to estimate the sampling error).

    Returns:
        ``(F,)`` or ``(n, F)``.

    Raises:
        ModelError: no trajectories, or a state/action out of the features' range.

    Example:
        >>> demos = Trajectories.from_pairs([[(0, 0), (1, 0)], [(1, 0)]])
        >>> empirical_feature_expectations(torch.eye(2), demos, 0.5)
        tensor([0.5000, 0.7500])
    """
    if not isinstance(trajectories, Trajectories):
        raise TypeError(
            f"expected trajectories to be Trajectories, got {type(trajectories).__name__}"
        )
    if trajectories.num_trajectories == 0:
        raise ModelError("expected at least one trajectory, got an empty set of demonstrations")
    phi = check_tensor("features", features)
    S = phi.shape[0]
    states, actions, mask = trajectories.states, trajectories.actions, trajectories.mask
    if ((states >= S) & mask).any():
        raise ModelError(
            f"a trajectory visits state {int(states[mask].max())}, but features cover only "
            f"S = {S} states"
        )
    L = trajectories.max_length
    weights = discount ** torch.arange(L, dtype=phi.dtype, device=phi.device)
    weights = weights * mask.to(phi.device, phi.dtype)  # (n, L)
    s = states.clamp(max=S - 1).to(phi.device)
    if phi.dim() == 2:
        step_features = phi[s]  # (n, L, F)
    else:
        A = phi.shape[1]
        if ((actions >= A) & mask).any():
            raise ModelError(
                f"a trajectory takes action {int(actions[mask].max())}, but features cover only "
                f"A = {A} actions"
            )
        step_features = phi[s, actions.clamp(max=A - 1).to(phi.device)]  # (n, L, F)
    per_trajectory = torch.einsum("nl,nlf->nf", weights, step_features)
    if reduction == "none":
        return per_trajectory
    if reduction != "mean":
        raise ValueError(f"expected reduction 'mean' or 'none', got {reduction!r}")
    return per_trajectory.mean(0)


def monte_carlo_feature_expectations(
    transition: torch.Tensor,
    policy: torch.Tensor,
    features: torch.Tensor,
    discount: float,
    start: torch.Tensor | int,
    *,
    num_trajectories: int,
    horizon: int,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Monte Carlo feature expectations (the paper's step 1 and 5): sample, then average.

    Args:
        transition: ``(A, S, S)`` or ``(B, A, S, S)``.
        policy: ``(S,)`` / ``(S, A)`` or a batch ``(B, S)`` / ``(B, S, A)`` of policies.
        features: ``(S, F)`` or ``(S, A, F)``.
        discount: in (0, 1].
        start: a start state or a ``(S,)`` / ``(B, S)`` distribution.
        num_trajectories: samples per policy.
        horizon: steps per sample; the truncation bias is ``<= discount^H max|phi| / (1 -
            discount)`` relative to the infinite-horizon ``mu``.
        seed, generator: randomness (a generator wins over a seed).

    Returns:
        ``(F,)`` or ``(B, F)`` estimates.

    Example:
        >>> T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]], dtype=torch.float64)
        >>> phi = torch.eye(2, dtype=torch.float64)
        >>> monte_carlo_feature_expectations(T, torch.tensor([0, 0]), phi, 0.5, 0,
        ...                                  num_trajectories=4, horizon=3, seed=0)
        tensor([1.0000, 0.7500], dtype=torch.float64)
    """
    T = check_tensor("transition", transition)
    phi = check_features(features, T.shape[-1], T.shape[-3])
    samples = sample_trajectories(
        T, policy, start, num_trajectories, horizon, seed=seed, generator=generator
    )
    if isinstance(samples, Trajectories):
        return empirical_feature_expectations(phi, samples, discount)
    B, N = len(samples), num_trajectories
    joined = Trajectories(
        torch.cat([b.states for b in samples]),
        torch.cat([b.actions for b in samples]),
        torch.cat([b.lengths for b in samples]),
    )
    per_trajectory = empirical_feature_expectations(phi, joined, discount, reduction="none")
    return per_trajectory.reshape(B, N, -1).mean(1)


def _check_start(start: torch.Tensor, num_states: int) -> torch.Tensor:
    d0 = check_tensor("start", start)
    check_shape("start", d0, (num_states,), f"(..., S={num_states})")
    check_probabilities("start", d0)
    return d0
