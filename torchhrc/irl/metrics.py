"""How good is a learned reward: policy agreement with the expert and true expected return.

Example:
    >>> import torch
    >>> q = torch.tensor([[1.0, 0.0], [1.0, 2.0]])        # Q[a, s]
    >>> policy_agreement(q, torch.tensor([1, 1]))         # state 0: 0 and 1 tie, state 1: 1
    tensor(1.)
"""

from __future__ import annotations

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.solvers.value_iteration import policy_evaluation

__all__ = ["expected_return", "normalized_return", "policy_agreement"]


def policy_agreement(
    q_values: torch.Tensor, policy: torch.Tensor, *, tol: float = 1e-6
) -> torch.Tensor:
    """Fraction of states where ``policy`` takes an action that is optimal for the expert.

    An action agrees in ``s`` when ``Q*(a, s) >= max_a' Q*(a', s) - tol`` (ties count as
    agreement: several actions can be optimal, e.g. on a grid's diagonal).

    Args:
        q_values: ``(..., A, S)`` optimal action values of the true reward.
        policy: ``(..., S)`` int64 actions.
        tol: absolute tolerance on the action values.

    Returns:
        ``(...)`` agreement in [0, 1].

    Example:
        >>> policy_agreement(torch.tensor([[0.0], [1.0]]), torch.tensor([0]))
        tensor(0.)
    """
    q = check_tensor("q_values", q_values)
    check_shape("q_values", q, (None, None), "(..., A, S)")
    check_shape("policy", policy, (q.shape[-1],), f"(..., S={q.shape[-1]})")
    chosen = q.gather(-2, policy.long().unsqueeze(-2).expand(*policy.shape[:-1], 1, -1))
    best = q.amax(-2, keepdim=True)
    return (chosen >= best - tol).squeeze(-2).to(q.dtype).mean(-1)


def expected_return(
    transition: torch.Tensor,
    reward: torch.Tensor,
    discount: float,
    policy: torch.Tensor,
    start: torch.Tensor,
) -> torch.Tensor:
    """Expected discounted return ``D . V^pi`` of a policy under a (true) reward.

    Args:
        transition: ``(..., A, S, S)``.
        reward: ``(..., A, S)``.
        discount: in (0, 1).
        policy: ``(..., S)`` int64 or ``(..., S, A)`` probabilities.
        start: ``(..., S)`` initial distribution.

    Returns:
        ``(...)`` expected returns.

    Example:
        >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)
        >>> R = torch.tensor([[1.0, 0.0]], dtype=torch.float64)
        >>> expected_return(T, R, 0.5, torch.tensor([0, 0]), torch.tensor([1.0, 0.0]))
        tensor(2., dtype=torch.float64)
    """
    values = policy_evaluation(transition, reward, discount, policy)
    return (values * start.to(values.dtype)).sum(-1)


def normalized_return(
    transition: torch.Tensor,
    reward: torch.Tensor,
    discount: float,
    policy: torch.Tensor,
    start: torch.Tensor,
) -> torch.Tensor:
    """The true value of ``policy`` as a fraction of the optimal one's above a random policy's.

    ``(V(policy) - V(random)) / (V(optimal) - V(random))`` with ``V = start . V^pi`` under the
    true ``reward`` and ``random`` the uniform stochastic policy: 1 for an optimal policy,
    0 for one no better than chance (the score of ``docs/irl.md``).

    Args:
        transition: ``(A, S, S)``.
        reward: ``(A, S)`` the true reward.
        discount: in (0, 1).
        policy: ``(S,)`` int64 or ``(S, A)`` probabilities.
        start: ``(S,)`` initial distribution.

    Returns:
        ``()`` the score (``nan`` when the random policy is optimal).

    Example:
        >>> T = torch.eye(2, dtype=torch.float64).expand(2, 2, 2).clone()
        >>> T[1] = torch.tensor([[0.0, 1.0], [0.0, 1.0]], dtype=torch.float64)  # a1 -> s1
        >>> R = torch.tensor([[0.0, 1.0], [0.0, 1.0]], dtype=torch.float64)
        >>> d0 = torch.tensor([1.0, 0.0], dtype=torch.float64)
        >>> normalized_return(T, R, 0.5, torch.tensor([1, 1]), d0).item()
        1.0
    """
    from torchhrc.solvers.value_iteration import value_iteration

    T = check_tensor("transition", transition)
    A, S = T.shape[-3], T.shape[-1]
    optimal = value_iteration(T, reward, discount).policy
    uniform = T.new_full((S, A), 1.0 / A)
    values = [expected_return(T, reward, discount, p, start) for p in (policy, optimal, uniform)]
    return (values[0] - values[2]) / (values[1] - values[2])
