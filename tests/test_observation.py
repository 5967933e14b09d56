"""Tests of torchhrc.observation: exact cell masses, gradients, the track likelihood, learning."""

from __future__ import annotations

import math

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.observation import (
    DiscretizedGaussianObservation,
    HandTracks,
    ObservationGrid,
    bivariate_normal_cdf,
    discretize_positions,
    discretized_gaussian,
    fit_observation_model,
    log_discretized_gaussian,
    sample_positions,
    simulate_tracks,
    track_log_likelihood,
)
from torchhrc.pomdp import MOMDP

D = torch.float64


def _grid(gx: int = 5, gy: int = 4) -> ObservationGrid:
    return ObservationGrid.uniform((-1.0, 1.0), (-0.5, 1.5), (gx, gy))


def _brute_force_mass(mean, cov, lo, hi, n=800):
    """Midpoint-rule integral of the density over [lo, hi] (2D); the reference."""
    xs = lo[0] + (torch.arange(n, dtype=D) + 0.5) * (hi[0] - lo[0]) / n
    ys = lo[1] + (torch.arange(n, dtype=D) + 0.5) * (hi[1] - lo[1]) / n
    pts = torch.stack(torch.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    dens = torch.distributions.MultivariateNormal(mean, cov).log_prob(pts).exp()
    return float(dens.sum() * (hi[0] - lo[0]) * (hi[1] - lo[1]) / n**2)


# ------------------------------------------------------------------------- the grid
def test_grid_indexing_and_centres():
    g = ObservationGrid.uniform((0.0, 2.0), (0.0, 3.0), (2, 3))
    assert g.shape == (2, 3) and g.num_cells == 6
    # cell (1, 2) -> index 5, centre (1.5, 2.5)
    assert g.cell_centers()[5].tolist() == [1.5, 2.5]
    pts = torch.tensor([[0.5, 0.5], [1.5, 2.5], [-10.0, 10.0], [10.0, -10.0], [1.0, 1.0]])
    # the outer cells absorb everything outside; an edge belongs to the cell above it
    assert discretize_positions(g, pts).tolist() == [0, 5, 2, 3, 4]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"x_edges": torch.tensor([0.0, 0.0, 1.0]), "y_edges": torch.tensor([0.0, 1.0])},
        {"x_edges": torch.tensor([0.0]), "y_edges": torch.tensor([0.0, 1.0])},
        {"x_edges": torch.tensor([0.0, math.inf]), "y_edges": torch.tensor([0.0, 1.0])},
    ],
)
def test_grid_rejects_bad_edges(kwargs):
    with pytest.raises(ModelError, match="edges"):
        ObservationGrid(**kwargs)


# ----------------------------------------------------------------- exact masses
def test_bivariate_cdf_matches_scipy():
    stats = pytest.importorskip("scipy.stats")
    gen = torch.Generator().manual_seed(0)
    h = torch.randn(25, generator=gen, dtype=D) * 2
    k = torch.randn(25, generator=gen, dtype=D) * 2
    for rho in (-0.95, -0.3, 0.0, 0.6, 0.99, 0.999):
        got = bivariate_normal_cdf(h, k, torch.tensor(rho, dtype=D))
        ref = [
            stats.multivariate_normal(mean=[0, 0], cov=[[1, rho], [rho, 1]]).cdf([a, b])
            for a, b in zip(h.tolist(), k.tolist())
        ]
        assert torch.allclose(got, torch.tensor(ref, dtype=D), atol=1e-7, rtol=0)
    # worked by hand: Phi2(0, 0; rho) = 1/4 + asin(rho) / (2 pi)
    z = torch.zeros((), dtype=D)
    r = torch.tensor(0.3, dtype=D)
    assert bivariate_normal_cdf(z, z, r).item() == pytest.approx(
        0.25 + math.asin(0.3) / (2 * math.pi), abs=1e-14
    )


