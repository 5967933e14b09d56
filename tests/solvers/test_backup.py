"""Tests of the point-based backup kernel: brute-force reference, both flat kernels, lower-
bound preservation, and factored (MOMDP) == flat through to_pomdp."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.solvers.backup import momdp_point_backup, point_backup
from torchhrc.solvers.blind import blind_policy
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.testing import random_belief, random_momdp, random_pomdp


def _reference_backup(model, alphas, belief):
    """One belief, Python loops over a, o and vectors (Pineau et al. 2003, Eq. 8-10)."""
    T, Z, R, g = model.T, model.Z, model.R, model.discount
    A, O = T.shape[0], Z.shape[-1]
    best_value, best_vector, best_action = -float("inf"), None, None
    for a in range(A):
        vector = R[a].clone()
        for o in range(O):
            projections = [g * T[a] @ (Z[a, :, o] * alpha) for alpha in alphas]
            scores = [float(belief @ p) for p in projections]
            vector = vector + projections[max(range(len(scores)), key=scores.__getitem__)]
        value = float(belief @ vector)
        if value > best_value:
            best_value, best_vector, best_action = value, vector, a
    return best_vector, best_action, best_value


@pytest.mark.parametrize("method", ["gamma", "belief", "auto"])
def test_flat_backup_matches_loop_reference(method):
    model = random_pomdp(4, 3, 3, seed=0)
    alphas = torch.randn(5, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    policy = AlphaVectorPolicy(alphas, torch.zeros(5, dtype=torch.long))
    beliefs = random_belief((7, 4), seed=2)
    result = point_backup(model, policy, beliefs, method=method)
    for m in range(7):
        vector, action, value = _reference_backup(model, alphas, beliefs[m])
        torch.testing.assert_close(result.alphas[m], vector)
        assert result.actions[m].item() == action
        assert result.values[m].item() == pytest.approx(value)
    torch.testing.assert_close(result.values, result.q_values.amax(-1))


def test_backup_of_blind_vectors_improves_and_stays_a_lower_bound():
    model = random_pomdp(5, 3, 2, discount=0.9, seed=3)
    lower = blind_policy(model)
    beliefs = random_belief((20, 5), seed=4)
    result = point_backup(model, lower, beliefs)
    # a blind vector alpha_a satisfies alpha_a = R_a + g T_a alpha_a, one candidate of the backup
    assert (result.values >= lower.value(beliefs) - 1e-9).all()
    # repeated backups converge monotonically toward (and never above) V*; QMDP bounds V*
    from torchhrc.solvers.qmdp import qmdp_policy

    upper = qmdp_policy(model)
    policy = lower
    for _ in range(30):
        policy = point_backup(model, policy, beliefs).as_policy()
    assert (policy.value(beliefs) <= upper.value(beliefs) + 1e-9).all()


def test_dtype_follows_the_model():
    model = random_pomdp(3, 2, 2, dtype=torch.float32, seed=5)
    result = point_backup(model, blind_policy(model), random_belief((4, 3), seed=6))
    assert result.alphas.dtype == torch.float32


def _embed(momdp, policy):
    """MOMDP vectors (N, Y) of x -> flat vectors (N, X*Y), very low outside x's block."""
    X, Y = momdp.num_observed, momdp.num_hidden
    flat = torch.full((policy.num_vectors, X, Y), -1e4, dtype=policy.alphas.dtype)
    flat[torch.arange(policy.num_vectors), policy.observed] = policy.alphas
    return AlphaVectorPolicy(flat.reshape(-1, X * Y), policy.actions)


@pytest.mark.parametrize("static", [True, False])
def test_factored_backup_equals_flat_backup(static):
    model = random_momdp(4, 3, 3, 2, static=static, discount=0.9, seed=7)
    X, Y = 4, 3
    generator = torch.Generator().manual_seed(8)
    alphas = torch.randn(9, Y, dtype=torch.float64, generator=generator)
    observed = torch.tensor([0, 1, 2, 3, 0, 1, 2, 3, 0])
    policy = AlphaVectorPolicy(alphas, torch.randint(0, 3, (9,), generator=generator), observed)
    x = torch.tensor([0, 1, 2, 3, 2, 0])
    beliefs = random_belief((6, Y), seed=9)
    factored = momdp_point_backup(model, policy, x, beliefs)
    flat_beliefs = torch.zeros(6, X, Y, dtype=torch.float64)
    flat_beliefs[torch.arange(6), x] = beliefs
    flat = point_backup(model.to_pomdp(), _embed(model, policy), flat_beliefs.reshape(6, X * Y))
    torch.testing.assert_close(factored.values, flat.values)
    torch.testing.assert_close(factored.q_values, flat.q_values)
    assert torch.equal(factored.actions, flat.actions)
    block = flat.alphas.reshape(6, X, Y)[torch.arange(6), x]
    torch.testing.assert_close(factored.alphas, block)
    assert torch.equal(factored.observed, x)


def test_factored_backup_with_sparse_transitions():
    # deterministic moves: only one x2 per (a, x) is reachable
    model = random_momdp(5, 2, 3, 2, static=True, sparsity=0.0, seed=10)
    Tx = torch.zeros_like(model.Tx)
    target = torch.tensor([[1, 2, 3, 4, 0], [0, 0, 1, 2, 3], [4, 4, 4, 4, 4]])
    Tx[torch.arange(3)[:, None], torch.arange(5)[None, :], :, target] = 1.0
    model = type(model)(Tx=Tx, Ty=None, Z=model.Z, R=model.R, x0=0, b0=model.b0, discount=0.9)
    policy = blind_policy(model)
    x = torch.arange(5)
    beliefs = random_belief((5, 2), seed=11)
    factored = momdp_point_backup(model, policy, x, beliefs)
    flat_beliefs = torch.zeros(5, 5, 2, dtype=torch.float64)
    flat_beliefs[x, x] = beliefs
    flat = point_backup(model.to_pomdp(), _embed(model, policy), flat_beliefs.reshape(5, 10))
    torch.testing.assert_close(factored.values, flat.values)


def test_bad_input():
    model = random_pomdp(3, 2, 2, seed=12)
    policy = blind_policy(model)
    with pytest.raises(ModelError, match=r"beliefs to have shape \(M, S=3\)"):
        point_backup(model, policy, torch.ones(2, 4, dtype=torch.float64))
    with pytest.raises(ValueError, match="method"):
        point_backup(model, policy, model.b0[None], method="fast")
    batched = random_pomdp(3, 2, 2, batch_shape=(2,), seed=12)
    with pytest.raises(ModelError, match="batch_shape"):
        point_backup(batched, policy, model.b0[None])
    momdp = random_momdp(3, 2, 2, 2, seed=13)
    partial = blind_policy(momdp).select(torch.tensor([0, 1, 2, 3]))  # no vector for x = 2
    with pytest.raises(ModelError, match=r"no alpha vector for observed value\(s\) x = \[2\]"):
        momdp_point_backup(momdp, partial, torch.tensor([0]), momdp.b0[None])
    with pytest.raises(ModelError, match=r"x in \[0, 3\)"):
        momdp_point_backup(momdp, blind_policy(momdp), torch.tensor([3]), momdp.b0[None])
