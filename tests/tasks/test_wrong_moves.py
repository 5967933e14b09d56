"""Tests of torchhrc.tasks.wrong_moves: the price of a move a type's partners never made."""

from __future__ import annotations

import warnings

import pytest
import torch
from _task_steps import steps_from_rows as _steps

import torchhrc
from torchhrc.tasks.wrong_moves import contested_states, price_wrong_moves

# two states, actions 0 wait (changes nothing), 1 left, 2 right (each moves to state 1)
EFFECT = torch.tensor([[0, 1], [1, 1], [1, 1]])


def _reference(R, steps, assignments, effect, visits=3, rare=0.1):
    """The rule written as plain loops over types, states and actions."""
    A, X, K = R.shape
    counts = torch.zeros(K, X, A)
    for i in range(steps.mask.shape[0]):
        for t in range(steps.mask.shape[1]):
            if steps.mask[i, t]:
                counts[assignments[i], steps.states[i, t], steps.actions[i, t]] += 1
    waits = [a for a in range(A) if all(int(effect[a, x]) == x for x in range(X))]
    out = R.clone()
    if not waits or K < 2:
        return out
    w = waits[0]
    for x in range(X):
        counting = [k for k in range(K) if counts[k, x].sum() >= visits]
        if len({int(counts[k, x].argmax()) for k in counting}) < 2:
            continue
        owns = {k: int(counts[k, x].argmax()) for k in counting}
        gains = {k: max(float(R[owns[k], x, k] - R[w, x, k]), 0.0) for k in counting}
        for k in counting:
            own = owns[k]
            for a in range(A):
                if a in (w, own) or counts[k, x, a] / counts[k, x].sum() >= rare:
                    continue
                if own == w:  # what the move gains the types whose own move it is
                    gain = max([gains[z] for z in counting if owns[z] == a], default=0.0)
                else:
                    gain = gains[k]
                out[a, x, k] = min(float(R[a, x, k]), float(R[w, x, k]) - gain)
    return out


def test_a_wrong_move_costs_what_the_right_one_gains_worked_by_hand():
    # state 0: type 0's partners go left (4 times), type 1's right (4 times, one slip left)
    rows = [[(0, 1)]] * 4 + [[(0, 2)]] * 3 + [[(0, 1)]]
    assignments = torch.tensor([0, 0, 0, 0, 1, 1, 1, 1])
    R = torch.zeros(3, 2, 2, dtype=torch.float64)
    R[:, 0, 0] = torch.tensor([-0.2, 0.8, -0.1])  # type 0: wait, left, right
    R[:, 0, 1] = torch.tensor([0.1, -0.3, 0.6])  # type 1
    priced, lowered = price_wrong_moves(R, _steps(rows), assignments, EFFECT)
    # type 0: right capped at -0.2 - (0.8 + 0.2) = -1.2
    assert priced[:, 0, 0].tolist() == pytest.approx([-0.2, 0.8, -1.2])
    # type 1 made "left" in 1 of 4 steps (0.25 >= 0.1): its own, left as learned
    assert priced[:, 0, 1].tolist() == pytest.approx([0.1, -0.3, 0.6])
    assert lowered.sum() == 1 and bool(lowered[2, 0, 0])
    assert torch.equal(priced[:, 1], R[:, 1])  # state 1 was never demonstrated
    contested, own, _ = contested_states(_steps(rows), assignments, 2, 2, 3)
    assert contested.tolist() == [True, False] and own[:, 0].tolist() == [1, 2]


def test_a_type_that_waits_pays_what_the_move_gains_the_others_worked_by_hand():
    # state 0: type 0's partners wait (4 times), type 1's go left (4 times)
    rows = [[(0, 0)]] * 4 + [[(0, 1)]] * 4
    assignments = torch.tensor([0, 0, 0, 0, 1, 1, 1, 1])
    R = torch.zeros(3, 2, 2, dtype=torch.float64)
    R[:, 0, 0] = torch.tensor([0.3, 0.1, -0.2])  # type 0: wait, left, right
    R[:, 0, 1] = torch.tensor([-0.2, 0.8, -0.1])  # type 1: left gains 1.0 over its wait
    priced, lowered = price_wrong_moves(R, _steps(rows), assignments, EFFECT)
    # type 0: left capped at 0.3 - 1.0; right, no counting type's own move, at its wait (0.3)
    assert priced[:, 0, 0].tolist() == pytest.approx([0.3, -0.7, -0.2])
    # type 1: right capped at -0.2 - (0.8 + 0.2) = -1.2, its wait not priced
    assert priced[:, 0, 1].tolist() == pytest.approx([-0.2, 0.8, -1.2])
    assert lowered.sum() == 2 and bool(lowered[1, 0, 0]) and bool(lowered[2, 0, 1])


