"""Tests of torchhrc.irl.features: exact, finite-horizon, Monte Carlo and empirical mu."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.irl.features import (
    check_features,
    discounted_occupancy,
    empirical_feature_expectations,
    feature_expectations,
    indicator_features,
    monte_carlo_feature_expectations,
    reward_from_weights,
    start_distribution,
)
from torchhrc.irl.trajectories import Trajectories, sample_trajectories


def _random_mdp(A: int = 3, S: int = 5, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(A, S, S, generator=g, dtype=torch.float64).softmax(-1)


def _brute_force_mu(T, pi, phi, discount, d0, steps):
    """sum_{t < steps} discount^t d_t phi, propagating d_t step by step."""
    P = torch.einsum("sa,ast->st", pi, T)
    d, total = d0.clone(), torch.zeros(phi.shape[-1], dtype=torch.float64)
    for t in range(steps):
        if phi.dim() == 2:
            total += discount**t * d @ phi
        else:
            total += discount**t * torch.einsum("s,sa,saf->f", d, pi, phi)
        d = d @ P
    return total


def test_hand_worked_two_state_chain():
    # state 0 -> state 1 -> state 1 ...; mu = (1, g + g^2 + ...) = (1, g / (1 - g))
    T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]], dtype=torch.float64)
    phi = torch.eye(2, dtype=torch.float64)
    d0 = torch.tensor([1.0, 0.0], dtype=torch.float64)
    mu = feature_expectations(T, torch.tensor([0, 0]), phi, 0.75, d0)
    torch.testing.assert_close(mu, torch.tensor([1.0, 3.0], dtype=torch.float64))
    mu3 = feature_expectations(T, torch.tensor([0, 0]), phi, 0.75, d0, horizon=3)
    torch.testing.assert_close(mu3, torch.tensor([1.0, 0.75 + 0.5625], dtype=torch.float64))


@pytest.mark.parametrize("horizon", [None, 1, 2, 7, 16, 33])
def test_exact_matches_step_by_step_reference(horizon):
    T = _random_mdp()
    g = torch.Generator().manual_seed(1)
    pi = torch.rand(5, 3, generator=g, dtype=torch.float64).softmax(-1)
    phi = torch.rand(5, 4, generator=g, dtype=torch.float64)
    d0 = torch.rand(5, generator=g, dtype=torch.float64).softmax(-1)
    mu = feature_expectations(T, pi, phi, 0.9, d0, horizon=horizon)
    reference = _brute_force_mu(T, pi, phi, 0.9, d0, 400 if horizon is None else horizon)
    torch.testing.assert_close(mu, reference, atol=1e-12, rtol=1e-10)


def test_state_action_features_and_occupancy():
    T = _random_mdp()
    g = torch.Generator().manual_seed(2)
    pi = torch.rand(5, 3, generator=g, dtype=torch.float64).softmax(-1)
    d0 = torch.full((5,), 0.2, dtype=torch.float64)
    phi_sa = torch.rand(5, 3, 2, generator=g, dtype=torch.float64)
    mu = feature_expectations(T, pi, phi_sa, 0.8, d0)
    torch.testing.assert_close(mu, _brute_force_mu(T, pi, phi_sa, 0.8, d0, 300))
    # state features broadcast over actions give the same expectations
    phi_s = torch.rand(5, 2, generator=g, dtype=torch.float64)
    mu_s = feature_expectations(T, pi, phi_s, 0.8, d0)
    mu_sa = feature_expectations(T, pi, phi_s.unsqueeze(1).expand(5, 3, 2), 0.8, d0)
    torch.testing.assert_close(mu_s, mu_sa)
    # state-action indicators: mu sums to 1 / (1 - discount), marginal = occupancy
    mu_ind = feature_expectations(T, pi, indicator_features(5, 3), 0.8, d0).reshape(5, 3)
    rho = discounted_occupancy(T, pi, 0.8, d0)
    torch.testing.assert_close(mu_ind.sum(-1), rho)
    torch.testing.assert_close(rho.sum(), torch.tensor(5.0, dtype=torch.float64))


def test_batched_policies_equal_per_policy_loop():
    T = _random_mdp()
    policies = torch.randint(3, (7, 5), generator=torch.Generator().manual_seed(3))
    phi = torch.rand(5, 3, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    d0 = torch.full((5,), 0.2, dtype=torch.float64)
    for horizon in (None, 9):
        batched = feature_expectations(T, policies, phi, 0.9, d0, horizon=horizon)
        loop = torch.stack(
            [feature_expectations(T, p, phi, 0.9, d0, horizon=horizon) for p in policies]
        )
        torch.testing.assert_close(batched, loop)
    # a batch of MDPs, one per policy
    Ts = torch.stack([_random_mdp(seed=s) for s in range(7)])
    batched = feature_expectations(Ts, policies, phi, 0.9, d0)
    loop = torch.stack([feature_expectations(t, p, phi, 0.9, d0) for t, p in zip(Ts, policies)])
    torch.testing.assert_close(batched, loop)


def test_exact_and_monte_carlo_agree_within_sampling_error():
    T = _random_mdp(S=6, seed=5)
    policy = torch.tensor([0, 1, 2, 0, 1, 2])
    phi = torch.rand(6, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    d0 = torch.full((6,), 1 / 6, dtype=torch.float64)
    H, N = 120, 4000  # truncation bias 0.9^120 * max|phi| / 0.1 < 1e-4
    exact = feature_expectations(T, policy, phi, 0.9, d0)
    samples = sample_trajectories(T, policy, d0, N, H, seed=0)
    per_trajectory = empirical_feature_expectations(phi, samples, 0.9, reduction="none")
    standard_error = per_trajectory.std(0) / N**0.5
    estimate = per_trajectory.mean(0)
    assert ((estimate - exact).abs() <= 4 * standard_error + 1e-4).all()
    mc = monte_carlo_feature_expectations(
        T, policy, phi, 0.9, d0, num_trajectories=N, horizon=H, seed=0
    )
    torch.testing.assert_close(mc, estimate)
    # batched over policies: each row within its sampling error of the exact value
    policies = torch.stack([policy, torch.zeros(6, dtype=torch.long)])
    mc2 = monte_carlo_feature_expectations(
        T, policies, phi, 0.9, d0, num_trajectories=N, horizon=H, seed=1
    )
    exact2 = feature_expectations(T, policies, phi, 0.9, d0)
    assert ((mc2 - exact2).abs() <= 4 * standard_error.max() * 2 + 1e-4).all()


def test_empirical_unequal_lengths_by_hand():
    phi = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], dtype=torch.float64)
    demos = Trajectories.from_pairs([[(0, 0), (1, 0), (2, 0)], [(2, 0)]])
    # traj 0: phi0 + .5 phi1 + .25 phi2 = (1.25, .75); traj 1: phi2 = (1, 1)
    mu_hat = empirical_feature_expectations(phi, demos, 0.5)
    torch.testing.assert_close(mu_hat, torch.tensor([1.125, 0.875], dtype=torch.float64))
    assert start_distribution(demos, 3).tolist() == [0.5, 0.0, 0.5]


def test_occupancy_is_differentiable():
    T = _random_mdp(S=4, seed=7)
    phi = torch.rand(4, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(8))
    logits = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    d0 = torch.full((4,), 0.25, dtype=torch.float64, requires_grad=True)

    def f(logits, d0):
        return feature_expectations(T, logits.softmax(-1), phi, 0.9, d0, horizon=6)

    assert torch.autograd.gradcheck(f, (logits, d0))
    assert torch.autograd.gradcheck(
        lambda x: feature_expectations(T, x.softmax(-1), phi, 0.9, d0.detach()), (logits,)
    )


def test_reward_from_weights_layout():
    phi = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], dtype=torch.float64)
    R = reward_from_weights(phi, torch.tensor([2.0, -1.0], dtype=torch.float64), 4)
    assert R.shape == (4, 3) and R[3].tolist() == [2.0, -1.0, 1.0]
    phi_sa = torch.arange(12, dtype=torch.float64).reshape(3, 2, 2)
    R = reward_from_weights(phi_sa, torch.tensor([[1.0, 0.0], [0.0, 1.0]], dtype=torch.float64), 2)
    assert R.shape == (2, 2, 3)
    assert R[1, 0, 2].item() == phi_sa[2, 0, 1].item()


def test_errors_name_the_argument():
    with pytest.raises(
        ModelError, match=r"features of shape \(S=5, F\) to match the MDP's 5 states"
    ):
        check_features(torch.zeros(4, 2), 5, 3)
    with pytest.raises(ModelError, match=r"\(S=5, A=3, F\)"):
        check_features(torch.zeros(5, 2, 2), 5, 3)
    with pytest.raises(ModelError, match=r"\(S, F\) or \(S, A, F\)"):
        check_features(torch.zeros(5), 5, 3)
    with pytest.raises(ModelError, match="non-finite"):
        check_features(torch.full((5, 1), float("nan")), 5, 3)
    demos = Trajectories(
        torch.zeros(0, 2, dtype=torch.long),
        torch.zeros(0, 2, dtype=torch.long),
        torch.zeros(0, dtype=torch.long),
    )
    with pytest.raises(ModelError, match="empty set of demonstrations"):
        empirical_feature_expectations(torch.eye(2), demos, 0.9)
    with pytest.raises(ModelError, match="features cover only S = 2"):
        empirical_feature_expectations(torch.eye(2), Trajectories.from_pairs([[(3, 0)]]), 0.9)
    with pytest.raises(ModelError, match="infinite horizon needs discount < 1"):
        feature_expectations(
            _random_mdp(),
            torch.zeros(5, dtype=torch.long),
            torch.eye(5),
            1.0,
            torch.full((5,), 0.2, dtype=torch.float64),
        )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_outputs_follow_the_input_dtype(dtype):
    T = _random_mdp().to(dtype)
    phi = torch.rand(5, 2, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
    d0 = torch.full((5,), 0.2, dtype=dtype)
    policy = torch.tensor([0, 1, 2, 0, 1])
    mu = feature_expectations(T, policy, phi, 0.9, d0)
    assert mu.dtype == dtype
    reference = feature_expectations(T.double(), policy, phi, 0.9, d0.double())
    torch.testing.assert_close(mu.double(), reference, atol=1e-4, rtol=1e-4)
    assert discounted_occupancy(T, policy, 0.9, d0, horizon=5).dtype == dtype
