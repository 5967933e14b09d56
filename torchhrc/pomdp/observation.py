"""Observation models: a discretized 2D Gaussian over a grid of the horizontal plane.

In the paper's hand-finishing task the robot cannot see the person's type; it sees the
person's hand position in the horizontal plane, and the observation function is "a
discretized 2D-Gaussian, giving the probability of the position of a human hand in the
horizontal plane conditioned on the human preference" (Nikolaidis et al., Evaluation,
"Online estimation of human type"). The paper specifies the mean and variance by hand and
leaves learning them to future work;
:func:`~torchhrc.pomdp.observation_fit.fit_observation_model` learns them from recorded hand
tracks by maximising the log marginal likelihood through the MOMDP belief filter.

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
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from torchhrc._checks import broadcast_shapes, check_shape, check_tensor
from torchhrc.errors import ModelError

__all__ = [
    "DiscretizedGaussianObservation",
    "ObservationGrid",
    "bivariate_normal_cdf",
    "discretize_positions",
    "discretized_gaussian",
    "log_discretized_gaussian",
    "sample_positions",
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
