"""SARSOP's per-belief cache of evaluations, each one record, stored at the possible children
when they are few.

An evaluation of a belief gives, for every child ``(a, x2, o)``, its probability and bounds:
``prob``, ``low``, ``up`` of shape ``(A, K, O)``, with ``q_low`` and ``q_up`` ``(A,)``. They
are held as one *record*, a 1-D array of ``2 A + 3 A K O`` entries: ``q_low``, ``q_up``, then
``prob``, ``low`` and ``up`` in ``(a, k, o)`` order (:func:`pack`, :func:`unpack`). One array
a belief rather than five: on a small model their headers outweighed their data (``network``,
7 states: 1.6 kB of Python objects a belief, 27,000 beliefs after 10 s), and the compiled
steps read and write the record whole (:func:`~torchhrc.solvers.backup_kernel.backup_one`,
``trial_step``).

The search keeps the last record per distinct belief (it chooses the next step from it, and a
backup refreshes only the best action's children, APPL's ``getNewUBValueUseCache``). On a
MOMDP most children are impossible (APPL's ``TagAvoid.pomdpx``: 1.1 % of the 750 children of
a belief have ``P > 0``; 16 kB a belief, 288 MB of a 20 s solve): an entry then keeps only
the possible children's values and their flat indices (and any other nonzero entry), and is
expanded when read: the same record, bit for bit.

Example:
    >>> import numpy as np
    >>> cache = EvaluationCache(num_actions=2)
    >>> prob = np.zeros((2, 1, 80)); prob[0, 0, 3] = 1.0
    >>> cache[7] = pack(np.zeros(2), np.ones(2), prob, prob * 2.0, prob * 5.0)
    >>> q_low, q_up, p, low, up = unpack(cache[7], 2, 80)
    >>> float(up[0, 0, 3]), up.shape, cache.packed(7), 7 in cache, len(cache)
    (5.0, (2, 1, 80), True, True, 1)
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

__all__ = ["EvaluationCache", "action_prob", "pack", "unpack", "upper_part"]

Entry = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: an entry is packed when at most this fraction of its children is possible
PACK_FRACTION = 0.25
#: and when it has at least this many children (a small entry costs little memory, and its
#: expansion at every read would cost bridge-repair's 60-child beliefs 7 % of their backups)
PACK_MIN_CHILDREN = 128


def pack(q_low: np.ndarray, q_up: np.ndarray, prob: np.ndarray, low: np.ndarray,
         up: np.ndarray) -> np.ndarray:  # fmt: skip
    """The record ``(2 A + 3 A K O,)`` of an evaluation: ``q_low``, ``q_up`` ``(A,)``, then
    ``prob``, ``low``, ``up`` ``(A, K, O)`` flattened (a new array)."""
    return np.concatenate([q_low.reshape(-1), q_up.reshape(-1), prob.reshape(-1),
                           low.reshape(-1), up.reshape(-1)])  # fmt: skip


def unpack(record: np.ndarray, num_actions: int, num_obs: int) -> Entry:
    """``q_low``, ``q_up`` ``(A,)`` and ``prob``, ``low``, ``up`` ``(A, K, O)``: views of a
    record of ``A = num_actions`` actions and ``O = num_obs`` observations.

    Raises:
        ValueError: a record whose length is not ``2 A + 3 A K O`` for some ``K >= 1``.
    """
    A, O = num_actions, num_obs
    n = record.shape[0]
    K = (n - 2 * A) // (3 * A * O) if A > 0 and O > 0 else 0
    if record.ndim != 1 or K < 1 or n != 2 * A + 3 * A * K * O:
        raise ValueError(f"expected a record of 2 A + 3 A K O entries (A={A}, O={O}, K >= 1), "
                         f"got shape {record.shape}")  # fmt: skip
    C = A * K * O
    s = (A, K, O)
    p = 2 * A
    return (record[:A], record[A:p], record[p : p + C].reshape(s),
            record[p + C : p + 2 * C].reshape(s), record[p + 2 * C :].reshape(s))  # fmt: skip


def upper_part(record: np.ndarray, num_actions: int) -> tuple[np.ndarray, np.ndarray]:
    """``Q_up (A,)`` and the children's upper bounds ``(A K O,)`` of a record (views; what a
    backup reads of a belief's last evaluation, without the observation count)."""
    A = num_actions
    C = (record.shape[0] - 2 * A) // 3
    return record[A : 2 * A], record[2 * A + 2 * C :]


