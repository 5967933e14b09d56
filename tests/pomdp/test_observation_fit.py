"""Tests of torchhrc.pomdp.observation_fit: the track likelihood, learning, simulated tracks."""

from __future__ import annotations

import math

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.observation import (
    DiscretizedGaussianObservation,
    ObservationGrid,
)
from torchhrc.pomdp.observation_fit import (
    HandTracks,
    fit_observation_model,
    simulate_tracks,
    track_log_likelihood,
)

D = torch.float64


def _grid(gx: int = 5, gy: int = 4) -> ObservationGrid:
    return ObservationGrid.uniform((-1.0, 1.0), (-0.5, 1.5), (gx, gy))


# --------------------------------------------------------------- track likelihood
def _small_problem(seed=0):
    g = _grid(6, 6)
    X, Y, A = 3, 2, 2
    gen = torch.Generator().manual_seed(seed)
    Tx = torch.rand(A, X, Y, X, generator=gen, dtype=D) + 0.1
    Tx = Tx / Tx.sum(-1, keepdim=True)
    m = DiscretizedGaussianObservation(
        g,
        torch.tensor([[[-0.5, 0.2]], [[0.0, 0.9]], [[0.5, 0.4]]], dtype=D)
        + torch.tensor([[-0.2, 0.0], [0.2, 0.0]], dtype=D),  # (X, Y, 2)
        torch.tensor([[0.25, 0.3], [0.4, 0.2]], dtype=D),  # (Y, 2)
        num_observed=X,
        num_hidden=Y,
    )
    return g, Tx, m


def test_track_likelihood_equals_brute_force_enumeration():
    _, Tx, m = _small_problem()
    t = simulate_tracks(m, Tx, num_tracks=5, length=6, seed=0)
    t = HandTracks(t.observed, t.actions, t.cells, torch.tensor([6, 3, 1, 6, 4]))
    b0 = torch.tensor([0.3, 0.7], dtype=D)
    Z = m().detach()
    got = track_log_likelihood(Z, Tx, t, b0=b0)
    for n in range(5):
        total = 0.0
        for y in range(2):
            p = b0[y].item()
            for s in range(int(t.lengths[n])):
                a, x, x2, o = (
                    int(v)
                    for v in (
                        t.actions[n, s],
                        t.observed[n, s],
                        t.observed[n, s + 1],
                        t.cells[n, s],
                    )
                )
                p *= Tx[a, x, y, x2].item() * Z[0, x2, y, o].item()
            total += p
        assert got[n].item() == pytest.approx(math.log(total), rel=1e-12)


def test_static_closed_form_equals_the_belief_filter():
    pytest.importorskip("torchhrc.pomdp.belief")
    _, Tx, m = _small_problem(1)
    t = simulate_tracks(m, Tx, num_tracks=6, length=5, seed=2)
    t = HandTracks(t.observed, t.actions, t.cells, torch.tensor([5, 2, 5, 1, 3, 4]))
    eye = torch.eye(2, dtype=D).view(1, 1, 2, 1, 2).expand(2, 3, 2, 3, 2)
    Z = m()
    closed = track_log_likelihood(Z, Tx, t)
    filtered = track_log_likelihood(Z, Tx, t, Ty=eye)
    assert torch.allclose(closed, filtered, atol=1e-11)
    # and the gradients agree
    g1 = torch.autograd.grad(closed.sum(), m.loc, retain_graph=True)[0]
    g2 = torch.autograd.grad(filtered.sum(), m.loc)[0]
    assert torch.allclose(g1, g2, atol=1e-10)


def test_tracks_are_validated():
    with pytest.raises(ModelError, match=r"observed to have shape \(N, L \+ 1\)"):
        HandTracks(
            torch.zeros(2, 3, dtype=torch.long),
            torch.zeros(2, 3, dtype=torch.long),
            torch.zeros(2, 3, dtype=torch.long),
            torch.tensor([3, 3]),
        )
    with pytest.raises(ModelError, match="lengths in"):
        HandTracks(
            torch.zeros(1, 3, dtype=torch.long),
            torch.zeros(1, 2, dtype=torch.long),
            torch.zeros(1, 2, dtype=torch.long),
            torch.tensor([0]),
        )
    _, Tx, m = _small_problem()
    t = HandTracks(
        torch.zeros(1, 2, dtype=torch.long),
        torch.zeros(1, 1, dtype=torch.long),
        torch.tensor([[99]]),
        torch.tensor([1]),
    )
    with pytest.raises(ModelError, match="cells in"):
        track_log_likelihood(m(), Tx, t)


