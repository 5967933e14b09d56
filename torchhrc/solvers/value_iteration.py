"""Value iteration and exact policy evaluation for batches of MDPs.

Notation (shared/DESIGN.md): S states, A actions; leading batch dims ``...`` broadcast,
so many MDPs (or one MDP under many reward hypotheses, as in IRL) are solved at once::

    T: (..., A, S, S)   T[..., a, s, s2] = P(s2 | s, a)
    R: (..., A, S)      R[..., a, s]     = expected immediate reward of a in s

Bellman optimality (Puterman 1994, Sec. 6.3)::

    Q(a, s) = R(a, s) + discount * sum_s2 T(a, s, s2) V(s2),   V(s) = max_a Q(a, s)

Value iteration stops when the Bellman residual ``max |V_k - V_{k-1}|`` falls below
``tol * (1 - discount) / (2 * discount)``, which makes the greedy policy ``tol``-optimal and
``|V_k - V*| <= tol / 2`` (Puterman 1994, Thm. 6.3.1).

Example:
    >>> import torch
    >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)   # one action that stays put
    >>> R = torch.tensor([[1.0, 0.0]], dtype=torch.float64)
    >>> value_iteration(T, R, 0.5).values.round(decimals=6)
    tensor([2., 0.], dtype=torch.float64)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchhrc._checks import (
    broadcast_shapes,
    check_discount,
    check_probabilities,
    check_shape,
    check_tensor,
)
from torchhrc.errors import ModelError

__all__ = ["MDPSolution", "bellman_expectation", "policy_evaluation", "value_iteration"]


@dataclass(frozen=True)
class MDPSolution:
    """The result of :func:`value_iteration`.

    Attributes:
        values: ``(..., S)`` optimal state values ``V(s)`` (within ``tol / 2``).
        q_values: ``(..., A, S)`` action values ``Q(a, s) = R(a, s) + discount * T V``.
        policy: ``(..., S)`` int64, a greedy action per state.
        iterations: number of Bellman backups performed.
        residual: the last Bellman residual ``max |V_k - V_{k-1}|`` over the whole batch.
        error_bound: ``discount * residual / (1 - discount)``, a bound on
            ``max |values - V*|`` (inf when the discount is 1).
    """

    values: torch.Tensor
    q_values: torch.Tensor
    policy: torch.Tensor
    iterations: int
    residual: float
    error_bound: float


def _as_float(name: str, value: object) -> torch.Tensor:
    value = check_tensor(name, value, floating=False)
    if not value.is_floating_point():
        value = value.to(torch.float64)
    return value


def _check_mdp(T: object, R: object, discount: object) -> tuple[torch.Tensor, torch.Tensor, float]:
    T = _as_float("T", T)
    check_shape("T", T, (None, None, None), "(..., A, S, S)")
    A, S = T.shape[-3], T.shape[-1]
    if T.shape[-2] != S:
        raise ModelError(
            f"expected T to have shape (..., A, S, S), actual shape = {tuple(T.shape)}"
        )
    R = _as_float("R", R)
    check_shape("R", R, (A, S), f"(..., A={A}, S={S})")
    try:
        broadcast_shapes(T.shape[:-3], R.shape[:-2])
    except RuntimeError:
        raise ModelError(
            f"batch dims of T {tuple(T.shape[:-3])} and R {tuple(R.shape[:-2])} do not broadcast"
        ) from None
    if not torch.isfinite(R).all():
        raise ModelError("R has non-finite entries")
    check_probabilities("T", T.detach())
    discount = check_discount(discount)
    dtype = torch.promote_types(T.dtype, R.dtype)
    return T.to(dtype), R.to(dtype), discount


def bellman_expectation(T: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """``sum_s2 T(a, s, s2) V(s2)`` for every action and state, batched.

    Args:
        T: ``(..., A, S, S)`` transition probabilities.
        values: ``(..., S)`` state values (any batch dims broadcasting with ``T``'s).

    Returns:
        ``(..., A, S)`` expected next-state values.

    Example:
        >>> T = torch.tensor([[[0.5, 0.5], [0.0, 1.0]]])
        >>> bellman_expectation(T, torch.tensor([2.0, 4.0]))
        tensor([[3., 4.]])
    """
    return (T @ values.unsqueeze(-2).unsqueeze(-1)).squeeze(-1)


def value_iteration(
    T: torch.Tensor,
    R: torch.Tensor,
    discount: float,
    *,
    tol: float = 1e-8,
    max_iterations: int = 100_000,
    initial_values: torch.Tensor | None = None,
) -> MDPSolution:
    """Solve a batch of MDPs by value iteration (Bellman 1957; Puterman 1994, Sec. 6.3).

    All MDPs of the batch are iterated together until the largest residual meets the
    stopping rule ``max |V_k - V_{k-1}| < tol * (1 - discount) / (2 * discount)``.

    Args:
        T: ``(..., A, S, S)`` transition probabilities ``T[..., a, s, s2] = P(s2 | s, a)``.
        R: ``(..., A, S)`` rewards; batch dims broadcast with ``T``'s (e.g. ``R`` of shape
            ``(K, A, S)`` with one ``T`` of shape ``(A, S, S)`` solves K reward hypotheses).
        discount: discount factor in (0, 1]; with 1 the loop stops when the residual is
            below ``tol`` (only meaningful for proper, absorbing MDPs).
        tol: target accuracy of the greedy policy's value.
        max_iterations: hard cap on the number of backups.
        initial_values: optional ``(..., S)`` starting values (default zeros).

    Returns:
        :class:`MDPSolution` with ``values (..., S)``, ``q_values (..., A, S)``,
        ``policy (..., S)`` (int64) and ``iterations``. Differentiable in ``R`` and ``T``
        through the unrolled iterations.

    Raises:
        ModelError: shapes disagree or ``T`` is not a probability tensor.

    Example:
        >>> T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]], [[1.0, 0.0], [1.0, 0.0]]])
        >>> R = torch.tensor([[0.0, 1.0], [0.0, 0.0]])
        >>> value_iteration(T, R, 0.9).policy
        tensor([0, 0])
    """
    T, R, g = _check_mdp(T, R, discount)
    if tol <= 0:
        raise ValueError(f"expected tol > 0, got {tol}")
    if max_iterations < 1:
        raise ValueError(f"expected max_iterations >= 1, got {max_iterations}")
    batch = broadcast_shapes(T.shape[:-3], R.shape[:-2])
    S = T.shape[-1]
    if initial_values is None:
        V = R.new_zeros(*batch, S)
    else:
        V = check_tensor("initial_values", initial_values).to(R.dtype)
        check_shape("initial_values", V, (S,), f"(..., S={S})")
    threshold = tol * (1.0 - g) / (2.0 * g) if g < 1.0 else tol
    residual = float("inf")
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 -- iterations is reported
        Q = R + g * bellman_expectation(T, V)
        V_new = Q.amax(dim=-2)
        residual = (V_new - V).abs().max().item() if V_new.numel() else 0.0
        V = V_new
        if residual < threshold:
            break
    Q = R + g * bellman_expectation(T, V)
    return MDPSolution(
        values=V,
        q_values=Q,
        policy=Q.argmax(dim=-2),
        iterations=iterations,
        residual=residual,
        error_bound=g * residual / (1.0 - g) if g < 1.0 else float("inf"),
    )


def policy_evaluation(
    T: torch.Tensor, R: torch.Tensor, discount: float, policy: torch.Tensor
) -> torch.Tensor:
    """Exact value of a fixed policy by one linear solve, ``V = (I - discount P_pi)^-1 r_pi``.

    ``P_pi(s, s2) = sum_a pi(a | s) T(a, s, s2)`` and ``r_pi(s) = sum_a pi(a | s) R(a, s)``.

    Args:
        T: ``(..., A, S, S)`` transition probabilities.
        R: ``(..., A, S)`` rewards.
        discount: discount factor in (0, 1).
        policy: ``(..., S)`` int64 deterministic actions, or ``(..., S, A)`` floating
            stochastic policy ``pi[..., s, a] = P(a | s)``.

    Returns:
        ``(..., S)`` policy values (differentiable in ``T``, ``R`` and a stochastic policy).

    Example:
        >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)
        >>> R = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
        >>> policy_evaluation(T, R, 0.5, torch.tensor([0, 0]))
        tensor([2., 4.], dtype=torch.float64)
    """
    T, R, g = _check_mdp(T, R, discount)
    if g >= 1.0:
        raise ModelError("policy_evaluation needs discount < 1 (the linear system is singular)")
    A, S = T.shape[-3], T.shape[-1]
    policy = check_tensor("policy", policy, floating=False)
    if policy.is_floating_point():
        check_shape("policy", policy, (S, A), f"(..., S={S}, A={A})")
        check_probabilities("policy", policy.detach())
        pi = policy.to(R.dtype)
    else:
        check_shape("policy", policy, (S,), f"(..., S={S})")
        if policy.numel() and (policy.min() < 0 or policy.max() >= A):
            raise ModelError(
                f"expected policy actions in [0, {A}), got values in "
                f"[{policy.min().item()}, {policy.max().item()}]"
            )
        pi = torch.nn.functional.one_hot(policy.long(), A).to(R.dtype)
    # P[..., s, s2] = sum_a pi[..., s, a] T[..., a, s, s2];  r[..., s] = sum_a pi R
    P = torch.einsum("...sa,...ast->...st", pi, T)
    r = torch.einsum("...sa,...as->...s", pi, R)
    eye = torch.eye(S, dtype=R.dtype, device=R.device)
    batch = broadcast_shapes(P.shape[:-2], r.shape[:-1])
    lhs = (eye - g * P).expand(*batch, S, S)
    return torch.linalg.solve(lhs, r.expand(*batch, S).unsqueeze(-1)).squeeze(-1)
