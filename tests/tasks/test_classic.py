"""Tests of torchhrc.tasks.classic: sizes, normalisation, values worked from the definitions."""

from __future__ import annotations

import math

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.sparse import SparsePOMDP
from torchhrc.pomdp.sparse_momdp import SparseMOMDP
from torchhrc.tasks import classic
from torchhrc.tasks.classic import ROCK_SAMPLE_INSTANCES, rock_sample, tag, tiger


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
    mm = tag(form="momdp", robot_start=3)
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
    mm = rock_sample(n, k, form="momdp", seed=3)
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
    sp = rock_sample(7, 8, form="sparse")
    assert (sp.num_states, sp.num_actions, sp.num_observations) == (12545, 13, 3)
    assert sp.transitions[0].shape[0] == 13 * 12545  # deterministic moves
    assert sp.b0.sum().item() == pytest.approx(1.0)
    with pytest.raises(ModelError, match="entries"):
        rock_sample(7, 8)
    with pytest.raises(ModelError, match="Ty would have"):
        rock_sample(7, 8, form="momdp")
    sm = rock_sample(7, 8, form="sparse_momdp")  # the description fits: one successor each
    assert (sm.num_observed, sm.num_hidden) == (50, 256)
    assert sm.transitions[0].shape[0] == 13 * 50 * 256


def test_rock_sample_bad_layouts():
    with pytest.raises(ModelError, match="outside the 3x3 grid"):
        rock_sample(3, 1, rocks=[(3, 0)])
    with pytest.raises(ModelError, match="distinct"):
        rock_sample(3, 2, rocks=[(1, 1), (1, 1)])
    with pytest.raises(ModelError, match="expected 2 rock positions"):
        rock_sample(3, 2, rocks=[(1, 1)])
    # seeded layouts are deterministic
    assert torch.equal(rock_sample(3, 2, seed=5).R, rock_sample(3, 2, seed=5).R)


# One builder per benchmark: every form is a conversion of one description. Each form is
# checked against another path: the dense MOMDP flattened by MOMDP.to_pomdp() and lumped here
# by dense sums (not by the builder's coordinate lumping), the SparseMOMDP against
# SparseMOMDP.from_dense of the dense MOMDP, the sparse flat form against the dense one.
BENCHMARKS = {
    "rock_sample_4_4": lambda **kw: rock_sample(4, 4, **kw),
    "rock_sample_3_2_seed3": lambda **kw: rock_sample(3, 2, seed=3, **kw),
    "tag": lambda **kw: tag(**kw),
    "tag_start3_p06": lambda **kw: tag(robot_start=3, move_away_probability=0.6, **kw),
}


