"""SARSOP's per-belief cache of evaluations, stored at the possible children when they are few.

An evaluation of a belief gives, for every child ``(a, x2, o)``, its probability and bounds:
``prob``, ``low``, ``up`` of shape ``(A, K, O)``, with ``q_low`` and ``q_up`` ``(A,)``. The
search keeps the last one per distinct belief (it chooses the next step from it, and a backup
refreshes only the best action's children, APPL's ``getNewUBValueUseCache``). On a MOMDP most
children are impossible (APPL's ``TagAvoid.pomdpx``: 1.1 % of the 750 children of a belief
have ``P > 0``; 16 kB a belief, 288 MB of a 20 s solve): an entry then keeps only the
possible children's values and their flat indices (and any other nonzero entry), and is
expanded when read: the same arrays, bit for bit.

Example:
    >>> import numpy as np
    >>> cache = EvaluationCache()
    >>> prob = np.zeros((2, 1, 80)); prob[0, 0, 3] = 1.0
    >>> cache[7] = (np.zeros(2), np.ones(2), prob, prob * 2.0, prob * 5.0)
    >>> q_low, q_up, p, low, up = cache[7]
    >>> float(up[0, 0, 3]), cache.packed(7), 7 in cache, len(cache)
    (5.0, True, True, 1)
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

__all__ = ["EvaluationCache"]

Entry = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: an entry is packed when at most this fraction of its children is possible
PACK_FRACTION = 0.25
#: and when it has at least this many children (a small entry costs little memory, and its
#: expansion at every read would cost bridge-repair's 60-child beliefs 7 % of their backups)
PACK_MIN_CHILDREN = 128


class EvaluationCache:
    """``cache[key] = (q_low (A,), q_up (A,), prob, low, up (A, K, O))``; reads give the same
    five arrays (expanded from a packed entry: new arrays, safe to modify)."""

    def __init__(self) -> None:
        self._entries: dict[int, tuple] = {}

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: object) -> bool:
        return key in self._entries

    def __iter__(self) -> Iterator[int]:
        return iter(self._entries)

    def __setitem__(self, key: int, entry: Entry) -> None:
        prob = entry[2]
        if prob.size < PACK_MIN_CHILDREN:  # (the common case of small models: one check)
            self._entries[key] = entry
            return
        q_low, q_up, _, low, up = entry
        flat = prob.reshape(-1)
        nz = np.flatnonzero(flat)
        if nz.size > PACK_FRACTION * flat.size:
            self._entries[key] = entry
            return
        lo, hi = low.reshape(-1), up.reshape(-1)
        if np.count_nonzero(lo) > nz.size or np.count_nonzero(hi) > nz.size:
            nz = np.flatnonzero((flat != 0) | (lo != 0) | (hi != 0))  # kept exactly as given
        self._entries[key] = (q_low, q_up, prob.shape, nz.astype(np.int32), flat[nz], lo[nz],
                              hi[nz])  # fmt: skip

    def __getitem__(self, key: int) -> Entry:
        entry = self._entries[key]
        return entry if len(entry) == 5 else self._expand(entry)  # type: ignore[return-value]

    def get(self, key: int) -> Entry | None:
        """The entry of ``key``, or None."""
        entry = self._entries.get(key)
        if entry is None or len(entry) == 5:
            return entry  # type: ignore[return-value]
        return self._expand(entry)

    @staticmethod
    def _expand(entry: tuple) -> Entry:
        q_low, q_up, shape, nz, p, lo, hi = entry
        # one zeroed block for the three arrays, each a row of it (one allocation instead of
        # three: the search expands an entry at every step and backup through it)
        full = np.zeros((3, math.prod(shape)), dtype=np.result_type(p, lo, hi))
        full[0, nz], full[1, nz], full[2, nz] = p, lo, hi
        return (q_low, q_up, full[0].reshape(shape), full[1].reshape(shape),
                full[2].reshape(shape))  # fmt: skip

    def packed(self, key: int) -> bool:
        """Whether ``key``'s entry is stored at its possible children only."""
        return len(self._entries[key]) != 5

    def nbytes(self) -> int:
        """The bytes of the arrays held (without Python's per-object overhead)."""
        return sum(getattr(a, "nbytes", 0) for e in self._entries.values() for a in e)
