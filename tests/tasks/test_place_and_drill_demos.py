"""Tests for the place-and-drill demonstration simulator: task validity, the strategies'
shapes, noise statistics against an independent replay of the rules, determinism."""

from __future__ import annotations

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.tasks.place_and_drill import (
    demonstration,
    placement_orders,
    simulate_demonstrations,
    simulate_study,
    task_vocabulary,
)

CHUNK = {"safe": None, "efficient": 1, "pairs": 2}


def _short(steps):
    return " ".join(f"{actor[0]}:{action}" for actor, action in steps)


def _replay(steps, strategy, n):
    """Walk a sequence with plain Python sets; check legality; return (rule, taken) per step.

    The rule's action is computed independently of the simulator (from the module docstring):
    the human places the next screw of ``order`` when P mod g != 0 or Q == 0, the robot
    drills the earliest placed undrilled screw once its chunk of g placements is complete.
    """
    g = n if CHUNK[strategy] is None else min(CHUNK[strategy], n)
    placed, drilled = [], set()
    order = [action[len("place_") :] for actor, action in steps if action.startswith("place_")]
    out = []
    for t, (actor, action) in enumerate(steps):
        assert actor == ("human" if t % 2 == 0 else "robot"), f"step {t} out of turn"
        pending = [p for p in placed if p not in drilled]
        if actor == "human":
            legal = {f"place_{p}" for p in "ABCDEFGH"[:n] if p not in placed} | {"wait"}
            nxt = [p for p in order if p not in placed]
            rule = (
                f"place_{nxt[0]}"
                if len(placed) < n and (len(placed) % g != 0 or not pending)
                else "wait"
            )
            assert action in legal, f"step {t}: illegal {action} (placed {placed})"
            if action != "wait":
                placed.append(action[len("place_") :])
        else:
            legal = {f"drill_{p}" for p in pending} | {"wait"}
            chunk_end = (placed.index(pending[0]) // g + 1) * g if pending else 0
            complete = len(placed) >= chunk_end or len(placed) == n
            rule = f"drill_{pending[0]}" if pending and complete else "wait"
            assert action in legal, f"step {t}: illegal {action} (pending {pending})"
            if action != "wait":
                drilled.add(action[len("drill_") :])
        out.append((rule, action, len(legal) > 1))
    assert len(placed) == n and drilled == set(placed), "not every screw placed and drilled"
    assert steps[-1][1].startswith("drill_"), "a demonstration ends with the last drill"
    return out


def test_noiseless_strategies_by_hand():
    assert _short(demonstration("safe", "BAC")) == (
        "h:place_B r:wait h:place_A r:wait h:place_C r:drill_B h:wait r:drill_A h:wait r:drill_C"
    )
    assert _short(demonstration("efficient", "CAB")) == (
        "h:place_C r:drill_C h:place_A r:drill_A h:place_B r:drill_B"
    )
    assert _short(demonstration("pairs", "ABCD")) == (
        "h:place_A r:wait h:place_B r:drill_A h:wait r:drill_B "
        "h:place_C r:wait h:place_D r:drill_C h:wait r:drill_D"
    )
    assert _short(demonstration("pairs", "ACB")) == (
        "h:place_A r:wait h:place_C r:drill_A h:wait r:drill_C h:place_B r:drill_B"
    )
    assert _short(demonstration("safe", "A")) == "h:place_A r:drill_A"
    with pytest.raises(ModelError, match="permutation"):
        demonstration("safe", "AAB")
    with pytest.raises(ModelError, match="unknown strategy"):
        demonstration("careful", "AB")


def test_default_study_is_the_papers_design():
    d = simulate_study(seed=3)
    assert d.num_sequences == 54 and len(d.unique_subjects) == 18
    assert d.vocabulary == task_vocabulary(3) and d.num_symbols == 8
    assert d.unique_subjects[0] == "S01" and d.sequence_ids[:3] == ("0", "1", "2")
    per_subject = {}
    for subject, label in zip(d.subjects, d.types):
        per_subject.setdefault(subject, set()).add(label)
    assert all(len(v) == 1 for v in per_subject.values()), "a subject has one type"
    labels = [next(iter(v)) for v in per_subject.values()]
    assert labels.count("safe") == labels.count("efficient") == 9
    assert bool((d.lengths % 2 == 0).all()) and int(d.lengths.min()) >= 6


@pytest.mark.parametrize("n_positions", [1, 3, 4])
def test_noisy_sequences_are_task_valid(n_positions):
    d = simulate_study(
        n_subjects=30,
        n_positions=n_positions,
        strategies=("safe", "efficient", "pairs"),
        noise=0.3,
        robot_noise=0.3,
        seed=n_positions,
    )
    for steps, strategy in zip(d.to_lists(), d.types):
        _replay(steps, strategy, n_positions)


def test_noise_zero_follows_the_rules_and_the_preferred_order():
    d = simulate_study(
        n_subjects=12, n_positions=4, strategies="safe,efficient,pairs", noise=0.0, order_change=0.0
    )
    orders = placement_orders(d)
    for subject_orders in orders.values():
        assert len(subject_orders) == 3 and len(set(subject_orders)) == 1
    for steps, strategy, subject in zip(d.to_lists(), d.types, d.subjects):
        assert steps == demonstration(strategy, orders[subject][0])


def test_noise_rate_matches_the_deviation_frequency():
    rate = 0.2
    d = simulate_study(
        n_subjects=120, strategies="safe,efficient,pairs", noise=rate, robot_noise=rate, seed=5
    )
    # The replay's human rule uses the sequence's own realised placement order (a noisy
    # placement looks like the rule's choice), so measure the robot's steps, whose rule is
    # exact: among robot steps with a choice, the noise rate is the deviation frequency.
    robot = [
        (rule, taken)
        for steps, strategy in zip(d.to_lists(), d.types)
        for t, (rule, taken, has_choice) in enumerate(_replay(steps, strategy, 3))
        if t % 2 == 1 and has_choice
    ]
    frequency = sum(rule != taken for rule, taken in robot) / len(robot)
    assert len(robot) > 1500
    assert abs(frequency - rate) < 0.03


def test_default_noise_deviates_human_steps_only():
    # robot_noise defaults to 0: every robot step follows the rule (the type's preference),
    # while human steps do deviate.
    d = simulate_study(n_subjects=60, strategies="safe,efficient,pairs", noise=0.15, seed=2)
    human_deviations = 0
    for steps, strategy in zip(d.to_lists(), d.types):
        for t, (rule, taken, _) in enumerate(_replay(steps, strategy, 3)):
            if t % 2 == 1:
                assert rule == taken
            else:
                human_deviations += rule != taken
    assert human_deviations > 10


def test_noise_range_draws_a_rate_per_subject():
    low = simulate_study(n_subjects=60, noise=(0.0, 0.0), seed=1)
    high = simulate_study(n_subjects=60, noise=(0.3, 0.5), seed=1)
    assert float(high.lengths.float().mean()) > float(low.lengths.float().mean())


def test_seeded_determinism():
    a = simulate_study(seed=11)
    assert a == simulate_study(seed=11)
    assert a != simulate_study(seed=12)
    g1, g2 = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    assert simulate_study(generator=g1) == simulate_study(generator=g2)


def test_batched_kernel_equals_one_at_a_time():
    g = torch.Generator().manual_seed(0)
    orders = torch.stack([torch.randperm(5, generator=g) for _ in range(9)])
    chunks = torch.tensor([5, 1, 2, 3, 1, 2, 5, 4, 1])
    zeros = torch.zeros(9, dtype=torch.float64)
    seqs, lengths = simulate_demonstrations(orders, chunks, zeros, zeros)
    for b in range(9):
        one, one_len = simulate_demonstrations(
            orders[b : b + 1], chunks[b : b + 1], zeros[:1], zeros[:1]
        )
        assert int(one_len[0]) == int(lengths[b])
        assert torch.equal(one[0, : one_len[0]], seqs[b, : lengths[b]])
        assert bool((seqs[b, lengths[b] :] == 0).all())


def test_placement_orders_read_from_any_demonstrations():
    d = Demonstrations.from_lists(
        [demonstration("safe", "CAB"), demonstration("pairs", "BCA")], subjects=["x", "x"]
    )
    assert placement_orders(d) == {"x": [("C", "A", "B"), ("B", "C", "A")]}


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_positions": 0}, "n_positions"),
        ({"n_subjects": 0}, "n_subjects"),
        ({"strategies": ("safe", "safe")}, "distinct"),
        ({"strategies": ("fast",)}, "unknown strategy 'fast'"),
        ({"noise": 1.5}, "noise"),
        ({"noise": (0.3, 0.1)}, "noise"),
        ({"order_change": -0.1}, "order_change"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ModelError, match=match):
        simulate_study(**kwargs)
    with pytest.raises(TypeError):
        simulate_study(n_demos=2.5)


def test_lagging_strategy_drills_the_previous_screw():
    from torchhrc.tasks.place_and_drill.demos import demonstration

    steps = [f"{actor[0]}:{action}" for actor, action in demonstration("lagging", "CAB")]
    assert steps == [
        "h:place_C", "r:wait",
        "h:place_A", "r:drill_C",
        "h:place_B", "r:drill_A",
        "h:wait", "r:drill_B",
    ]  # fmt: skip


def test_uniform_deviations_draw_any_action_of_the_actor():
    """noise = robot_noise = 1 with uniform deviations: every step of the first turns is a
    uniform draw over the actor's n + 1 actions, legal or not."""
    from torchhrc.tasks.place_and_drill.demos import simulate_demonstrations

    B, n = 20000, 3
    g = torch.Generator().manual_seed(11)
    orders = torch.rand(B, n, generator=g).argsort(-1)
    one = torch.ones(B, dtype=torch.float64)
    seqs, lengths = simulate_demonstrations(
        orders, torch.full((B,), n), one, one, generator=g, deviation="uniform"
    )
    first_h = torch.bincount(seqs[:, 0], minlength=2 * n + 2)[: n + 1].double() / B
    second_r = torch.bincount(seqs[:, 1], minlength=2 * n + 2)[n + 1 :].double() / B
    # 4 options each: 0.25 +- 4 standard errors (0.0031)
    assert ((first_h - 0.25).abs() < 0.0125).all()
    assert ((second_r - 0.25).abs() < 0.0125).all()
    # an illegal drill (nothing placed at the robot's first step unless the human placed)
    # is recorded and changes nothing: every sequence still ends with all screws drilled
    ends = seqs.gather(1, (lengths - 1)[:, None]).squeeze(-1)
    assert ((ends > n) & (ends < 2 * n + 1)).all()  # the last step is a drill


def test_batched_simulation_gives_valid_padded_sequences():
    """A study simulated in several batches: one padded tensor, every sequence task-valid
    (each screw placed once then drilled once, under other-legal deviations)."""
    import torchhrc.tasks.place_and_drill.demos as demos_module

    old = demos_module._BATCH
    try:
        demos_module._BATCH = 50  # 120 demonstrations: three batches of different widths
        d = simulate_study(n_subjects=40, seed=5, noise=0.3, robot_noise=0.2, order_change=1.0)
    finally:
        demos_module._BATCH = old
    assert d.num_sequences == 120 and int(d.lengths.max()) == d.sequences.shape[1]
    n = 3
    for row, length in zip(d.sequences.tolist(), d.lengths.tolist()):
        steps = row[:length]
        assert sorted(a for a in steps if a < n) == list(range(n))  # each placed once
        assert sorted(a - n - 1 for a in steps if n < a < 2 * n + 1) == list(range(n))
