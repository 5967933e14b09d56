"""Tests of torchhrc.tasks.place_and_drill.model: states, effects, features, and the task's Tx,
steps and MOMDP as the pipeline builds them (worked by hand); the deprecated old names."""

from __future__ import annotations

import itertools

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.tasks.interface import behaviour_from_preferences, chain_preferences
from torchhrc.tasks.pipeline import build_model, task_momdp, transition_from_behaviour
from torchhrc.tasks.place_and_drill.demos import demonstration, simulate_study
from torchhrc.tasks.place_and_drill.model import (
    DRILLED,
    EMPTY,
    FEATURE_NAMES,
    PLACED,
    PlaceAndDrillTask,
    interpret_clusters,
)


def placement_transition(task, placement, *, noise=0.05, pause=0.0):
    """The task's ``Tx (A, X, Y, X)`` from placement preferences ``(Y, A, n)`` (the same in
    every state), through the pipeline's functions."""
    behaviour = behaviour_from_preferences(task, placement.unsqueeze(-2), noise=noise, pause=pause)
    return transition_from_behaviour(task, behaviour)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_states_enumerate_every_status_once(n):
    task = PlaceAndDrillTask(n)
    status = task.status
    assert status.shape == (3**n, n)
    rows = {tuple(r) for r in status.tolist()}
    assert rows == set(itertools.product(range(3), repeat=n))
    assert torch.equal(task.encode(status), torch.arange(3**n))
    assert task.state_names[task.initial_state] == "E" * n
    assert task.state_names[task.terminal_state] == "D" * n


def test_effects_against_a_loop_over_states():
    task = PlaceAndDrillTask(3)
    for x, row in enumerate(task.status.tolist()):
        for i in range(3):
            drilled = list(row)
            if row[i] == PLACED:
                drilled[i] = DRILLED
            assert task.robot_effect[1 + i, x] == task.encode(torch.tensor(drilled))
            placed = list(row)
            if row[i] == EMPTY:
                placed[i] = PLACED
            assert task.place_effect[x, i] == task.encode(torch.tensor(placed))
        assert task.robot_effect[0, x] == x  # wait changes nothing


def test_features_one_hot_except_terminal():
    task = PlaceAndDrillTask(3)
    phi = task.features()
    assert phi.shape == (4, 27, len(FEATURE_NAMES))
    total = phi.sum(-1)
    assert torch.all(total[:, task.terminal_state] == 0)
    mask = torch.ones(27, dtype=torch.bool)
    mask[task.terminal_state] = False
    assert torch.all(total[:, mask] == 1)
    x = task.encode(torch.tensor([PLACED, EMPTY, EMPTY]))
    by_name = dict(zip(FEATURE_NAMES, range(6)))
    assert phi[1, x, by_name["drill_early"]] == 1  # drill A while B, C empty
    assert phi[2, x, by_name["drill_invalid"]] == 1  # drill empty B
    assert phi[0, x, by_name["wait_early"]] == 1
    full = task.encode(torch.tensor([PLACED, PLACED, DRILLED]))
    assert phi[1, full, by_name["drill_ready"]] == 1
    assert phi[0, full, by_name["wait_late"]] == 1
    assert phi[0, task.initial_state, by_name["wait_idle"]] == 1


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_placement_transition_is_stochastic_and_legal(dtype):
    task = PlaceAndDrillTask(3)
    g = torch.Generator().manual_seed(0)
    p = torch.rand(2, 4, 3, generator=g).to(dtype)
    Tx = placement_transition(task, p, noise=0.1, pause=0.02)
    assert Tx.shape == (4, 27, 2, 27) and Tx.dtype == dtype
    torch.testing.assert_close(Tx.sum(-1), torch.ones_like(Tx.sum(-1)))
    # only x2 reachable by the robot's effect and at most one placement have mass
    for a, x in [(0, 0), (1, 9), (3, 13)]:
        mid = int(task.robot_effect[a, x])
        allowed = {mid} | {int(task.place_effect[mid, i]) for i in range(3)}
        support = set(torch.nonzero(Tx[a, x, 0]).flatten().tolist())
        assert support <= allowed


