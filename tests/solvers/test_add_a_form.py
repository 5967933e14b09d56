"""Adding a model form (docs/architecture.md, "Where to add ... a model form"): a model type
of its own, lowered to a built-in container and registered with ``register_form``, is then
solved by ``solve()`` with SARSOP and PBVI; the bounds bracket the exact value, worked by hand
and by brute force over the finitely many reachable beliefs."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import torch

from torchhrc.pomdp import MOMDP
from torchhrc.solvers import PBVIConfig, SARSOPConfig, solve
from torchhrc.solvers.forms import as_solver_model, has_form, register_form

LEFT, RIGHT = 0, 1  # actions; the hidden y is the end holding the prize: 0 left, 1 right


@dataclass(frozen=True)
class ChainWorld:
    """A corridor of ``length`` cells; a prize lies at one end, which the robot does not know.

    Each move costs ``step_cost``; moving onto the prize's end earns ``prize``, and the robot
    is back at ``start`` with a new prize, at either end with probability 1/2. The robot sees
    its cell (observed ``x``), never the prize: arriving at the empty end tells it the side.
    """

    length: int = 5
    start: int = 2
    step_cost: float = 1.0
    prize: float = 10.0
    discount: float = 0.9


def lower(world: ChainWorld) -> MOMDP:
    """The world as a dense MOMDP: x the cell, y the prize's end, one (uninformative) o."""
    X, Y, A = world.length, 2, 2
    Tx = torch.zeros(A, X, Y, X, dtype=torch.float64)
    # y2 = y unless the prize was collected (every row of Ty sums to 1, reachable or not)
    Ty = torch.eye(Y, dtype=torch.float64)[:, None, :].expand(A, X, Y, X, Y).clone()
    R = torch.full((A, X, Y), -world.step_cost, dtype=torch.float64)
    for a, step in ((LEFT, -1), (RIGHT, 1)):
        for x in range(X):
            target = min(max(x + step, 0), X - 1)
            for y, prize_cell in ((0, 0), (1, X - 1)):
                if target == prize_cell:  # collected: back to the start, a new prize
                    R[a, x, y] += world.prize
                    Tx[a, x, y, world.start] = 1.0
                    Ty[a, x, y, world.start] = 0.5
                else:
                    Tx[a, x, y, target] = 1.0
    return MOMDP(
        Tx=Tx,
        Ty=Ty,
        Z=torch.ones(A, X, Y, 1, dtype=torch.float64),
        R=R,
        x0=world.start,
        b0=torch.tensor([0.5, 0.5], dtype=torch.float64),
        discount=world.discount,
    )


register_form(ChainWorld, lambda world, dtype: as_solver_model(lower(world), dtype=dtype))


def hand_value(world: ChainWorld) -> float:
    """V at the start of the default world: try the left end; if empty, walk to the right.

    With g the discount, W the value at the empty left end knowing the prize is right (four
    moves, the last one onto the prize), and V at the start not knowing:
    W = -1 - g - g^2 + 9 g^3 + g^4 V and V = -1 + g (0.5 (9 + g V) + 0.5 (-1 + g W)).
    """
    g = world.discount
    w_const, w_v = -1 - g - g**2 + 9 * g**3, g**4  # W = w_const + w_v V
    # V = c + k V after substituting W
    c = -1 + g * (0.5 * 9 + 0.5 * (-1 + g * w_const))
    k = g * (0.5 * g + 0.5 * g * w_v)
    return c / (1 - k)


def brute_force_value(model: MOMDP, *, tol: float = 1e-12) -> float:
    """Value iteration over every belief reachable from the start (a finite set here)."""
    A, X = model.R.shape[:2]
    joint = model.Tx.unsqueeze(-1) * model.Ty  # (A, X, Y, X, Y) = P(x2, y2 | x, y, a)
    start = (model.x0, tuple(model.b0.tolist()))
    beliefs, successors, frontier = {start: 0}, {}, [start]
    while frontier:
        x, b = frontier.pop()
        belief = torch.tensor(b, dtype=torch.float64)
        for a in range(A):
            reward = float(model.R[a, x] @ belief)
            nxt = torch.einsum("y,yuv->uv", belief, joint[a, x])  # (X, Y) P(x2, y2)
            branches = []
            for x2 in range(X):
                p = float(nxt[x2].sum())
                if p > 0:
                    key = (x2, tuple(round(v, 12) for v in (nxt[x2] / p).tolist()))
                    if key not in beliefs:
                        beliefs[key] = len(beliefs)
                        frontier.append(key)
                    branches.append((p, key))
            successors[(x, b), a] = (reward, branches)
    values = dict.fromkeys(beliefs, 0.0)
    while True:
        new = {
            node: max(
                successors[node, a][0]
                + model.discount * sum(p * values[k] for p, k in successors[node, a][1])
                for a in range(A)
            )
            for node in beliefs
        }
        if max(abs(new[n] - values[n]) for n in beliefs) < tol:
            return new[start]
        values = new


def test_a_registered_form_is_solved_within_its_exact_value() -> None:
    world = ChainWorld()
    assert has_form(world)
    exact = brute_force_value(lower(world))
    assert exact == pytest.approx(hand_value(world), abs=1e-9)  # the two references agree
    sol = solve(world, SARSOPConfig(time_limit=60.0, precision=1e-3, seed=0))
    assert sol.lower - 1e-6 <= exact <= sol.upper + 1e-6
    assert sol.upper - sol.lower <= 1e-3 + 1e-9
    # PBVI's belief set reaches every reachable belief (11): its lower bound comes within
    # 5.5e-4 of the exact value
    pbvi = solve(world, PBVIConfig(time_limit=60.0, seed=0))
    assert pbvi.lower - 1e-6 <= exact <= pbvi.upper + 1e-6
    assert pbvi.lower == pytest.approx(exact, abs=1e-2)