def _classes(name: str, mm: MOMDP) -> tuple[torch.Tensor, torch.Tensor]:
    """One-hot maps of the flat MOMDP's states (X * Y) and observations (X * O) onto the
    published flat model's (RockSample: the exit states are one terminal state, the position
    is not observed; Tag: the robot's cell when apart, 29 when co-located)."""
    X, Y, O = mm.num_observed, mm.num_hidden, mm.num_observations
    s, o = torch.arange(X * Y), torch.arange(X * O)
    if name.startswith("rock"):
        state, obs = s.clamp(max=(X - 1) * Y), o % O
    else:
        state, obs = s, torch.where(o % 2 == 0, o // 2, X)
    onehot = torch.nn.functional.one_hot
    return onehot(state).double(), onehot(obs).double()


@pytest.mark.parametrize("name", sorted(BENCHMARKS))
def test_the_flattened_momdp_lumps_exactly_to_the_dense_form(name):
    build = BENCHMARKS[name]
    dense, mm = build(), build(form="momdp")
    assert isinstance(dense, POMDP) and isinstance(mm, MOMDP)
    f = mm.to_pomdp()
    M, N = _classes(name, mm)  # (S_momdp, S), (O_momdp, O)
    T = f.T @ M  # (A, S_momdp, S): the lumped rows of every state
    Z = f.Z @ N  # (A, S_momdp, O)
    first = M.argmax(0)  # the first state of each class
    # lumpable: every state of a class has its class's rows, reward and observations
    cls = M.argmax(1)
    torch.testing.assert_close(T, T[:, first[cls]], rtol=0, atol=1e-12)
    torch.testing.assert_close(Z, Z[:, first[cls]], rtol=0, atol=1e-12)
    torch.testing.assert_close(f.R, f.R[:, first[cls]], rtol=0, atol=0)
    torch.testing.assert_close(T[:, first], dense.T, rtol=0, atol=1e-12)
    torch.testing.assert_close(Z[:, first], dense.Z, rtol=0, atol=1e-12)
    torch.testing.assert_close(f.R[:, first], dense.R, rtol=0, atol=0)
    torch.testing.assert_close(f.b0 @ M, dense.b0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", sorted(BENCHMARKS))
def test_the_sparse_forms_are_the_dense_forms(name):
    build = BENCHMARKS[name]
    sparse, dense = build(form="sparse"), build()
    assert isinstance(sparse, SparsePOMDP)
    back = sparse.to_dense()
    for field in ("T", "Z", "R", "b0"):
        torch.testing.assert_close(getattr(back, field), getattr(dense, field), rtol=0, atol=0)
    assert (sparse.states, sparse.observations) == (dense.states, dense.observations)
    sm, mm = build(form="sparse_momdp"), build(form="momdp")
    assert isinstance(sm, SparseMOMDP)
    ref = SparseMOMDP.from_dense(mm)
    sizes = (mm.num_actions, mm.num_observed, mm.num_hidden, mm.num_observed, mm.num_hidden)

    def joint(m: SparseMOMDP) -> torch.Tensor:
        P = torch.zeros(sizes, dtype=torch.float64)
        return P.index_put_(tuple(m.transitions[0].T), m.transitions[1], accumulate=True)

    torch.testing.assert_close(joint(sm), joint(ref), rtol=0, atol=1e-15)
    for field in ("Z", "R", "b0", "initial"):
        torch.testing.assert_close(getattr(sm, field), getattr(ref, field), rtol=0, atol=0)
    assert (sm.x0, sm.hidden_states, sm.observations) == (
        ref.x0,
        ref.hidden_states,
        ref.observations,
    )


def test_old_builder_names_warn_and_equal_the_forms():
    pairs = [
        (lambda: classic.rock_sample_sparse(3, 2), lambda: rock_sample(3, 2, form="sparse")),
        (lambda: classic.tag_sparse(robot_start=2), lambda: tag(form="sparse", robot_start=2)),
    ]
    for old, new in pairs:
        with pytest.warns(DeprecationWarning, match="form="):
            a = old()
        b = new()
        assert torch.equal(a.to_dense().T, b.to_dense().T) and torch.equal(a.b0, b.b0)
    with pytest.warns(DeprecationWarning, match='form="momdp"'):
        a = classic.rock_sample_momdp(3, 2)
    assert torch.equal(a.Tx, rock_sample(3, 2, form="momdp").Tx)
    with pytest.warns(DeprecationWarning, match="robot_start=0"):
        a = classic.tag_momdp()  # the old default: the robot starts in cell 0
    assert a.x0 == 0 and a.initial is None
    assert tag(form="momdp").initial is not None  # tag's default: a random first cell


def test_form_argument_is_checked():
    with pytest.raises(ValueError, match="expected form to be one of"):
        rock_sample(3, 2, form="pomdp")  # type: ignore[call-overload]
    with pytest.raises(ValueError, match="device applies to the dense forms"):
        tag(form="sparse", device="cpu")
    with pytest.raises(ModelError, match="robot_start"):
        tag(form="sparse_momdp", robot_start=29)


def test_rock_sample_momdp_rocks_do_not_depend_on_the_next_position():
    # A rock changes with (a, x, y) only (sampling spoils it), so Ty must not depend on x2,
    # also where x2 is impossible (SparseMOMDP.to_dense fills those with the hidden move):
    # what a .pomdpx file with one variable per rock says (tests/io/test_pomdpx_policy.py).
    mm = rock_sample(3, 2, form="momdp")
    torch.testing.assert_close(mm.Ty, mm.Ty[..., :1, :].expand_as(mm.Ty), rtol=0, atol=0)
    # the default layout of (3, 2) with seed 0 puts rock 1 at (0, 0) = x 0: sampling there
    # spoils it (y 0b11 -> 0b01), whatever x2, even x2 = 5, which sampling never reaches
    sample = 4
    assert mm.Ty[sample, 0, 0b11, 5].tolist() == [0.0, 1.0, 0.0, 0.0]
    assert mm.Tx[sample, 0, 0b11, 5].item() == 0.0