def test_behaviour_from_preferences_batched_equals_each_item():
    task = PlaceAndDrillTask(2)
    p = torch.rand(2, 3, 3, 9, 2, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    batched = behaviour_from_preferences(task, p, noise=0.1, pause=0.05)
    assert batched.shape == (2, 3, 3, 9, 3)
    for b in range(2):
        one = behaviour_from_preferences(task, p[b], noise=0.1, pause=0.05)
        torch.testing.assert_close(batched[b], one, rtol=0, atol=1e-15)


def test_placement_transition_by_hand():
    task = PlaceAndDrillTask(2)
    p = torch.zeros(1, 3, 2, dtype=torch.float64)
    p[0, 0] = torch.tensor([3.0, 1.0])  # after a wait: A three times as likely as B
    Tx = placement_transition(task, p, noise=0.2, pause=0.1)
    pe = task.encode(torch.tensor([PLACED, EMPTY]))
    ep = task.encode(torch.tensor([EMPTY, PLACED]))
    # (1 - pause) * ((1 - noise) * 3/4 + noise / 2) = 0.9 * 0.7
    assert Tx[0, 0, 0, pe].item() == pytest.approx(0.9 * 0.7)
    assert Tx[0, 0, 0, ep].item() == pytest.approx(0.9 * 0.3)
    assert Tx[0, 0, 0, 0].item() == pytest.approx(0.1)
    # nothing empty: the bench stays as the robot left it
    full = task.encode(torch.tensor([PLACED, PLACED]))
    assert Tx[0, full, 0, full].item() == 1.0


def test_placement_transition_rejects_bad_input():
    task = PlaceAndDrillTask(2)
    with pytest.raises(ModelError, match=r"\(\.\.\., Y, A=3, X=9 or 1, H=2\)"):
        placement_transition(task, torch.ones(1, 2, 2))
    with pytest.raises(ModelError, match="non-negative"):
        placement_transition(task, -torch.ones(1, 3, 2))
    with pytest.raises(ModelError, match="noise"):
        placement_transition(task, torch.ones(1, 3, 2), noise=1.5)
    with pytest.raises(ModelError, match="pause"):
        placement_transition(task, torch.ones(1, 3, 2), pause=1.0)


def test_demonstration_steps_follow_the_bench():
    task = PlaceAndDrillTask(3)
    demos = Demonstrations.from_lists(
        [demonstration("safe", "BAC"), demonstration("efficient", "CAB")]
    )
    steps = task.read_steps(demos)
    names = task.state_names
    safe = [names[x] for x in steps.states[0, : steps.lengths[0]].tolist()]
    assert safe == ["EEE", "EPE", "PPE", "PPP", "PDP", "DDP"]
    assert [task.actions[a] for a in steps.actions[0, :6].tolist()] == [
        "wait", "wait", "wait", "drill_B", "drill_A", "drill_C",
    ]  # fmt: skip
    eff = [names[x] for x in steps.states[1, : steps.lengths[1]].tolist()]
    assert eff == ["EEE", "EEP", "PED", "DPD"]
    assert names[int(steps.next_states[1, 3])] == "DDD"
    # the human's placements: none in the safe person's drilling steps, C A B interleaved
    assert steps.human[0, :6].tolist() == [1, 0, 2, -1, -1, -1]
    assert steps.human[1, :4].tolist() == [2, 0, 1, -1]
    # every step is consistent with the task's mechanics
    m = steps.mask
    mid = task.robot_effect[steps.actions[m], steps.states[m]]
    reach = (task.place_effect[mid] == steps.next_states[m, None]).any(-1)
    assert torch.all(reach | (mid == steps.next_states[m]))


def test_demonstration_steps_rejects_foreign_symbols():
    demos = Demonstrations.from_lists([[("human", "place_Z"), ("robot", "wait")]])
    with pytest.raises(ModelError, match="place_Z"):
        PlaceAndDrillTask(3).read_steps(demos)


def test_reading_steps_rejects_placing_an_occupied_position():
    demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "wait"),
                                        ("human", "place_A")]])  # fmt: skip
    with pytest.raises(ModelError, match=r"place_A.*cannot happen in state 'P'"):
        PlaceAndDrillTask(1).read_steps(demos)


def _true_chains(demos: Demonstrations) -> tuple[torch.Tensor, torch.Tensor]:
    labels = torch.tensor([t == "efficient" for t in demos.types]).long()
    counts = torch.stack([demos.subset(labels == k).transition_counts() + 0.1 for k in range(2)])
    return counts / counts.sum(-1, keepdim=True), labels


def test_interpret_clusters_names_the_strategies():
    demos = simulate_study(n_subjects=6, n_demos=2, noise=0.0, seed=1)
    chains, _ = _true_chains(demos)
    assert interpret_clusters(PlaceAndDrillTask(3), chains, demos.vocabulary) == (
        "safe",
        "efficient",
    )
    assert interpret_clusters(PlaceAndDrillTask(3), chains.flip(0), demos.vocabulary) == (
        "efficient",
        "safe",
    )


def test_placement_probabilities_read_the_chain():
    demos = simulate_study(n_subjects=4, n_demos=2, noise=0.0, seed=0)
    chains, _ = _true_chains(demos)
    task = PlaceAndDrillTask(3)
    p = chain_preferences(chains, demos.vocabulary, task.robot_actions, task.human_actions)
    assert p.shape == (2, 4, 3)
    v = list(demos.vocabulary)
    assert p[1, 1, 2] == chains[1, v.index(("robot", "drill_A")), v.index(("human", "place_C"))]