# ------------------------------------------------------------------------ learning
def test_fit_recovers_the_generating_means_and_scales():
    _, Tx, true = _small_problem()
    # ~670 hand positions per (x, y): standard error of a mean <= 0.4 / sqrt(670) ~ 0.016
    tracks = simulate_tracks(true, Tx, num_tracks=400, length=10, seed=4)
    model = DiscretizedGaussianObservation(
        true.grid,
        true.loc.detach() + torch.tensor([[0.15, -0.1], [-0.1, 0.15]], dtype=D),
        torch.full((2, 2), 0.5, dtype=D),
        num_observed=3,
        num_hidden=2,
    )
    seen = []
    fit = fit_observation_model(
        model,
        Tx,
        tracks,
        optimizer="lbfgs",
        lr=1.0,
        steps=30,
        callback=lambda step, ll: seen.append((step, ll)),
    )
    assert fit.log_likelihood > fit.initial_log_likelihood
    assert all(b >= a - 1e-9 for a, b in zip(fit.history, fit.history[1:]))  # L-BFGS ascends
    assert len(seen) == fit.steps
    true_ll = track_log_likelihood(true(), Tx, tracks).sum().item()
    assert fit.log_likelihood >= true_ll - 1e-6  # the maximum is at least the truth's
    assert torch.allclose(model.mean(), true.mean(), atol=0.06)  # ~4 standard errors
    assert torch.allclose(model.scale(), true.scale(), rtol=0.12)


def test_fit_recovers_a_correlation():
    g = _grid(8, 8)
    X, Y = 1, 2
    Tx = torch.ones(1, X, Y, X, dtype=D)
    true = DiscretizedGaussianObservation(
        g,
        torch.tensor([[-0.4, 0.3], [0.4, 0.7]], dtype=D),
        torch.tensor([0.35, 0.3], dtype=D),
        correlation=torch.tensor([0.6, -0.5], dtype=D),
        num_observed=X,
        num_hidden=Y,
    )
    tracks = simulate_tracks(true, Tx, num_tracks=120, length=12, seed=5)
    model = DiscretizedGaussianObservation(
        g,
        torch.tensor([[-0.2, 0.5], [0.2, 0.5]], dtype=D),
        torch.tensor([0.5, 0.5], dtype=D),
        correlation=torch.zeros(2, dtype=D),
        num_observed=X,
        num_hidden=Y,
    )
    fit_observation_model(model, Tx, tracks, optimizer="lbfgs", lr=1.0, steps=10)
    # ~720 positions per type: standard error of a correlation ~ (1 - rho^2) / sqrt(720) ~ 0.03
    assert torch.allclose(model.correlation(), true.correlation(), atol=0.1)
    assert torch.allclose(model.mean(), true.mean(), atol=0.06)
    assert torch.allclose(model.scale(), true.scale(), rtol=0.12)


def test_fit_with_adam_minibatches_is_seeded_and_ascends():
    _, Tx, true = _small_problem()
    tracks = simulate_tracks(true, Tx, num_tracks=60, length=8, seed=6)

    def run(seed):
        model = DiscretizedGaussianObservation(
            true.grid,
            true.loc.detach() + 0.1,
            torch.full((2, 2), 0.5, dtype=D),
            num_observed=3,
            num_hidden=2,
        )
        return fit_observation_model(model, Tx, tracks, lr=0.05, steps=8, batch_size=25, seed=seed)

    a, b, c = run(0), run(0), run(1)
    assert a.history == b.history
    assert a.history != c.history  # the seed drives the minibatch order
    assert a.history[-1] > a.history[0]


def test_fit_rejects_bad_settings():
    _, Tx, m = _small_problem()
    t = simulate_tracks(m, Tx, num_tracks=2, length=2, seed=0)
    with pytest.raises(ModelError, match="optimizer"):
        fit_observation_model(m, Tx, t, optimizer="sgd")
    with pytest.raises(ModelError, match="steps"):
        fit_observation_model(m, Tx, t, steps=0)


def test_simulate_tracks_of_a_random_start_needs_x0():
    _, Tx, m = _small_problem()
    A, X, Y = Tx.shape[-4], Tx.shape[-3], Tx.shape[-2]
    joint = torch.full((X, Y), 1.0 / (X * Y), dtype=D)
    model = MOMDP(Tx=Tx, Ty=None, Z=torch.full((A, X, Y, 2), 0.5, dtype=D),
                  R=torch.zeros(A, X, Y, dtype=D), x0=0,
                  b0=torch.full((Y,), 1.0 / Y, dtype=D), discount=0.9, initial=joint)  # fmt: skip
    with pytest.raises(ValueError, match="pass x0"):
        simulate_tracks(m, model, num_tracks=2, length=3, seed=0)
    t = simulate_tracks(m, model, num_tracks=2, length=3, seed=0, x0=1)
    assert t.observed[:, 0].tolist() == [1, 1]
