"""Structured POMDPs for the ``structured`` check set of ``make_suite.py`` (never tuned on).

Four families with the shapes of classic problems, built from a seed or from parameters:

* :func:`maze`: navigation in a random maze from an unknown start, after Hallway (Littman,
  Cassandra & Kaelbling 1995): noisy wall sensing, slippery moves, a goal to declare;
* :func:`doors`: the tiger problem (Kaelbling, Littman & Cassandra 1998) with ``k`` doors;
* :func:`maintenance`: a machine that wears out, inspected and repaired at a cost, after the
  bridge inspection problem of Ellis, Jiang & Corotis (1995) (pomdp-solve's
  ``bridge-repair``): discount 0.99 and rewards in the hundreds;
* :func:`corridor`: localisation along a long corridor with a few landmarks, after the 1-D
  problems of pomdp-solve's examples (``1d``): a long horizon before the goal is reached.

Example:
    >>> model = doors(3)
    >>> model.num_states, model.num_actions, model.num_observations
    (3, 4, 3)
"""

from __future__ import annotations

import numpy as np
import torch

from torchhrc.pomdp import POMDP

__all__ = ["corridor", "doors", "maintenance", "maze"]

_MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))  # north, east, south, west


def _pomdp(T: np.ndarray, Z: np.ndarray, R: np.ndarray, b0: np.ndarray, discount: float) -> POMDP:
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    return POMDP(T=t(T), Z=t(Z), R=t(R), b0=t(b0), discount=discount)


def _connected(free: set[tuple[int, int]]) -> bool:
    start = next(iter(free))
    seen, stack = {start}, [start]
    while stack:
        i, j = stack.pop()
        for di, dj in _MOVES:
            c = (i + di, j + dj)
            if c in free and c not in seen:
                seen.add(c)
                stack.append(c)
    return len(seen) == len(free)


def maze(n: int, seed: int, *, wall_fraction: float = 0.25, slip: float = 0.2,
         flip: float = 0.1, discount: float = 0.95) -> POMDP:  # fmt: skip
    """Navigation in an ``n x n`` maze with random walls (its free cells connected).

    States: the free cells; the start is uniform over them. Actions: north, east, south,
    west (the move succeeds with probability ``1 - slip``, else the robot stays; into a wall
    it stays; reward -0.04) and ``declare`` (+1 at the goal, then a uniform restart; -1
    elsewhere, where it stays). Observations (16): the four walls around the cell, each bit
    read wrongly with probability ``flip``.

    Example:
        >>> maze(5, seed=0).num_observations
        16
    """
    rng = np.random.default_rng(seed)
    while True:
        wall = rng.random((n, n)) < wall_fraction
        free = {(i, j) for i in range(n) for j in range(n) if not wall[i, j]}
        if len(free) >= 4 and _connected(free):
            break
    cells = sorted(free)
    index = {c: k for k, c in enumerate(cells)}
    S, A, O = len(cells), 5, 16
    goal = int(rng.integers(S))
    T, R = np.zeros((A, S, S)), np.full((A, S), -0.04)
    walls = np.zeros((S, 4), dtype=np.int64)
    for (i, j), s in index.items():
        for a, (di, dj) in enumerate(_MOVES):
            s2 = index.get((i + di, j + dj), s)
            walls[s, a] = s2 == s
            T[a, s, s2] += 1.0 - slip
            T[a, s, s] += slip
        T[4, s] = 1.0 / S if s == goal else np.eye(S)[s]
        R[4, s] = 1.0 if s == goal else -1.0
    bits = (np.arange(O)[:, None] >> np.arange(4)) & 1  # (O, 4) the walls read
    agree = (bits[None, :, :] == walls[:, None, :]).sum(-1)  # (S, O)
    Z1 = (1.0 - flip) ** agree * flip ** (4 - agree)
    Z = np.broadcast_to(Z1, (A, S, O)).copy()
    return _pomdp(T, Z, R, np.full(S, 1.0 / S), discount)


