"""Tests of AlphaVectorPolicy, Solution and the pruning functions."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.pruning import prune_by_beliefs, prune_dominated
from torchhrc.solvers.solution import Solution
from torchhrc.testing import random_belief


def _flat():
    alphas = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.6, 0.6], [0.5, 0.5]], dtype=torch.float64)
    return AlphaVectorPolicy(alphas, torch.tensor([0, 1, 2, 3]))


def test_value_and_action_worked_by_hand():
    policy = _flat()
    beliefs = torch.tensor([[0.9, 0.1], [0.5, 0.5], [0.2, 0.8]], dtype=torch.float64)
    torch.testing.assert_close(
        policy.value(beliefs), torch.tensor([0.9, 0.6, 0.8], dtype=torch.float64)
    )
    assert policy.action(beliefs).tolist() == [0, 2, 1]


@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
def test_batched_equals_loop(batch):
    policy = _flat()
    beliefs = random_belief((*batch, 2), seed=0)
    values, actions = policy.value(beliefs), policy.action(beliefs)
    assert values.shape == batch and actions.shape == batch
    for b, v, a in zip(beliefs.reshape(-1, 2), values.reshape(-1), actions.reshape(-1)):
        scores = [float(alpha @ b) for alpha in policy.alphas]
        assert v.item() == pytest.approx(max(scores))
        assert a.item() == policy.actions[scores.index(max(scores))].item()


def test_momdp_policy_only_uses_the_vectors_of_x():
    alphas = torch.tensor([[5.0, 5.0], [1.0, 0.0], [0.0, 1.0]], dtype=torch.float64)
    policy = AlphaVectorPolicy(alphas, torch.tensor([7, 8, 9]), observed=torch.tensor([0, 1, 1]))
    b = torch.tensor([[0.3, 0.7], [0.3, 0.7], [0.8, 0.2]], dtype=torch.float64)
    x = torch.tensor([0, 1, 1])
    torch.testing.assert_close(
        policy.value(x, b), torch.tensor([5.0, 0.7, 0.8], dtype=torch.float64)
    )
    assert policy.action(x, b).tolist() == [7, 9, 8]
    # x broadcasts against the belief batch
    assert policy.action(1, b).tolist() == [9, 9, 8]
    with pytest.raises(ModelError, match=r"no alpha vector for observed value\(s\) x = \[2\]"):
        policy.value(torch.tensor([2]), b[:1])
    with pytest.raises(ModelError, match="needs the observed value x"):
        policy.value(b)


def test_from_action_vectors_layout():
    vectors = torch.arange(12, dtype=torch.float64).reshape(2, 3, 2)  # (A, X, Y)
    policy = AlphaVectorPolicy.from_action_vectors(vectors, momdp=True)
    for n in range(6):
        a, x = policy.actions[n].item(), policy.observed[n].item()
        torch.testing.assert_close(policy.alphas[n], vectors[a, x])


def test_prune_keeps_the_value_function():
    generator = torch.Generator().manual_seed(1)
    alphas = torch.randn(40, 3, dtype=torch.float64, generator=generator)
    alphas = torch.cat([alphas, alphas[:5] - 0.1, alphas[:3]])  # dominated and duplicates
    policy = AlphaVectorPolicy(alphas, torch.arange(48))
    pruned = policy.prune()
    assert pruned.num_vectors < 40
    beliefs = random_belief((500, 3), seed=2)
    torch.testing.assert_close(pruned.value(beliefs), policy.value(beliefs))


def test_prune_dominated_matches_brute_force():
    generator = torch.Generator().manual_seed(3)
    alphas = torch.randint(0, 3, (30, 2), generator=generator).double()
    groups = torch.randint(0, 2, (30,), generator=generator)
    keep = prune_dominated(alphas, groups)
    for i in range(30):
        dominated = any(
            j != i
            and groups[j] == groups[i]
            and bool((alphas[j] >= alphas[i]).all())
            and (bool((alphas[j] > alphas[i]).any()) or j < i)
            for j in range(30)
        )
        assert keep[i].item() == (not dominated)
    # every group keeps at least one vector
    assert set(groups[keep].tolist()) == set(groups.tolist())


def test_prune_by_beliefs_keeps_values_at_the_beliefs():
    generator = torch.Generator().manual_seed(4)
    alphas = torch.randn(50, 4, dtype=torch.float64, generator=generator)
    beliefs = random_belief((10, 4), seed=5)
    keep = prune_by_beliefs(alphas, beliefs)
    assert keep.sum() <= 10
    torch.testing.assert_close((beliefs @ alphas[keep].T).amax(-1), (beliefs @ alphas.T).amax(-1))
    # MOMDP form: groups without beliefs keep everything
    policy = AlphaVectorPolicy(
        alphas[:, :2], torch.zeros(50, dtype=torch.long), observed=torch.arange(50) % 3
    )
    pruned = policy.prune(random_belief((4, 2), seed=6), x=torch.tensor([0, 0, 1, 1]))
    assert (pruned.observed == 2).sum() == (policy.observed == 2).sum()
    assert (pruned.observed == 0).sum() <= 4


def test_validation_and_to():
    with pytest.raises(ModelError, match=r"alphas to have shape \(N, S\)"):
        AlphaVectorPolicy(torch.zeros(3), torch.zeros(3, dtype=torch.long))
    with pytest.raises(ModelError, match=r"actions to have shape \(N=2,\)"):
        AlphaVectorPolicy(torch.zeros(2, 2), torch.zeros(3, dtype=torch.long))
    with pytest.raises(TypeError, match="integer dtype"):
        AlphaVectorPolicy(torch.zeros(2, 2), torch.zeros(2))
    with pytest.raises(ModelError, match="not finite"):
        AlphaVectorPolicy(torch.tensor([[0.0, float("nan")]]), torch.zeros(1, dtype=torch.long))
    for bad in (float("nan"), float("inf"), -float("inf")):  # one entry deep in the vectors
        for dtype in (torch.float32, torch.float64):
            alphas = torch.randn(300, 70, dtype=dtype)
            alphas[211, 43] = bad
            with pytest.raises(ModelError, match=r"alphas\[211, 43\] = (nan|-?inf) is not"):
                AlphaVectorPolicy(alphas, torch.zeros(300, dtype=torch.long))
    AlphaVectorPolicy(torch.zeros(0, 3), torch.zeros(0, dtype=torch.long))  # no vector: fine
    with pytest.raises(ModelError, match=r"belief to have shape \(\.\.\., S=2\)"):
        _flat().value(torch.ones(3))
    p32 = _flat().to(dtype=torch.float32)
    assert p32.alphas.dtype == torch.float32 and p32.actions.dtype == torch.int64


def test_solution_bounds_and_summary():
    policy = _flat()
    sol = Solution(policy, lower=1.0, upper=2.5, history=[{"time_s": 0.3, "lower": 1.0}])
    assert sol.gap == 1.5
    assert sol.summary() == {"lower": 1.0, "upper": 2.5, "gap": 1.5, "time_s": 0.3, "n_alphas": 4}
    with pytest.raises(ModelError, match="exceeds upper"):
        Solution(policy, lower=3.0, upper=2.0)
    with pytest.raises(ModelError, match="NaN"):
        Solution(policy, lower=float("nan"), upper=2.0)
