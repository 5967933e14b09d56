"""Observation models: a discretized 2D Gaussian over a grid of the horizontal plane.

In the paper's hand-finishing task the robot cannot see the person's type; it sees the
person's hand position in the horizontal plane, and the observation function is "a
discretized 2D-Gaussian, giving the probability of the position of a human hand in the
horizontal plane conditioned on the human preference" (Nikolaidis et al., Evaluation,
"Online estimation of human type"). The paper specifies the mean and variance by hand and
leaves learning them to future work; :func:`fit_observation_model` learns them from recorded
hand tracks by maximising the log marginal likelihood through the MOMDP belief filter.

Grid. An :class:`ObservationGrid` has ``Gx + 1`` increasing edges along the first axis and
``Gy + 1`` along the second; cell ``(i, j)`` is ``[x_edges[i], x_edges[i+1]) x
[y_edges[j], y_edges[j+1])`` and has the flat observation index ``o = i * Gy + j``
(``O = Gx * Gy``). The outermost cells absorb the tails: the first and last edges of each
axis are treated as ``-inf`` and ``+inf`` when computing probabilities (and when locating a
position), so every distribution over cells sums to one.

Cell masses are exact, from the normal CDF over the cell rectangle, not a density at the
cell centre:

* diagonal covariance (``correlation=None``): the rectangle probability is the product of
  two 1D interval probabilities ``Phi((b - m) / s) - Phi((a - m) / s)``, computed in log space
  (``log_ndtr``) with the interval reflected to the lower tail, so that log masses stay
  accurate far in the tails;
* full covariance (a correlation ``rho`` per distribution): by inclusion-exclusion over the
  four corners of the bivariate normal CDF ``Phi2(h, k; rho)``, evaluated with the
  Sheppard/Drezner-Wesolowsky integral
  ``Phi2(h, k; rho) = Phi(h) Phi(k) + 1/(2 pi) int_0^asin(rho) exp(-(h^2 + k^2 - 2 h k sin t)
  / (2 cos^2 t)) dt`` (Drezner & Wesolowsky 1990; Genz 2004, Stat. Comput. 14:251) by
  48-point Gauss-Legendre quadrature, differentiable in ``h``, ``k`` and ``rho``. Each cell is
  first reflected into the lower-left quadrant of its standardised coordinates (``u -> -u``
  flips the sign of ``rho``) to limit cancellation. Measured against
  ``scipy.stats.multivariate_normal.cdf``: absolute error below ``1e-11`` for
  ``|rho| <= 0.999``.

Shapes (``...`` are batch dims that broadcast)::

    mean:        (..., 2)       the Gaussian's mean in the plane (same units as the edges)
    scale:       (..., 2)       per-axis standard deviations, > 0
    correlation: (...)          in (-1, 1), or None for a diagonal covariance
    covariance:  (..., 2, 2)    alternative to scale + correlation
    probs:       (..., O)       probs[..., i * Gy + j] = P(hand in cell (i, j))
    positions:   (..., 2)       continuous hand positions; cells (...) int64 indices

For a MOMDP, :class:`DiscretizedGaussianObservation` holds a mean and covariance per
``(x, y)`` (observed state, hidden type) and produces the ``Z: (A, X, Y, O)`` tensor of
:class:`~torchhrc.pomdp.MOMDP`, ``Z[a, x2, y2, o] = P(o | x2, y2)`` (independent of the
action).

Example:
    >>> import torch
    >>> grid = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (4, 4))
    >>> p = discretized_gaussian(grid, torch.zeros(2, dtype=torch.float64), scale=torch.ones(2))
    >>> p.shape, round(p.sum().item(), 12)
    (torch.Size([16]), 1.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from torchhrc._checks import broadcast_shapes, check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP

__all__ = [
    "DiscretizedGaussianObservation",
    "HandTracks",
    "ObservationFit",
    "ObservationGrid",
    "bivariate_normal_cdf",
    "discretize_positions",
    "discretized_gaussian",
    "fit_observation_model",
    "log_discretized_gaussian",
    "sample_positions",
    "simulate_tracks",
    "track_log_likelihood",
]

# Standardised coordinate that stands in for an infinite outer edge: the normal mass beyond
# 40 standard deviations is exp(-800), below every floating-point resolution, while
# log_ndtr(-40) and the quadrature stay finite (no inf * 0 in values or gradients).
_FAR = 40.0
_NODES = 48


def _legendre(dtype: torch.dtype, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    x, w = np.polynomial.legendre.leggauss(_NODES)
    return (
        torch.as_tensor(x, dtype=dtype, device=device),
        torch.as_tensor(w, dtype=dtype, device=device),
    )


# --------------------------------------------------------------------------- the grid
@dataclass(frozen=True)
class ObservationGrid:
    """A rectangular grid of cells in the horizontal plane; the outer cells absorb the tails.

    Args:
        x_edges: ``(Gx + 1,)`` strictly increasing edges along the first axis (``Gx >= 1``).
        y_edges: ``(Gy + 1,)`` strictly increasing edges along the second axis.

    Cell ``(i, j)`` has the flat index ``o = i * Gy + j``. The first and last edge of each
    axis only place the outer cells' centres (for plots); for probabilities they are
    ``-inf`` / ``+inf``.

    Example:
        >>> g = ObservationGrid.uniform((0.0, 1.0), (0.0, 2.0), (2, 4))
        >>> g.shape, g.num_cells, g.cell_centers()[5].tolist()
        ((2, 4), 8, [0.75, 0.75])
    """

    x_edges: torch.Tensor
    y_edges: torch.Tensor

    def __post_init__(self) -> None:
        for name in ("x_edges", "y_edges"):
            e = check_tensor(name, getattr(self, name))
            if e.dim() != 1 or e.shape[0] < 2:
                raise ModelError(
                    f"expected {name} to have shape (G + 1,) with G >= 1, "
                    f"actual shape = {tuple(e.shape)}"
                )
            if not torch.isfinite(e).all():
                raise ModelError(f"expected {name} to be finite, got {e.tolist()}")
            if not (e[1:] > e[:-1]).all():
                raise ModelError(f"expected {name} to be strictly increasing, got {e.tolist()}")

    @classmethod
    def uniform(
        cls,
        x_range: tuple[float, float],
        y_range: tuple[float, float],
        shape: tuple[int, int],
        *,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> ObservationGrid:
        """A grid of ``shape = (Gx, Gy)`` equal cells spanning ``x_range x y_range``."""
        gx, gy = (int(s) for s in shape)
        if gx < 1 or gy < 1:
            raise ModelError(f"expected shape to be two positive ints, got {shape!r}")
        return cls(
            torch.linspace(
                float(x_range[0]), float(x_range[1]), gx + 1, dtype=dtype, device=device
            ),
            torch.linspace(
                float(y_range[0]), float(y_range[1]), gy + 1, dtype=dtype, device=device
            ),
        )

    @property
    def shape(self) -> tuple[int, int]:
        """``(Gx, Gy)``, the number of cells along each axis."""
        return (self.x_edges.shape[0] - 1, self.y_edges.shape[0] - 1)

    @property
    def num_cells(self) -> int:
        """``O = Gx * Gy``."""
        gx, gy = self.shape
        return gx * gy

    def cell_centers(self) -> torch.Tensor:
        """``(O, 2)`` centres of the cells (between the finite edges), in flat order."""
        cx = 0.5 * (self.x_edges[1:] + self.x_edges[:-1])
        cy = 0.5 * (self.y_edges[1:] + self.y_edges[:-1])
        gx, gy = self.shape
        return torch.stack(
            [cx.unsqueeze(-1).expand(gx, gy), cy.unsqueeze(0).expand(gx, gy)], dim=-1
        ).reshape(gx * gy, 2)

    def locate(self, positions: torch.Tensor) -> torch.Tensor:
        """The cell index ``(...)`` int64 of each position ``(..., 2)``; see
        :func:`discretize_positions`."""
        return discretize_positions(self, positions)

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> ObservationGrid:
        """A copy with the edges moved to ``device`` / cast to ``dtype``."""
        return ObservationGrid(
            self.x_edges.to(device=device, dtype=dtype), self.y_edges.to(device=device, dtype=dtype)
        )


def discretize_positions(grid: ObservationGrid, positions: torch.Tensor) -> torch.Tensor:
    """Map continuous positions to cell indices; positions outside the grid fall in the outer cells.

    Args:
        grid: the grid.
        positions: ``(..., 2)`` points in the plane.

    Returns:
        ``(...)`` int64 flat cell indices ``i * Gy + j``.

    Example:
        >>> g = ObservationGrid.uniform((0.0, 1.0), (0.0, 1.0), (2, 2))
        >>> discretize_positions(g, torch.tensor([[0.1, 0.9], [5.0, -5.0]])).tolist()
        [1, 2]
    """
    positions = check_tensor("positions", positions)
    check_shape("positions", positions, (2,), "(..., 2)")
    if not torch.isfinite(positions).all():
        raise ModelError("positions has non-finite entries")
    xe = grid.x_edges.to(device=positions.device, dtype=positions.dtype)
    ye = grid.y_edges.to(device=positions.device, dtype=positions.dtype)
    i = torch.bucketize(positions[..., 0].contiguous(), xe[1:-1], right=True)
    j = torch.bucketize(positions[..., 1].contiguous(), ye[1:-1], right=True)
    return i * grid.shape[1] + j


# ------------------------------------------------------------------------ the math
def bivariate_normal_cdf(h: torch.Tensor, k: torch.Tensor, rho: torch.Tensor) -> torch.Tensor:
    """``Phi2(h, k; rho) = P(U <= h, V <= k)`` for standard normals with correlation ``rho``.

    ``Phi2 = Phi(h) Phi(k) + 1/(2 pi) int_0^asin(rho) exp(-(h^2 + k^2 - 2 h k sin t) /
    (2 cos^2 t)) dt`` (Sheppard's formula as used by Drezner & Wesolowsky 1990 and Genz 2004),
    with 48-point Gauss-Legendre quadrature; differentiable in all three arguments. Absolute
    error below ``1e-11`` for ``|rho| <= 0.999`` (tests compare with scipy). Inputs must be
    finite (use +-40 for infinite limits).

    Args:
        h: ``(...)`` upper limits of the first variable.
        k: ``(...)`` upper limits of the second variable.
        rho: ``(...)`` correlations in ``(-1, 1)``; the three broadcast.

    Returns:
        ``(...)`` the probabilities.

    Example:
        >>> z = torch.zeros((), dtype=torch.float64)
        >>> round(bivariate_normal_cdf(z, z, torch.tensor(0.5, dtype=torch.float64)).item(), 12)
        0.333333333333
    """
    h, k, rho = torch.broadcast_tensors(h, k, rho)
    nodes, weights = _legendre(h.dtype, h.device)
    upper = torch.asin(rho).unsqueeze(-1)  # (..., 1)
    s = torch.sin(upper * (nodes + 1) / 2)  # (..., n)
    hh, kk = h.unsqueeze(-1), k.unsqueeze(-1)
    f = torch.exp(-(hh * hh + kk * kk - 2 * hh * kk * s) / (2 * (1 - s * s)))
    integral = (upper.squeeze(-1) / 2) * (weights * f).sum(-1) / (2 * math.pi)
    return torch.special.ndtr(h) * torch.special.ndtr(k) + integral


def _log_interval(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """``log(Phi(hi) - Phi(lo))`` for ``lo < hi`` (standardised), accurate in both tails."""
    flip = (lo + hi) > 0
    a = torch.where(flip, -hi, lo)
    b = torch.where(flip, -lo, hi)
    log_b = torch.special.log_ndtr(b)
    log_a = torch.special.log_ndtr(a)
    # log(Phi(b) - Phi(a)) = log Phi(b) + log(1 - exp(log Phi(a) - log Phi(b))), diff < 0.
    return log_b + torch.log(-torch.expm1(log_a - log_b))


def _standardised_edges(
    edges: torch.Tensor, mean: torch.Tensor, scale: torch.Tensor
) -> torch.Tensor:
    """``(..., G + 1)`` standardised edges; the outer ones pushed to at most -+40 (see _FAR)."""
    z = (edges - mean.unsqueeze(-1)) / scale.unsqueeze(-1)
    far = torch.full_like(z[..., :1], _FAR)
    first = torch.minimum(z[..., 1:2] - 1, -far)
    last = torch.maximum(z[..., -2:-1] + 1, far)
    return torch.cat([first, z[..., 1:-1], last], dim=-1)


def _resolve_scale(
    scale: torch.Tensor | None,
    covariance: torch.Tensor | None,
    correlation: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    if covariance is not None:
        if scale is not None or correlation is not None:
            raise ModelError("give either covariance or scale (and correlation), not both")
        covariance = check_tensor("covariance", covariance)
        check_shape("covariance", covariance, (2, 2), "(..., 2, 2)")
        var = torch.diagonal(covariance, dim1=-2, dim2=-1)
        if not (var > 0).all():
            raise ModelError(f"expected covariance to have a positive diagonal, got {var.tolist()}")
        if not torch.allclose(covariance[..., 0, 1], covariance[..., 1, 0]):
            raise ModelError("expected covariance to be symmetric")
        scale = var.sqrt()
        correlation = covariance[..., 0, 1] / (scale[..., 0] * scale[..., 1])
    if scale is None:
        raise ModelError("give scale (..., 2) or covariance (..., 2, 2)")
    scale = check_tensor("scale", scale)
    check_shape("scale", scale, (2,), "(..., 2)")
    if not (scale > 0).all():
        raise ModelError(f"expected scale > 0, got min {scale.min().item():.6g}")
    if correlation is not None:
        correlation = check_tensor("correlation", correlation)
        if not (correlation.abs() < 1).all():
            raise ModelError(
                "expected correlation in (-1, 1) (a positive definite covariance), got "
                f"max |rho| = {correlation.abs().max().item():.6g}"
            )
    return scale, correlation


def log_discretized_gaussian(
    grid: ObservationGrid,
    mean: torch.Tensor,
    *,
    scale: torch.Tensor | None = None,
    correlation: torch.Tensor | None = None,
    covariance: torch.Tensor | None = None,
) -> torch.Tensor:
    """Log probability mass of every grid cell under a 2D Gaussian (exact cell integrals).

    Args:
        grid: the grid (its edges are cast to ``mean``'s dtype and device).
        mean: ``(..., 2)`` means.
        scale: ``(..., 2)`` per-axis standard deviations (> 0).
        correlation: ``(...)`` correlation in ``(-1, 1)``; None for a diagonal covariance.
        covariance: ``(..., 2, 2)`` instead of ``scale`` and ``correlation``.

    Returns:
        ``(..., O)`` log masses, ``logsumexp(-1) == 0``; the batch dims of the arguments
        broadcast.

    Raises:
        ModelError: a non-positive scale, ``|correlation| >= 1``, or bad shapes.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> log_discretized_gaussian(g, torch.zeros(2), scale=torch.ones(2)).exp()
        tensor([0.2500, 0.2500, 0.2500, 0.2500])
    """
    mean = check_tensor("mean", mean)
    check_shape("mean", mean, (2,), "(..., 2)")
    scale, correlation = _resolve_scale(scale, covariance, correlation)
    dtype = torch.promote_types(mean.dtype, scale.dtype)
    mean, scale = mean.to(dtype), scale.to(dtype)
    grid = grid.to(device=mean.device, dtype=dtype)
    mean, scale = torch.broadcast_tensors(mean, scale)
    gx, gy = grid.shape
    zx = _standardised_edges(grid.x_edges, mean[..., 0], scale[..., 0])  # (..., Gx + 1)
    zy = _standardised_edges(grid.y_edges, mean[..., 1], scale[..., 1])  # (..., Gy + 1)
    if correlation is None:
        lx = _log_interval(zx[..., :-1], zx[..., 1:])  # (..., Gx)
        ly = _log_interval(zy[..., :-1], zy[..., 1:])  # (..., Gy)
        out = lx.unsqueeze(-1) + ly.unsqueeze(-2)
        return out.reshape(*out.shape[:-2], gx * gy)
    probs = _rectangle_masses(zx, zy, correlation.to(dtype))
    return torch.log(probs)


def _rectangle_masses(zx: torch.Tensor, zy: torch.Tensor, rho: torch.Tensor) -> torch.Tensor:
    """``(..., Gx * Gy)`` bivariate normal masses of the cells ``[zx_i, zx_i+1] x [zy_j, zy_j+1]``.

    Each cell is reflected so that its standardised centre lies in the lower-left quadrant
    (``u -> -u`` maps the interval ``[a, b]`` to ``[-b, -a]`` and ``rho`` to ``-rho``), where
    the four corner CDF values are small and their inclusion-exclusion loses little.
    """
    gx, gy = zx.shape[-1] - 1, zy.shape[-1] - 1
    batch = broadcast_shapes(zx.shape[:-1], zy.shape[:-1], rho.shape)
    ax, bx = zx[..., :-1].unsqueeze(-1), zx[..., 1:].unsqueeze(-1)  # (..., Gx, 1)
    ay, by = zy[..., :-1].unsqueeze(-2), zy[..., 1:].unsqueeze(-2)  # (..., 1, Gy)
    fx = (ax + bx) > 0
    fy = (ay + by) > 0
    ax, bx = torch.where(fx, -bx, ax), torch.where(fx, -ax, bx)
    ay, by = torch.where(fy, -by, ay), torch.where(fy, -ay, by)
    r = rho.reshape(*rho.shape, 1, 1) * torch.where(fx ^ fy, -1.0, 1.0).to(rho.dtype)
    shape = (*batch, gx, gy)
    ax, bx, ay, by, r = (t.expand(shape) for t in (ax, bx, ay, by, r))
    corners_h = torch.stack([bx, ax, bx, ax], dim=-1)
    corners_k = torch.stack([by, by, ay, ay], dim=-1)
    signs = torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=rho.dtype, device=rho.device)
    f = bivariate_normal_cdf(corners_h, corners_k, r.unsqueeze(-1))
    mass = (f * signs).sum(-1).clamp_min(0.0)
    mass = mass / mass.sum(dim=(-2, -1), keepdim=True)
    return mass.reshape(*batch, gx * gy)


def discretized_gaussian(
    grid: ObservationGrid,
    mean: torch.Tensor,
    *,
    scale: torch.Tensor | None = None,
    correlation: torch.Tensor | None = None,
    covariance: torch.Tensor | None = None,
) -> torch.Tensor:
    """Probability mass ``(..., O)`` of every grid cell; see :func:`log_discretized_gaussian`.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (0.0, 1.0), (2, 1))
        >>> discretized_gaussian(g, torch.zeros(2), scale=torch.ones(2)).tolist()
        [0.5, 0.5]
    """
    return log_discretized_gaussian(
        grid, mean, scale=scale, correlation=correlation, covariance=covariance
    ).exp()


def _covariance(scale: torch.Tensor, correlation: torch.Tensor | None) -> torch.Tensor:
    var = scale * scale
    cov = torch.diag_embed(var)
    if correlation is not None:
        off = correlation * scale[..., 0] * scale[..., 1]
        cov = cov.clone()
        cov[..., 0, 1] = off
        cov[..., 1, 0] = off
    return cov


def sample_positions(
    mean: torch.Tensor,
    *,
    scale: torch.Tensor | None = None,
    correlation: torch.Tensor | None = None,
    covariance: torch.Tensor | None = None,
    num_samples: int | None = None,
    generator: torch.Generator | None = None,
    seed: int | None = None,
) -> torch.Tensor:
    """Draw hand positions from 2D Gaussians (reparameterised: differentiable in the parameters).

    Args:
        mean: ``(..., 2)`` means.
        scale, correlation, covariance: as in :func:`log_discretized_gaussian`.
        num_samples: if given, a leading sample dim of this size.
        generator: the random generator; or ``seed`` to make one.
        seed: seed of a fresh generator (ignored when ``generator`` is given).

    Returns:
        ``(num_samples, ..., 2)`` or ``(..., 2)`` positions.

    Example:
        >>> p = sample_positions(torch.zeros(2), scale=torch.ones(2), num_samples=3, seed=0)
        >>> p.shape
        torch.Size([3, 2])
    """
    mean = check_tensor("mean", mean)
    check_shape("mean", mean, (2,), "(..., 2)")
    scale, correlation = _resolve_scale(scale, covariance, correlation)
    if generator is None:
        generator = torch.Generator(device=mean.device)
        generator.manual_seed(0 if seed is None else int(seed))
    chol = torch.linalg.cholesky(_covariance(scale.to(mean.dtype), correlation))
    batch = broadcast_shapes(mean.shape[:-1], chol.shape[:-2])
    shape = (*(() if num_samples is None else (int(num_samples),)), *batch, 2)
    eps = torch.randn(shape, generator=generator, dtype=mean.dtype, device=mean.device)
    return mean + (chol @ eps.unsqueeze(-1)).squeeze(-1)


# --------------------------------------------------------------- the learnable model
def _as_param_shape(name: str, value: torch.Tensor, target: tuple[int, ...]) -> torch.Tensor:
    try:
        return value.expand(target).clone() if value.shape != target else value.clone()
    except RuntimeError:
        raise ModelError(
            f"expected {name} to broadcast to {target}, actual shape = {tuple(value.shape)}"
        ) from None


class DiscretizedGaussianObservation(nn.Module):
    """A learnable discretized 2D Gaussian observation model ``P(o | x, y)`` of a MOMDP.

    The hand position of a person of type ``y`` when the task is in observed state ``x`` is
    ``N(offset[x, y] + loc[x, y], diag(scale) with correlation rho[x, y])`` and the robot
    observes the grid cell it falls in. ``loc``, ``log(scale)`` and (optionally) ``atanh(rho
    / max_correlation)`` are ``nn.Parameter``s of whatever shape the constructor's arguments
    have, broadcast to ``(X, Y, ...)``: pass ``loc`` of shape ``(Y, 2)`` for one mean per
    type shared by all states, ``(X, Y, 2)`` for one per pair, and a fixed ``offset``
    (a buffer, e.g. ``(X, 1, 2)`` from the box position) for state-dependent means with
    per-type learnable parts.

    Args:
        grid: the observation grid (``O`` cells).
        loc: ``(..., 2)`` learnable mean part, broadcastable to ``(X, Y, 2)``.
        scale: ``(..., 2)`` initial per-axis standard deviations (> 0), broadcastable to
            ``(X, Y, 2)``; learned as ``log_scale``.
        num_observed: ``X``.
        num_hidden: ``Y``.
        correlation: ``(...)`` broadcastable to ``(X, Y)``, initial correlations; ``None``
            (default) for diagonal covariances (fixed zero correlation).
        offset: ``(..., 2)`` fixed mean offsets (buffer) broadcastable to ``(X, Y, 2)``.
        num_actions: ``A``, the size of the action dim of :meth:`forward`'s output.
        max_correlation: ``|rho|`` is kept below this (``rho = max * tanh(raw)``).

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (3, 3))
        >>> m = DiscretizedGaussianObservation(g, torch.tensor([[-0.5, 0.0], [0.5, 0.0]]),
        ...                                    torch.full((2,), 0.3), num_observed=4, num_hidden=2)
        >>> m().shape  # Z: (A, X, Y, O)
        torch.Size([1, 4, 2, 9])
    """

    loc: nn.Parameter
    log_scale: nn.Parameter
    offset: torch.Tensor
    x_edges: torch.Tensor
    y_edges: torch.Tensor

    def __init__(
        self,
        grid: ObservationGrid,
        loc: torch.Tensor,
        scale: torch.Tensor,
        *,
        num_observed: int,
        num_hidden: int,
        correlation: torch.Tensor | None = None,
        offset: torch.Tensor | None = None,
        num_actions: int = 1,
        max_correlation: float = 0.99,
    ) -> None:
        super().__init__()
        for name, value in (("num_observed", num_observed), ("num_hidden", num_hidden)):
            if not isinstance(value, int) or value < 1:
                raise ModelError(f"expected {name} to be a positive int, got {value!r}")
        if not isinstance(num_actions, int) or num_actions < 1:
            raise ModelError(f"expected num_actions to be a positive int, got {num_actions!r}")
        if not 0.0 < max_correlation < 1.0:
            raise ModelError(f"expected max_correlation in (0, 1), got {max_correlation}")
        loc = check_tensor("loc", loc)
        check_shape("loc", loc, (2,), "(..., 2) broadcastable to (X, Y, 2)")
        scale = check_tensor("scale", scale)
        check_shape("scale", scale, (2,), "(..., 2) broadcastable to (X, Y, 2)")
        if not (scale > 0).all():
            raise ModelError(f"expected scale > 0, got min {scale.min().item():.6g}")
        self.num_observed, self.num_hidden, self.num_actions = num_observed, num_hidden, num_actions
        self.max_correlation = float(max_correlation)
        self.grid_shape = grid.shape
        full = (num_observed, num_hidden, 2)
        _as_param_shape("loc", loc, full)
        _as_param_shape("scale", scale, full)
        self.loc = nn.Parameter(loc.detach().clone())
        self.log_scale = nn.Parameter(scale.detach().log().to(loc.dtype))
        if correlation is not None:
            correlation = check_tensor("correlation", correlation)
            _as_param_shape("correlation", correlation, full[:2])
            if not (correlation.abs() < max_correlation).all():
                raise ModelError(
                    f"expected |correlation| < max_correlation = {max_correlation}, got "
                    f"{correlation.abs().max().item():.6g}"
                )
            raw = torch.atanh(correlation.detach().to(loc.dtype) / max_correlation)
            self.raw_correlation: nn.Parameter | None = nn.Parameter(raw)
        else:
            self.raw_correlation = None
        if offset is None:
            offset = loc.new_zeros(1, 1, 2)
        offset = check_tensor("offset", offset)
        check_shape("offset", offset, (2,), "(..., 2) broadcastable to (X, Y, 2)")
        _as_param_shape("offset", offset, full)
        self.register_buffer("offset", offset.detach().clone().to(loc.dtype))
        self.register_buffer("x_edges", grid.x_edges.detach().clone().to(loc.dtype))
        self.register_buffer("y_edges", grid.y_edges.detach().clone().to(loc.dtype))

    @property
    def grid(self) -> ObservationGrid:
        """The observation grid (on the module's device and dtype)."""
        return ObservationGrid(self.x_edges, self.y_edges)

    @property
    def num_observations(self) -> int:
        """``O``, the number of grid cells."""
        return self.grid_shape[0] * self.grid_shape[1]

    def mean(self) -> torch.Tensor:
        """``(X, Y, 2)`` the Gaussian means ``offset + loc``."""
        full = (self.num_observed, self.num_hidden, 2)
        return (self.offset + self.loc).expand(full)

    def scale(self) -> torch.Tensor:
        """``(X, Y, 2)`` per-axis standard deviations ``exp(log_scale)``."""
        return self.log_scale.exp().expand(self.num_observed, self.num_hidden, 2)

    def correlation(self) -> torch.Tensor | None:
        """``(X, Y)`` correlations, or ``None`` for diagonal covariances."""
        if self.raw_correlation is None:
            return None
        rho = self.max_correlation * torch.tanh(self.raw_correlation)
        return rho.expand(self.num_observed, self.num_hidden)

    def covariance(self) -> torch.Tensor:
        """``(X, Y, 2, 2)`` covariance matrices."""
        return _covariance(self.scale(), self.correlation())

    def log_probs(self) -> torch.Tensor:
        """``(X, Y, O)`` log observation probabilities ``log P(o | x, y)``."""
        return log_discretized_gaussian(
            self.grid, self.mean(), scale=self.scale(), correlation=self.correlation()
        )

    def forward(self) -> torch.Tensor:
        """``Z: (A, X, Y, O)``, ``Z[a, x2, y2, o] = P(o | x2, y2)`` (a broadcast view over A)."""
        z = self.log_probs().exp()
        return z.unsqueeze(0).expand(self.num_actions, *z.shape)

    def sample(
        self,
        x: torch.Tensor,
        y: torch.Tensor,
        *,
        generator: torch.Generator | None = None,
        seed: int | None = None,
    ) -> torch.Tensor:
        """Hand positions ``(..., 2)`` for observed states ``x (...)`` and types ``y (...)``."""
        x, y = torch.broadcast_tensors(torch.as_tensor(x), torch.as_tensor(y))
        mean = self.mean()[x, y]
        scale = self.scale()[x, y]
        rho = self.correlation()
        return sample_positions(
            mean,
            scale=scale,
            correlation=None if rho is None else rho[x, y],
            generator=generator,
            seed=seed,
        )


# ------------------------------------------------------------- tracks and learning
@dataclass(frozen=True)
class HandTracks:
    """Recorded hand tracks: observed states, robot actions, and the hand's grid cells.

    Step ``t`` of track ``n`` (``t < lengths[n]``): in observed state ``observed[n, t]`` the
    robot takes ``actions[n, t]``, the state becomes ``observed[n, t + 1]`` and the hand is
    seen in cell ``cells[n, t]`` (``P(o | x2, y)``). Entries past a track's length are
    padding (any valid index).

    Args:
        observed: ``(N, L + 1)`` int64 observed states ``x_0 .. x_L``.
        actions: ``(N, L)`` int64 robot actions.
        cells: ``(N, L)`` int64 observed grid cells.
        lengths: ``(N,)`` int64 number of steps of each track, in ``[1, L]``.
        positions: optional ``(N, L, 2)`` continuous hand positions behind ``cells``.
        types: optional ``(N,)`` int64 true hidden values (for scoring only, never used by
            :func:`fit_observation_model`).
    """

    observed: torch.Tensor
    actions: torch.Tensor
    cells: torch.Tensor
    lengths: torch.Tensor
    positions: torch.Tensor | None = field(default=None, repr=False)
    types: torch.Tensor | None = None

    def __post_init__(self) -> None:
        for name in ("observed", "actions", "cells", "lengths"):
            v = check_tensor(name, getattr(self, name), floating=False)
            if v.dtype != torch.int64:
                raise TypeError(f"expected {name} to be int64, got {v.dtype}")
        if self.actions.dim() != 2:
            raise ModelError(
                f"expected actions to have shape (N, L), actual shape = {tuple(self.actions.shape)}"
            )
        n, length = self.actions.shape
        if tuple(self.observed.shape) != (n, length + 1):
            raise ModelError(
                f"expected observed to have shape (N, L + 1) = {(n, length + 1)}, "
                f"actual shape = {tuple(self.observed.shape)}"
            )
        if tuple(self.cells.shape) != (n, length):
            raise ModelError(
                f"expected cells to have shape (N, L) = {(n, length)}, "
                f"actual shape = {tuple(self.cells.shape)}"
            )
        if tuple(self.lengths.shape) != (n,):
            raise ModelError(
                f"expected lengths to have shape (N,) = ({n},), "
                f"actual shape = {tuple(self.lengths.shape)}"
            )
        if n and ((self.lengths < 1).any() or (self.lengths > length).any()):
            raise ModelError(f"expected lengths in [1, {length}], got {self.lengths.tolist()}")
        for name in ("observed", "actions", "cells"):
            if (getattr(self, name) < 0).any():
                raise ModelError(f"expected {name} to be non-negative indices")

    @property
    def num_tracks(self) -> int:
        return self.actions.shape[0]

    @property
    def mask(self) -> torch.Tensor:
        """``(N, L)`` bool, True on real steps."""
        steps = torch.arange(self.actions.shape[1], device=self.actions.device)
        return steps < self.lengths.unsqueeze(-1)

    def check_against(self, num_actions: int, num_observed: int, num_observations: int) -> None:
        """Raise :class:`ModelError` if an index is out of range for a model of these sizes."""
        mask = self.mask
        for name, values, size in (
            ("actions", self.actions[mask], num_actions),
            ("cells", self.cells[mask], num_observations),
            ("observed", self.observed, num_observed),
        ):
            if values.numel() and int(values.max()) >= size:
                raise ModelError(f"expected {name} in [0, {size}), got {int(values.max())}")


def _unpack_transition(
    transition: MOMDP | torch.Tensor, b0: torch.Tensor | None, Ty: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
    if isinstance(transition, MOMDP):
        return (
            transition.Tx,
            transition.Ty if Ty is None else Ty,
            (transition.b0 if b0 is None else b0),
        )
    Tx = check_tensor("transition", transition)
    check_shape("transition", Tx, (None, None, None, None), "(A, X, Y, X)")
    if b0 is None:
        Y = Tx.shape[-2]
        b0 = Tx.new_full((Y,), 1.0 / Y)
    return Tx, Ty, b0


def _safe_log(x: torch.Tensor) -> torch.Tensor:
    # log(0) = -inf with a zero (not NaN) gradient where x == 0.
    pos = x > 0
    return torch.where(pos, torch.log(torch.where(pos, x, torch.ones_like(x))), -torch.inf)


def track_log_likelihood(
    observation: torch.Tensor,
    transition: MOMDP | torch.Tensor,
    tracks: HandTracks,
    *,
    b0: torch.Tensor | None = None,
    Ty: torch.Tensor | None = None,
) -> torch.Tensor:
    """Log marginal likelihood of each track with the hidden type unknown.

    The sum over time of the MOMDP belief filter's log normalisers (paper Eq. 3):
    ``log p(x_1:T, o_1:T | x_0, a_0:T-1) = sum_t log P(x_t+1, o_t+1 | x_t, a_t, b_t)``.
    ``Tx`` does not involve the observation model, so its gradient is that of
    ``log p(o_1:T | x_0:T, a)``. With a static type (``Ty is None``) this is computed in closed
    form, vectorised over time: ``logsumexp_y [log b0(y) + sum_t log Tx[a_t, x_t, y, x_t+1] +
    log Z[a_t, x_t+1, y, o_t]]``; otherwise by running
    :func:`torchhrc.belief.momdp_log_update` along the tracks.

    Args:
        observation: ``(A, X, Y, O)`` observation probabilities (e.g. ``model()``), or
            ``(X, Y, O)`` when they do not depend on the action.
        transition: a :class:`~torchhrc.pomdp.MOMDP` (its ``Tx``, ``Ty``, ``b0``; its ``Z``
            is ignored) or ``Tx: (A, X, Y, X)``.
        tracks: the tracks.
        b0: ``(Y,)`` initial type belief (default: the MOMDP's, or uniform).
        Ty: ``(A, X, Y, X, Y)`` type transitions (default: the MOMDP's, or static).

    Returns:
        ``(N,)`` log likelihoods; ``-inf`` for a track impossible under the model.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> Z = torch.full((1, 1, 2, 4), 0.25, dtype=torch.float64)
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> t = HandTracks(torch.zeros(1, 3, dtype=torch.long), torch.zeros(1, 2, dtype=torch.long),
        ...                torch.tensor([[0, 3]]), torch.tensor([2]))
        >>> round(track_log_likelihood(Z, Tx, t).item(), 6) == round(2 * math.log(0.25), 6)
        True
    """
    Tx, Ty, b0 = _unpack_transition(transition, b0, Ty)
    Z = check_tensor("observation", observation)
    if Z.dim() == 3:
        Z = Z.unsqueeze(0)
    A, X, Y = Tx.shape[-4], Tx.shape[-3], Tx.shape[-2]
    check_shape("observation", Z, (None, X, Y, None), f"(A, X={X}, Y={Y}, O)")
    if Z.shape[0] not in (1, A):
        raise ModelError(f"expected observation to have A = 1 or {A}, got {Z.shape[0]}")
    tracks.check_against(A, X, Z.shape[-1])
    if Ty is not None:
        return _sequential_log_likelihood(Z.expand(A, *Z.shape[1:]), Tx, Ty, b0, tracks)
    mask = tracks.mask  # (N, L)
    x, x2 = tracks.observed[:, :-1], tracks.observed[:, 1:]
    a = tracks.actions
    aZ = a if Z.shape[0] == A else torch.zeros_like(a)
    log_tx = _safe_log(Tx[a, x, :, x2])  # (N, L, Y)
    log_z = _safe_log(Z[aZ, x2, :, tracks.cells])  # (N, L, Y)
    step = torch.where(mask.unsqueeze(-1), log_tx + log_z, torch.zeros_like(log_z))
    joint = _safe_log(b0) + step.sum(dim=1)  # (N, Y)
    return torch.logsumexp(joint, dim=-1)


def _sequential_log_likelihood(
    Z: torch.Tensor, Tx: torch.Tensor, Ty: torch.Tensor, b0: torch.Tensor, tracks: HandTracks
) -> torch.Tensor:
    from torchhrc.belief import momdp_log_update

    model = MOMDP(
        Tx=Tx,
        Ty=Ty,
        Z=Z,
        R=Z.new_zeros(Tx.shape[:-1]),
        x0=0,
        b0=b0,
        discount=1.0,
        validate_probabilities=False,
    )
    n = tracks.num_tracks
    log_b = _safe_log(b0).expand(n, b0.shape[-1])
    total = Z.new_zeros(n)
    lengths = tracks.lengths
    for t in range(int(lengths.max()) if n else 0):  # the filter is a recursion in time
        active = torch.nonzero(lengths > t).squeeze(-1)
        r = momdp_log_update(
            model,
            tracks.observed[active, t],
            log_b[active],
            tracks.actions[active, t],
            tracks.observed[active, t + 1],
            tracks.cells[active, t],
            on_zero="ninf",
        )
        log_b = log_b.index_put((active,), r.belief)
        total = total.index_add(0, active, r.log_normalizer)
    return total


@dataclass(frozen=True)
class ObservationFit:
    """Result of :func:`fit_observation_model`.

    Attributes:
        log_likelihood: final total log marginal likelihood of the tracks.
        initial_log_likelihood: the same before the first step.
        history: total log likelihood after each optimiser step.
        steps: optimiser steps taken.
        converged: the relative change fell below ``tol``.
    """

    log_likelihood: float
    initial_log_likelihood: float
    history: tuple[float, ...]
    steps: int
    converged: bool


def fit_observation_model(
    model: DiscretizedGaussianObservation,
    transition: MOMDP | torch.Tensor,
    tracks: HandTracks,
    *,
    b0: torch.Tensor | None = None,
    Ty: torch.Tensor | None = None,
    steps: int = 300,
    lr: float = 0.05,
    optimizer: str = "adam",
    batch_size: int | None = None,
    tol: float = 1e-9,
    seed: int = 0,
    callback: Callable[[int, float], None] | None = None,
) -> ObservationFit:
    """Learn the observation model from hand tracks by maximum marginal likelihood.

    Maximises ``sum_n log p(x_1:T, o_1:T | x_0, a)`` of :func:`track_log_likelihood`, the
    MOMDP belief filter's log normalisers with the type unknown, by gradient ascent with
    autograd (Adam, or L-BFGS with a strong-Wolfe line search). The model's parameters are
    updated in place. The loss is the negative mean log likelihood per step.

    Args:
        model: the observation model to fit (its parameters are the starting point).
        transition: a MOMDP (``Tx``, ``Ty``, ``b0``; ``Z`` ignored) or ``Tx: (A, X, Y, X)``.
        tracks: the recorded tracks.
        b0, Ty: override the MOMDP's initial type belief / type transitions.
        steps: maximum optimiser steps.
        lr: learning rate.
        optimizer: ``"adam"`` or ``"lbfgs"``.
        batch_size: tracks per minibatch (Adam only; default all tracks).
        tol: stop when the relative change of the full log likelihood is below this.
        seed: seeds the minibatch order.
        callback: called as ``callback(step, log_likelihood)`` after each step.

    Returns:
        :class:`ObservationFit`.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (4, 4))
        >>> m = DiscretizedGaussianObservation(g, torch.zeros(1, 2, 2, dtype=torch.float64),
        ...     torch.ones(2, dtype=torch.float64), num_observed=1, num_hidden=2)
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> t = simulate_tracks(m, Tx, num_tracks=4, length=3, seed=0)
        >>> fit_observation_model(m, Tx, t, steps=2).steps
        2
    """
    if optimizer not in ("adam", "lbfgs"):
        raise ModelError(f"expected optimizer 'adam' or 'lbfgs', got {optimizer!r}")
    if not isinstance(steps, int) or steps < 1:
        raise ModelError(f"expected steps to be a positive int, got {steps!r}")
    n_steps = int(tracks.lengths.sum())
    if n_steps == 0:
        raise ModelError("tracks has no steps to learn from")
    params = [p for p in model.parameters() if p.requires_grad]
    gen = torch.Generator()
    gen.manual_seed(int(seed))

    def full_ll() -> torch.Tensor:
        return track_log_likelihood(model(), transition, tracks, b0=b0, Ty=Ty).sum()

    history: list[float] = []
    converged = False
    with torch.no_grad():
        initial = float(full_ll())
    previous = initial
    if optimizer == "lbfgs":
        opt: torch.optim.Optimizer = torch.optim.LBFGS(
            params, lr=lr, max_iter=20, line_search_fn="strong_wolfe"
        )

        def closure() -> torch.Tensor:
            opt.zero_grad()
            loss = -full_ll() / n_steps
            loss.backward()
            return loss

    else:
        opt = torch.optim.Adam(params, lr=lr)
    step = 0
    for step in range(1, steps + 1):
        if optimizer == "lbfgs":
            opt.step(closure)  # type: ignore[arg-type]
        elif batch_size is None or batch_size >= tracks.num_tracks:
            opt.zero_grad()
            loss = -full_ll() / n_steps
            loss.backward()
            opt.step()
        else:
            order = torch.randperm(tracks.num_tracks, generator=gen)
            for start in range(0, tracks.num_tracks, batch_size):
                idx = order[start : start + batch_size]
                sub = _subset(tracks, idx)
                opt.zero_grad()
                ll = track_log_likelihood(model(), transition, sub, b0=b0, Ty=Ty).sum()
                (-ll / n_steps).backward()
                opt.step()
        with torch.no_grad():
            value = float(full_ll())
        if not math.isfinite(value):
            raise ModelError(
                "the tracks' log likelihood became non-finite: an observed cell has probability "
                "zero under the model (check the grid and the initial parameters)"
            )
        history.append(value)
        if callback is not None:
            callback(step, value)
        if abs(value - previous) <= tol * max(1.0, abs(previous)):
            converged = True
            break
        previous = value
    return ObservationFit(
        log_likelihood=history[-1],
        initial_log_likelihood=initial,
        history=tuple(history),
        steps=step,
        converged=converged,
    )


def _subset(tracks: HandTracks, idx: torch.Tensor) -> HandTracks:
    return HandTracks(
        observed=tracks.observed[idx],
        actions=tracks.actions[idx],
        cells=tracks.cells[idx],
        lengths=tracks.lengths[idx],
        positions=None if tracks.positions is None else tracks.positions[idx],
        types=None if tracks.types is None else tracks.types[idx],
    )


@torch.no_grad()
def simulate_tracks(
    model: DiscretizedGaussianObservation,
    transition: MOMDP | torch.Tensor,
    *,
    num_tracks: int,
    length: int,
    b0: torch.Tensor | None = None,
    x0: int | None = None,
    actions: torch.Tensor | None = None,
    seed: int = 0,
) -> HandTracks:
    """Simulate hand tracks of persons with a static hidden type.

    Each track draws a type ``y ~ b0`` once, then for ``t < length`` takes the action
    ``actions[n, t]`` (default: uniform random), samples ``x_t+1 ~ Tx[a, x_t, y, :]`` and the
    hand position from the model's Gaussian for ``(x_t+1, y)``, and records its grid cell.

    Args:
        model: the (true) observation model.
        transition: a MOMDP (``Tx``, ``b0``, ``x0``) or ``Tx: (A, X, Y, X)``.
        num_tracks: ``N``.
        length: ``L`` steps per track.
        b0: ``(Y,)`` type distribution (default the MOMDP's, or uniform).
        x0: initial observed state (default the MOMDP's, or 0).
        actions: ``(N, L)`` int64 actions (default uniform random).
        seed: seed of the generator.

    Returns:
        :class:`HandTracks` with ``positions`` and ``types`` filled.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> m = DiscretizedGaussianObservation(g, torch.zeros(2), torch.ones(2),
        ...                                    num_observed=1, num_hidden=1)
        >>> simulate_tracks(m, torch.ones(1, 1, 1, 1), num_tracks=2, length=3).cells.shape
        torch.Size([2, 3])
    """
    Tx, _, b0 = _unpack_transition(transition, b0, None)
    if x0 is None:
        if isinstance(transition, MOMDP) and transition.random_start:
            raise ValueError(
                "the MOMDP has a random first x (initial): pass x0, the observed value the "
                "tracks start at"
            )
        x0 = transition.x0 if isinstance(transition, MOMDP) else 0
    A, X = Tx.shape[-4], Tx.shape[-3]
    if (model.num_observed, model.num_hidden) != (X, Tx.shape[-2]):
        raise ModelError(
            f"model has (X, Y) = {(model.num_observed, model.num_hidden)}, the transition "
            f"{(X, Tx.shape[-2])}"
        )
    gen = torch.Generator(device=Tx.device)
    gen.manual_seed(int(seed))
    device = Tx.device
    if actions is None:
        actions = torch.randint(A, (num_tracks, length), generator=gen, device=device)
    elif tuple(actions.shape) != (num_tracks, length):
        raise ModelError(
            f"expected actions to have shape (N, L) = {(num_tracks, length)}, "
            f"actual shape = {tuple(actions.shape)}"
        )
    types = torch.multinomial(b0.expand(num_tracks, -1), 1, generator=gen).squeeze(-1)
    observed = torch.empty(num_tracks, length + 1, dtype=torch.long, device=device)
    observed[:, 0] = int(x0)
    for t in range(length):  # sampling a Markov chain is sequential in time
        p = Tx[actions[:, t], observed[:, t], types]  # (N, X)
        observed[:, t + 1] = torch.multinomial(p, 1, generator=gen).squeeze(-1)
    positions = model.sample(observed[:, 1:], types.unsqueeze(-1), generator=gen)
    cells = discretize_positions(model.grid, positions)
    return HandTracks(
        observed=observed,
        actions=actions.long(),
        cells=cells,
        lengths=torch.full((num_tracks,), length, dtype=torch.long, device=device),
        positions=positions,
        types=types,
    )
