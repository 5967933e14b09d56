"""Tests of torchhrc.tasks.classic: sizes, normalisation, values worked from the definitions."""

from __future__ import annotations

import math

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.classic import (
    ROCK_SAMPLE_INSTANCES,
    rock_sample,
    rock_sample_momdp,
    rock_sample_sparse,
    tag,
    tag_momdp,
    tiger,
)


def _rows_normalised(t: torch.Tensor) -> bool:
    return bool(torch.allclose(t.sum(-1), torch.ones_like(t.sum(-1)), atol=1e-12))


def test_tiger_definition():
    m = tiger()
    assert (m.num_states, m.num_actions, m.num_observations, m.discount) == (2, 3, 2, 0.95)
    torch.testing.assert_close(m.R[0], torch.tensor([-1.0, -1.0], dtype=torch.float64))
    assert m.Z[0, 0, 0].item() == 0.85 and m.Z[0, 1, 1].item() == 0.85
    assert m.T[1].eq(0.5).all() and m.T[0].equal(torch.eye(2, dtype=torch.float64))


def test_tag_sizes_and_normalisation():
    m = tag()
    assert (m.num_states, m.num_actions, m.num_observations) == (870, 5, 30)
    assert m.discount == 0.95
    assert _rows_normalised(m.T) and _rows_normalised(m.Z) and _rows_normalised(m.b0)
    # uniform start over the 29 x 29 untagged pairs
    assert torch.count_nonzero(m.b0).item() == 29 * 29


def test_tag_opponent_moves_worked_by_hand():
    m = tag()
    # cells: rows 0-2 hold columns 5-7 (cells 0-8), row 3 cells 9-18, row 4 cells 19-28.
    robot, opponent = 19, 22  # robot at (row 4, col 0), opponent at (row 4, col 3)
    s = robot * 30 + opponent
    north = 9  # the robot moves to (row 3, col 0)
    row = m.T[0, s].reshape(29, 30)
    assert row.sum(-1).nonzero().flatten().tolist() == [north]
    # level rows: north (-> cell 12) and south (a wall: stays) get 0.2 each; east (-> cell 23)
    # gets 0.4; staying gets 0.2 + the 0.2 of the wall bump.
    expected = torch.zeros(30, dtype=torch.float64)
    expected[12], expected[23], expected[22] = 0.2, 0.4, 0.4
    torch.testing.assert_close(row[north], expected)
    assert m.R[0, s].item() == -1.0 and m.R[4, s].item() == -10.0


def test_tag_tagging_and_observations():
    m = tag()
    s = 5 * 30 + 5  # co-located in cell 5
    assert m.R[4, s].item() == 10.0
    assert m.T[4, s, 5 * 30 + 29].item() == 1.0  # tagged, absorbing
    tagged = 5 * 30 + 29
    assert (m.T[:, tagged, tagged] == 1).all() and (m.R[:, tagged] == 0).all()
    assert m.Z[0, s, 29].item() == 1.0  # "same" when co-located
    assert m.Z[2, 7 * 30 + 3, 7].item() == 1.0  # otherwise the robot's own cell


def test_tag_momdp_matches_flat_tag():
    mm = tag_momdp(robot_start=3)
    flat = tag(robot_start=3)
    f = mm.to_pomdp()
    assert (mm.num_observed, mm.num_hidden, mm.num_actions) == (29, 30, 5)
    torch.testing.assert_close(f.T, flat.T)
    torch.testing.assert_close(f.R, flat.R)
    torch.testing.assert_close(f.b0, flat.b0)
    # flat Tag observation o = robot cell (apart) or 29 (same); MOMDP flat o = x2 * 2 + same.
    r = torch.arange(870) // 30
    same = flat.Z[..., 29]
    torch.testing.assert_close(f.Z[:, torch.arange(870), r * 2 + 1], same)
    torch.testing.assert_close(f.Z[:, torch.arange(870), r * 2], 1 - same)


def test_rock_sample_4_4_sizes_and_normalisation():
    m = rock_sample(4, 4)
    assert (m.num_states, m.num_actions, m.num_observations) == (257, 9, 3)
    assert _rows_normalised(m.T) and _rows_normalised(m.Z)
    # start: the published (0, 2) cell, every rock quality equally likely
    p0 = 2 * 4 + 0
    torch.testing.assert_close(m.b0[p0 * 16 : (p0 + 1) * 16], torch.full((16,), 1 / 16).double())