@pytest.mark.parametrize("rho", [None, 0.0, 0.7, -0.5])
def test_cell_masses_equal_brute_force_integration(rho):
    g = _grid()
    mean = torch.tensor([0.1, 0.4], dtype=D)
    scale = torch.tensor([0.5, 0.35], dtype=D)
    r = None if rho is None else torch.tensor(rho, dtype=D)
    p = discretized_gaussian(g, mean, scale=scale, correlation=r).reshape(5, 4)
    c = 0.0 if rho is None else rho
    cov = torch.tensor([[0.25, c * 0.5 * 0.35], [c * 0.5 * 0.35, 0.35**2]], dtype=D)
    for i, j in [(1, 1), (2, 2), (3, 1), (1, 2)]:  # interior cells
        lo = (g.x_edges[i].item(), g.y_edges[j].item())
        hi = (g.x_edges[i + 1].item(), g.y_edges[j + 1].item())
        ref = _brute_force_mass(mean, cov, lo, hi)
        assert p[i, j].item() == pytest.approx(ref, abs=2e-6)
    # an outer cell: the corner (0, 0) takes everything below x_edges[1] and y_edges[1]
    # (the integral from 10 standard deviations below the mean, where the rest is < 1e-22;
    # deterministic, no sampling)
    lo = (mean[0].item() - 10 * 0.5, mean[1].item() - 10 * 0.35)
    hi = (g.x_edges[1].item(), g.y_edges[1].item())
    ref = _brute_force_mass(mean, cov, lo, hi, n=1600)
    assert p[0, 0].item() == pytest.approx(ref, abs=1e-6)
    # and it is more than the cell's own square: the grid's outer cells are unbounded
    inner = _brute_force_mass(mean, cov, (g.x_edges[0].item(), g.y_edges[0].item()), hi)
    assert p[0, 0].item() > inner + 1e-5  # 4e-5 to 0.013 more here


def test_full_covariance_path_with_zero_correlation_equals_diagonal_path():
    g = _grid(6, 7)
    gen = torch.Generator().manual_seed(1)
    mean = torch.randn(3, 2, generator=gen, dtype=D)
    scale = torch.rand(3, 2, generator=gen, dtype=D) + 0.2
    diag = discretized_gaussian(g, mean, scale=scale)
    full = discretized_gaussian(g, mean, scale=scale, correlation=torch.zeros(3, dtype=D))
    assert torch.allclose(diag, full, atol=1e-13)


