"""Tests of torchhrc.tasks.gridworld: dynamics, reward, features, expert, sampler."""

from __future__ import annotations

import pytest
import torch

from torchhrc._checks import check_probabilities
from torchhrc.errors import ModelError
from torchhrc.irl.trajectories import check_trajectories
from torchhrc.tasks.gridworld import ACTIONS, Gridworld


def test_transition_is_stochastic_with_walls_slip_and_absorbing_goal():
    world = Gridworld(size=4, goal=(3, 3), hazards=((1, 1),), slip=0.2)
    T = world.transition
    check_probabilities("T", T)
    right, up, stay = ACTIONS.index("right"), ACTIONS.index("up"), ACTIONS.index("stay")
    s = world.state(1, 1)
    # intended move w.p. 0.8 + 0.2/4, each other direction 0.2/4
    assert T[right, s, world.state(1, 2)].item() == pytest.approx(0.85)
    for cell in [(0, 1), (2, 1), (1, 0)]:
        assert T[right, s, world.state(*cell)].item() == pytest.approx(0.05)
    assert T[right, s, s].item() == pytest.approx(0.0)
    # a wall keeps the agent in place: "up" from the top-left corner
    corner = world.state(0, 0)
    assert T[up, corner, corner].item() == pytest.approx(0.8 + 0.05 + 0.05)  # up, left slips
    assert T[stay, s, s].item() == pytest.approx(0.8)
    goal = world.state(3, 3)
    assert (T[:, goal, goal] == 1).all()


def test_reward_features_and_true_weights():
    world = Gridworld(size=3, goal=(0, 2), hazards=((1, 1),), step_reward=-0.1)
    R = world.reward
    assert R.shape == (5, 9) and (R == R[0]).all()
    assert R[0, world.state(0, 2)].item() == 1.0
    assert R[0, world.state(1, 1)].item() == -1.0
    assert R[0, world.state(2, 0)].item() == pytest.approx(-0.1)
    phi = world.features("semantic")
    assert phi.shape == (9, 3)
    assert phi[world.state(2, 0)].tolist() == [0.0, 0.0, 1.0]  # distance 4 / (2 * 2)
    assert phi[world.state(0, 2)].tolist() == [1.0, 0.0, 0.0]
    torch.testing.assert_close(phi @ world.true_weights() + world.step_reward, R[0])
    ind = world.features("indicator")
    torch.testing.assert_close(ind @ world.true_weights("indicator"), R[0])


def test_expert_heads_for_the_goal_and_around_hazards():
    world = Gridworld(size=3, goal=(0, 2), hazards=((0, 1),), slip=0.0, hazard_reward=-5.0)
    policy = world.expert_policy()
    assert ACTIONS[policy[world.state(1, 2)]] == "up"
    # from (0, 0) the direct route crosses the hazard: the expert goes down first
    assert ACTIONS[policy[world.state(0, 0)]] == "down"


def test_demonstrations_are_seeded_valid_and_of_unequal_length():
    world = Gridworld.random(6, 5, seed=2, slip=0.1)
    a = world.demonstrations(30, 20, seed=1, min_length=5)
    b = world.demonstrations(30, 20, seed=1, min_length=5)
    c = world.demonstrations(30, 20, seed=2, min_length=5)
    assert torch.equal(a.states, b.states) and torch.equal(a.lengths, b.lengths)
    assert not torch.equal(a.states, c.states)
    assert a.lengths.min() >= 5 and a.lengths.max() <= 20 and len(set(a.lengths.tolist())) > 1
    assert (a.states[~a.mask] == 0).all()
    check_trajectories(a, world.transition)
    expert = world.expert_policy()
    assert (a.actions[a.mask] == expert[a.states[a.mask]]).all()
    assert (a.states[:, 0] != world.state(*world.goal)).all()  # uniform over non-goal cells


def test_random_layout_is_seeded():
    assert Gridworld.random(8, 6, seed=4) == Gridworld.random(8, 6, seed=4)
    world = Gridworld.random(8, 6, seed=4)
    assert len(set(world.hazards)) == 6 and world.goal not in world.hazards


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"goal": (5, 0)}, "inside the 4x4 grid"),
        ({"goal": (1, 1), "hazards": ((1, 1),)}, "must not be a hazard"),
        ({"slip": 1.5}, r"slip in \[0, 1\]"),
        ({"discount": 1.0}, r"discount in \(0, 1\)"),
        ({"size": 1}, "size to be an int >= 2"),
    ],
)
def test_bad_parameters(kwargs, match):
    params = {"size": 4, "goal": (3, 3)} | kwargs
    with pytest.raises(ModelError, match=match):
        Gridworld(**params)
