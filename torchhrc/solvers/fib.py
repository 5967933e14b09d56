"""The Fast Informed Bound (Hauskrecht 2000): an upper bound tighter than QMDP.

One vector per action, the fixed point of::

    alpha_a(s) = R(a, s) + discount * sum_o max_a2 sum_s2 T(a, s, s2) Z(a, s2, o) alpha_a2(s2)

It keeps the observation inside the maximisation, so ``V*(b) <= max_a alpha_a . b <=`` QMDP
(Hauskrecht 2000, Thm. 9). The iteration starts from the QMDP vectors, and the operator is
monotone, so every iterate is already an upper bound (stopping early is safe).

MOMDP (Ong et al. 2010): the observed part ``x2`` of the next state acts as a second,
exact observation; the vectors are ``(A, X, Y)``. When the hidden value is static
(``Ty = None``) the successor's hidden value is known given ``(y, x2, o)`` and FIB equals QMDP.

Per iteration the flat cost is ``A * S * S * O * A`` (one batched matmul, no ``(A, O, S, S)``
tensor). An unbatched model (dense, MOMDP or sparse) is iterated by its solver form
(:meth:`~torchhrc.solvers.forms.base.SolverModel.fib_vectors`, SARSOP's initialisation: numpy
on the CPU, ``Ty`` kept factored), a batch by the torch kernels of
:mod:`~torchhrc.solvers.tensor_bounds` (:func:`fib_backup` is theirs, re-exported here).

Example:
    >>> import torch
    >>> from torchhrc.testing import random_pomdp
    >>> from torchhrc.solvers.qmdp import qmdp_vectors
    >>> model = random_pomdp(4, 2, 3, seed=0)
    >>> bool((fib_vectors(model) <= qmdp_vectors(model) + 1e-8).all())  # (each to its tol)
    True
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from torchhrc.solvers.clock import NEVER
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.qmdp import IterationConfig, bound_form, solve_bound
from torchhrc.solvers.solution import Solution
from torchhrc.solvers.tensor_bounds import fib_backup, tensor_fib_vectors

if TYPE_CHECKING:
    from torchhrc.solvers.qmdp import AnyModel

__all__ = ["FIBConfig", "fib", "fib_backup", "fib_policy", "fib_vectors"]


def fib_vectors(
    model: AnyModel,
    *,
    tol: float = 1e-8,
    max_iterations: int = 100_000,
    initial: torch.Tensor | None = None,
) -> torch.Tensor:
    """FIB upper-bound vectors, one per action: ``(..., A, S)`` or ``(..., A, X, Y)``, batched.

    An unbatched model without ``initial`` is iterated by its solver form (the code of
    SARSOP's initialisation; a sparse model too): on TagAvoid as a MOMDP (870 x 29 states)
    0.8 s against 9.8 s for the batched torch kernel, which forms an ``(A, X, Y, X2, O, A)``
    product for every ``x``. The form's iteration also stops once the bounds of MacQueen
    (1966) put it within ``tol`` of the fixed point (near discount 1, long before the change
    falls below ``tol``; see ``tensor_bounds._iterate_fib``), so the two agree to about ``tol``.

    Args:
        model: a POMDP or MOMDP (leading batch dims allowed), or an unbatched
            :class:`~torchhrc.pomdp.SparsePOMDP` / :class:`~torchhrc.pomdp.SparseMOMDP`.
        tol: stop within ``tol`` of FIB's fixed point (MacQueen's bracket or the
            contraction bound, as ``tensor_bounds._iterate_fib``).
        max_iterations: cap on the iterations.
        initial: starting vectors, which must be an upper bound (default: QMDP).

    Returns:
        Vectors with ``max_a vectors[a] . b >= V*(b)``, never above the QMDP vectors by more
        than ``tol``.

    Raises:
        TypeError: ``model`` of no known form.
        ModelError: ``model.discount >= 1``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> fib_vectors(random_momdp(3, 2, 2, 2, static=False, seed=0)).shape
        torch.Size([2, 3, 2])
    """
    if initial is None and not len(getattr(model, "batch_shape", ())):
        return bound_form(model).fib_vectors(tol, NEVER, max_iterations)[0]
    return tensor_fib_vectors(model, tol=tol, max_iterations=max_iterations, initial=initial)


def fib_policy(model: AnyModel, *, tol: float = 1e-8) -> AlphaVectorPolicy:
    """The FIB vectors of an unbatched model as a policy (its value is an upper bound).

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> fib_policy(random_pomdp(3, 2, 2, seed=0)).num_vectors
        2
    """
    vectors = fib_vectors(model, tol=tol)
    return AlphaVectorPolicy.from_action_vectors(vectors, momdp=bound_form(model).factored)


@dataclass(frozen=True, kw_only=True)
class FIBConfig(IterationConfig):
    """Settings of :func:`fib` (keyword-only).

    Attributes:
        tol: stop when an iteration changes the vectors by less than this.
        max_iterations: cap on the iterations.
    """


def fib(model: AnyModel, config: FIBConfig | None = None) -> Solution:
    """Solve with the Fast Informed Bound: the policy is the FIB vectors, ``upper`` at ``b0``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> fib(tiger()).upper < 189.0
        True
    """
    return solve_bound(model, config, FIBConfig, fib_vectors, "fib")
