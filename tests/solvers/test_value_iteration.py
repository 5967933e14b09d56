"""Tests of torchhrc.solvers.value_iteration: hand-worked values, linear-solve and brute-force
references, batching, differentiability and input validation."""

from __future__ import annotations

import itertools

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.solvers.value_iteration import policy_evaluation, value_iteration


def _random_mdp(batch, A, S, seed, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    T = torch.rand(*batch, A, S, S, generator=g, dtype=dtype) ** 3
    T = T / T.sum(-1, keepdim=True)
    R = torch.randn(*batch, A, S, generator=g, dtype=dtype)
    return T, R


def _two_state():
    # action 0 = stay, action 1 = switch; staying in state 1 pays 1, switching costs 0.1.
    T = torch.tensor([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 0.0]]], dtype=torch.float64)
    R = torch.tensor([[0.0, 1.0], [-0.1, -0.1]], dtype=torch.float64)
    return T, R


def test_hand_worked_two_state_mdp():
    T, R = _two_state()
    sol = value_iteration(T, R, 0.9, tol=1e-10)
    # V1 = 1 / (1 - 0.9) = 10; V0 = -0.1 + 0.9 * 10 = 8.9; Q(stay, 0) = 0.9 * 8.9 = 8.01.
    torch.testing.assert_close(sol.values, torch.tensor([8.9, 10.0], dtype=torch.float64))
    torch.testing.assert_close(
        sol.q_values, torch.tensor([[8.01, 10.0], [8.9, 7.91]], dtype=torch.float64)
    )
    assert sol.policy.tolist() == [1, 0]
    assert sol.policy.dtype == torch.int64
    assert sol.error_bound < 1e-9


@pytest.mark.parametrize("discount", [0.5, 0.95])
def test_matches_brute_force_over_deterministic_policies(discount):
    T, R = _random_mdp((), 2, 3, seed=1)
    sol = value_iteration(T, R, discount, tol=1e-10)
    best = torch.full((3,), -float("inf"), dtype=torch.float64)
    for actions in itertools.product(range(2), repeat=3):
        best = torch.maximum(best, policy_evaluation(T, R, discount, torch.tensor(actions)))
    torch.testing.assert_close(sol.values, best, atol=1e-8, rtol=0)
    # the greedy policy's exact value (linear solve) equals the value-iteration values
    torch.testing.assert_close(
        policy_evaluation(T, R, discount, sol.policy), sol.values, atol=1e-8, rtol=0
    )


@pytest.mark.parametrize("batch", [(2,), (2, 3)])
def test_batched_equals_loop(batch):
    T, R = _random_mdp(batch, 3, 4, seed=2)
    sol = value_iteration(T, R, 0.9, tol=1e-10)
    assert sol.values.shape == (*batch, 4)
    assert sol.q_values.shape == (*batch, 3, 4)
    for index in itertools.product(*(range(n) for n in batch)):
        one = value_iteration(T[index], R[index], 0.9, tol=1e-10)
        torch.testing.assert_close(sol.values[index], one.values, atol=1e-9, rtol=0)
        assert torch.equal(sol.policy[index], one.policy)


def test_many_reward_hypotheses_share_one_transition():
    T, _ = _random_mdp((), 2, 4, seed=3)
    R = torch.randn(5, 2, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    sol = value_iteration(T, R, 0.8)
    assert sol.values.shape == (5, 4)
    for k in range(5):
        torch.testing.assert_close(sol.values[k], value_iteration(T, R[k], 0.8).values)


def test_stochastic_policy_evaluation_is_mixture_of_linear_solves():
    T, R = _random_mdp((), 2, 3, seed=5)
    pi = torch.tensor([[0.3, 0.7], [1.0, 0.0], [0.5, 0.5]], dtype=torch.float64)
    V = policy_evaluation(T, R, 0.9, pi)
    # V satisfies its own Bellman equation
    P = torch.einsum("sa,ast->st", pi, T)
    r = (pi * R.T).sum(-1)
    torch.testing.assert_close(V, r + 0.9 * P @ V)


def test_float32_and_dtype_follow_input():
    T, R = _random_mdp((), 2, 3, seed=6, dtype=torch.float32)
    sol = value_iteration(T, R, 0.9, tol=1e-4)
    assert sol.values.dtype == torch.float32
    ref = value_iteration(T.double(), R.double(), 0.9, tol=1e-10)
    torch.testing.assert_close(sol.values.double(), ref.values, atol=1e-3, rtol=0)


def test_error_bound_holds():
    T, R = _random_mdp((), 3, 5, seed=7)
    loose = value_iteration(T, R, 0.95, tol=1.0)
    exact = value_iteration(T, R, 0.95, tol=1e-12)
    assert (loose.values - exact.values).abs().max() <= loose.error_bound + 1e-12
    assert loose.iterations < exact.iterations


def test_gradcheck_in_reward():
    T, R = _random_mdp((), 2, 3, seed=8)
    R.requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda r: value_iteration(T, r, 0.7, tol=1e-6, max_iterations=200).values, (R,)
    )


def test_policy_evaluation_gradcheck():
    T, R = _random_mdp((), 2, 3, seed=9)
    R.requires_grad_(True)
    policy = torch.tensor([0, 1, 1])
    assert torch.autograd.gradcheck(lambda r: policy_evaluation(T, r, 0.9, policy), (R,))


def test_bad_input_messages():
    T, R = _two_state()
    with pytest.raises(ModelError, match=r"R to have shape"):
        value_iteration(T, R[:, :1], 0.9)
    with pytest.raises(ModelError, match=r"T\[0, 0\] row sums"):
        value_iteration(T * 0.5, R, 0.9)
    with pytest.raises(ModelError, match="discount"):
        value_iteration(T, R, 1.5)
    with pytest.raises(TypeError, match=r"T to be a torch\.Tensor"):
        value_iteration([[1.0]], R, 0.9)
    with pytest.raises(ModelError, match=r"actions in \[0, 2\)"):
        policy_evaluation(T, R, 0.9, torch.tensor([0, 2]))
    with pytest.raises(ModelError, match="discount < 1"):
        policy_evaluation(T, R, 1.0, torch.tensor([0, 1]))
