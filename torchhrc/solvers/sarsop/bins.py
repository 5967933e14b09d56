"""SARSOP's value-directed binning: the predictor ``V_hat`` of the optimal value at a belief,
learned online, which tells a trial where to stop (Kurniawati et al. 2008, section 4.2).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__: list[str] = []


class _Bins:
    """SARSOP's lower-bound predictor ``V_hat``, as APPL's ``BinManagerSet`` computes it.

    One predictor per observed value ``x`` (a flat model has one), two levels of bins over
    (initial upper bound, entropy): ``ceil(n / 2)`` and ``n`` bins per axis (APPL: 5 and 10).
    A belief is binned once, by the value at it of the *initial* upper bound (the corner
    values, fixed: its bin never moves) over the range of its ``x``'s corner values, and by
    its entropy over ``log Y``; a bin holds the mean of the latest lower bounds of its beliefs
    (one entry per distinct belief, not per tree node) and the sum of its beliefs' squared
    prediction errors, and the prediction comes from the level whose bin has the smaller
    error (Kurniawati et al. 2008, section 4.2; APPL ``BinManager.cpp``). A belief alone in
    its coarse bin is predicted at its upper bound, which sends the search on to explore it.
    """

    def __init__(self, corner: np.ndarray, max_entropy: float, n: int) -> None:
        self.corner = corner  # (X, Y) initial upper-bound corner values
        self.lo = corner.min(1)
        self.span = np.maximum(corner.max(1) - self.lo, 1e-12)
        self.max_entropy = max(max_entropy, 1e-12)
        self.sizes = (max(1, (n + 1) // 2), n) if n > 1 else (1,)
        # per level, the bins in use: (x, i, j) -> [sum of lower bounds, count, squared error]
        # (plain floats in lists: a backup updates two bins, where numpy scalar access cost
        # more than the arithmetic)
        self.cells: list[dict[tuple[int, int, int], list[float]]] = [{} for _ in self.sizes]
        # belief id -> [x, its bin (i, j) per level, last lower bound, squared error per
        # level, those bins' cells] (a list, updated in place: a backup allocates nothing)
        self.state: dict[int, list[Any]] = {}

    def update(self, key: int, x: int, belief: np.ndarray, entropy: float, upper: float,
               lower: float) -> None:  # fmt: skip
        """Record the lower bound ``lower`` of the belief ``key`` (of observed value ``x``)."""
        st = self.state.get(key)
        if st is None:
            u0 = float(self.corner[x] @ belief)
            where, cells, errs = [], [], []
            for lv, k in enumerate(self.sizes):
                i = int(min(k - 1, max(0.0, (u0 - self.lo[x]) / self.span[x] * k)))
                j = int(min(k - 1, max(0.0, entropy / self.max_entropy * k)))
                cell = self.cells[lv].setdefault((x, i, j), [0.0, 0.0, 0.0])
                c = cell[1]
                err = upper - lower if c == 0 else cell[0] / c - lower
                cell[2] += err * err
                cell[0] += lower
                cell[1] = c + 1
                where.append((i, j))
                cells.append(cell)
                errs.append(err * err)
            self.state[key] = [x, where, lower, errs, cells]
            return
        prev, errs = st[2], st[3]
        for lv, cell in enumerate(st[4]):
            c = cell[1]
            if c == 1:
                err = upper - lower
                cell[2] = err * err
            else:
                err = cell[0] / c - lower
                cell[2] += err * err - errs[lv]
            errs[lv] = err * err
            cell[0] += lower - prev
        st[2] = lower

    def predict(self, key: int, upper: float, lower: float) -> float:
        """The predicted optimal value at the belief ``key``, within ``[lower, upper]``."""
        st = self.state.get(key)
        if st is None:
            return upper
        cells = st[4]
        if cells[0][1] <= 1:
            return upper
        best = 0
        smallest = cells[0][2]
        for lv in range(1, len(cells)):
            e = cells[lv][2]
            if e + 1e-10 < smallest:
                best, smallest = lv, e
        total, count, _ = cells[best]
        return min(upper, max(lower, total / count))
