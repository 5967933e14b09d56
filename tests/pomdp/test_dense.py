"""Tests of torchhrc.pomdp: validation messages, to_pomdp / from_pomdp round trips."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.belief import momdp_update, update
from torchhrc.tasks.classic import rock_sample, tiger
from torchhrc.testing import random_belief, random_momdp, random_pomdp


def _kwargs(m: POMDP) -> dict:
    return {"T": m.T, "Z": m.Z, "R": m.R, "b0": m.b0, "discount": m.discount}


# ----------------------------------------------------------------------------- validation


def test_pomdp_validation_names_tensor_index_and_value():
    m = tiger()
    T = m.T.clone()
    T[1, 0, 1] = 0.7  # row [1, 0] sums to 1.2
    with pytest.raises(ModelError, match=r"T\[1, 0\] row sums to 1\.2"):
        POMDP(**{**_kwargs(m), "T": T})
    Z = m.Z.clone()
    Z[0, 1, 0] = -0.5
    with pytest.raises(ModelError, match=r"Z\[0, 1, 0\] = -0\.5 is not a probability"):
        POMDP(**{**_kwargs(m), "Z": Z})
    b0 = torch.tensor([float("nan"), 0.5], dtype=torch.float64)
    with pytest.raises(ModelError, match=r"b0\[0\] = nan is not finite"):
        POMDP(**{**_kwargs(m), "b0": b0})
    with pytest.raises(ModelError, match=r"Z to have shape \(\.\.\., A=3, S=2, O\)"):
        POMDP(**{**_kwargs(m), "Z": m.Z[:2]})
    with pytest.raises(ModelError, match="discount in"):
        POMDP(**{**_kwargs(m), "discount": 1.5})
    with pytest.raises(TypeError, match=r"T to be a torch\.Tensor"):
        POMDP(**{**_kwargs(m), "T": m.T.numpy()})
    with pytest.raises(ModelError, match="actions must be distinct"):
        POMDP(**_kwargs(m), actions=("a", "a", "b"))


def test_momdp_validation_names_tensor_index_and_value():
    m = random_momdp(3, 2, 2, 2, static=False, seed=0)
    Ty = m.Ty.clone()
    Ty[1, 2, 0, 1] = 0.0
    with pytest.raises(ModelError, match=r"Ty\[1, 2, 0, 1\] row sums to 0"):
        MOMDP(Tx=m.Tx, Ty=Ty, Z=m.Z, R=m.R, x0=0, b0=m.b0, discount=0.9)
    with pytest.raises(ModelError, match=r"x0 in \[0, 3\), got 3"):
        MOMDP(Tx=m.Tx, Ty=None, Z=m.Z, R=m.R, x0=3, b0=m.b0, discount=0.9)


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("static", [True, False])
@pytest.mark.parametrize("batch", [(), (2,)])
def test_to_pomdp_from_pomdp_round_trip(static, batch):
    m = random_momdp(3, 4, 2, 3, static=static, batch_shape=batch, seed=1)
    back = MOMDP.from_pomdp(m.to_pomdp(), num_hidden=4)
    assert back.static_hidden == static
    torch.testing.assert_close(back.Tx, m.Tx)
    if not static:
        torch.testing.assert_close(back.Ty, m.Ty)
    torch.testing.assert_close(back.Z, m.Z)
    torch.testing.assert_close(back.R, m.R)
    torch.testing.assert_close(back.b0, m.b0)
    assert back.x0 == m.x0 and back.discount == m.discount


def test_from_pomdp_recovers_names_and_beliefs_agree():
    m = rock_sample(2, 1, form="momdp")
    flat = m.to_pomdp()
    back = MOMDP.from_pomdp(flat, num_hidden=m.num_hidden)
    assert back.observed_states == m.observed_states
    assert back.hidden_states == m.hidden_states and back.observations == m.observations
    assert back.Ty is not None  # sampling changes the rock: not static
    torch.testing.assert_close(back.to_pomdp().T, flat.T)
    by = random_belief((m.num_hidden,), seed=2)
    # at cell x = 1 check the rock (action 5): the robot stays, observes "good"
    r1 = momdp_update(m, 1, by, 5, 1, 1)
    r2 = momdp_update(back, 1, by, 5, 1, 1)
    torch.testing.assert_close(r1.belief, r2.belief)


def test_from_pomdp_rejects_models_that_do_not_factor():
    m = random_pomdp(6, 2, 3, seed=3)
    with pytest.raises(ModelError, match="do not factor into X \\* Y with Y = 4"):
        MOMDP.from_pomdp(m, num_hidden=4)
    with pytest.raises(ModelError, match="observations do not factor into X \\* O"):
        MOMDP.from_pomdp(m, num_hidden=3)  # X = 2 does not divide O = 3
    mm = random_momdp(2, 3, 2, 2, seed=4)
    flat = mm.to_pomdp()
    Z = flat.Z.clone()
    Z[1, 4] = torch.tensor([0.5, 0.0, 0.5, 0.0], dtype=torch.float64)  # x2 = 1 seen as x = 0
    with pytest.raises(ModelError, match="Z does not reveal the observed part"):
        MOMDP.from_pomdp(POMDP(**{**_kwargs(flat), "Z": Z}), num_hidden=3)
    b0 = torch.full((6,), 1 / 6, dtype=torch.float64)
    with pytest.raises(ModelError, match="b0 must put all its mass on one observed value"):
        MOMDP.from_pomdp(POMDP(**{**_kwargs(flat), "b0": b0}), num_hidden=3)
    with pytest.raises(TypeError, match="num_hidden"):
        MOMDP.from_pomdp(flat, num_hidden=0)


def test_flat_update_through_to_pomdp_matches_factored_filter_over_a_trajectory():
    m = random_momdp(3, 3, 2, 2, static=False, seed=5)
    flat = m.to_pomdp()
    g = torch.Generator().manual_seed(6)
    x, by = m.x0, m.b0
    b = flat.b0
    for _ in range(5):
        a = int(torch.randint(2, (), generator=g))
        x2 = int(torch.randint(3, (), generator=g))
        o = int(torch.randint(2, (), generator=g))
        r = momdp_update(m, x, by, a, x2, o)
        rf = update(flat, b, a, x2 * 2 + o)
        torch.testing.assert_close(rf.belief.reshape(3, 3)[x2], r.belief)
        torch.testing.assert_close(rf.log_normalizer, r.log_normalizer)
        x, by, b = x2, r.belief, rf.belief


# -- a random first observed value (MOMDP.initial) -------------------------------------------
def _joint(X: int, Y: int, seed: int) -> torch.Tensor:
    j = torch.rand(X, Y, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return j / j.sum()


def test_with_initial_sets_the_most_probable_x_and_its_conditional():
    joint = torch.tensor([[0.1, 0.1], [0.0, 0.0], [0.2, 0.6]], dtype=torch.float64)
    m = random_momdp(3, 2, 2, 2, seed=0).with_initial(joint)
    assert m.random_start and m.x0 == 2
    torch.testing.assert_close(m.b0, torch.tensor([0.25, 0.75], dtype=torch.float64))
    assert torch.equal(m.initial_distribution(), joint)
    # the flat form starts from the joint
    torch.testing.assert_close(m.to_pomdp().b0, joint.reshape(-1), rtol=0, atol=0)
    # a joint on one x is no random start
    one = torch.zeros(3, 2, dtype=torch.float64)
    one[1] = torch.tensor([0.4, 0.6], dtype=torch.float64)
    m1 = m.with_initial(one)
    assert not m1.random_start and m1.initial is None and m1.x0 == 1
    torch.testing.assert_close(m1.initial_distribution(), one, rtol=0, atol=1e-15)
    # to(): the joint moves with the other tensors
    assert m.to(dtype=torch.float32).initial.dtype == torch.float32


def test_initial_validation_names_what_is_wrong():
    m = random_momdp(3, 2, 2, 2, seed=0)
    joint = _joint(3, 2, 1)
    with pytest.raises(ModelError, match=r"initial to have shape \(X=3, Y=2\)"):
        dataclasses.replace(m, initial=joint.reshape(2, 3))
    with pytest.raises(ModelError, match="initial"):
        dataclasses.replace(m, initial=joint * 2)
    with pytest.raises(ModelError, match="all its mass on one observed value"):
        one = torch.zeros(3, 2, dtype=torch.float64)
        one[0] = 0.5
        dataclasses.replace(m, initial=one)
    with pytest.raises(ModelError, match=r"b0 must be initial's P\(y \| x0 = 0\)"):
        dataclasses.replace(m, initial=joint)  # m.b0 is not joint's conditional at x0
    gapped = joint.clone()
    gapped[0] = 0.0
    gapped = gapped / gapped.sum()
    with pytest.raises(ModelError, match="gives x0 = 0 no mass"):
        dataclasses.replace(m, initial=gapped)
    with pytest.raises(ModelError, match="initial to have shape"):
        m.with_initial(joint[:2])


def test_from_pomdp_of_a_random_start_says_how_to_build_it():
    m = random_momdp(3, 2, 2, 2, seed=0).with_initial(_joint(3, 2, 2))
    with pytest.raises(ModelError, match="with_initial"):
        MOMDP.from_pomdp(m.to_pomdp(), num_hidden=2)
