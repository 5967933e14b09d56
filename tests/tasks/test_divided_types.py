"""Tests of torchhrc.tasks.divided_types: a learned type whose people's partners made
different moves in one state (two types merged)."""

from __future__ import annotations

import warnings

import pytest
import torch
from _task_steps import steps_from_rows as _steps

import torchhrc
from torchhrc.tasks.divided_types import divided_states
from torchhrc.tasks.suite import make_task


def test_own_moves_counted_by_subject_worked_by_hand():
    # one type, state 0; one sequence per subject:
    # s0, s1, s2: partners wait twice (own move: wait); s3, s4: hand twice (own: hand);
    # s5: wait once, hand once (no strict majority: no own move); s6: hand once (too few)
    rows = [[(0, 0), (0, 0)]] * 3 + [[(0, 1), (0, 1)]] * 2 + [[(0, 0), (0, 1)], [(0, 1)]]
    steps = _steps(rows)
    one = torch.zeros(7, dtype=torch.long)
    divided, own = divided_states(steps, one, torch.arange(7), num_types=1, num_states=1,
                                  num_actions=2)  # fmt: skip
    assert own[0, 0].tolist() == [3, 2]
    assert divided.tolist() == [[True]]  # 2 subjects off the most common move, 2/5 >= 0.25
    # the same subjects as two types: each type's people agree
    two = torch.tensor([0, 0, 0, 1, 1, 0, 1])
    divided, own = divided_states(steps, two, torch.arange(7), num_types=2, num_states=1,
                                  num_actions=2)  # fmt: skip
    assert own[:, 0].tolist() == [[3, 0], [0, 2]] and not divided.any()
    # thresholds: 2 of 5 off is under a share of a half, and under 3 subjects
    assert not divided_states(steps, one, torch.arange(7), num_types=1, num_states=1,
                              num_actions=2, min_share=0.5)[0].any()  # fmt: skip
    assert not divided_states(steps, one, torch.arange(7), num_types=1, num_states=1,
                              num_actions=2, min_subjects=3)[0].any()  # fmt: skip
    # a subject's several sequences are pooled: two sequences of one hand each make an own move
    again = _steps([[(0, 1)], [(0, 1)], *rows[:3]])
    pooled = divided_states(again, torch.zeros(5, dtype=torch.long), torch.tensor([9, 9, 0, 1, 2]),
                            num_types=1, num_states=1, num_actions=2)[1]  # fmt: skip
    assert pooled[0, 0].tolist() == [3, 1]


def test_true_types_are_not_divided_and_merged_ones_are():
    """On suite tasks, the true partition has no divided state; joining the two smallest
    types, whose partners serve them differently, gives one (a merge found from the data
    alone)."""
    for name in ("fetch_order", "tool_handover", "screws_hands_off"):
        world = make_task(name)
        demos, types = world.demonstrations(subjects=30, per_subject=4, seed=0)
        steps = world.task.read_steps(demos)
        shape = dict(num_types=world.num_types, num_states=world.task.num_states,
                     num_actions=world.task.num_actions)  # fmt: skip
        divided, _ = divided_states(steps, types, demos.subject_index, **shape)
        assert not divided.any(), name
        small = torch.bincount(types, minlength=world.num_types).argsort()[:2].tolist()
        merged = torch.where(types == small[0], small[1], types)
        divided, own = divided_states(steps, merged, demos.subject_index, **shape)
        assert divided.any(), name
        assert divided.nonzero()[:, 0].unique().tolist() == [small[1]]  # the merged type only
        y, x = divided.nonzero()[0].tolist()
        assert (own[y, x] > 0).sum() >= 2  # its people's partners made two own moves there


def test_learn_records_the_divided_states():
    world = make_task("fetch_order")
    demos, _ = world.demonstrations(subjects=30, per_subject=4, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pooled = torchhrc.learn(world.task, demos, k=1, seed=0, solve=False)
    record = pooled.info["divided"]
    assert record["states"] >= 1 and record["where"]  # three types in one: divided
    first = record["where"][0]
    assert first["type"] == pooled.type_names[0] and first["state"] in world.task.state_names
    assert set(first["subjects"]) <= set(world.task.robot_actions)
    assert sum(first["subjects"].values()) <= 30 and len(first["subjects"]) >= 2


def test_bad_arguments_are_named():
    steps = _steps([[(0, 0)]] * 2)
    with pytest.raises(ValueError, match=r"assignments of shape \(N,\) = \(2,\)"):
        divided_states(steps, torch.zeros(3, dtype=torch.long), torch.arange(2), num_types=1,
                       num_states=1, num_actions=1)  # fmt: skip
    with pytest.raises(ValueError, match=r"subjects of shape \(N,\) = \(2,\)"):
        divided_states(steps, torch.zeros(2, dtype=torch.long), torch.arange(1), num_types=1,
                       num_states=1, num_actions=1)  # fmt: skip
    with pytest.raises(ValueError, match="min_share in"):
        divided_states(steps, torch.zeros(2, dtype=torch.long), torch.arange(2), num_types=1,
                       num_states=1, num_actions=1, min_share=0.0)  # fmt: skip
