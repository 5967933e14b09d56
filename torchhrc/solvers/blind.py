"""Blind-policy lower bound: one alpha vector per action, "repeat a forever" (Hauskrecht 2000).

The value of always taking action ``a``, whatever is observed, solves::

    alpha_a(s) = R(a, s) + discount * sum_s2 T(a, s, s2) alpha_a(s2)

and ``max_a alpha_a . b <= V*(b)``: each vector is the value of an actual policy. SARSOP
initialises its lower bound this way (Kurniawati et al. 2008). The iteration starts at the
constant ``min R / (1 - discount)`` (a lower bound) and the operator is monotone, so every
iterate is a lower bound; stopping early is safe. Small systems (up to 2048 states per
action, or per action and hidden value for a static MOMDP) are solved exactly by LU instead.

MOMDP (Ong et al. 2010): vectors ``(A, X, Y)`` computed factored, never forming the flat
transition matrix.

Example:
    >>> import torch
    >>> from torchhrc.testing import random_pomdp
    >>> blind_vectors(random_pomdp(3, 2, 2, seed=0)).shape
    torch.Size([2, 3])
"""

from __future__ import annotations

import numpy as np
import torch

from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.solvers._factored import (
    Expectation,
    check_model,
    check_unit_discount,
    reward_bounds,
    state_dims,
)
from torchhrc.solvers.policy import AlphaVectorPolicy

__all__ = ["blind_policy", "blind_vectors"]


def blind_vectors(
    model: POMDP | MOMDP, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> torch.Tensor:
    """Blind-policy lower-bound vectors: ``(..., A, S)`` or ``(..., A, X, Y)``, batched.

    Args:
        model: a POMDP or MOMDP (leading batch dims allowed).
        tol: stop when the largest change of an iteration is below ``tol``.
        max_iterations: cap on the iterations.

    Returns:
        Vectors with ``vectors[a] . b <= V*(b)`` for every ``a`` and belief ``b``.

    Example:
        >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)
        >>> m = POMDP(T=T, Z=torch.ones(1, 2, 1, dtype=torch.float64),
        ...           R=torch.tensor([[1.0, 2.0]], dtype=torch.float64),
        ...           b0=torch.tensor([0.5, 0.5], dtype=torch.float64), discount=0.5)
        >>> blind_vectors(m).round(decimals=6)
        tensor([[2., 4.]], dtype=torch.float64)
    """
    model = check_model(model)
    check_unit_discount(model, "the blind lower bound")
    g = model.discount
    low, _ = reward_bounds(model)
    sd = state_dims(model)
    R = model.R
    start = (low / (1.0 - g)).reshape(*low.shape, *([1] * (sd + 1)))
    E = Expectation(model)
    exact = E.solve_fixed_point(R, g)
    if exact is not None:
        return exact  # the exact fixed point, up to the LU's round-off
    if E.sparse is not None and R.device.type == "cpu" and R.dim() == sd + 1:
        # unbatched sparse model on CPU: the same monotone iteration on numpy views of the
        # row-sparse operator (per-op overhead far below torch's at these sizes)
        M = E.sparse[1]
        cols, vals = M.cols.numpy(), M.vals.numpy()  # (W, R) each
        r = R.detach().reshape(-1).numpy()
        a = np.full_like(r, float(start.reshape(())))
        for _ in range(max_iterations):
            new = np.maximum(r + g * (vals * a[cols]).sum(0), a)
            change = float(np.abs(new - a).max()) if new.size else 0.0
            a = new
            if change < tol * (1.0 - g):
                break
        return torch.from_numpy(a).view(R.shape)
    alpha = torch.zeros_like(R) + start
    for _ in range(max_iterations):
        new = torch.maximum(R + g * E(alpha, per_action=True), alpha)
        change = (new - alpha).abs().max().item() if new.numel() else 0.0
        alpha = new
        if change < tol * (1.0 - g):
            break
    return alpha


def blind_policy(
    model: POMDP | MOMDP, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> AlphaVectorPolicy:
    """The blind policies of an unbatched model as an :class:`AlphaVectorPolicy`.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> blind_policy(random_momdp(3, 2, 2, 2, seed=0)).observed.tolist()
        [0, 0, 1, 1, 2, 2]
    """
    vectors = blind_vectors(model, tol=tol, max_iterations=max_iterations)
    return AlphaVectorPolicy.from_action_vectors(vectors, momdp=state_dims(model) == 2)
