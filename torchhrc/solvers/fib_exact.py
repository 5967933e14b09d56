"""The Fast Informed Bound's fixed point of a small flat model, exactly, by policy iteration.

FIB (Hauskrecht 2000) is the fixed point ``F*`` of::

    F(alpha)[a, s] = R[a, s] + gamma sum_o max_a2 sum_s2 W[a, s, o, s2] alpha[a2, s2]

with ``W[a, s, o, s2] = T[a, s, s2] Z[a, s2, o]``. The maximum is taken apart for each
``(a, s, o)``, so ``F`` is the Bellman operator of an MDP whose states are the pairs ``(a,
s)`` and whose decision at ``(a, s)`` picks one ``a2`` per ``o`` (its "policy" ``pi[a, s,
o]``). Howard's policy iteration therefore reaches ``F*`` in a few steps: the values of a
fixed ``pi`` are one linear system of ``A S`` unknowns, ``(I - gamma M_pi) alpha = R``, and
improving ``pi`` greedily never lowers them. On a model of a few states the iteration from
QMDP takes hundreds of steps to close within the search's tolerance (Tiger at precision 1e-3:
329 steps, 8 of the 14 ms of a one-iteration solve); one system of 6 unknowns, solved once,
replaces them.

The result is certified as the iteration's is: one step ``F(alpha)`` from the policy's values
``alpha`` and the bracket of MacQueen (1966), ``F* <= F(alpha) + k max(F(alpha) - alpha)``
(``k = w / (1 - w)``, ``w`` the operator's weight on a constant, ``gamma`` times a row's sum:
:func:`~torchhrc.solvers._factored.bracket_slack`), so the vectors returned are an upper bound
of ``F*``, hence of the optimal value, whatever the round-off of the solves.

Example:
    >>> import numpy as np
    >>> T = np.array([[[1.0, 0.0], [0.0, 1.0]]])  # one action: stay
    >>> Z = np.ones((1, 2, 1))  # one observation
    >>> R = np.array([[1.0, 2.0]])
    >>> out = fib_fixed_point(T, Z, R, 0.5)
    >>> np.round(out.vectors, 9).tolist(), out.iterations  # R / (1 - gamma)
    ([[2.0, 4.0]], 1)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from torchhrc.solvers._factored import bracket_slack

__all__ = [
    "FIB_EXACT_MAX_ENTRIES",
    "FIB_EXACT_MAX_UNKNOWNS",
    "FIBFixedPoint",
    "fib_exact_pays",
    "fib_fixed_point",
]

#: Largest system ``A S`` solved by :func:`fib_fixed_point` (a 300-unknown LU is about 9e6
#: multiply-adds, a millisecond).
FIB_EXACT_MAX_UNKNOWNS = 300
#: Largest ``W[a, s, o, s2] = T Z`` it forms (``A S O S`` floats: 32 MB; hallway's is 378,000).
FIB_EXACT_MAX_ENTRIES = 1 << 22


class FIBFixedPoint(NamedTuple):
    """What :func:`fib_fixed_point` found."""

    vectors: np.ndarray  # (A, S) an upper bound of the FIB fixed point, within round-off of it
    iterations: int  # policy-improvement steps (each one linear solve)


def fib_exact_pays(A: int, S: int, O: int) -> bool:
    """Whether :func:`fib_fixed_point` is the cheaper way to FIB's fixed point of a dense
    flat model with ``A`` actions, ``S`` states and ``O`` observations: at most
    :data:`FIB_EXACT_MAX_UNKNOWNS` unknowns and :data:`FIB_EXACT_MAX_ENTRIES` entries of
    ``T Z``, and a solve (``(A S)^3 / 3`` multiply-adds)
    within 16 steps of the iteration it replaces (``(A S)^2 O`` each; the iteration takes
    16-330 steps on the small problems of the suite at precision 1e-3, the policy iteration
    one or two solves from QMDP's choices).

    Example:
        >>> fib_exact_pays(3, 2, 2), fib_exact_pays(5, 60, 21), fib_exact_pays(5, 870, 30)
        (True, True, False)
        >>> fib_exact_pays(1, 300, 1000)  # 300 unknowns, but T Z of 9e7 entries
        False
    """
    n = A * S
    return n <= FIB_EXACT_MAX_UNKNOWNS and n <= 48 * O and n * O * S <= FIB_EXACT_MAX_ENTRIES


def _step(W2: np.ndarray, R: np.ndarray, gamma: float, alpha: np.ndarray, O: int) -> np.ndarray:
    """``F(alpha) (A, S)``: ``W2 @ alpha.T`` is ``Q[a, s, o, a2] = sum_s2 W alpha[a2, s2]``."""
    A, S = R.shape
    return R + gamma * (W2 @ alpha.T).reshape(A, S, O, A).max(-1).sum(-1)


def fib_fixed_point(T: np.ndarray, Z: np.ndarray, R: np.ndarray, gamma: float,
                    start: np.ndarray | None = None, max_iterations: int = 64,
                    ) -> FIBFixedPoint | None:  # fmt: skip
    """FIB's per-action vectors ``(A, S)`` of a dense flat model by policy iteration.

    Args:
        T: ``(A, S, S)`` ``T[a, s, s2] = P(s2 | s, a)``.
        Z: ``(A, S, O)`` ``Z[a, s2, o] = P(o | s2, a)``.
        R: ``(A, S)`` rewards.
        gamma: the discount, in ``[0, 1)``.
        start: ``(A, S)`` vectors whose greedy choices start the iteration (QMDP's: its
            choices are usually most of FIB's); default ``R``. The result is at most
            ``start`` where ``start`` is an upper bound of FIB (the minimum is taken, as the
            iteration from QMDP keeps).
        max_iterations: the policy-improvement steps allowed.

    Returns:
        The vectors and the steps taken, or ``None`` where the iteration cannot certify its
        result: the linear system is singular (or its solution not finite), the steps run out,
        or the operator's weight on a constant is not below 1 (no bracket). The caller then
        iterates ``F``.

    Raises:
        ValueError: shapes that do not match, or ``gamma`` outside ``[0, 1)``.
    """
    T, Z, R = (np.asarray(t, dtype=np.float64) for t in (T, Z, R))
    if start is not None:
        start = np.asarray(start, dtype=np.float64)
    if T.ndim != 3 or T.shape[1] != T.shape[2]:
        raise ValueError(f"expected T to have shape (A, S, S), got {T.shape}")
    A, S = T.shape[:2]
    if Z.ndim != 3 or Z.shape[:2] != (A, S):
        raise ValueError(f"expected Z to have shape ({A}, {S}, O), got {Z.shape}")
    if R.shape != (A, S):
        raise ValueError(f"expected R to have shape ({A}, {S}), got {R.shape}")
    if not 0.0 <= gamma < 1.0:
        raise ValueError(f"expected gamma in [0, 1), got {gamma}")
    if start is not None and start.shape != (A, S):
        raise ValueError(f"expected start to have shape ({A}, {S}), got {start.shape}")
    O = Z.shape[2]
    # W2[(a, s, o), s2] = T[a, s, s2] Z[a, s2, o]
    W = T[:, :, None, :] * Z.transpose(0, 2, 1)[:, None, :, :]  # (A, S, O, S2)
    W2 = W.reshape(A * S * O, S)
    n = A * S
    eye = np.eye(n)
    alpha = R.copy() if start is None else start
    Q = (W2 @ alpha.T).reshape(A, S, O, A)
    pi = Q.argmax(-1)  # (A, S, O)
    choices = np.arange(A)
    for steps in range(1, max_iterations + 1):
        # M[(a, s), (a2, s2)] = sum_o W[a, s, o, s2] [pi[a, s, o] = a2]
        pick = (pi[:, :, None, :] == choices[:, None]).astype(np.float64)  # (A, S, A2, O)
        M = np.matmul(pick, W).reshape(n, n)  # (A, S, A2, S2): one small product per (a, s)
        try:
            alpha = np.linalg.solve(eye - gamma * M, R.reshape(n)).reshape(A, S)
        except np.linalg.LinAlgError:
            return None
        if not np.isfinite(alpha).all():
            return None
        Q = (W2 @ alpha.T).reshape(A, S, O, A)
        best = Q.argmax(-1)
        # change a choice only where another is better beyond round-off (no cycling on ties)
        mine = np.take_along_axis(Q, pi[..., None], -1)[..., 0]
        top = np.take_along_axis(Q, best[..., None], -1)[..., 0]
        better = top > mine + 1e-12 * np.maximum(1.0, np.abs(top))
        if not better.any():
            return _certified(W2, R, gamma, alpha, O, start, steps)
        pi = np.where(better, best, pi)
    return None


def _certified(W2: np.ndarray, R: np.ndarray, gamma: float, alpha: np.ndarray, O: int,
               start: np.ndarray | None, steps: int) -> FIBFixedPoint | None:  # fmt: skip
    """The policy's values ``alpha`` made an upper bound of ``F*`` (see the module); None
    without a bracket."""
    stepped = _step(W2, R, gamma, alpha, O)
    m = float((stepped - alpha).max())
    # the weight of a constant, per row: gamma times the row's sum over (o, s2) of T Z (1
    # within the model's tolerance); a bracket widened by the largest weight if m > 0, the
    # smallest if not
    unit = gamma * W2.sum(1).reshape(*R.shape, O).sum(-1)
    k = bracket_slack(float(unit.max() if m > 0 else unit.min()))
    if not np.isfinite(k):
        return None
    out = stepped + k * m  # MacQueen (1966): an upper bound of F*
    if start is not None:
        out = np.minimum(out, start)
    return FIBFixedPoint(out, steps)