def test_where_the_types_agree_or_one_was_seldom_there_nothing_changes():
    R = torch.zeros(3, 2, 2, dtype=torch.float64)
    R[1, 0], R[2, 0] = 1.0, 0.5  # left right, right half as good: above any price in state 0
    agree = [[(0, 1)]] * 8
    assignments = torch.tensor([0, 0, 0, 0, 1, 1, 1, 1])
    assert torch.equal(price_wrong_moves(R, _steps(agree), assignments, EFFECT)[0], R)
    seldom = [[(0, 1)]] * 4 + [[(0, 2)]] * 2  # type 1 acted twice there: below 3 visits
    few = torch.tensor([0, 0, 0, 0, 1, 1])
    assert torch.equal(price_wrong_moves(R, _steps(seldom), few, EFFECT)[0], R)
    # a task without a wait (every action moves somewhere): nothing to price against
    moving = torch.tensor([[1, 0], [1, 1], [1, 1]])
    contested = [[(0, 1)]] * 4 + [[(0, 2)]] * 4
    assert torch.equal(price_wrong_moves(R, _steps(contested), assignments, moving)[0], R)


def test_it_agrees_with_a_loop_over_types_states_and_actions():
    g = torch.Generator().manual_seed(3)
    X, A, K, N = 6, 4, 3, 60
    effect = torch.randint(0, X, (A, X), generator=g)
    effect[0] = torch.arange(X)  # the wait
    assignments = torch.randint(0, K, (N,), generator=g)
    favourite = torch.randint(0, A, (K, X), generator=g)
    rows = []
    for i in range(N):
        row = []
        for _ in range(5):
            x = int(torch.randint(0, X, (1,), generator=g))
            slip = float(torch.rand(1, generator=g)) < 0.15
            a = (
                int(torch.randint(0, A, (1,), generator=g))
                if slip
                else int(favourite[assignments[i], x])
            )
            row.append((x, a))
        rows.append(row)
    R = torch.randn(A, X, K, dtype=torch.float64, generator=g)
    steps = _steps(rows)
    priced, lowered = price_wrong_moves(R, steps, assignments, effect)
    expected = _reference(R, steps, assignments, effect)
    torch.testing.assert_close(priced, expected, rtol=0, atol=1e-12)
    assert torch.equal(lowered, priced != R) and int(lowered.sum()) > 5  # a real check


def test_bad_arguments_are_named():
    steps = _steps([[(0, 1)]] * 2)
    with pytest.raises(ValueError, match=r"reward of shape \(A, X, K\)"):
        price_wrong_moves(torch.zeros(3, 2), steps, torch.tensor([0, 1]), EFFECT)
    with pytest.raises(ValueError, match=r"robot_effect of shape \(A, X\) = \(3, 2\)"):
        price_wrong_moves(torch.zeros(3, 2, 2), steps, torch.tensor([0, 1]), EFFECT[:2])
    with pytest.raises(ValueError, match=r"assignments of shape \(N,\) = \(2,\)"):
        price_wrong_moves(torch.zeros(3, 2, 2), steps, torch.tensor([0]), EFFECT)
    with pytest.raises(ValueError, match="rare in"):
        price_wrong_moves(torch.zeros(3, 2, 2), steps, torch.tensor([0, 1]), EFFECT, rare=0)


def test_the_robot_that_does_not_know_the_order_waits_for_it():
    """``fetch_order``: every type's partner fetched the part its person wanted first, so
    IRL prices a wrong first fetch like a wait and the type-aware robot guessed (the true
    model waits for the person to show their order: docs/evaluation_history.md, "The price of
    a wrong move"). With the symmetric price it waits; with the rewards as learned it does
    not."""
    from torchhrc.tasks.suite import make_task

    world = make_task("fetch_order")
    demos, _ = world.demonstrations(subjects=30, per_subject=4, seed=0)
    x0 = int(world.task.initial_state)
    first = {}
    for rule in ("symmetric", "learned"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = torchhrc.learn(world.task, demos, seed=0, solver_time=3.0,
                                   irl_wrong_moves=rule)  # fmt: skip
        controller = torchhrc.Controller.from_model(model)
        controller.reset()
        first[rule] = world.task.robot_actions[int(controller.act(x0))]
        assert model.info["irl"]["wrong_moves"] == rule
        assert (model.info["wrong_moves"]["lowered"] > 0) == (rule == "symmetric")
    assert first == {"symmetric": "wait", "learned": first["learned"]}
    assert first["learned"] != "wait"