def test_rock_sample_dynamics_worked_by_hand():
    n, k = 4, 4
    rocks, _ = ROCK_SAMPLE_INSTANCES[(n, k)]
    m = rock_sample(n, k)
    Q = 2**k
    x, y = rocks[0]  # rock 0 at (3, 1)
    p = y * n + x
    q = 0b0101  # rocks 0 and 2 good
    s = p * Q + q
    sample = 4
    assert m.R[sample, s].item() == 10.0
    assert m.T[sample, s, p * Q + 0b0100].item() == 1.0  # rock 0 turns bad
    assert m.R[sample, p * Q + 0b0100].item() == -10.0
    assert m.R[sample, 0 * Q + q].item() == -10.0  # (0, 0) holds no rock
    east = 2
    assert m.R[east, s].item() == 10.0  # x = 3 is the last column: exit
    assert m.T[east, s, n * n * Q].item() == 1.0
    check = 5 + 2  # rock 2 at (1, 3): distance from (3, 1) = sqrt(8)
    accuracy = 0.5 * (1 + 2 ** (-math.sqrt(8) / 20))
    assert m.Z[check, s, 1].item() == pytest.approx(accuracy)  # rock 2 good: "good"
    assert m.Z[check, s, 2].item() == pytest.approx(1 - accuracy)
    assert m.Z[check, s, 0].item() == 0.0
    assert m.Z[5 + 0, s, 1].item() == 1.0  # on rock 0: a perfect reading
    north = 0
    assert m.T[north, s, (p + n) * Q + q].item() == 1.0
    assert m.T[north, (3 * n) * Q + q, (3 * n) * Q + q].item() == 1.0  # top wall
    terminal = n * n * Q
    assert (m.T[:, terminal, terminal] == 1).all() and (m.R[:, terminal] == 0).all()


@pytest.mark.parametrize(("n", "k"), [(4, 4), (3, 2)])
def test_rock_sample_momdp_agrees_with_the_flat_model(n, k):
    mm = rock_sample_momdp(n, k, seed=3)
    flat = rock_sample(n, k, seed=3)
    f = mm.to_pomdp()
    Q = 2**k
    G = n * n * Q
    assert (mm.num_observed, mm.num_hidden) == (n * n + 1, Q)
    torch.testing.assert_close(f.T[:, :G, :G], flat.T[:, :G, :G])
    torch.testing.assert_close(f.T[:, :G, G:].sum(-1), flat.T[:, :G, G])  # one terminal
    torch.testing.assert_close(f.R[:, :G], flat.R[:, :G])
    torch.testing.assert_close(f.Z[:, :G].reshape(-1, G, n * n + 1, 3).sum(-2), flat.Z[:, :G])
    assert f.b0.nonzero().flatten().tolist() == flat.b0.nonzero().flatten().tolist()


def test_rock_sample_7_8_sparse_and_size_guards():
    sp = rock_sample_sparse(7, 8)
    assert (sp.num_states, sp.num_actions, sp.num_observations) == (12545, 13, 3)
    assert sp.transitions[0].shape[0] == 13 * 12545  # deterministic moves
    assert sp.b0.sum().item() == pytest.approx(1.0)
    with pytest.raises(ModelError, match="entries"):
        rock_sample(7, 8)
    with pytest.raises(ModelError, match="Ty would have"):
        rock_sample_momdp(7, 8)


def test_rock_sample_bad_layouts():
    with pytest.raises(ModelError, match="outside the 3x3 grid"):
        rock_sample(3, 1, rocks=[(3, 0)])
    with pytest.raises(ModelError, match="distinct"):
        rock_sample(3, 2, rocks=[(1, 1), (1, 1)])
    with pytest.raises(ModelError, match="expected 2 rock positions"):
        rock_sample(3, 2, rocks=[(1, 1)])
    # seeded layouts are deterministic
    assert torch.equal(rock_sample(3, 2, seed=5).R, rock_sample(3, 2, seed=5).R)
