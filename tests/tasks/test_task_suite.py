"""torchhrc.tasks.suite: every task is a valid CollaborativeTask with simulated people of
known types, the suite covers the ranges issue 31 asks for, and the demonstrations are
what the people's tables say."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from torchhrc.metrics import adjusted_rand_index
from torchhrc.tasks import check_task, learn, make_task, suite_tasks
from torchhrc.tasks.people import TabularPeople
from torchhrc.tasks.suite import SUITE
from torchhrc.tasks.suite.builder import intent_signal


@pytest.fixture(scope="module")
def suite():
    return {name: make_task(name) for name in suite_tasks()}


def _memory_matters(people: TabularPeople) -> bool:
    """The behaviour differs between memory states somewhere (history-dependent)."""
    p = people.policy  # (Y, M, X, A, H + 1)
    return bool((p - p[:, :1]).abs().amax() > 0)


def _action_matters(people: TabularPeople) -> bool:
    p = people.policy
    return bool((p - p[:, :, :, :1]).abs().amax() > 0)


def test_the_suite_covers_the_ranges_of_issue_31(suite):
    assert len(suite) >= 8 and tuple(SUITE) == suite_tasks()
    types = [t.num_types for t in suite.values()]
    states = [t.task.num_states for t in suite.values()]
    assert all(2 <= y <= 5 for y in types) and {2, 5} <= set(types)
    assert all(20 <= x <= 300 for x in states) and min(states) < 30 and max(states) > 200
    observed = [t.observed for t in suite.values()]
    assert any(observed) and not all(observed)
    history = [_memory_matters(t.people) for t in suite.values()]
    assert any(history) and not all(history)
    # the state-only tasks still depend on the state (not on the robot's action alone)
    for t in suite.values():
        p = t.people.policy
        assert (p - p[:, :, :1]).abs().amax() > 0


@pytest.mark.parametrize("name", suite_tasks())
def test_every_task_is_valid_and_its_pieces_agree(suite, name):
    twp = suite[name]
    task = twp.task
    check_task(task)
    A, X, Y = task.num_actions, task.num_states, twp.num_types
    assert twp.true_reward.shape == (A, X, Y)
    assert (twp.true_reward[:, task.terminal] == 0).all()
    assert len(set(twp.type_names)) == Y and all(n.isidentifier() for n in twp.type_names)
    assert twp.observed == (task.intent_accuracy is not None)
    # every state is reachable, so a terminal state is too
    assert task.terminal.any()
    # the types' best responses differ somewhere
    r = twp.true_reward.permute(2, 1, 0)  # (Y, X, A)
    best = r >= r.amax(-1, keepdim=True) - 1e-12
    assert (best != best[:1]).any()
    if twp.observed:
        z = twp.true_observation
        assert z.shape == (A, X, Y, task.num_human_actions + 1)
        assert torch.allclose(z.sum(-1), torch.ones((), dtype=z.dtype))


@pytest.mark.parametrize("name", suite_tasks())
def test_people_only_take_legal_actions(suite, name):
    twp = suite[name]
    people, task = twp.people, twp.task
    Y, M, X, A = people.num_types, people.num_memory, task.num_states, task.num_actions
    y, m, x, a = torch.meshgrid(*(torch.arange(n) for n in (Y, M, X, A)), indexing="ij")
    y, m, x, a = (t.reshape(-1).repeat(4) for t in (y, m, x, a))
    g = torch.Generator().manual_seed(0)
    for noise in (0.0, 0.5, 1.0):
        h, new_m = people.act(y, x, a, m.unsqueeze(-1), g, noise=noise)
        acted = h >= 0
        assert task.human_legal[x[acted], h[acted]].all()
        # nobody acts where nothing is legal; with noise 1 somebody acts wherever one can
        assert not acted[~task.human_legal[x].any(-1)].any()
        if noise == 1.0:
            assert acted[task.human_legal[x].any(-1)].all()
        assert ((new_m >= 0) & (new_m < M)).all()


@pytest.mark.parametrize("name", suite_tasks())
def test_demonstrations_replay_the_people_tables(suite, name):
    """At noise 0, every human step of a demonstration is the person's table action (the
    suite's people are deterministic), with the memory replayed from the start; the true
    labels are the generating types; the task reads the demonstrations."""
    twp = suite[name]
    task, people = twp.task, twp.people
    assert isinstance(people, TabularPeople)
    assert ((people.policy == 0) | (people.policy == 1)).all()  # deterministic people
    demos, types = twp.demonstrations(subjects=2 * twp.num_types, per_subject=2, noise=0.0,
                                      seed=3)  # fmt: skip
    assert demos.types == tuple(twp.type_names[t] for t in types.tolist())
    assert torch.equal(
        types, (torch.arange(2 * twp.num_types) % twp.num_types).repeat_interleave(2)
    )
    steps = task.read_steps(demos)
    table = people.policy.argmax(-1)  # (Y, M, X, A): H means no action
    H = task.num_human_actions
    for n in range(len(demos)):
        y, m = int(types[n]), 0
        for t in range(int(steps.lengths[n])):
            x, a, h = int(steps.states[n, t]), int(steps.actions[n, t]), int(steps.human[n, t])
            mid = int(task.robot_effect[a, x])
            want = int(table[y, m, mid, a])
            assert h == (-1 if want == H else want), (n, t)
            m = int(people.update[y, m, mid, a, h if h >= 0 else H])
        end = int(steps.next_states[n, int(steps.lengths[n]) - 1])
        assert bool(task.terminal[end]) or int(steps.lengths[n]) == twp.horizon


@pytest.mark.parametrize("name", suite_tasks())
def test_noisy_demonstrations_are_seeded_and_readable(suite, name):
    twp = suite[name]
    a, ya = twp.demonstrations(subjects=twp.num_types, per_subject=3, noise=0.3, seed=11)
    b, yb = twp.demonstrations(subjects=twp.num_types, per_subject=3, noise=0.3, seed=11)
    assert a == b and torch.equal(ya, yb)
    c, _ = twp.demonstrations(subjects=twp.num_types, per_subject=3, noise=0.3, seed=12)
    assert c != a
    twp.task.read_steps(a)
    # noise makes the person leave their table somewhere
    clean, _ = twp.demonstrations(subjects=twp.num_types, per_subject=3, noise=0.0, seed=11)
    assert clean != a


def test_two_types_cannot_be_told_apart_where_their_best_responses_differ(suite):
    """screws_hands_off: while the robot waits, "hands_off" and "eager" place the same screw
    (identical behaviour in those states), yet the best robot action differs (wait vs drill)
    in some of them: the evaluation must report the belief as split there."""
    twp = suite["screws_hands_off"]
    hands_off, eager = twp.type_names.index("hands_off"), twp.type_names.index("eager")
    p = twp.people.policy[:, 0, :, 0]  # memory 0, robot waits: (Y, X, H + 1)
    live = ~twp.task.terminal
    same = (p[hands_off] == p[eager]).all(-1) & live
    assert same[live].all()
    r = twp.true_reward.permute(2, 1, 0)
    differ = r[hands_off].argmax(-1) != r[eager].argmax(-1)
    assert (same & differ).any()


def test_learn_runs_on_a_suite_task_at_the_true_k(suite):
    twp = suite["tool_handover"]  # observed: the learned model carries the reach signal
    demos, types = twp.demonstrations(subjects=8, per_subject=2, noise=0.05, seed=0)
    model = learn(twp.task, demos, k=twp.num_types, restarts=3, solve=False, seed=0)
    assert model.num_types == twp.num_types
    assert adjusted_rand_index(types.tolist(), model.assignments.tolist()) == pytest.approx(1.0)
    A, X, H = twp.task.num_actions, twp.task.num_states, twp.task.num_human_actions
    Z = model.momdp.Z
    assert Z.shape == (A, X, twp.num_types, H + 1)
    assert torch.allclose(Z.sum(-1), torch.ones((), dtype=Z.dtype))
    # the learned reach signal agrees with the true one for the self-server at the start,
    # where its demonstrating robot waits (so the learned behaviour has seen the state)
    y = twp.type_names.index("self_server")
    k = int(torch.mode(model.assignments[types == y]).values)
    x0 = twp.task.initial_state
    fetch = twp.task.human_actions.index("fetch_tool")
    assert int(twp.true_observation[0, x0, y].argmax()) == fetch
    assert int(Z[0, x0, k].argmax()) == fetch


@pytest.mark.parametrize("name", suite_tasks())
def test_the_learned_signal_of_the_true_behaviour_is_the_true_signal(suite, name):
    """``observation(model)`` reads the reach signal off a model's ``Tx``: given the true
    people's ``Tx`` it gives back ``true_observation``, and given a noisy behaviour's ``Tx``
    the signal of that behaviour (``intent_signal`` of its rows under the idle robot)."""
    twp = suite[name]
    task, people = twp.task, twp.people
    if not twp.observed:
        assert task.observation(SimpleNamespace(Tx=None)) is None
        return
    A, X, Y, H = task.num_actions, task.num_states, twp.num_types, task.num_human_actions
    legal = torch.cat([task.human_legal, torch.ones(X, 1, dtype=torch.bool)], -1).double()
    uniform = (legal / legal.sum(-1, keepdim=True)).view(1, X, 1, H + 1)
    live = ~task.terminal
    for weight in (1.0, 0.6):
        behaviour = weight * people.policy[:, 0] + (1 - weight) * uniform  # (Y, X_mid, A, H+1)
        Tx = torch.zeros(A, X, Y, X, dtype=torch.float64)
        for a in range(A):
            for x in range(X):
                m = int(task.robot_effect[a, x])
                for h in range(H + 1):
                    nxt = m if h == H else int(task.human_effect[m, h])
                    Tx[a, x, :, nxt] += behaviour[:, m, a, h]
        Z = task.observation(SimpleNamespace(Tx=Tx))
        intent = behaviour[:, :, 0].permute(1, 0, 2)  # (X, Y, H + 1), the robot idle
        want = intent_signal(intent, task.intent_accuracy, A)
        assert torch.allclose(Z[:, live], want[:, live], atol=1e-12)
        if weight == 1.0:
            assert torch.allclose(Z[:, live], twp.true_observation[:, live], atol=1e-12)