def doors(k: int, accuracy: float = 0.8, discount: float = 0.95) -> POMDP:
    """The tiger problem with ``k`` doors: listen (-1; the tiger's door is heard with
    probability ``accuracy``, each other door with the rest shared equally) or open a door
    (+10, or -100 at the tiger; then the tiger is placed anew, uniformly).

    Example:
        >>> float(doors(2).R[1, 0])
        -100.0
    """
    S, A, O = k, k + 1, k
    T = np.empty((A, S, S))
    T[0], T[1:] = np.eye(S), 1.0 / S
    Z = np.full((A, S, O), 1.0 / O)
    Z[0] = (1.0 - accuracy) / (k - 1)
    np.fill_diagonal(Z[0], accuracy)
    R = np.full((A, S), 10.0)
    R[0] = -1.0
    R[1:][np.arange(k), np.arange(k)] = -100.0
    return _pomdp(T, Z, R, np.full(S, 1.0 / S), discount)


def maintenance(levels: int = 6, discount: float = 0.99) -> POMDP:
    """A machine that wears through ``levels`` conditions, the last one failed (seen).

    Actions: run (from level ``s``, wear one level with probability ``0.15 + 0.1 s / levels``
    and fail outright with 0.03; earn 100 down to 20 by condition, -500 when failed),
    inspect (as run, 15 more cost, and a reading of the condition off by a level or more with
    decaying probability), repair (one level better, then wear; 60 more cost), replace (as
    new, -300). Without an inspection the readings tell only failed or not.

    Example:
        >>> maintenance().num_states
        6
    """
    S, A, O = levels, 4, levels
    wear = np.zeros((S, S))
    for s in range(S - 1):
        p = 0.15 + 0.1 * s / S
        wear[s, s], wear[s, s + 1] = 0.97 - p, p
        wear[s, S - 1] += 0.03
    wear[S - 1, S - 1] = 1.0
    better = np.eye(S, k=-1)
    better[0, 0] = 1.0
    T = np.stack([wear, wear, better @ wear, np.tile(np.eye(S)[0], (S, 1))])
    income = np.linspace(100.0, 20.0, S)
    income[-1] = -500.0
    R = np.stack([income, income - 15.0, income - 60.0, np.full(S, -300.0)])
    reading = np.exp(-np.abs(np.arange(S)[:, None] - np.arange(O)[None, :]) / 0.6)
    Z = np.zeros((A, S, O))
    Z[:, :, : O - 1] = 1.0 / (O - 1)  # no inspection: not failed, nothing more
    Z[1] = reading / reading.sum(1, keepdims=True)
    Z[:, S - 1] = np.eye(O)[O - 1]  # a failure is seen
    return _pomdp(T, Z, R, np.eye(S)[0], discount)


def corridor(n: int, landmarks: tuple[int, ...] = (0,), *, slip: float = 0.1,
             sense: float = 0.9, discount: float = 0.95) -> POMDP:  # fmt: skip
    """Localisation in a corridor of ``n`` cells from a uniform start.

    Actions: left, right (the move fails with probability ``slip``; -0.1), and ``declare``
    (+10 at the last cell, then a uniform restart; -10 elsewhere, where it stays).
    Observations: ``landmark`` or ``nothing``; a landmark cell (``landmarks``, and the last
    cell) reads ``landmark`` with probability ``sense``, any other cell with ``1 - sense``.

    Example:
        >>> model = corridor(8, landmarks=(0, 3))
        >>> model.num_states, model.num_actions, model.num_observations
        (8, 3, 2)
    """
    S, A, O = n, 3, 2
    T = np.zeros((A, S, S))
    for s in range(S):
        for a, step in ((0, -1), (1, 1)):
            t = min(max(s + step, 0), S - 1)
            T[a, s, t] += 1.0 - slip
            T[a, s, s] += slip
    T[2] = np.eye(S)
    T[2, S - 1] = 1.0 / S  # a declared goal: a uniform restart
    marked = np.zeros(S, dtype=bool)
    marked[list(landmarks)] = True
    marked[S - 1] = True
    Z = np.empty((A, S, O))
    Z[:, :, 0] = np.where(marked, sense, 1.0 - sense)
    Z[:, :, 1] = 1.0 - Z[:, :, 0]
    R = np.full((A, S), -0.1)
    R[2] = -10.0
    R[2, S - 1] = 10.0
    return _pomdp(T, Z, R, np.full(S, 1.0 / S), discount)
