"""Tests of torchhrc.pomdp.approach_observation (a hand that approaches its target)."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.approach_observation import (
    ApproachObservation,
    approach_log_likelihood,
    fit_approach_observation,
)
from torchhrc.pomdp.observation import DiscretizedGaussianObservation, ObservationGrid
from torchhrc.pomdp.observation_fit import track_log_likelihood
from torchhrc.tasks.hand_finishing.person import HandMotion, simulate_hand_tracks
from torchhrc.testing import random_momdp

GRID = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (5, 5))


def _setup(seed: int = 0, approach: float = 0.6):
    """A random 4-state, 2-type, 2-action MOMDP whose hand targets differ by type."""
    m = random_momdp(4, 2, 2, 25, seed=seed)
    offset = torch.tensor([[-0.5, 0.4], [0.5, -0.4]], dtype=torch.float64).expand(4, 2, 2)
    offset = offset + torch.linspace(-0.2, 0.2, 4, dtype=torch.float64).view(4, 1, 1)
    person = DiscretizedGaussianObservation(
        GRID, torch.zeros(2, dtype=torch.float64), torch.full((2,), 0.3, dtype=torch.float64),
        num_observed=4, num_hidden=2, offset=offset, num_actions=2,
    )  # fmt: skip
    truth = MOMDP(Tx=m.Tx, Ty=None, Z=person().detach().contiguous(), R=m.R, x0=0, b0=m.b0,
                  discount=0.9)  # fmt: skip
    motion = HandMotion(approach=approach, start=(0.8, 0.0))
    tracks = simulate_hand_tracks(truth, person, num_tracks=300, length=6, motion=motion,
                                  seed=seed)  # fmt: skip
    return truth, person, offset, tracks


def _model(offset, *, approach=0.5, start=(0.0, 0.0), loc=(0.0, 0.0), scale=0.4):
    stationary = DiscretizedGaussianObservation(
        GRID, torch.tensor(loc, dtype=torch.float64).expand(2, 2).clone(),
        torch.full((2, 2), scale, dtype=torch.float64), num_observed=4, num_hidden=2,
        offset=offset, num_actions=2,
    )  # fmt: skip
    return ApproachObservation(stationary, approach=approach, start=start)


def test_means_follow_the_hand_recursion():
    _truth, _person, offset, tracks = _setup()
    model = _model(offset, approach=0.6, start=(0.8, 0.0))
    means = model.means(tracks.observed)  # (N, L, Y, 2)
    hand = torch.tensor([0.8, 0.0], dtype=torch.float64).expand(tracks.num_tracks, 2, 2)
    for t in range(tracks.observed.shape[1] - 1):  # the recursion, step by step
        hand = hand + 0.6 * (offset[tracks.observed[:, t + 1]] - hand)
        torch.testing.assert_close(means[:, t], hand)


def test_a_hand_at_its_target_is_the_static_model():
    # approach -> 1: the hand is at its target at every step, the static model's likelihood
    truth, _person, offset, tracks = _setup()
    model = _model(offset, approach=1.0 - 1e-12, start=(5.0, 5.0), loc=(0.1, -0.1), scale=0.3)
    static = track_log_likelihood(model.stationary(), truth, tracks)
    torch.testing.assert_close(approach_log_likelihood(model, truth, tracks), static)


def test_filter_normalisers_sum_to_the_likelihood():
    truth, _person, offset, tracks = _setup(seed=1)
    model = _model(offset, approach=0.7, start=(0.5, 0.2), scale=0.35)
    n = tracks.num_tracks
    b = truth.b0.expand(n, 2).clone()
    hands = model.filter_start(n)
    log_lik = torch.zeros(n, dtype=torch.float64)
    for t in range(tracks.observed.shape[1] - 1):
        # the normaliser of step t, recomputed from the filter's prior and posterior
        x, a, x2, o = (tracks.observed[:, t], tracks.actions[:, t], tracks.observed[:, t + 1],
                       tracks.cells[:, t])  # fmt: skip
        new_b, new_hands = model.filter_update(truth, x, b, a, x2, o, hands)
        lik = model.cell_log_probs(new_hands, x2, o).exp() * truth.Tx[a, x, :, x2]
        log_lik += torch.log((b * lik).sum(-1))
        torch.testing.assert_close(new_b, b * lik / (b * lik).sum(-1, keepdim=True))
        b, hands = new_b, new_hands
    with torch.no_grad():
        torch.testing.assert_close(log_lik, approach_log_likelihood(model, truth, tracks))


def test_gradcheck_float64():
    truth, _person, offset, tracks = _setup()
    small = type(tracks)(tracks.observed[:5], tracks.actions[:5], tracks.cells[:5],
                         tracks.lengths[:5])  # fmt: skip
    model = _model(offset, approach=0.6, start=(0.7, 0.1), loc=(0.05, -0.02), scale=0.35)

    def f(raw_a, start, loc, log_scale):
        return approach_log_likelihood(_with(model, raw_a, start, loc, log_scale), truth, small)

    args = tuple(
        p.detach().clone().requires_grad_(True)
        for p in (model.raw_approach, model.start, model.stationary.loc, model.stationary.log_scale)
    )
    assert torch.autograd.gradcheck(f, args)


def _with(model, raw_a, start, loc, log_scale):
    """A copy of ``model`` whose parameters are the given (differentiable) tensors."""
    clone = _model(model.stationary.offset)
    for module, name, value in ((clone, "raw_approach", raw_a), (clone, "start", start),
                                (clone.stationary, "loc", loc),
                                (clone.stationary, "log_scale", log_scale)):  # fmt: skip
        del module._parameters[name]
        setattr(module, name, value)
    return clone


def test_fit_recovers_the_generating_motion():
    truth, _person, offset, tracks = _setup(seed=2, approach=0.6)
    model = _model(offset, approach=0.3, start=(0.0, 0.0), scale=0.5)
    fit = fit_approach_observation(model, truth, tracks, steps=400, lr=0.05)
    # maximum likelihood: at least as likely as the generating parameters
    generating = _model(offset, approach=0.6, start=(0.8, 0.0), scale=0.3)
    with torch.no_grad():
        reference = float(approach_log_likelihood(generating, truth, tracks).sum())
    assert fit.log_likelihood >= reference - 1e-6 * abs(reference)
    assert fit.log_likelihood > fit.initial_log_likelihood
    assert model.approach().item() == pytest.approx(0.6, abs=0.05)
    torch.testing.assert_close(
        model.stationary.scale()[0].detach(),
        torch.full((2, 2), 0.3, dtype=torch.float64),
        atol=0.05,
        rtol=0,
    )


def test_errors():
    _, _, offset, _ = _setup()
    with pytest.raises(ModelError, match=r"approach in \(0, 1\)"):
        _model(offset, approach=1.0)
    with pytest.raises(ModelError, match="start to be two finite numbers"):
        _model(offset, start=(0.0, float("nan")))
    with pytest.raises(TypeError, match="DiscretizedGaussianObservation"):
        ApproachObservation(torch.zeros(2))  # type: ignore[arg-type]
    with pytest.raises(ModelError, match=r"observed of shape \(N, L \+ 1\)"):
        _model(offset).means(torch.zeros(3, 1, dtype=torch.long))
