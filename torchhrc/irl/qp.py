"""The quadratic program of the paper's IRL step 2, solved with cvxpy (lazily imported).

Given the feature expectations ``mu^(0..i-1)`` of the policies found so far and the expert's
``mu_hat`` (paper Eq. "quadraticProg"; Abbeel & Ng 2004, Sec. 3)::

    min_{lambda, mu} || mu_hat - mu ||_2
    s.t. sum_j lambda_j mu^(j) = mu,  lambda >= 0,  sum_j lambda_j = 1

i.e. the Euclidean projection of ``mu_hat`` onto the convex hull of the ``mu^(j)``. The
squared norm is minimised (the same minimiser; a QP in the strict sense, which every QP
solver accepts). ``t = ||mu_hat - mu||`` is the margin and ``w = (mu_hat - mu) / t``.

Example:
    >>> import torch
    >>> mus = torch.tensor([[2.0, 0.0], [0.0, 2.0]], dtype=torch.float64)
    >>> lam = solve_simplex_qp(mus, torch.tensor([1.0, 1.0], dtype=torch.float64))
    >>> [round(v, 4) for v in lam.tolist()]
    [0.5, 0.5]
"""

from __future__ import annotations

from typing import Any

import torch

from torchhrc.errors import ModelError, TorchHRCError

__all__ = ["QPError", "solve_simplex_qp"]


class QPError(ModelError):
    """The IRL quadratic program was not solved (the message names the solver and status)."""


def _import_cvxpy() -> Any:
    try:
        import cvxpy
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise TorchHRCError(
            "the max-margin QP of Abbeel-Ng IRL needs cvxpy: pip install torchhrc[full] "
            "(or use method='projection')"
        ) from error
    return cvxpy


def solve_simplex_qp(
    points: torch.Tensor,
    target: torch.Tensor,
    *,
    solver: str = "CLARABEL",
    solver_options: dict[str, Any] | None = None,
) -> torch.Tensor:
    """Mixture weights ``lambda`` of the point of ``conv(points)`` nearest to ``target``.

    Args:
        points: ``(K, F)`` the feature expectations ``mu^(j)`` of K policies.
        target: ``(F,)`` the expert's ``mu_hat``.
        solver: a cvxpy solver name (``"CLARABEL"``, ``"OSQP"``, ``"SCS"``, ...).
        solver_options: extra keyword arguments of ``cvxpy.Problem.solve``.

    Returns:
        ``(K,)`` ``lambda`` on the simplex (clipped at 0 and renormalised to remove the
        solver's round-off), dtype and device of ``points``.

    Raises:
        QPError: the solver raised, or reported a status other than ``optimal``
            (e.g. ``infeasible``, ``optimal_inaccurate``); the message names both.

    Example:
        >>> pts = torch.tensor([[0.0, 0.0], [1.0, 0.0]], dtype=torch.float64)
        >>> solve_simplex_qp(pts, torch.tensor([3.0, 1.0], dtype=torch.float64)).round()
        tensor([0., 1.], dtype=torch.float64)
    """
    cp = _import_cvxpy()
    M = points.detach().cpu().double().numpy()  # (K, F)
    mu_hat = target.detach().cpu().double().numpy()  # (F,)
    K, F = M.shape
    lam = cp.Variable(K)
    mu = cp.Variable(F)
    problem = cp.Problem(
        cp.Minimize(cp.sum_squares(mu_hat - mu)),
        [M.T @ lam == mu, lam >= 0, cp.sum(lam) == 1],
    )
    try:
        problem.solve(solver=solver, **(solver_options or {}))
    except cp.error.SolverError as error:
        raise QPError(f"the IRL QP failed: solver {solver} raised {error}") from error
    status = problem.status
    if status != cp.OPTIMAL or lam.value is None:
        raise QPError(
            f"the IRL QP was not solved: solver {solver} reported status {status!r} "
            f"(K={K} policies, F={F} features)"
        )
    value = torch.as_tensor(lam.value, dtype=points.dtype, device=points.device).clamp_min(0.0)
    total = value.sum()
    if not torch.isfinite(total) or total <= 0:
        raise QPError(f"the IRL QP returned invalid weights: solver {solver}, status {status!r}")
    return value / total
