"""Tests of torchhrc.irl.type_rewards: one reward per human type for the MOMDP."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.irl.maxent import maxent_irl
from torchhrc.irl.metrics import policy_agreement
from torchhrc.irl.projection import apprenticeship_learning
from torchhrc.irl.trajectories import Trajectories
from torchhrc.irl.type_rewards import learn_type_rewards, type_transitions
from torchhrc.pomdp import MOMDP
from torchhrc.solvers.value_iteration import value_iteration
from torchhrc.tasks.gridworld import Gridworld

# Two human types share a 5x5 workspace but prefer opposite corners (types of the paper:
# same task states, different preferences). Features: at corner A, at corner B, hazard.
CORNERS = ((0, 4), (4, 0))
HAZARDS = ((2, 2), (2, 1))


def _worlds():
    return [Gridworld(size=5, goal=c, hazards=HAZARDS, slip=0.05) for c in CORNERS]


def _features(world: Gridworld) -> torch.Tensor:
    phi = torch.zeros(world.num_states, 3, dtype=torch.float64)
    for f, c in enumerate(CORNERS):
        phi[world.state(*c), f] = 1.0
    for h in HAZARDS:
        phi[world.state(*h), 2] = 1.0
    return phi


def _momdp() -> tuple[MOMDP, list[Trajectories], torch.Tensor]:
    worlds = _worlds()
    # Tx[a, x, y, x2]: the type's own goal absorbs (a finished task for that type)
    Tx = torch.stack([w.transition for w in worlds], dim=2)
    A, X, Y = Tx.shape[0], Tx.shape[1], Tx.shape[2]
    model = MOMDP(
        Tx=Tx,
        Ty=None,
        Z=torch.ones(A, X, Y, 1, dtype=torch.float64),
        R=torch.zeros(A, X, Y, dtype=torch.float64),
        x0=12,
        b0=torch.full((Y,), 0.5, dtype=torch.float64),
        discount=0.9,
    )
    demos = [w.demonstrations(400, 40, seed=y) for y, w in enumerate(worlds)]
    return model, demos, _features(worlds[0])


@pytest.mark.parametrize("method", ["projection", "qp", "maxent"])
def test_each_type_gets_its_own_reward(method):
    model, demos, phi = _momdp()
    out = learn_type_rewards(
        model,
        demos,
        phi,
        method=method,
        epsilon=0.02 if method != "maxent" else 1e-6,
        horizon=None if method == "maxent" else 40,
        seed=0,
    )
    A, X, Y = model.num_actions, model.num_observed, model.num_hidden
    assert out.reward.shape == (A, X, Y) and out.weights.shape == (Y, 3)
    # R[a, x, y] = w_y . phi(x) for every a
    torch.testing.assert_close(out.reward, (phi @ out.weights.T).expand(A, X, Y))
    # type y's reward prefers its own corner
    assert out.weights[0, 0] > out.weights[0, 1] and out.weights[1, 1] > out.weights[1, 0]
    for y, world in enumerate(_worlds()):
        learned = value_iteration(world.transition, out.reward[:, :, y], 0.9).policy
        torch.testing.assert_close(learned, out.policies[y])
        assert policy_agreement(world.solve().q_values, learned, tol=1e-2) >= 0.95
    updated = dataclasses.replace(model, R=out.reward)  # drops straight into the MOMDP
    assert updated.R.shape == model.R.shape


def test_batched_types_equal_separate_runs():
    model, demos, phi = _momdp()
    T = type_transitions(model)
    out = learn_type_rewards(model, demos, phi, method="maxent", epsilon=1e-8)
    for y in range(2):
        single = maxent_irl(T[y], phi, demos[y], discount=0.9, tol=1e-8)
        torch.testing.assert_close(out.weights[y], single.weights, atol=1e-5, rtol=1e-5)
    # Abbeel-Ng: the same initial policies give the same runs, batched or not
    out = learn_type_rewards(T, demos, phi, discount=0.9, horizon=40, epsilon=0.02, seed=3)
    for y in range(2):
        single = apprenticeship_learning(
            T[y],
            phi,
            demos[y],
            discount=0.9,
            horizon=40,
            epsilon=0.02,
            initial_policy=out.results[y].policies[0],
        )
        torch.testing.assert_close(out.results[y].margins, single.margins)
        torch.testing.assert_close(out.weights[y], single.weights)


@pytest.mark.parametrize("rule", ["closest", "paper", "last", "dominant"])
def test_reward_rules(rule):
    model, demos, phi = _momdp()
    out = learn_type_rewards(
        model, demos, phi, horizon=40, epsilon=1e-3, max_iterations=6, reward_rule=rule
    )
    attribute = {"closest": "closest_weights", "paper": "paper_weights", "last": "last_weights",
                 "dominant": "dominant_weights"}  # fmt: skip
    for y in range(2):
        assert out.results[y].rule == rule
        torch.testing.assert_close(out.weights[y], getattr(out.results[y], attribute[rule]))
        torch.testing.assert_close(out.weights[y], out.results[y].weights)


def test_state_action_features_give_action_dependent_rewards():
    model, demos, phi = _momdp()
    A = model.num_actions
    phi_sa = phi.unsqueeze(1).repeat(1, A, 1)
    phi_sa = torch.cat([phi_sa, torch.eye(A, dtype=torch.float64).expand(25, A, A) * 0.1], -1)
    out = learn_type_rewards(model, demos, phi_sa, horizon=40, epsilon=0.05)
    expected = torch.einsum("xaf,yf->axy", phi_sa, out.weights)
    torch.testing.assert_close(out.reward, expected)


def test_errors_name_the_cluster():
    model, demos, phi = _momdp()
    with pytest.raises(ModelError, match="2 types, got 1 clusters"):
        learn_type_rewards(model, demos[:1], phi)
    empty = Trajectories(
        torch.zeros(0, 1, dtype=torch.long),
        torch.zeros(0, 1, dtype=torch.long),
        torch.zeros(0, dtype=torch.long),
    )
    with pytest.raises(ModelError, match=r"demonstrations_by_cluster\[1\] is empty"):
        learn_type_rewards(model, [demos[0], empty], phi)
    jump = Trajectories.from_pairs([[(0, 0), (24, 0)]])
    with pytest.raises(
        ModelError, match=r"demonstrations_by_cluster\[0\]\[0\] step 0 visits an impossible"
    ):
        learn_type_rewards(model, [jump, demos[1]], phi)
    with pytest.raises(ModelError, match=r"features of shape \(S=25, F\)"):
        learn_type_rewards(model, demos, phi[:10])
    with pytest.raises(TypeError, match="needs discount="):
        learn_type_rewards(type_transitions(model), demos, phi)
    with pytest.raises(ModelError, match=r"\(Y, A, X, X\)"):
        learn_type_rewards(torch.ones(3, 3, dtype=torch.float64), demos, phi, discount=0.9)
    with pytest.raises(ValueError, match="method"):
        learn_type_rewards(model, demos, phi, method="svm")
    with pytest.raises(ValueError, match="reward_rule"):
        learn_type_rewards(model, demos, phi, reward_rule="median")