@pytest.mark.parametrize("batch", [(), (2,), (2, 3)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("correlated", [False, True])
def test_rows_sum_to_one_and_batched_equals_loop(batch, dtype, correlated):
    g = _grid()
    gen = torch.Generator().manual_seed(2)
    mean = torch.randn(*batch, 2, generator=gen).to(dtype) * 0.5
    scale = (torch.rand(*batch, 2, generator=gen) + 0.1).to(dtype)
    rho = (torch.rand(batch, generator=gen) * 1.6 - 0.8).to(dtype) if correlated else None
    p = discretized_gaussian(g, mean, scale=scale, correlation=rho)
    assert p.shape == (*batch, 20) and p.dtype == dtype
    assert (p >= 0).all()
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert torch.allclose(p.sum(-1), torch.ones((), dtype=dtype), atol=tol)
    flat_m, flat_s = mean.reshape(-1, 2), scale.reshape(-1, 2)
    flat_r = None if rho is None else rho.reshape(-1)
    for n in range(flat_m.shape[0]):
        one = discretized_gaussian(
            g, flat_m[n], scale=flat_s[n], correlation=None if flat_r is None else flat_r[n]
        )
        assert torch.allclose(p.reshape(-1, 20)[n], one, atol=tol)


def test_covariance_argument_equals_scale_and_correlation():
    g = _grid()
    cov = torch.tensor([[0.3, 0.1], [0.1, 0.2]], dtype=D)
    a = discretized_gaussian(g, torch.zeros(2, dtype=D), covariance=cov)
    s = cov.diagonal().sqrt()
    b = discretized_gaussian(
        g, torch.zeros(2, dtype=D), scale=s, correlation=cov[0, 1] / (s[0] * s[1])
    )
    assert torch.allclose(a, b, atol=1e-14)


def test_log_masses_stay_finite_far_in_the_tail():
    g = _grid()
    # mean 60 standard deviations away: the far cells have mass ~exp(-1800), their logs finite
    lp = log_discretized_gaussian(
        g, torch.tensor([7.0, 0.0], dtype=D), scale=torch.full((2,), 0.1, dtype=D)
    )
    assert torch.isfinite(lp).all()
    assert lp.reshape(5, 4)[-1].logsumexp(-1).item() == pytest.approx(0.0, abs=1e-12)
    # worked by hand along the first axis: cell (0, j) needs x < -0.6, 76 std below the mean
    expected = torch.special.log_ndtr(torch.tensor((-0.6 - 7.0) / 0.1, dtype=D))
    assert lp.reshape(5, 4)[0].logsumexp(-1).item() == pytest.approx(expected.item(), rel=1e-10)


def test_bad_parameters_are_rejected():
    g = _grid()
    with pytest.raises(ModelError, match="scale > 0"):
        discretized_gaussian(g, torch.zeros(2), scale=torch.tensor([1.0, 0.0]))
    with pytest.raises(ModelError, match="correlation in"):
        discretized_gaussian(g, torch.zeros(2), scale=torch.ones(2), correlation=torch.tensor(1.0))
    with pytest.raises(ModelError, match=r"\(\.\.\., 2\)"):
        discretized_gaussian(g, torch.zeros(3), scale=torch.ones(2))
    with pytest.raises(ModelError, match="not both"):
        discretized_gaussian(g, torch.zeros(2), scale=torch.ones(2), covariance=torch.eye(2))
    with pytest.raises(TypeError, match="mean"):
        discretized_gaussian(g, [0.0, 0.0], scale=torch.ones(2))  # type: ignore[arg-type]


# ------------------------------------------------------------------------- gradients
@pytest.mark.parametrize("correlated", [False, True])
def test_gradcheck_masses(correlated):
    g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (3, 3))
    mean = torch.tensor([[0.2, -0.1], [-0.4, 0.3]], dtype=D, requires_grad=True)
    log_scale = torch.tensor([[-0.5, -0.2], [0.1, -0.7]], dtype=D, requires_grad=True)
    rho = torch.tensor([0.4, -0.6], dtype=D, requires_grad=True)

    def f(m, ls, r):
        return discretized_gaussian(g, m, scale=ls.exp(), correlation=r if correlated else None)

    assert torch.autograd.gradcheck(f, (mean, log_scale, rho), atol=1e-7)


def test_gradcheck_module_parameters_through_the_track_likelihood():
    g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (3, 3))
    m = DiscretizedGaussianObservation(
        g,
        torch.tensor([[-0.3, 0.0], [0.3, 0.1]], dtype=D),
        torch.tensor([0.4, 0.5], dtype=D),
        correlation=torch.tensor([0.2, -0.1], dtype=D),
        num_observed=2,
        num_hidden=2,
    )
    Tx = torch.full((1, 2, 2, 2), 0.5, dtype=D)
    t = simulate_tracks(m, Tx, num_tracks=3, length=4, seed=1)

    def f(loc, log_scale, raw):
        with torch.no_grad():
            m.loc.copy_(loc)
            m.log_scale.copy_(log_scale)
            m.raw_correlation.copy_(raw)
        # functional re-evaluation with the given tensors
        mean = m.offset + loc
        rho = m.max_correlation * torch.tanh(raw)
        z = discretized_gaussian(
            m.grid,
            mean.expand(2, 2, 2),
            scale=log_scale.exp().expand(2, 2, 2),
            correlation=rho.expand(2, 2),
        )
        return track_log_likelihood(z, Tx, t)

    args = (
        m.loc.detach().clone().requires_grad_(),
        m.log_scale.detach().clone().requires_grad_(),
        m.raw_correlation.detach().clone().requires_grad_(),
    )
    assert torch.autograd.gradcheck(f, args, atol=1e-7)


