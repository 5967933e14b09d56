"""Tests of torchhrc.tasks.divided_types: a learned type whose people's partners made
different moves in one state (two types merged)."""

from __future__ import annotations

import warnings

import pytest
import torch
from _task_steps import steps_from_rows as _steps

import torchhrc
from torchhrc.metrics import adjusted_rand_index
from torchhrc.tasks.divided_types import divided_states, split_divided
from torchhrc.tasks.pipeline import cluster_options, find_types, split_divided_types
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


def test_split_worked_by_hand():
    # type 0 in state 0: s0-s2 partners wait twice (own: wait), s3, s4 hand twice (own: hand),
    # s5 hands once (one step: counts by it), s6 waits once and hands once (a tie: stays,
    # before the settling, test below);
    rows = [[(0, 0), (0, 0)]] * 3 + [[(0, 1), (0, 1)]] * 2 + [[(0, 1)], [(0, 0), (0, 1)]]
    # type 1 (s7, s8, and a sequence of s3's) hands in state 0 too, and is not touched
    rows += [[(0, 1), (0, 1)]] * 3
    z0 = torch.tensor([0] * 7 + [1, 1, 1])
    subjects = torch.tensor([0, 1, 2, 3, 4, 5, 6, 7, 8, 3])
    z, splits = split_divided(_steps(rows), z0, subjects, num_types=2, num_states=1,
                              num_actions=2, max_types=6, settle=False)  # fmt: skip
    assert z.tolist() == [0, 0, 0, 2, 2, 2, 0, 1, 1, 1]
    assert splits == [{"type": 0, "state": 0, "move": 1, "kept_move": 0, "subjects": 3,
                       "settled": 3}]  # fmt: skip
    # max_types stops the split
    z, splits = split_divided(_steps(rows), z0, subjects, num_types=2, num_states=1,
                              num_actions=2, max_types=2)  # fmt: skip
    assert splits == [] and z.tolist() == z0.tolist()
    # fewer than min_subjects with the second move: no split
    _, splits = split_divided(_steps(rows), z0, subjects, num_types=2, num_states=1,
                              num_actions=2, max_types=6, min_subjects=3)  # fmt: skip
    assert splits == []
    # divided, but its two other own moves have one subject each: no group to split off
    rows = [[(0, 0), (0, 0)]] * 3 + [[(0, 1), (0, 1)], [(0, 2), (0, 2)]]
    steps = _steps(rows)
    one = torch.zeros(5, dtype=torch.long)
    shape = dict(num_types=1, num_states=1, num_actions=3)
    assert divided_states(steps, one, torch.arange(5), **shape)[0].all()
    assert split_divided(steps, one, torch.arange(5), max_types=6, **shape)[1] == []


def test_split_settles_a_subject_by_its_partners_moves_elsewhere():
    # state 0: s0-s3 partners wait twice, s4-s6 hand twice: the split's state; state 1: each
    # of s0-s6 once (s0-s3 wait, s4-s6 hand), s7 hands twice and s8 waits twice, neither
    # seen in state 0: s7 goes with the hands by state 1, s8 stays
    rows = [[(0, 0), (0, 0), (1, 0)]] * 4 + [[(0, 1), (0, 1), (1, 1)]] * 3
    rows += [[(1, 1), (1, 1)], [(1, 0), (1, 0)]]
    z, splits = split_divided(_steps(rows), torch.zeros(9, dtype=torch.long), torch.arange(9),
                              num_types=1, num_states=2, num_actions=2, max_types=6)  # fmt: skip
    assert z.tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 0]
    assert splits[0]["state"] == 0 and splits[0]["subjects"] == 3 and splits[0]["settled"] == 4
    # s7 is moved by one hand in state 0, but its partners waited 6 times in state 1, as the
    # kept half's did: settled back (its own steps are left out of the half it is scored in)
    rows = [[(0, 0), (0, 0), (1, 0)]] * 4 + [[(0, 1), (0, 1), (1, 1)]] * 3
    rows += [[(0, 1)] + [(1, 0)] * 6]
    z, splits = split_divided(_steps(rows), torch.zeros(8, dtype=torch.long), torch.arange(8),
                              num_types=1, num_states=2, num_actions=2, max_types=6)  # fmt: skip
    assert z.tolist() == [0, 0, 0, 0, 1, 1, 1, 0]
    assert splits[0]["subjects"] == 4 and splits[0]["settled"] == 3


