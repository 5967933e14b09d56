"""SARSOP's value-directed binning: the predictor ``V_hat`` of the optimal value at a belief,
learned online, which tells a trial where to stop (Kurniawati et al. 2008, section 4.2).
"""

from __future__ import annotations

from array import array
from itertools import repeat

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
        # per level, the bins in use: (x, i, j) -> [sum of lower bounds, count, squared error,
        # the bin's number] (plain floats in lists: a backup updates two bins, where numpy
        # scalar access cost more than the arithmetic), and the same cells by number
        self.cells: list[dict[tuple[int, int, int], list[float]]] = [{} for _ in self.sizes]
        self._cell_list: list[list[list[float]]] = [[] for _ in self.sizes]
        # per belief id (the search's ids run 0, 1, 2, ...): its cell's number per level (-1:
        # not binned yet), its last lower bound and its squared error per level, in flat
        # arrays (8 bytes an entry, where a list per belief held about 650 bytes of objects)
        self._at = [array("q") for _ in self.sizes]
        self._lower = array("d")
        self._errs = [array("d") for _ in self.sizes]

    def _grow(self, key: int) -> None:
        """Room for the belief ids up to ``key`` (at least doubled)."""
        n = max(key + 1, 2 * len(self._lower), 64) - len(self._lower)
        for at in self._at:
            at.extend(repeat(-1, n))
        self._lower.extend(repeat(0.0, n))
        for errs in self._errs:
            errs.extend(repeat(0.0, n))

    def where(self, key: int) -> list[tuple[int, int]] | None:
        """The bin ``(i, j)`` of the belief ``key`` at each level, or None if not binned."""
        if key >= len(self._lower) or self._at[0][key] < 0:
            return None
        # (a lookup for tests and inspection: the cells are few)
        return [next(k[1:] for k, cell in self.cells[lv].items() if cell[3] == at[key])
                for lv, at in enumerate(self._at)]  # fmt: skip

    def update(self, key: int, x: int, belief: np.ndarray, entropy: float, upper: float,
               lower: float) -> None:  # fmt: skip
        """Record the lower bound ``lower`` of the belief ``key`` (of observed value ``x``)."""
        if key >= len(self._lower):
            self._grow(key)
        if self._at[0][key] < 0:
            u0 = float(self.corner[x] @ belief)
            for lv, k in enumerate(self.sizes):
                i = int(min(k - 1, max(0.0, (u0 - self.lo[x]) / self.span[x] * k)))
                j = int(min(k - 1, max(0.0, entropy / self.max_entropy * k)))
                cell = self.cells[lv].get((x, i, j))
                if cell is None:  # a new bin: its number is its place in the list
                    cell = [0.0, 0.0, 0.0, len(self._cell_list[lv])]
                    self.cells[lv][(x, i, j)] = cell
                    self._cell_list[lv].append(cell)
                c = cell[1]
                err = upper - lower if c == 0 else cell[0] / c - lower
                cell[2] += err * err
                cell[0] += lower
                cell[1] = c + 1
                self._at[lv][key] = cell[3]
                self._errs[lv][key] = err * err
            self._lower[key] = lower
            return
        prev = self._lower[key]
        for lv, at in enumerate(self._at):
            cell = self._cell_list[lv][at[key]]
            errs = self._errs[lv]
            c = cell[1]
            if c == 1:
                err = upper - lower
                cell[2] = err * err
            else:
                err = cell[0] / c - lower
                cell[2] += err * err - errs[key]
            errs[key] = err * err
            cell[0] += lower - prev
        self._lower[key] = lower

    def predict(self, key: int, upper: float, lower: float) -> float:
        """The predicted optimal value at the belief ``key``, within ``[lower, upper]``."""
        if key >= len(self._lower):
            return upper
        at = self._at
        n0 = at[0][key]
        if n0 < 0:
            return upper
        cells = self._cell_list
        best = cells[0][n0]
        if best[1] <= 1:
            return upper
        smallest = best[2]
        for lv in range(1, len(at)):
            cell = cells[lv][at[lv][key]]
            if cell[2] + 1e-10 < smallest:
                best, smallest = cell, cell[2]
        return min(upper, max(lower, best[0] / best[1]))
