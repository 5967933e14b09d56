"""Tests of torchhrc.irl.maxent.maxent_irl_types: several experts' rewards, partly pooled."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.irl.features import empirical_feature_expectations, feature_expectations
from torchhrc.irl.maxent import maxent_irl, maxent_irl_types
from torchhrc.irl.trajectories import Trajectories

# A three-state chain, two actions: "go" (state s -> s + 1, the last state stays) and "stay".
# Tabular features, one per (state, action).
S, A = 3, 2


def _chain() -> torch.Tensor:
    T = torch.zeros(A, S, S, dtype=torch.float64)
    for s in range(S):
        T[0, s, min(s + 1, S - 1)] = 1.0  # go
        T[1, s, s] = 1.0  # stay
    return T


def _features() -> torch.Tensor:
    return torch.eye(S * A, dtype=torch.float64).reshape(S, A, S * A)  # (S, A, F)


def _demos(actions: list[list[int]]) -> Trajectories:
    """Trajectories from the start state 0 with the given action sequences."""
    T = _chain()
    states, acts = [], []
    for seq in actions:
        s, row = 0, []
        for a in seq:
            row.append(s)
            s = int(T[a, s].argmax())
        states.append(row)
        acts.append(seq)
    lengths = torch.tensor([len(a) for a in acts])
    return Trajectories(torch.tensor(states), torch.tensor(acts), lengths)


def _experts() -> list[Trajectories]:
    # expert 0 walks to the end and stays there; expert 1 stays at the start mostly: it never
    # reaches state 2, where expert 0 shows "stay"
    e0 = _demos([[0, 0, 1, 1, 1, 1, 1, 1]] * 6 + [[0, 1, 0, 1, 1, 1, 1, 1]])
    e1 = _demos([[1, 1, 1, 1, 1, 1, 1, 1]] * 6 + [[0, 1, 1, 1, 1, 1, 1, 1]])
    return [e0, e1]


def test_no_pooling_is_each_expert_fitted_alone():
    T = _chain().expand(2, A, S, S)
    demos = _experts()
    fit = maxent_irl_types(T, _features(), demos, discount=0.8, l2=0.1, pooling=0.0)
    for k in range(2):
        alone = maxent_irl(T[k], _features(), demos[k], discount=0.8, l2=0.1)
        torch.testing.assert_close(fit.weights[k], alone.weights, atol=1e-6, rtol=0)


@pytest.mark.parametrize("pooling", [0.3, 0.8])
def test_the_fit_is_the_stationary_point_of_the_pooled_objective(pooling):
    """At the optimum ``theta_k = theta_0 + delta_k``: each expert's gradient
    ``mu_hat_k - mu_k`` equals ``l2 / (1 - p) delta_k`` and their sum ``K l2 / p theta_0``,
    with ``mu_k`` computed here from the soft-optimal policy of the learned reward (an
    independent forward pass, not the fit's autograd)."""
    T, phi, l2, discount = _chain().expand(2, A, S, S), _features(), 0.1, 0.8
    demos = _experts()
    fit = maxent_irl_types(T, phi, demos, discount=discount, l2=l2, pooling=pooling, tol=1e-9)
    gaps = []
    for k in range(2):
        mu_hat = empirical_feature_expectations(phi, demos[k], discount)
        start = torch.zeros(S, dtype=torch.float64)
        start[0] = 1.0
        mu = feature_expectations(T[k], fit.policy[k], phi, discount, start)
        gaps.append(mu_hat - mu)
    gaps = torch.stack(gaps)
    # theta_0 from the experts' sum, delta_k = theta_k - theta_0
    shared = gaps.sum(0) * pooling / (2 * l2)
    delta = fit.weights - shared
    torch.testing.assert_close(gaps, l2 / (1 - pooling) * delta, atol=1e-6, rtol=0)


def test_a_state_one_expert_never_reaches_takes_the_others_preference():
    """Expert 1 never reaches state 2; expert 0 stays there (its "go" stays too, and it
    never takes it). Alone, expert 1 has no preference there (the rewards of the two
    actions are equal); pooled, its preference for "stay" rises with the pooling towards
    expert 0's. (The rewards' level in a state is free; the preference is the difference.)"""
    T, phi = _chain().expand(2, A, S, S), _features()

    def preference(pooling: float) -> torch.Tensor:
        w = maxent_irl_types(T, phi, _experts(), discount=0.8, l2=0.1, pooling=pooling).weights
        return w[:, 2 * A + 1] - w[:, 2 * A]  # (state 2, stay) - (state 2, go), per expert

    alone, half, most = preference(0.0), preference(0.5), preference(0.9)
    assert abs(float(alone[1])) < 1e-6 < float(alone[0])
    assert 0.1 < float(half[1]) < float(most[1]) < float(alone[0])


def test_bad_arguments_are_named():
    T, phi = _chain().expand(2, A, S, S), _features()
    with pytest.raises(ValueError, match="pooling in \\[0, 1\\)"):
        maxent_irl_types(T, phi, _experts(), discount=0.8, pooling=1.0)
    with pytest.raises(ValueError, match="2 trajectory sets"):
        maxent_irl_types(T, phi, _experts()[:1], discount=0.8)
    with pytest.raises(ModelError, match="demonstrations\\[1\\] is empty"):
        none = torch.zeros(0, 1, dtype=torch.long)
        empty = Trajectories(none, none, torch.zeros(0, dtype=torch.long))
        maxent_irl_types(T, phi, [_experts()[0], empty], discount=0.8)