def test_split_settles_a_subject_by_the_persons_own_moves():
    # state 0, the split's: s0-s3 partners wait twice, s4-s6 hand twice; state 1: every
    # partner waits, and the person then acts: s0-s3 (move 0), s4-s6 (move 1); s7 and s8
    # never meet state 0 and their partners wait in state 1 as all do, but s7 acts as s4-s6
    # do (move 1) and s8 as s0-s3 (move 0): s7 goes with the hands by her own moves
    rows = [[(0, 0), (0, 0), (1, 0, 0), (1, 0, 0)]] * 4
    rows += [[(0, 1), (0, 1), (1, 0, 1), (1, 0, 1)]] * 3
    rows += [[(1, 0, 1), (1, 0, 1)], [(1, 0, 0), (1, 0, 0)]]
    z, splits = split_divided(_steps(rows), torch.zeros(9, dtype=torch.long), torch.arange(9),
                              num_types=1, num_states=2, num_actions=2, max_types=6)  # fmt: skip
    assert z.tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 0]
    assert splits[0]["subjects"] == 3 and splits[0]["settled"] == 4
    # where both halves act alike (state 2: the partner waits, the person makes move 2) a
    # subject's many steps there weigh nothing: s7 has 60 such steps and one of move 1 in
    # state 1, and still goes with the hands (a uniform prior over the person's moves in each
    # half charged the smaller half about 0.05 nats a step there, 3 in all, more than the
    # one step that tells the halves apart)
    common = [(2, 0, 2)] * 4
    rows = [[(0, 0), (0, 0), (1, 0, 0), (1, 0, 0), *common]] * 4
    rows += [[(0, 1), (0, 1), (1, 0, 1), (1, 0, 1), *common]] * 3
    rows += [[(1, 0, 1), *[(2, 0, 2)] * 60], [(1, 0, 0), (1, 0, 0), *common]]
    z, _ = split_divided(_steps(rows), torch.zeros(9, dtype=torch.long), torch.arange(9),
                         num_types=1, num_states=3, num_actions=2, max_types=6)  # fmt: skip
    assert z.tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 0]


def test_split_restores_merged_types_and_leaves_true_ones():
    """Joining two types whose partners serve them differently, then splitting, gives back
    the true partition; the true partition is never split (suite tasks, 30 x 4)."""
    for name in ("fetch_order", "tool_handover", "screws_hands_off"):
        world = make_task(name)
        demos, types = world.demonstrations(subjects=30, per_subject=4, seed=1)
        z, splits = split_divided_types(world.task, demos, types, max_types=6)
        assert splits == [] and z.tolist() == types.tolist(), name
        small = torch.bincount(types, minlength=world.num_types).argsort()[:2].tolist()
        merged = torch.where(types == small[0], small[1], types)
        merged = torch.unique(merged, return_inverse=True)[1]  # types 0 .. K - 2
        z, splits = split_divided_types(world.task, demos, merged, max_types=6)
        assert len(splits) == 1, name
        assert splits[0]["state"] in world.task.state_names
        assert adjusted_rand_index(types.tolist(), z.tolist()) == pytest.approx(1.0), name


def test_learn_splits_a_merged_type_unless_told_not_to():
    world = make_task("tool_handover")  # 2 types whose partners differ
    demos, types = world.demonstrations(subjects=20, per_subject=3, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # a clustering that cannot find the second type: one order, k at most 1 ... 2
        options = dict(k_max=2, criterion="bic", min_gain=10.0, seed=0, solve=False)
        split = torchhrc.learn(world.task, demos, **options)
        kept = torchhrc.learn(world.task, demos, split_divided=False, **options)
        forced = torchhrc.learn(world.task, demos, k=1, seed=0, solve=False)
    assert kept.info["k"] == kept.info["k_clustered"] == 1 and kept.info["split"] == []
    assert split.info["k_clustered"] == 1 and split.info["k"] == 2
    assert len(split.info["split"]) == 1 and len(split.type_names) == 2
    assert adjusted_rand_index(types.tolist(), split.assignments.tolist()) == pytest.approx(1.0)
    assert split.info["divided"]["states"] == 0  # what the split mended
    assert forced.info["k"] == 1 and forced.info["split"] == []  # a given k is kept


def test_find_types_splits_the_clustering_up_to_its_max_types():
    """``find_types`` (learn()'s clustering and split): a clustering held at one type is split
    back into the task's two; not with ``split=False``, nor past ``options["k_max"]``."""
    world = make_task("tool_handover")  # 2 types whose partners differ
    demos, types = world.demonstrations(subjects=20, per_subject=3, seed=0)
    one = cluster_options(k=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit, z, splits = find_types(world.task, demos, one, seed=0, max_types=6)
        _, kept, none = find_types(world.task, demos, one, seed=0, max_types=6, split=False)
        _, capped, beyond = find_types(world.task, demos, one, seed=0)  # k_max = 1
    assert int(fit.k) == 1 and len(splits) == 1
    assert adjusted_rand_index(types.tolist(), z.tolist()) == pytest.approx(1.0)
    assert none == [] and kept.tolist() == [0] * len(types)
    assert beyond == [] and capped.tolist() == [0] * len(types)


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
    with pytest.raises(ValueError, match="max_types >= 1"):
        split_divided(steps, torch.zeros(2, dtype=torch.long), torch.arange(2), num_types=1,
                      num_states=1, num_actions=1, max_types=0)  # fmt: skip
