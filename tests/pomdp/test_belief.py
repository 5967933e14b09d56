"""Tests of torchhrc.pomdp.belief: hand-worked values, flat == MOMDP, batched == loop, gradcheck."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.belief import (
    BeliefUpdate,
    correct,
    log_matmul_exp,
    log_update,
    log_update_all,
    momdp_correct,
    momdp_log_update,
    momdp_log_update_all,
    momdp_predict,
    momdp_update,
    momdp_update_all,
    predict,
    predict_all,
    update,
    update_all,
)
from torchhrc.tasks.classic import tiger
from torchhrc.testing import random_belief, random_momdp, random_pomdp

BATCHES = [(), (2,), (2, 3)]
DTYPES = [torch.float32, torch.float64]


def _tol(dtype: torch.dtype) -> dict[str, float]:
    return (
        {"atol": 1e-5, "rtol": 1e-4} if dtype == torch.float32 else {"atol": 1e-12, "rtol": 1e-10}
    )


# ----------------------------------------------------------------------------- hand-worked


def test_tiger_listen_updates_worked_by_hand():
    m = tiger()
    r = update(m, m.b0, action=0, observation=0)  # listen, hear tiger-left
    assert isinstance(r, BeliefUpdate)
    torch.testing.assert_close(r.belief, torch.tensor([0.85, 0.15], dtype=torch.float64))
    assert r.log_normalizer.item() == pytest.approx(math.log(0.5))
    r2 = update(m, r.belief, 0, 0)  # hear left again: 0.85^2 / (0.85^2 + 0.15^2)
    assert r2.belief[0].item() == pytest.approx(0.7225 / 0.745)
    assert r2.log_normalizer.exp().item() == pytest.approx(0.85 * 0.85 + 0.15 * 0.15)
    r3 = update(m, r.belief, 0, 1)  # then hear right: back to 1/2
    torch.testing.assert_close(r3.belief, torch.tensor([0.5, 0.5], dtype=torch.float64))


def test_tiger_open_resets_belief():
    m = tiger()
    b = torch.tensor([0.97, 0.03], dtype=torch.float64)
    for o in (0, 1):
        r = update(m, b, 1, o)
        torch.testing.assert_close(r.belief, torch.full((2,), 0.5, dtype=torch.float64))
        assert r.log_normalizer.item() == pytest.approx(math.log(0.5))


def test_predict_correct_split_equals_update():
    m = random_pomdp(5, 3, 4, seed=1)
    b = random_belief((5,), seed=2)
    pred = predict(m, b, 2)
    torch.testing.assert_close(pred, b @ m.T[2])
    torch.testing.assert_close(predict_all(m, b)[2], pred)
    torch.testing.assert_close(correct(m, pred, 2, 1).belief, update(m, b, 2, 1).belief)


# ----------------------------------------------------------------------------- batched


@pytest.mark.parametrize("batch", BATCHES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_update_batched_equals_loop_and_normalised(batch, dtype):
    S, A, O = 4, 3, 5
    m = random_pomdp(S, A, O, batch_shape=batch, dtype=dtype, seed=3)
    g = torch.Generator().manual_seed(4)
    b = random_belief((*batch, S), dtype=dtype, seed=5)
    a = torch.randint(A, batch, generator=g)
    o = torch.randint(O, batch, generator=g)
    r = update(m, b, a, o)
    assert r.belief.shape == (*batch, S) and r.log_normalizer.shape == batch
    assert r.belief.dtype == dtype
    torch.testing.assert_close(r.belief.sum(-1), torch.ones(batch, dtype=dtype), **_tol(dtype))
    assert (r.belief >= 0).all()
    for idx in (
        torch.cartesian_prod(*[torch.arange(n) for n in batch]).reshape(-1, len(batch))
        if batch
        else [()]
    ):
        idx = tuple(int(i) for i in idx)
        single = POMDP(T=m.T[idx], Z=m.Z[idx], R=m.R[idx], b0=m.b0[idx], discount=m.discount)
        ri = update(single, b[idx], int(a[idx]), int(o[idx]))
        torch.testing.assert_close(r.belief[idx], ri.belief, **_tol(dtype))
        torch.testing.assert_close(r.log_normalizer[idx], ri.log_normalizer, **_tol(dtype))


def test_unbatched_model_with_per_belief_actions_equals_loop():
    m = random_pomdp(5, 3, 2, seed=22, sparsity=0.3)
    b = random_belief((4, 3, 5), seed=23)
    g = torch.Generator().manual_seed(24)
    a = torch.randint(3, (4, 3), generator=g)
    o = torch.randint(2, (4, 3), generator=g)
    r = update(m, b, a, o, on_zero="ninf")
    lr = log_update(m, b.log(), a, o, on_zero="ninf")
    for i in range(4):
        for j in range(3):
            ri = update(m, b[i, j], int(a[i, j]), int(o[i, j]), on_zero="ninf")
            torch.testing.assert_close(r.belief[i, j], ri.belief)
            torch.testing.assert_close(r.log_normalizer[i, j], ri.log_normalizer)
            torch.testing.assert_close(lr.log_normalizer[i, j], ri.log_normalizer)
    torch.testing.assert_close(predict(m, b, a)[1, 2], b[1, 2] @ m.T[a[1, 2]])


@pytest.mark.parametrize("batch", BATCHES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_update_all_equals_single_updates(batch, dtype):
    S, A, O = 4, 3, 2
    m = random_pomdp(S, A, O, dtype=dtype, seed=6)  # model unbatched, beliefs batched
    b = random_belief((*batch, S), dtype=dtype, seed=7)
    r = update_all(m, b)
    assert r.belief.shape == (*batch, A, O, S) and r.log_normalizer.shape == (*batch, A, O)
    total = r.log_normalizer.exp().sum(-1)  # sum_o P(o | b, a) = 1
    torch.testing.assert_close(total, torch.ones_like(total), **_tol(dtype))
    for a in range(A):
        for o in range(O):
            ri = update(m, b, a, o)
            torch.testing.assert_close(r.belief[..., a, o, :], ri.belief, **_tol(dtype))
            torch.testing.assert_close(
                r.log_normalizer[..., a, o], ri.log_normalizer, **_tol(dtype)
            )
    lr = log_update_all(m, b.log())
    torch.testing.assert_close(lr.belief.exp(), r.belief, **_tol(dtype))
    torch.testing.assert_close(lr.log_normalizer, r.log_normalizer, **_tol(dtype))


@pytest.mark.parametrize("batch", BATCHES)
def test_log_update_equals_update(batch):
    m = random_pomdp(6, 2, 3, batch_shape=batch, seed=8)
    b = random_belief((*batch, 6), seed=9)
    a = torch.zeros(batch, dtype=torch.long) + 1
    r = update(m, b, a, 2)
    lr = log_update(m, b.log(), a, 2)
    torch.testing.assert_close(lr.belief.exp(), r.belief)
    torch.testing.assert_close(lr.log_normalizer, r.log_normalizer)


def test_log_update_keeps_mass_that_underflows_in_probability_space():
    m = tiger()
    # belief (1, e^-1000): in probability space the second entry is exactly 0.
    log_b = torch.tensor([0.0, -1000.0], dtype=torch.float64)
    r = log_update(m, log_b, 0, 1)  # hear tiger-right
    expected_gap = math.log(0.85 / 0.15) - 1000.0
    assert torch.isfinite(r.belief).all()
    assert (r.belief[1] - r.belief[0]).item() == pytest.approx(expected_gap)
    assert r.log_normalizer.item() == pytest.approx(math.log(0.15), rel=1e-9)


# ----------------------------------------------------------------------------- MOMDP


@pytest.mark.parametrize("static", [True, False])
@pytest.mark.parametrize("batch", BATCHES)
def test_momdp_update_equals_flat_update_through_to_pomdp(static, batch):
    X, Y, A, O = 3, 4, 2, 3
    m = random_momdp(X, Y, A, O, static=static, batch_shape=batch, seed=10)
    flat = m.to_pomdp()
    g = torch.Generator().manual_seed(11)
    x = torch.randint(X, batch, generator=g)
    a = torch.randint(A, batch, generator=g)
    x2 = torch.randint(X, batch, generator=g)
    o = torch.randint(O, batch, generator=g)
    by = random_belief((*batch, Y), seed=12)
    r = momdp_update(m, x, by, a, x2, o)
    onehot = torch.nn.functional.one_hot(x, X).to(by.dtype)
    b_flat = (onehot.unsqueeze(-1) * by.unsqueeze(-2)).reshape(*batch, X * Y)
    rf = update(flat, b_flat, a, x2 * O + o)
    bf = rf.belief.reshape(*batch, X, Y)
    torch.testing.assert_close(
        bf.gather(-2, x2[..., None, None].expand(*batch, 1, Y)).squeeze(-2), r.belief
    )
    torch.testing.assert_close(rf.log_normalizer, r.log_normalizer)
    torch.testing.assert_close(r.belief.sum(-1), torch.ones(batch, dtype=torch.float64))
    lr = momdp_log_update(m, x, by.log(), a, x2, o)
    torch.testing.assert_close(lr.belief.exp(), r.belief)
    torch.testing.assert_close(lr.log_normalizer, r.log_normalizer)


@pytest.mark.parametrize("static", [True, False])
@pytest.mark.parametrize("dtype", DTYPES)
def test_momdp_update_all_equals_loop(static, dtype):
    X, Y, A, O = 3, 2, 2, 2
    m = random_momdp(X, Y, A, O, static=static, dtype=dtype, seed=13)
    by = random_belief((2, Y), dtype=dtype, seed=14)
    x = torch.tensor([0, 2])
    r = momdp_update_all(m, x, by)
    assert r.belief.shape == (2, A, X, O, Y)
    total = r.log_normalizer.exp().sum((-2, -1))
    torch.testing.assert_close(total, torch.ones_like(total), **_tol(dtype))
    lr = momdp_log_update_all(m, x, by.log())
    torch.testing.assert_close(lr.belief.exp(), r.belief, **_tol(dtype))
    for a in range(A):
        for x2 in range(X):
            for o in range(O):
                ri = momdp_update(m, x, by, a, x2, o)
                torch.testing.assert_close(r.belief[:, a, x2, o], ri.belief, **_tol(dtype))
                torch.testing.assert_close(
                    r.log_normalizer[:, a, x2, o], ri.log_normalizer, **_tol(dtype)
                )


def test_momdp_static_fast_path_equals_identity_ty():
    m = random_momdp(3, 4, 2, 2, static=True, seed=15)
    dense = MOMDP(
        Tx=m.Tx, Ty=m.hidden_transition().contiguous(), Z=m.Z, R=m.R, x0=0, b0=m.b0, discount=0.9
    )
    for args in [(0, m.b0, 1, 2, 0), (2, m.b0, 0, 1, 1)]:
        torch.testing.assert_close(momdp_update(m, *args).belief, momdp_update(dense, *args).belief)
    torch.testing.assert_close(
        momdp_update_all(m, 1, m.b0).belief, momdp_update_all(dense, 1, m.b0).belief
    )


def test_momdp_predict_sums_to_probability_of_x_next():
    m = random_momdp(3, 4, 2, 2, static=False, seed=16)
    pred = momdp_predict(m, 1, m.b0, 0, 2)
    expected = (m.Tx[0, 1, :, 2] * m.b0).sum()
    torch.testing.assert_close(pred.sum(), expected)


# ----------------------------------------------------------------------------- zero probability


def _impossible_tiger() -> POMDP:
    m = tiger()
    Z = m.Z.clone()
    Z[0] = torch.eye(2, dtype=torch.float64)  # a perfect sensor
    return POMDP(T=m.T, Z=Z, R=m.R, b0=m.b0, discount=m.discount)


def test_zero_probability_observation_raises_naming_action_and_observation():
    m = _impossible_tiger()
    b = torch.tensor([1.0, 0.0], dtype=torch.float64)
    with pytest.raises(ModelError, match=r"action=0.*observation=1"):
        update(m, b, 0, 1)
    with pytest.raises(ModelError, match="observation"):
        log_update(m, b.log(), 0, 1)
    with pytest.raises(ModelError, match="probability zero"):
        update_all(m, b, on_zero="raise")


def test_zero_probability_observation_ninf_gives_no_nan_values_or_gradients():
    m = _impossible_tiger()
    b = torch.tensor([1.0, 0.0], dtype=torch.float64, requires_grad=True)
    r = update(m, b, torch.tensor([0, 0]), torch.tensor([0, 1]), on_zero="ninf")
    assert r.log_normalizer[0].item() == 0.0 and r.log_normalizer[1].item() == -math.inf
    torch.testing.assert_close(r.belief[1], torch.full((2,), 0.5, dtype=torch.float64))
    (r.belief.sum() + r.log_normalizer[0]).backward()
    assert torch.isfinite(b.grad).all()
    lb = b.detach().log().requires_grad_(True)
    lr = log_update(m, lb, torch.tensor([0, 0]), torch.tensor([0, 1]), on_zero="ninf")
    assert lr.log_normalizer[1].item() == -math.inf and not torch.isnan(lr.belief).any()
    lr.belief[0, 0].backward()
    assert not torch.isnan(lb.grad).any()
    ra = update_all(m, b.detach())
    assert torch.isneginf(ra.log_normalizer[0, 1]) and not torch.isnan(ra.belief).any()


def test_momdp_zero_probability_raises_and_ninf():
    m = random_momdp(2, 2, 1, 2, seed=17)
    Tx = torch.zeros_like(m.Tx)
    Tx[..., 0] = 1.0  # x always goes to 0
    m = MOMDP(Tx=Tx, Ty=None, Z=m.Z, R=m.R, x0=0, b0=m.b0, discount=0.9)
    with pytest.raises(ModelError, match=r"x_next=1"):
        momdp_update(m, 0, m.b0, 0, 1, 0)
    r = momdp_update(m, 0, m.b0, 0, 1, 0, on_zero="ninf")
    assert r.log_normalizer.item() == -math.inf and torch.isfinite(r.belief).all()


def test_log_matmul_exp_handles_all_neg_inf_rows():
    x = torch.tensor(
        [[0.0, -math.inf], [-math.inf, -math.inf]], dtype=torch.float64, requires_grad=True
    )
    y = torch.tensor([[1.0], [-math.inf]], dtype=torch.float64, requires_grad=True)
    out = log_matmul_exp(x, y)
    assert out[0, 0].item() == pytest.approx(1.0) and out[1, 0].item() == -math.inf
    out[0, 0].backward()
    assert not torch.isnan(x.grad).any() and not torch.isnan(y.grad).any()
    a = torch.randn(3, 4, dtype=torch.float64)
    b = torch.randn(4, 2, dtype=torch.float64)
    torch.testing.assert_close(log_matmul_exp(a, b), (a.exp() @ b.exp()).log())


# ----------------------------------------------------------------------------- gradients


def test_gradcheck_flat_update_wrt_belief_and_model():
    m = random_pomdp(3, 2, 2, seed=18)
    b = random_belief((2, 3), seed=19).requires_grad_(True)
    T = m.T.clone().requires_grad_(True)
    Z = m.Z.clone().requires_grad_(True)
    a, o = torch.tensor([0, 1]), torch.tensor([1, 1])

    def f(b, T, Z):
        model = POMDP(T=T, Z=Z, R=m.R, b0=m.b0, discount=0.9, validate_probabilities=False)
        r = update(model, b, a, o)
        lr = log_update(model, b.log(), a, o)
        ra = update_all(model, b)
        return r.belief, r.log_normalizer, lr.belief, ra.belief, ra.log_normalizer

    assert torch.autograd.gradcheck(f, (b, T, Z))


@pytest.mark.parametrize("static", [True, False])
def test_gradcheck_momdp_update_wrt_belief_and_model(static):
    m = random_momdp(2, 3, 2, 2, static=static, seed=20)
    by = random_belief((2, 3), seed=21).requires_grad_(True)
    Tx = m.Tx.clone().requires_grad_(True)
    Z = m.Z.clone().requires_grad_(True)
    Ty = None if static else m.Ty.clone().requires_grad_(True)
    x, a, x2, o = torch.tensor([0, 1]), torch.tensor([1, 0]), torch.tensor([1, 1]), 0

    def f(by, Tx, Z, *rest):
        model = MOMDP(
            Tx=Tx,
            Ty=rest[0] if rest else None,
            Z=Z,
            R=m.R,
            x0=0,
            b0=m.b0,
            discount=0.9,
            validate_probabilities=False,
        )
        r = momdp_update(model, x, by, a, x2, o)
        lr = momdp_log_update(model, x, by.log(), a, x2, o)
        ra = momdp_update_all(model, x, by)
        return r.belief, r.log_normalizer, lr.belief, ra.belief

    inputs = (by, Tx, Z) if static else (by, Tx, Z, Ty)
    assert torch.autograd.gradcheck(f, inputs)


# ----------------------------------------------------------------------------- validation


def test_bad_inputs_raise_clear_errors():
    m = tiger()
    with pytest.raises(ModelError, match=r"action in \[0, 3\), got 3"):
        update(m, m.b0, 3, 0)
    with pytest.raises(ModelError, match=r"observation in \[0, 2\), got -1"):
        update(m, m.b0, 0, torch.tensor([0, -1]))
    with pytest.raises(TypeError, match="action"):
        update(m, m.b0, torch.tensor(0.0), 0)
    with pytest.raises(TypeError, match="observation"):
        update(m, m.b0, 0, 1.0)  # a float is not an index, even a whole one
    # NumPy integers are indices (as in the Controller): the same belief as Python ints
    torch.testing.assert_close(update(m, m.b0, np.int64(0), np.int32(1)), update(m, m.b0, 0, 1))
    with pytest.raises(ModelError, match=r"belief.*last dim 2"):
        update(m, torch.ones(3, dtype=torch.float64) / 3, 0, 0)
    with pytest.raises(TypeError, match="model"):
        update(m.T, m.b0, 0, 0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="on_zero"):
        update(m, m.b0, 0, 0, on_zero="nan")  # type: ignore[arg-type]
    mm = random_momdp(2, 2, 1, 1, seed=0)
    with pytest.raises(ModelError, match="x_next"):
        momdp_update(mm, 0, mm.b0, 0, 2, 0)
    with pytest.raises(ModelError, match="predicted"):
        momdp_correct(mm, torch.ones(3, dtype=torch.float64), 0, 0, 0)
