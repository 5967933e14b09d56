"""Tests of torchhrc.irl.maxent: soft value iteration, implicit gradients, MaxEnt IRL."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.irl.features import feature_expectations
from torchhrc.irl.maxent import maxent_irl, maxent_objective, soft_value_iteration
from torchhrc.irl.metrics import policy_agreement
from torchhrc.irl.trajectories import Trajectories
from torchhrc.tasks.gridworld import Gridworld


def _random_mdp(A=3, S=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(A, S, S, generator=g, dtype=torch.float64).softmax(-1)


def _soft_vi_reference(T, R, discount, sweeps=400):
    V = torch.zeros(T.shape[-1], dtype=torch.float64)
    for _ in range(sweeps):
        V = torch.logsumexp(R + discount * torch.einsum("ast,t->as", T, V), dim=0)
    return V


def test_soft_value_iteration_matches_plain_sweeps():
    T = _random_mdp()
    R = torch.randn(3, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    solution = soft_value_iteration(T, R, 0.9)
    torch.testing.assert_close(solution.values, _soft_vi_reference(T, R, 0.9), atol=1e-9, rtol=0)
    torch.testing.assert_close(solution.policy.sum(-1), torch.ones(5, dtype=torch.float64))
    torch.testing.assert_close(
        solution.policy, torch.softmax(solution.q_values, dim=0).transpose(0, 1)
    )


def test_soft_value_iteration_stops_at_the_values_rounding_on_a_large_reward_scale():
    """Rewards of order 1e4 give values of order 1e5, whose rounding (a few ulps, ~1e-11) is
    far above ``tol=1e-12``: Newton reaches the fixed point in a handful of steps and then
    only adds rounding; it stops there (it ran to ``max_iterations`` before, minutes per call
    inside MaxEnt IRL). The values still satisfy the soft Bellman equation to rounding."""
    g = torch.Generator().manual_seed(0)
    T = torch.rand(2, 4, 4, generator=g, dtype=torch.float64).softmax(-1)
    R = 1e4 * torch.randn(2, 4, dtype=torch.float64, generator=g)
    solution = soft_value_iteration(T, R, 0.95, tol=1e-12, max_iterations=2_000)
    assert solution.iterations < 50
    backup = torch.logsumexp(R + 0.95 * torch.einsum("ast,t->as", T, solution.values), dim=0)
    torch.testing.assert_close(solution.values, backup, rtol=1e-12, atol=0)


@pytest.mark.parametrize("batch", [(), (2,), (2, 3)])
def test_soft_value_iteration_batched_equals_loop(batch):
    T = _random_mdp()
    R = torch.randn(*batch, 3, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    values = soft_value_iteration(T, R, 0.8).values
    flat = R.reshape(-1, 3, 5)
    loop = torch.stack([soft_value_iteration(T, r, 0.8).values for r in flat])
    torch.testing.assert_close(values.reshape(-1, 5), loop)


def test_soft_value_iteration_gradcheck_reward_and_transition():
    logits = torch.randn(2, 4, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    logits.requires_grad_(True)
    R = torch.randn(2, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    R.requires_grad_(True)

    def values(logits, R):
        return soft_value_iteration(logits.softmax(-1), R, 0.85, tol=1e-13).values

    assert torch.autograd.gradcheck(values, (logits, R), atol=1e-6)
    # broadcast batch: many rewards, one transition tensor
    Rb = torch.randn(3, 2, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(values, (logits, Rb), atol=1e-6)


def test_objective_gradient_is_feature_matching_gap_and_passes_gradcheck():
    T = _random_mdp(S=6, seed=5)
    phi = torch.rand(6, 3, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    mu_hat = torch.rand(4, dtype=torch.float64) * 3
    d0 = torch.full((6,), 1 / 6, dtype=torch.float64)
    theta = torch.randn(3, 4, dtype=torch.float64, requires_grad=True)  # 3 hypotheses
    g = maxent_objective(theta, T, phi, mu_hat, d0, 0.9, l2=0.1, tol=1e-13)
    (grad,) = torch.autograd.grad(g.sum(), theta)
    with torch.no_grad():
        R = torch.einsum("saf,hf->has", phi, theta)
        policy = soft_value_iteration(T, R, 0.9, tol=1e-13).policy
        mu = feature_expectations(T, policy, phi, 0.9, d0)
    torch.testing.assert_close(grad, mu_hat - mu - 0.1 * theta.detach(), atol=1e-8, rtol=1e-7)
    assert torch.autograd.gradcheck(
        lambda th: maxent_objective(th, T, phi, mu_hat, d0, 0.9, l2=0.1, tol=1e-13), (theta,)
    )


def test_maxent_recovers_gridworld_expert():
    for seed in (0, 1):
        world = Gridworld.random(8, 6, seed=seed, slip=0.1)
        phi = world.features("semantic")
        demos = world.demonstrations(500, 80, seed=seed)
        result = maxent_irl(world.transition, phi, demos, discount=0.9, l2=1e-3, tol=1e-6)
        assert result.converged and result.gradient_norm <= 1e-6
        learned = world.solve(result.reward(phi, world.num_actions)).policy
        assert policy_agreement(world.solve().q_values, learned, tol=1e-2) >= 0.95


def test_batched_hypotheses_equal_separate_runs():
    world = Gridworld.random(5, 3, seed=2, slip=0.1)
    phi = world.features("semantic")
    demos = world.demonstrations(200, 60, seed=2)
    starts = torch.tensor(
        [[0.0, 0.0, 0.0], [1.0, -1.0, 0.5], [-2.0, 0.0, 1.0]], dtype=torch.float64
    )
    batched = maxent_irl(
        world.transition, phi, demos, discount=0.9, initial_weights=starts, tol=1e-8
    )
    assert batched.weights.shape == (3, 3) and batched.policy.shape == (3, 25, 5)
    for h in range(3):
        single = maxent_irl(
            world.transition, phi, demos, discount=0.9, initial_weights=starts[h : h + 1], tol=1e-8
        )
        # a strictly concave objective (l2 > 0): every start reaches the same optimum
        torch.testing.assert_close(batched.weights[h], single.weights[0], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(batched.weights[0], batched.weights[2], atol=1e-5, rtol=1e-5)


def test_maxent_deterministic_and_errors():
    world = Gridworld.random(4, 2, seed=0, slip=0.1)
    phi = world.features("semantic")
    demos = world.demonstrations(50, 60, seed=0)
    a = maxent_irl(world.transition, phi, demos, discount=0.9, num_hypotheses=2, seed=5)
    b = maxent_irl(world.transition, phi, demos, discount=0.9, num_hypotheses=2, seed=5)
    assert torch.equal(a.weights, b.weights)
    with pytest.raises(ModelError, match="features of shape"):
        maxent_irl(world.transition, torch.eye(3), demos, discount=0.9)
    with pytest.raises(ModelError, match="impossible transition"):
        far = Trajectories.from_pairs([[(0, 0), (15, 0)]])
        maxent_irl(world.transition, phi, far, discount=0.9)
    with pytest.raises(ModelError, match=r"discount in \(0, 1\)"):
        maxent_irl(world.transition, phi, demos, discount=1.0)
    with pytest.raises(ModelError, match=r"discount in \(0, 1\)"):
        soft_value_iteration(world.transition, world.reward, 1.0)
