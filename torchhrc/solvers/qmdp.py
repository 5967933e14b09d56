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
from torchhrc.solvers.forms import as_solver_model
from torchhrc.solvers.forms.base import SolverModel
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.solution import Solution
from torchhrc.solvers.tensor_bounds import mdp_q_values, mdp_upper_vectors

if TYPE_CHECKING:
    from torchhrc.pomdp import MOMDP, POMDP, SparseMOMDP, SparsePOMDP

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


def qmdp_vectors(
    model: AnyModel, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> torch.Tensor:
    """QMDP upper-bound vectors, one per action: ``(..., A, S)`` or ``(..., A, X, Y)``.

    ``max_a vectors[a] . b >= V*(b)`` for every belief ``b`` (for a MOMDP at ``(x, b_y)``,
    ``max_a vectors[a, x] . b_y >= V*(x, b_y)``). A batch runs the torch kernel
    (:func:`~torchhrc.solvers.tensor_bounds.mdp_upper_vectors`); an unbatched model of any
    form is iterated by its solver form (``upper_vectors``): a dense POMDP or MOMDP by the same
    kernel, a sparse model (:class:`~torchhrc.pomdp.SparsePOMDP`,
    :class:`~torchhrc.pomdp.SparseMOMDP`) on its stored successors only (to ``tol``,
    without the ``max_iterations`` cap).

    Raises:
        TypeError: ``model`` of no known form.
        ModelError: ``model.discount >= 1``.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> qmdp_vectors(random_pomdp(4, 3, 2, batch_shape=(5,), seed=1)).shape
        torch.Size([5, 3, 4])
    """
    if len(getattr(model, "batch_shape", ())):  # a batch of tensor models: the torch kernel
        return mdp_upper_vectors(model, tol=tol, max_iterations=max_iterations)
    return bound_form(model).upper_vectors("qmdp", tol, max_iterations)


def bound_form(model: AnyModel) -> SolverModel:
    """The solver form of an unbatched model whose discount is below 1 (the bounds' check)."""
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