def action_prob(record: np.ndarray, num_actions: int, action: int) -> np.ndarray:
    """``(K O,)`` the probabilities of action ``action``'s children in a record (a view;
    what a backup reads to tell the action's possible children).

    Example:
        >>> prob = np.arange(8.0).reshape(2, 2, 2)
        >>> action_prob(pack(np.zeros(2), np.ones(2), prob, prob, prob), 2, 1).tolist()
        [4.0, 5.0, 6.0, 7.0]
    """
    A = num_actions
    n = (record.shape[0] - 2 * A) // (3 * A)  # K O
    return record[2 * A + action * n : 2 * A + (action + 1) * n]


class EvaluationCache:
    """``cache[key] = record`` (:func:`pack`) of a model of ``num_actions`` actions; reads give
    the same record (expanded from a packed entry: a new array, safe to modify)."""

    def __init__(self, num_actions: int) -> None:
        self.num_actions = int(num_actions)
        self._entries: dict[int, np.ndarray | tuple] = {}

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: object) -> bool:
        return key in self._entries

    def __iter__(self) -> Iterator[int]:
        return iter(self._entries)

    def __setitem__(self, key: int, record: np.ndarray) -> None:
        n = record.shape[0]
        if n < 3 * PACK_MIN_CHILDREN:  # (the common case of small models: one check)
            self._entries[key] = record
            return
        q = 2 * self.num_actions
        C = (n - q) // 3
        prob, lo, hi = record[q : q + C], record[q + C : q + 2 * C], record[q + 2 * C :]
        nz = np.flatnonzero(prob)
        if nz.size > PACK_FRACTION * C or C < PACK_MIN_CHILDREN:
            self._entries[key] = record
            return
        if np.count_nonzero(lo) > nz.size or np.count_nonzero(hi) > nz.size:
            nz = np.flatnonzero((prob != 0) | (lo != 0) | (hi != 0))  # kept exactly as given
        self._entries[key] = (record[:q].copy(), C, nz.astype(np.int32), prob[nz], lo[nz],
                              hi[nz])  # fmt: skip

    def __getitem__(self, key: int) -> np.ndarray:
        entry = self._entries[key]
        return entry if type(entry) is not tuple else self._expand(entry)

    def get(self, key: int) -> np.ndarray | None:
        """The record of ``key``, or None."""
        entry = self._entries.get(key)
        if type(entry) is not tuple:
            return entry  # type: ignore[return-value]
        return self._expand(entry)

    @staticmethod
    def _expand(entry: tuple) -> np.ndarray:
        q, C, nz, p, lo, hi = entry
        record = np.zeros(q.shape[0] + 3 * C, dtype=np.result_type(q, p, lo, hi))
        record[: q.shape[0]] = q
        body = record[q.shape[0] :].reshape(3, C)
        body[0, nz], body[1, nz], body[2, nz] = p, lo, hi
        return record

    def packed(self, key: int) -> bool:
        """Whether ``key``'s entry is stored at its possible children only."""
        return type(self._entries[key]) is tuple

    def nbytes(self) -> int:
        """The bytes of the arrays held (without Python's per-object overhead)."""
        return sum(
            e.nbytes if type(e) is not tuple else sum(getattr(a, "nbytes", 0) for a in e)
            for e in self._entries.values()
        )