# ---------------------------------------------------------------------- the module
def test_module_produces_a_valid_momdp_observation_tensor():
    g = _grid()
    X, Y, A = 4, 2, 3
    offset = torch.linspace(-0.5, 0.5, X, dtype=D).view(X, 1, 1) * torch.tensor([1.0, 0.0], dtype=D)
    m = DiscretizedGaussianObservation(
        g,
        torch.tensor([[-0.2, 0.3], [0.2, 0.6]], dtype=D),  # (Y, 2): one learnable mean per type
        torch.tensor([0.3, 0.25], dtype=D),
        offset=offset,
        num_observed=X,
        num_hidden=Y,
        num_actions=A,
    )
    Z = m()
    assert Z.shape == (A, X, Y, 20)
    assert torch.allclose(Z.sum(-1), torch.ones((), dtype=D), atol=1e-12)
    # the module equals the functional form for every (x, y)
    for x in range(X):
        for y in range(Y):
            ref = discretized_gaussian(g, offset[x, 0] + m.loc[y], scale=m.scale()[x, y])
            assert torch.allclose(Z[1, x, y], ref, atol=1e-14)
    mo = MOMDP(
        Tx=torch.full((A, X, Y, X), 1.0 / X, dtype=D),
        Ty=None,
        Z=Z,
        R=torch.zeros(A, X, Y, dtype=D),
        x0=0,
        b0=torch.full((Y,), 0.5, dtype=D),
        discount=0.9,
    )
    assert mo.num_observations == 20
    cov = m.covariance()
    assert cov.shape == (X, Y, 2, 2) and torch.allclose(cov[0, 1], torch.diag(m.scale()[0, 1] ** 2))


def test_module_rejects_bad_arguments():
    g = _grid()
    with pytest.raises(ModelError, match="broadcast"):
        DiscretizedGaussianObservation(
            g, torch.zeros(3, 2), torch.ones(2), num_observed=4, num_hidden=2
        )
    with pytest.raises(ModelError, match="scale > 0"):
        DiscretizedGaussianObservation(
            g, torch.zeros(2), -torch.ones(2), num_observed=1, num_hidden=1
        )
    with pytest.raises(ModelError, match="max_correlation"):
        DiscretizedGaussianObservation(
            g,
            torch.zeros(2),
            torch.ones(2),
            num_observed=1,
            num_hidden=1,
            correlation=torch.tensor(0.995),
        )


def test_sampling_is_seeded_and_matches_the_cell_masses():
    g = _grid()
    mean = torch.tensor([0.2, 0.5], dtype=D)
    scale = torch.tensor([0.4, 0.3], dtype=D)
    rho = torch.tensor(0.5, dtype=D)
    a = sample_positions(mean, scale=scale, correlation=rho, num_samples=200_000, seed=3)
    b = sample_positions(mean, scale=scale, correlation=rho, num_samples=200_000, seed=3)
    assert torch.equal(a, b)
    freq = torch.bincount(discretize_positions(g, a), minlength=20).double() / a.shape[0]
    p = discretized_gaussian(g, mean, scale=scale, correlation=rho)
    # binomial standard error <= sqrt(0.25 / 2e5) ~ 1.1e-3; 5 sigma
    assert torch.allclose(freq, p, atol=5.6e-3)
    emp_cov = torch.cov(a.T)
    assert torch.allclose(emp_cov[0, 1], rho * 0.4 * 0.3, atol=3e-3)


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
    pytest.importorskip("torchhrc.belief")
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