def test_learned_model_reproduces_each_types_rule():
    """IRL on noiseless demonstrations: each type's MDP policy follows its strategy."""
    from torchhrc.solvers.value_iteration import value_iteration

    demos = simulate_study(n_subjects=6, n_demos=2, noise=0.0, seed=0)
    chains, labels = _true_chains(demos)
    task = PlaceAndDrillTask(3)
    learned = build_model(task, demos, chains, labels, irl_iterations=5)
    m = learned.momdp
    assert m.Ty is None and m.num_observed == 27 and m.num_hidden == 2
    assert torch.all(m.R[:, task.terminal_state] == 0)
    status = task.status
    pending = (status == PLACED).any(-1)
    empty = (status == EMPTY).any(-1)
    for k, name in enumerate(learned.type_names):
        policy = value_iteration(m.Tx[:, :, k], m.R[..., k], m.discount).policy
        a = policy[pending]
        drills = (a > 0) & (
            status[pending].gather(-1, (a - 1).clamp_min(0)[:, None])[:, 0] == PLACED
        )
        want = ~empty[pending] if name == "safe" else torch.ones_like(drills)
        assert torch.equal(drills, want), name


def test_task_momdp_shapes_and_validation():
    task = PlaceAndDrillTask(2)
    Tx = placement_transition(task, torch.ones(3, 3, 2, dtype=torch.float64))
    R = torch.ones(3, 9, 3, dtype=torch.float64)
    b0 = torch.tensor([0.2, 0.3, 0.5], dtype=torch.float64)
    m = task_momdp(task, Tx, R, b0, type_names=("a", "b", "c"), discount=0.9)
    assert m.Z.shape == (3, 9, 3, 1) and m.x0 == 0 and m.discount == 0.9 and m.Ty is None
    assert m.hidden_states == ("a", "b", "c") and m.observed_states == task.state_names
    assert torch.all(m.R[:, task.terminal_state] == 0) and torch.all(R == 1)  # input untouched
    assert int((m.R == 0).sum()) == 3 * 3  # the all-drilled state only
    assert task_momdp(task, Tx, R).discount == task.discount
    with pytest.raises(ModelError, match="b0"):
        task_momdp(task, Tx, R, torch.tensor([0.5, 0.5], dtype=torch.float64))


# the task's old copy of the pipeline (issue 32): one release of deprecated names
ALIASES = [
    ("learn_type_weights", "torchhrc.tasks.pipeline", "learn_type_weights"),
    ("DemonstrationSteps", "torchhrc.tasks.interface", "TaskSteps"),
    ("LearnedTaskModel", "torchhrc.tasks.pipeline", "LearnedModel"),
    ("build_momdp", "torchhrc.tasks.pipeline", "task_momdp"),
]


@pytest.mark.parametrize("package", [False, True])
@pytest.mark.parametrize(("old", "module", "new"), ALIASES)
def test_old_names_warn_and_are_the_pipelines(old, module, new, package):
    import importlib

    where = importlib.import_module(
        "torchhrc.tasks.place_and_drill" + ("" if package else ".model")
    )
    expected = getattr(importlib.import_module(module), new)
    with pytest.warns(DeprecationWarning, match=f"model.{old} is deprecated; use {module}.{new}"):
        assert getattr(where, old) is expected
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        where.no_such_name  # noqa: B018


def test_old_forwards_warn_and_give_the_pipelines_results():
    import torchhrc.tasks.place_and_drill.model as model

    task = PlaceAndDrillTask(2)
    demos = Demonstrations.from_lists([[("human", "place_B"), ("robot", "drill_B"),
                                        ("human", "place_A"), ("robot", "drill_A")]])  # fmt: skip
    with pytest.warns(DeprecationWarning, match="use task.read_steps"):
        steps = model.demonstration_steps(task, demos)
    assert steps.states.tolist() == [[0, 1, 5]] and steps.next_states.tolist() == [[1, 5, 8]]
    p = torch.rand(2, 2, 3, 2, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    with pytest.warns(DeprecationWarning, match="transition_from_behaviour"):
        Tx = model.placement_transition(task, p, noise=0.1, pause=0.05)  # batched (2,)
    assert Tx.shape == (2, 3, 9, 2, 9)
    for b in range(2):
        torch.testing.assert_close(Tx[b], placement_transition(task, p[b], noise=0.1, pause=0.05))
    chains = torch.rand(1, 5, 5, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    vocabulary = (("robot", "wait"), ("robot", "drill_A"), ("robot", "drill_B"),
                  ("human", "place_A"), ("human", "place_B"))  # fmt: skip
    with pytest.warns(DeprecationWarning, match="chain_preferences"):
        pref = model.placement_probabilities(task, chains, vocabulary)
    assert pref[0, 2, 0] == chains[0, 2, 3] and pref[0, 0, 1] == chains[0, 0, 4]
    labels = torch.zeros(1, dtype=torch.long)
    counts = demos.transition_counts()[None] + 0.1
    with pytest.warns(DeprecationWarning, match="build_model"):
        old = model.build_learned_model(task, counts / counts.sum(-1, keepdim=True), demos,
                                        labels, discount=0.9, irl_iterations=2)  # fmt: skip
    assert old.momdp.discount == 0.9 and old.type_names == ("efficient",)
