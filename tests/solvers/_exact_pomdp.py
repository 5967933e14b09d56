"""An exact finite-horizon POMDP solver for tests (not part of the library).

Exact value iteration over alpha vectors (Sondik 1971; Monahan 1982): at each step

    Gamma_{a,o} = { discount * T_a diag(Z_a[:, o]) alpha : alpha in Gamma }
    Gamma_a     = R_a (+) Gamma_{a,1} (+) ... (+) Gamma_{a,O}     (cross sums)
    Gamma'      = prune(union_a Gamma_a)

with incremental pruning (Cassandra, Littman, Zhang 1997): every cross sum is pruned to the
vectors that are the strict maximum somewhere on the simplex. Pruning is exact: for two
states by the upper envelope of lines on [0, 1], otherwise by Lark's linear program
(scipy's HiGHS). The horizon-H values bracket the infinite-horizon optimum:

    V_H(b) + discount^H min(0, Rmin) / (1 - discount) <= V*(b)
                                         <= V_H(b) + discount^H max(0, Rmax) / (1 - discount)

Written independently of torchhrc.solvers (numpy + scipy only) so it can check them.
"""

from __future__ import annotations

import numpy as np

#: Optimal value of Tiger (Kaelbling et al. 1998; discount 0.95) at the uniform belief, from
#: this solver at horizon 300: 19.37095 <= V* <= 19.37141 (test_bounds.py re-derives it).
TIGER_OPTIMUM = 19.3710

#: Largest increase of the value function a pruned vector may carry (per pruning).
MARGIN = 1e-9


def _dedupe(vectors: np.ndarray) -> np.ndarray:
    rounded = np.round(vectors, 12)
    _, index = np.unique(rounded, axis=0, return_index=True)
    return vectors[np.sort(index)]


def _pointwise(vectors: np.ndarray) -> np.ndarray:
    keep = np.ones(len(vectors), dtype=bool)
    for i in range(len(vectors)):
        others = np.delete(np.arange(len(vectors)), i)
        others = others[keep[others]]
        if len(others) and np.any(np.all(vectors[others] >= vectors[i] - 1e-12, axis=1)):
            keep[i] = False
    return vectors[keep]


def _envelope_2(vectors: np.ndarray) -> np.ndarray:
    """Exact upper envelope on p = P(state 1) in [0, 1] of lines v0 + p * slope.

    The classic sweep: lines sorted by slope; a line is dropped when the next one overtakes
    it before it overtakes the previous one. Lines that win only on an interval shorter than
    1e-12 (touching at a point) are dropped: they do not change the envelope.
    """
    v0, slope = vectors[:, 0], vectors[:, 1] - vectors[:, 0]
    order = np.lexsort((v0, slope))  # by slope, then intercept
    hull: list[int] = []
    starts: list[float] = []  # where each hull line starts winning
    for i in order:
        if hull and slope[hull[-1]] == slope[i]:
            hull.pop()  # same slope: the later (larger intercept) line wins everywhere
            starts.pop()
        while hull:
            j = hull[-1]
            cross = (v0[j] - v0[i]) / (slope[i] - slope[j])  # line i overtakes j here
            if cross <= starts[-1] + 1e-12:
                hull.pop()
                starts.pop()
            else:
                break
        if not hull:
            hull.append(i)
            starts.append(-np.inf)
        else:
            j = hull[-1]
            hull.append(i)
            starts.append((v0[j] - v0[i]) / (slope[i] - slope[j]))
    ends = [*starts[1:], np.inf]
    keep = [h for h, a, b in zip(hull, starts, ends) if min(b, 1.0) - max(a, 0.0) > 1e-12]
    # drop lines that raise the envelope by less than MARGIN anywhere (the largest gain of
    # line i over its neighbours j, k is where j and k cross); never two neighbours at once
    while len(keep) > 2:
        dropped = False
        out = [keep[0]]
        for idx in range(1, len(keep) - 1):
            j, i, k = out[-1], keep[idx], keep[idx + 1]
            p = (v0[j] - v0[k]) / (slope[k] - slope[j])
            p = min(1.0, max(0.0, p))
            gain = v0[i] + p * slope[i] - max(v0[j] + p * slope[j], v0[k] + p * slope[k])
            if gain < MARGIN and out[-1] == keep[idx - 1]:
                dropped = True
                continue
            out.append(i)
        out.append(keep[-1])
        keep = out
        if not dropped:
            break
    return vectors[keep]


def _lark(vectors: np.ndarray) -> np.ndarray:
    from scipy.optimize import linprog

    vectors = _pointwise(_dedupe(vectors))
    n, S = vectors.shape
    if n <= 1:
        return vectors
    # vectors that win at a grid belief are certainly useful: no LP for them
    grid = np.random.default_rng(0).dirichlet(np.ones(S), size=64 * S)
    grid = np.vstack([grid, np.eye(S)])
    winners = set(np.argmax(grid @ vectors.T, axis=1).tolist())
    keep = []
    for i in range(n):
        if i in winners:
            keep.append(i)
            continue
        others = np.delete(vectors, i, axis=0)
        # maximise d s.t. b . (alpha_i - alpha_j) >= d for all j, b in the simplex
        c = np.zeros(S + 1)
        c[-1] = -1.0
        A_ub = np.hstack([-(vectors[i] - others), np.ones((len(others), 1))])
        b_ub = np.zeros(len(others))
        A_eq = np.hstack([np.ones((1, S)), np.zeros((1, 1))])
        bounds = [(0, 1)] * S + [(None, None)]
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=[1.0], bounds=bounds, method="highs")
        if res.status == 0 and -res.fun > 1e-9:
            keep.append(i)
    return vectors[keep]


def prune(vectors: np.ndarray) -> np.ndarray:
    vectors = _dedupe(vectors)
    if vectors.shape[1] == 2:
        return _envelope_2(vectors)
    return _lark(vectors)


def exact_alpha_vectors(T, Z, R, discount: float, horizon: int) -> np.ndarray:
    """The pruned horizon-``horizon`` alpha vectors (K, S) of a flat POMDP (numpy arrays)."""
    T, Z, R = (np.asarray(t, dtype=np.float64) for t in (T, Z, R))
    A, S, _ = T.shape
    O = Z.shape[-1]
    gamma = np.zeros((1, S))
    for _ in range(horizon):
        new = []
        for a in range(A):
            # projections[o]: (N, S), discount * sum_s2 T[a, s, s2] Z[a, s2, o] alpha(s2)
            projections = [discount * (gamma * Z[a, :, o]) @ T[a].T for o in range(O)]
            acc = prune(projections[0] + R[a] / O)
            for o in range(1, O):
                cross = (acc[:, None, :] + projections[o][None, :, :] + R[a] / O).reshape(-1, S)
                acc = prune(cross)
            new.append(acc)
        gamma = prune(np.concatenate(new, axis=0))
    return gamma


def optimal_value_bounds(T, Z, R, discount: float, belief, horizon: int) -> tuple[float, float]:
    """``(low, high)`` bracketing the infinite-horizon optimal value at ``belief``."""
    gamma = exact_alpha_vectors(T, Z, R, discount, horizon)
    value = float(np.max(gamma @ np.asarray(belief, dtype=np.float64)))
    R = np.asarray(R, dtype=np.float64)
    tail = discount**horizon / (1.0 - discount)
    return value + tail * min(0.0, R.min()), value + tail * max(0.0, R.max())
