"""The bound kernels of the tensor models (:class:`~torchhrc.pomdp.POMDP`,
:class:`~torchhrc.pomdp.MOMDP`, leading batch dims allowed): the lowest layer of the bounds.

* QMDP (Littman et al. 1995): value iteration on the underlying MDP, :func:`mdp_q_values`,
  and its upper-bound vectors :func:`mdp_upper_vectors`;
* the Fast Informed Bound (Hauskrecht 2000): one step of its operator, :func:`fib_backup`,
  and the iteration with the bracket of MacQueen (1966), :func:`_iterate_fib` (also the
  iteration of every solver form's FIB operator) and :func:`tensor_fib_vectors`.

The solver forms (:mod:`torchhrc.solvers.forms`) build on these; the bound algorithms
(:mod:`torchhrc.solvers.qmdp`, :mod:`torchhrc.solvers.fib`: ``qmdp_vectors``, ``fib_vectors``
and the ``qmdp``/``fib`` solvers, which take any model with a form) build on the forms, and
re-export these names. The kernels tell a flat model from a factored one by the layout of its
values (:func:`~torchhrc.solvers._factored.state_dims`), never by testing its class.

Example:
    >>> from torchhrc.testing import random_pomdp
    >>> model = random_pomdp(4, 2, 3, seed=0)
    >>> bool((tensor_fib_vectors(model) <= mdp_upper_vectors(model) + 1e-8).all())
    True
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.solvers._factored import (
    BRACKET_ROUND_OFF,
    Expectation,
    bracket_slack,
    check_model,
    check_unit_discount,
    state_dims,
)
from torchhrc.solvers.clock import NEVER, Deadline

__all__ = ["fib_backup", "mdp_q_values", "mdp_upper_vectors", "tensor_fib_vectors"]


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


def mdp_upper_vectors(
    model: POMDP | MOMDP, *, tol: float = 1e-8, max_iterations: int = 100_000
) -> torch.Tensor:
    """QMDP upper-bound vectors of a tensor model, batched: ``Q + error_bound`` of
    :func:`mdp_q_values`, ``(..., A, S)`` or ``(..., A, X, Y)``.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> mdp_upper_vectors(random_pomdp(4, 3, 2, batch_shape=(5,), seed=1)).shape
        torch.Size([5, 3, 4])
    """
    Q, bound = mdp_q_values(model, tol=tol, max_iterations=max_iterations)
    return Q + bound


def _iterate_fib(start: torch.Tensor, step: Callable[[torch.Tensor], torch.Tensor],
                 tol: float, deadline: Deadline, max_iterations: int,
                 info: dict[str, Any], discount: float) -> torch.Tensor:  # fmt: skip
    """``alpha <- min(step(alpha), alpha)`` from the upper bound ``start`` (Hauskrecht 2000).

    The FIB operator ``F`` is monotone, so every iterate is an upper bound and stopping early
    is safe. It is also a ``discount``-contraction that moves with a constant:
    ``F(alpha + c) = F(alpha) + discount * c`` (the weights ``P(o | a, s)`` of an action's
    row sum to 1), as a Bellman operator, so the bounds of MacQueen (1966) and Porteus (1971)
    hold with ``d = F(alpha) - alpha`` and ``k = discount / (1 - discount)``::

        F(alpha) + k min(d) <= F* <= F(alpha) + k max(d)

    ``F(alpha) + k max(d)`` is another upper bound, much tighter near discount 1, where plain
    iteration closes the excess over ``F*`` by ``discount`` a step. The iteration stops
    within ``tol`` of ``F*``: when the change is below ``tol / (2 k)`` (the contraction
    bound; the iterate is returned as it is), or once ``k (max d - min d) < tol`` (or below
    the round-off of ``d`` amplified by ``k``, where that is wider); ``info["stop"] =
    "converged"`` both. Else it stops after ``max_iterations`` or at ``deadline``. In all but
    the first case the result is the smaller of the iterate and the bound of the last step.
    (A change below ``tol`` alone is ``k`` times too weak: on pomdp.org's ``baseball``,
    discount 0.999, FIB stopped after one step, 0.006 above ``F*`` at ``b0``.)

    ``deadline`` (a safety net) is read from the second step on, and the forms compute the
    QMDP ``start`` to its tolerance whatever it says, so the result is never looser than one
    FIB step from QMDP: on a loaded machine the net had cut the QMDP iteration before its
    first sweep, and flat RockSample(4, 2) started SARSOP from the corners ``max R / (1 -
    discount)`` (an upper bound of 125-147 after 5 s against 15.18, where it converges in
    1.4 s). QMDP is an MDP value iteration, each sweep cheap next to a FIB step (APPL's
    ``FullObsUBInitializer`` has no time limit either).

    A model's rows may sum to 1 only within its validation's tolerance, so the weight of a
    constant, ``F(1) - F(0)`` (``discount`` times each row's sum), is measured: ``k`` is
    ``w / (1 - w)`` for its smallest entry ``w`` (:func:`~torchhrc.solvers._factored.\
bracket_slack`), which keeps the bound valid when ``max(d) <= 0`` (always, from an upper
    start); no shift is applied otherwise, nor where ``w`` is not below 1.
    """
    if start.device.type == "cpu":
        # numpy between the steps (the same elementwise floats): on a small model a step is
        # a few us of arithmetic, and each torch call here cost more (tiger: 12 % of a solve
        # to 1e-3 in this loop)
        def advance(a: np.ndarray) -> np.ndarray:
            return step(torch.from_numpy(a)).numpy()

        alpha, minimum, like = start.numpy(), np.minimum, np.full_like
    else:
        advance, alpha, minimum, like = step, start, torch.minimum, torch.full_like  # type: ignore[assignment]
    k = bracket_slack(float((advance(like(alpha, 1.0)) - advance(like(alpha, 0.0))).min()))
    # a change below this puts the iterate within tol of F* (the contraction bound, k max|d|)
    threshold = tol / (2.0 * k) if 0.0 < k < math.inf else tol
    info["stop"] = "max_iterations"
    shifted = None  # the bound F(alpha) + k max(d) of the last step
    for i in range(max_iterations):
        if i > 0 and deadline.passed():  # the first step runs whatever the clock says
            info["stop"] = "time_limit"
            break
        stepped = advance(alpha)
        d = stepped - alpha
        nonempty = math.prod(d.shape) > 0
        hi, lo = (float(d.max()), float(d.min())) if nonempty else (0.0, 0.0)
        new = minimum(stepped, alpha)
        change = float(abs(alpha - new).max()) if nonempty else 0.0
        alpha = new
        info["iterations"] = i + 1
        if change < threshold:  # within tol of F*: as it is
            info["stop"] = "converged"
            shifted = None
            break
        shifted = stepped + k * hi if hi <= 0.0 and math.isfinite(k) else None
        if shifted is not None:
            # the bracket cannot close below the round-off of d amplified by k
            floor = BRACKET_ROUND_OFF * k * float(abs(alpha).max())
            if k * (hi - lo) < max(tol, floor):
                info["stop"] = "converged"
                break
    if shifted is not None:
        alpha = minimum(alpha, shifted)
    return torch.from_numpy(alpha) if isinstance(alpha, np.ndarray) else alpha


_CHUNK_ELEMENTS = 1 << 24


def _flat_step(model: POMDP, alpha: torch.Tensor) -> torch.Tensor:
    T, Z, R = model.T, model.Z, model.R
    A, S, O = T.shape[-3], T.shape[-1], Z.shape[-1]
    # Y[..., a, s2, o, a2] = Z[..., a, s2, o] * alpha[..., a2, s2]
    Y = Z.unsqueeze(-1) * alpha.transpose(-1, -2).unsqueeze(-2).unsqueeze(-4)
    # G[..., a, s, o, a2] = sum_s2 T[..., a, s, s2] Y[..., a, s2, o, a2]
    G = T @ Y.reshape(*Y.shape[:-3], S, O * A)
    G = G.reshape(*G.shape[:-1], O, A)
    return R + model.discount * G.amax(-1).sum(-1)


def _momdp_step(model: MOMDP, alpha: torch.Tensor) -> torch.Tensor:
    Tx, Ty, Z, R, g = model.Tx, model.Ty, model.Z, model.R, model.discount
    if Ty is None:
        # sum_y2 collapses to y2 = y: max_a2 moves inside the products of nonnegative terms.
        # inner[..., a, x2, y] = sum_o Z[..., a, x2, y, o] * max_a2 alpha[..., a2, x2, y]
        inner = Z.sum(-1) * alpha.amax(-3).unsqueeze(-3)
        return R + g * torch.einsum("...axyz,...azy->...axy", Tx, inner)
    A, X, Y = Tx.shape[-4], Tx.shape[-3], Tx.shape[-2]
    O = Z.shape[-1]
    # K[..., a, x2, o, a2, y2] = Z[..., a, x2, y2, o] * alpha[..., a2, x2, y2]
    K = Z.permute(*range(Z.dim() - 4), -4, -3, -1, -2).unsqueeze(-2) * alpha.permute(
        *range(alpha.dim() - 3), -2, -3, -1
    ).unsqueeze(-4).unsqueeze(-3)
    per_x = max(1, A * Y * X * O * A * Y)
    chunk = max(1, _CHUNK_ELEMENTS // per_x)
    parts = []
    for start in range(0, X, chunk):
        stop = min(X, start + chunk)
        P = Tx[..., start:stop, :, :].unsqueeze(-1) * Ty[..., start:stop, :, :, :]
        # G[..., a, x, y, x2, o, a2] = sum_y2 P[..., a, x, y, x2, y2] K[..., a, x2, o, a2, y2]
        G = torch.einsum("...axyzw,...azoqw->...axyzoq", P, K)
        parts.append(G.amax(-1).sum((-1, -2)))
    return R + g * torch.cat(parts, dim=-2)


def fib_backup(model: POMDP | MOMDP, vectors: torch.Tensor) -> torch.Tensor:
    """One application of the FIB operator to ``vectors`` ``(..., A, S)`` / ``(..., A, X, Y)``.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> m = random_pomdp(3, 2, 2, seed=0)
        >>> fib_backup(m, torch.zeros(2, 3, dtype=torch.float64)).allclose(m.R)
        True
    """
    if state_dims(model) == 2:
        return _momdp_step(model, vectors)
    return _flat_step(model, vectors)


def tensor_fib_vectors(
    model: POMDP | MOMDP,
    *,
    tol: float = 1e-8,
    max_iterations: int = 100_000,
    initial: torch.Tensor | None = None,
) -> torch.Tensor:
    """FIB vectors of a tensor model by the torch kernel (batched): :func:`fib_backup` iterated
    by :func:`_iterate_fib` from ``initial`` (an upper bound; default the QMDP vectors).

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> tensor_fib_vectors(random_momdp(3, 2, 2, 2, static=False, seed=0)).shape
        torch.Size([2, 3, 2])
    """
    model = check_model(model)
    check_unit_discount(model, "FIB")
    alpha = mdp_upper_vectors(model, tol=tol) if initial is None else initial

    # the same iteration and stopping rule as the form's: a change below tol alone stops
    # discount / (1 - discount) times too early (over a batch, the bracket is taken over all
    # its members, which is valid for each and stops no earlier than each would)
    def step(vectors: torch.Tensor) -> torch.Tensor:
        return fib_backup(model, vectors)

    return _iterate_fib(alpha, step, tol, NEVER, max_iterations, {}, model.discount)
