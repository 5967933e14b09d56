"""QMDP: the value of the underlying MDP as alpha vectors, an upper bound (Littman et al. 1995).

Each action gets the vector of its MDP action values, so ``max_a Q(a) . b`` assumes the state
becomes fully observable after one step; it is an upper bound on the optimal POMDP value::

    Q(a, s) = R(a, s) + discount * sum_s2 T(a, s, s2) max_a2 Q(a2, s2)

For a MOMDP the same iteration runs factored over ``(x, y)`` (never forming the flat
``(X Y) x (X Y)`` matrix) and yields vectors ``(A, X, Y)``: one per action and observed ``x``.
The returned vectors add the value-iteration error bound, so they bound ``V*`` from above
even when the iteration is stopped early.

Example:
    >>> import torch
    >>> from torchhrc.testing import random_pomdp
    >>> model = random_pomdp(3, 2, 2, seed=0)
    >>> qmdp_vectors(model).shape
    torch.Size([2, 3])
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.solvers._factored import (
    BRACKET_ROUND_OFF,
    Expectation,
    check_model,
    check_unit_discount,
    state_dims,
)
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.solution import Solution

if TYPE_CHECKING:
    from torchhrc.solvers.forms.base import SolverModel
    from torchhrc.sparse import SparsePOMDP
    from torchhrc.sparse_momdp import SparseMOMDP

    AnyModel = POMDP | MOMDP | SparsePOMDP | SparseMOMDP

__all__ = [
    "IterationConfig",
    "QMDPConfig",
    "bound_solution",
    "mdp_q_values",
    "qmdp",
    "qmdp_policy",
    "qmdp_vectors",
    "solve_bound",
]


def mdp_q_values(
    model: POMDP | MOMDP, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> tuple[torch.Tensor, float]:
    """Value iteration on the fully observable MDP underlying ``model``, batched.

    From ``V = 0``, ``V <- max_a (R_a + discount E_a V)``. With ``d = V_new - V``, the bounds
    of MacQueen (1966) and Porteus (1971), ``V_new + k min(d) <= V* <= V_new + k max(d)``
    (``k = w / (1 - w)``, ``w`` the discount times the rows' sums, measured: 1 within a model's
    tolerance), bracket ``V*`` at every step; the iteration stops once each problem's bracket
    is narrower than ``tol`` (or than the round-off of ``d`` times ``k``, where that is wider:
    ``error_bound`` says so) or the change is below ``tol (1 - discount) / (2 discount)``, and
    ``V`` is the bracket's middle. Near discount 1 the bracket closes long before the change
    does (discount 0.9999, 6 states: a few dozen steps instead of some 200,000).

    Returns:
        ``(Q, error_bound)``: ``Q`` is ``(..., A, S)`` for a POMDP or ``(..., A, X, Y)`` for a
        MOMDP, and ``|Q - Q*| <= error_bound`` everywhere.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> Q, err = mdp_q_values(random_momdp(3, 2, 2, 2, seed=0))
        >>> tuple(Q.shape), err < 1e-8
        ((2, 3, 2), True)
    """
    model = check_model(model)
    check_unit_discount(model, "QMDP")
    g = model.discount
    sd = state_dims(model)
    action_dim = -1 - sd
    V = model.R.amax(action_dim) * 0.0
    threshold = tol * (1.0 - g) / (2.0 * g)
    E = Expectation(model)
    state = tuple(range(-sd, 0))
    batch = V.dim() - sd
    # each problem's smallest and largest weight of a constant: g times its rows' sums
    w = g * E(torch.ones_like(V))
    w_lo = w.amin(dim=(action_dim, *state)) if w.numel() else w.new_zeros(V.shape[:batch])
    w_hi = w.amax(dim=(action_dim, *state)) if w.numel() else w.new_zeros(V.shape[:batch])
    k_lo, k_hi = w_lo / (1.0 - w_lo), w_hi / (1.0 - w_hi)
    if not bool(((w_hi < 1.0) & (w_lo >= 0.0)).all()):  # rows far from stochastic
        k_lo = k_hi = torch.full_like(w_lo, float("inf"))
    residual = float("inf")
    bracket = None  # the last step's (middle, half-width) of V* - V, per problem
    closed = False  # stopped by the bracket
    for _ in range(max_iterations):
        V_new = (model.R + g * E(V)).amax(action_dim)
        d = V_new - V
        V = V_new
        if not d.numel():
            residual = 0.0
            break
        hi, lo = d.amax(dim=state), d.amin(dim=state)  # (*batch,)
        upper = torch.where(hi >= 0, k_hi, k_lo) * hi  # V* - V <= upper
        lower = torch.where(lo >= 0, k_lo, k_hi) * lo  # V* - V >= lower
        residual = float(d.abs().max())
        if residual < threshold:
            bracket = None  # the contraction bound below
            break
        half = (upper - lower) / 2.0
        bracket = ((upper + lower) / 2.0, half) if bool(torch.isfinite(half).all()) else None
        # the bracket cannot close below the round-off of d, amplified by k: near discount 1
        # and with large values, tol may lie below it (the bound is then that wide, and said)
        floor = BRACKET_ROUND_OFF * float(k_hi.max()) * float(V.abs().max())
        if bracket is not None and float(half.max()) < max(tol, floor) / 2.0:
            closed = True
            break
    error = g * residual / (1.0 - g)  # the contraction bound on |V - V*|
    # stopped by the bracket, or at the cap where the bracket is the narrower: its middle
    if bracket is not None and (closed or float(bracket[1].max()) < error):
        V = V + bracket[0].reshape(*V.shape[:batch], *(1,) * sd)
        error = float(bracket[1].max())
    Q = model.R + g * E(V)
    return Q, g * error


def qmdp_vectors(
    model: AnyModel, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> torch.Tensor:
    """QMDP upper-bound vectors, one per action: ``(..., A, S)`` or ``(..., A, X, Y)``.

    ``max_a vectors[a] . b >= V*(b)`` for every belief ``b`` (for a MOMDP at ``(x, b_y)``,
    ``max_a vectors[a, x] . b_y >= V*(x, b_y)``). A sparse model
    (:class:`~torchhrc.sparse.SparsePOMDP`, :class:`~torchhrc.sparse_momdp.SparseMOMDP`) is
    iterated by its solver form, on its stored successors only (to ``tol``, without the
    ``max_iterations`` cap).

    Raises:
        TypeError: ``model`` of no known form.
        ModelError: ``model.discount >= 1``.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> qmdp_vectors(random_pomdp(4, 3, 2, batch_shape=(5,), seed=1)).shape
        torch.Size([5, 3, 4])
    """
    if not isinstance(model, (POMDP, MOMDP)):
        return bound_form(model).upper_vectors("qmdp", tol)
    Q, bound = mdp_q_values(model, tol=tol, max_iterations=max_iterations)
    return Q + bound


def bound_form(model: AnyModel) -> SolverModel:
    """The solver form of an unbatched model whose discount is below 1 (the bounds' check)."""
    from torchhrc.solvers.forms import as_solver_model  # (the forms import this module)

    form = as_solver_model(model)
    if form.discount >= 1.0:
        raise ModelError(f"the upper bounds need discount < 1, got {form.discount}")
    return form


def qmdp_policy(
    model: AnyModel, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> AlphaVectorPolicy:
    """The QMDP policy of an unbatched model (its value is an upper bound on ``V*``).

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> qmdp_policy(random_pomdp(3, 2, 2, seed=0)).num_vectors
        2
    """
    vectors = qmdp_vectors(model, tol=tol, max_iterations=max_iterations)
    return AlphaVectorPolicy.from_action_vectors(vectors, momdp=bound_form(model).factored)


@dataclass(frozen=True, kw_only=True)
class IterationConfig:
    """A tolerance and an iteration cap, validated (the settings of the bound solvers)."""

    tol: float = 1e-8
    max_iterations: int = 100_000

    def __post_init__(self) -> None:
        if not self.tol > 0:
            raise ValueError(f"expected tol > 0, got {self.tol}")
        if self.max_iterations < 1:
            raise ValueError(f"expected max_iterations >= 1, got {self.max_iterations}")


@dataclass(frozen=True, kw_only=True)
class QMDPConfig(IterationConfig):
    """Settings of :func:`qmdp` (keyword-only).

    Attributes:
        tol: accuracy of the underlying MDP's value iteration.
        max_iterations: cap on its iterations.
    """


def bound_solution(model: AnyModel, vectors: torch.Tensor, start: float, name: str) -> Solution:
    """A :class:`Solution` whose policy is the given upper-bound vectors (one per action).

    ``upper`` is their value at the start; ``lower`` is the blind-policy lower bound there
    (the upper-bound policy's own value is not known without simulation). Both through the
    model's solver form (:meth:`~torchhrc.solvers.forms.base.SolverModel.value_at_roots`: at
    ``b0``, or the expectation over a random first ``x``, which is seen before acting).
    """
    form = bound_form(model)
    policy = AlphaVectorPolicy.from_action_vectors(vectors, momdp=form.factored)
    upper = form.value_at_roots(policy)
    lower = form.value_at_roots(form.blind_policy())
    elapsed = time.perf_counter() - start
    entry = {
        "time_s": elapsed,
        "lower": lower,
        "upper": upper,
        "gap": upper - lower,
        "n_alphas": policy.num_vectors,
        "n_beliefs": 1,
    }
    return Solution(
        policy=policy,
        lower=lower,
        upper=upper,
        history=[entry],
        info={"solver": name, "lower_from": "blind policies"},
    )


def solve_bound(
    model: AnyModel,
    config: IterationConfig | None,
    config_type: type[IterationConfig],
    vectors: Callable[..., torch.Tensor],
    name: str,
) -> Solution:
    """Validate, compute ``vectors(model, tol=..., max_iterations=...)`` and wrap them with
    :func:`bound_solution` (the one body of :func:`qmdp` and :func:`~torchhrc.solvers.fib.fib`).
    """
    start = time.perf_counter()
    config = config_type() if config is None else config
    if not isinstance(config, config_type):
        raise TypeError(
            f"expected config to be a {config_type.__name__}, got {type(config).__name__}"
        )
    if len(getattr(model, "batch_shape", ())):
        raise ModelError(f"{name} solves one model, got batch_shape {tuple(model.batch_shape)}")
    found = vectors(model, tol=config.tol, max_iterations=config.max_iterations)
    return bound_solution(model, found, start, name)


def qmdp(model: AnyModel, config: QMDPConfig | None = None) -> Solution:
    """Solve with QMDP: the policy is the QMDP vectors, ``upper`` their value at ``b0``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> round(qmdp(tiger()).upper, 6)
        189.0
    """
    return solve_bound(model, config, QMDPConfig, qmdp_vectors, "qmdp")
