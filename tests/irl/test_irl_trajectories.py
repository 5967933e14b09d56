"""Tests of torchhrc.irl.trajectories: container, transition checks, seeded sampler."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.irl.trajectories import (
    Trajectories,
    check_trajectories,
    policy_matrix,
    sample_trajectories,
)


def _chain() -> torch.Tensor:
    """(A=2, S=3, S=3): action 0 stays or moves right w.p. 1/2; action 1 resets to 0."""
    T = torch.zeros(2, 3, 3, dtype=torch.float64)
    T[0, 0, 0] = T[0, 0, 1] = 0.5
    T[0, 1, 1] = T[0, 1, 2] = 0.5
    T[0, 2, 2] = 1.0
    T[1, :, 0] = 1.0
    return T


def test_from_pairs_pads_and_masks():
    demos = Trajectories.from_pairs([[(0, 1), (2, 0), (1, 1)], [(2, 1)]])
    assert demos.states.tolist() == [[0, 2, 1], [2, 0, 0]]
    assert demos.actions.tolist() == [[1, 0, 1], [1, 0, 0]]
    assert demos.lengths.tolist() == [3, 1]
    assert demos.mask.tolist() == [[True, True, True], [True, False, False]]
    assert demos[[1]].lengths.tolist() == [1]


@pytest.mark.parametrize(
    ("states", "actions", "lengths", "match"),
    [
        ([[0, 1]], [[0]], [2], "actions to have the shape"),
        ([[0, 1]], [[0, 0]], [3], r"lengths\[0\] = 3 is out of range"),
        ([[0, 1]], [[0, 0]], [0], r"lengths\[0\] = 0"),
        ([[0, -1]], [[0, 0]], [2], r"states\[0, 1\] = -1 is negative"),
        ([[0, 1]], [[0, 0]], [2, 2], r"lengths to have shape \(N=1,\)"),
    ],
)
def test_trajectories_reject_bad_input(states, actions, lengths, match):
    with pytest.raises(ModelError, match=match):
        Trajectories(torch.tensor(states), torch.tensor(actions), torch.tensor(lengths))


def test_trajectories_reject_float_and_empty():
    with pytest.raises(TypeError, match="integer tensor"):
        Trajectories(torch.zeros(1, 2), torch.zeros(1, 2, dtype=torch.long), torch.tensor([2]))
    with pytest.raises(ModelError, match="at least one trajectory"):
        Trajectories.from_pairs([])
    with pytest.raises(ModelError, match="trajectory 1 is empty"):
        Trajectories.from_pairs([[(0, 0)], []])


def test_check_trajectories_names_the_impossible_step():
    T = _chain()
    ok = Trajectories.from_pairs([[(0, 0), (1, 0), (2, 1), (0, 0)]])
    check_trajectories(ok, T)
    bad = Trajectories.from_pairs([[(0, 0), (0, 0)], [(0, 0), (1, 0), (0, 0)]])
    with pytest.raises(
        ModelError, match=r"demonstrations\[1\] step 1 .* state 1 --action 0--> state 0"
    ):
        check_trajectories(bad, T)
    # padding beyond a trajectory's length is never checked
    padded = Trajectories(torch.tensor([[0, 2]]), torch.tensor([[0, 0]]), torch.tensor([1]))
    check_trajectories(padded, T)


def test_check_trajectories_range():
    T = _chain()
    with pytest.raises(ModelError, match=r"states\[0, 1\] = 5 is out of range"):
        check_trajectories(Trajectories.from_pairs([[(0, 0), (5, 0)]]), T)
    with pytest.raises(ModelError, match=r"actions\[0, 0\] = 2 is out of range"):
        check_trajectories(Trajectories.from_pairs([[(0, 2)]]), T)


def test_policy_matrix():
    pi = policy_matrix(torch.tensor([1, 0, 1]), 2, torch.float64)
    assert pi.tolist() == [[0, 1], [1, 0], [0, 1]]
    with pytest.raises(ModelError, match=r"actions in \[0, 2\)"):
        policy_matrix(torch.tensor([2, 0]), 2, torch.float64)
    with pytest.raises(ModelError, match="sums to"):
        policy_matrix(torch.tensor([[0.5, 0.6]]), 2, torch.float64)


def test_sampler_is_seeded_and_follows_the_dynamics():
    T = _chain()
    policy = torch.tensor([0, 0, 1])
    a = sample_trajectories(T, policy, 0, 400, 12, seed=3)
    b = sample_trajectories(T, policy, 0, 400, 12, seed=3)
    c = sample_trajectories(T, policy, 0, 400, 12, seed=4)
    assert torch.equal(a.states, b.states) and torch.equal(a.actions, b.actions)
    assert not torch.equal(a.states, c.states)
    check_trajectories(a, T)  # every sampled step is possible
    assert (a.actions == policy[a.states]).all()
    # empirical P(s2 = 1 | s = 0, a = 0) = 1/2 within 5 standard errors
    s, s2 = a.states[:, :-1], a.states[:, 1:]
    from_zero = s == 0
    n = int(from_zero.sum())
    frequency = (s2[from_zero] == 1).double().mean().item()
    assert abs(frequency - 0.5) < 5 * (0.25 / n) ** 0.5


def test_sampler_batched_policies_and_start_distribution():
    T = _chain()
    policies = torch.tensor([[0, 0, 0], [1, 1, 1]])
    start = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    batches = sample_trajectories(T, policies, start, 50, 5, seed=0)
    assert isinstance(batches, list) and len(batches) == 2
    assert (batches[0].states == 2).all()  # action 0 keeps state 2
    assert (batches[1].states[:, 0] == 2).all() and (batches[1].states[:, 1:] == 0).all()


def test_sampler_rejects_bad_sizes():
    with pytest.raises(ModelError, match="num_trajectories >= 1"):
        sample_trajectories(_chain(), torch.tensor([0, 0, 0]), 0, 0, 5)
    with pytest.raises(ModelError, match=r"start state in \[0, 3\)"):
        sample_trajectories(_chain(), torch.tensor([0, 0, 0]), 3, 1, 5)
