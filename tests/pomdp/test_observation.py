"""Tests of torchhrc.pomdp.observation: the grid, exact cell masses, gradients, the module."""

from __future__ import annotations

import math

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.observation import (
    DiscretizedGaussianObservation,
    ObservationGrid,
    bivariate_normal_cdf,
    discretize_positions,
    discretized_gaussian,
    log_discretized_gaussian,
    sample_positions,
)
from torchhrc.pomdp.observation_fit import simulate_tracks, track_log_likelihood

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
