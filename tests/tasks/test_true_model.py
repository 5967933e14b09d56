"""true_momdp / true_model_controller: the world's own people as a MOMDP, and the robot that
plans on it (evaluate_task(true_model=True)).

References: values worked by hand on the two-sided task of test_evaluation.py, and the
people's own simulator (TabularPeople.act and the task's effects) sampled step by step.
"""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch
from _sides import G, learned
from _sides import by_hand as _by_hand
from _sides import world as _world

import torchhrc
from torchhrc.errors import ModelError
from torchhrc.tasks.evaluation import TRUE_BEHAVIOUR, TRUE_MODEL, TRUE_REWARDS, evaluate_task
from torchhrc.tasks.people import TabularPeople, TaskWithPeople
from torchhrc.tasks.suite import make_task
from torchhrc.tasks.true_model import (
    true_behaviour_controller,
    true_model_controller,
    true_momdp,
    true_reward_controller,
)

START, A_SIDE, B_SIDE, MIDDLE, END = range(5)


def test_the_two_sided_task_worked_by_hand():
    eps = 0.2
    world = _world()
    m = true_momdp(world, noise=eps, shares=(3.0, 1.0))
    assert m.Ty is None and m.hidden_states == ("left", "right")  # no memory: a static type
    torch.testing.assert_close(m.b0, torch.tensor([0.75, 0.25], dtype=torch.float64))
    # at the start the person walks to her side, or with probability eps to a random one of
    # the two legal sides: 1 - eps / 2 to her own
    for y, own, other in ((0, A_SIDE, B_SIDE), (1, B_SIDE, A_SIDE)):
        for a in range(3):  # the robot's moves change nothing at the start
            row = m.Tx[a, START, y]
            assert float(row[own]) == pytest.approx(1 - eps / 2)
            assert float(row[other]) == pytest.approx(eps / 2)
    # from a side to the middle (the only legal move, noise or not); the middle waits for the
    # robot: a hand ends the task, waiting keeps it (the person has nothing legal there)
    assert float(m.Tx[0, A_SIDE, 1, MIDDLE]) == pytest.approx(1.0)
    assert float(m.Tx[0, MIDDLE, 0, MIDDLE]) == pytest.approx(1.0)
    assert float(m.Tx[1, MIDDLE, 1, END]) == pytest.approx(1.0)
    # the end keeps every action and has no reward
    assert bool((m.Tx[:, END, :, END] == 1).all()) and bool((m.R[:, END] == 0).all())
    torch.testing.assert_close(m.R[1, MIDDLE], torch.tensor([1.0, -1.0], dtype=torch.float64))


def test_a_terminal_state_keeps_even_where_the_people_could_move():
    # the same task where "go_a" at the end would lead back to the start (legal there, so a
    # slip takes it): an episode is over at the end, and the model keeps it there
    base = _world()

    class Restart(type(base.task)):
        human_effect = torch.tensor([[1, 2, 0], [1, 1, 3], [2, 2, 3], [3, 3, 3], [0, 4, 4]])

    task = Restart()
    assert bool(task.human_legal[END, 0])
    people = TabularPeople(base.type_names, base.people.policy, task.human_legal)
    world = TaskWithPeople(task, people, base.true_reward, horizon=6, observed=False)
    m = true_momdp(world, noise=0.3)
    assert bool((m.Tx[:, END, :, END] == 1).all())


def test_the_robot_of_the_true_model_gets_the_value_worked_by_hand():
    # it hands the side the person walked to: g^2 from each type, -g^2 when she slipped to
    # the other side (probability eps / 2): g^2 (1 - eps) per type
    eps, E = 0.2, 400
    world = _world()
    robot = true_model_controller(world, noise=eps, time_limit=1.0)
    result = evaluate_task(world, None, robots={"true": robot}, episodes=E, noise=eps, seed=3)
    se = result.ci[0] / 1.96
    want = G**2 * (1 - eps)
    assert torch.all((result.mean[0] - want).abs() < 4 * se), result.table()


@pytest.mark.parametrize("name", ["pace", "screws_hands_off", "tool_handover"])
def test_one_step_of_the_model_is_one_step_of_the_simulated_people(name):
    # the joint P(x2, h2 | x, h, a) of the model against the people's own simulator: for
    # random non-terminal (x, type, memory, a), 3000 simulated turns each
    noise = 0.1
    world = make_task(name)
    m = true_momdp(world, noise=noise)
    people, task = world.people, world.task
    M = people.num_memory
    N = m.num_hidden
    g = torch.Generator().manual_seed(0)
    live = torch.nonzero(~torch.as_tensor(task.terminal)).flatten()
    cases = 12
    x = live[torch.randint(live.numel(), (cases,), generator=g)]
    y = torch.randint(world.num_types, (cases,), generator=g)
    mem = torch.randint(M, (cases,), generator=g)
    a = torch.randint(task.num_actions, (cases,), generator=g)
    draws = 3000
    rep = lambda t: t.repeat_interleave(draws)  # noqa: E731
    xs, ys, ms, acts = rep(x), rep(y), rep(mem), rep(a)
    mid = torch.as_tensor(task.robot_effect)[acts, xs]
    h, new_m = people.act(ys, mid, acts, ms.unsqueeze(-1), g, noise=noise)
    x2 = torch.where(h >= 0, torch.as_tensor(task.human_effect)[mid, h.clamp_min(0)], mid)
    h2 = ys * M + new_m[:, 0]
    Ty = m.Ty if m.Ty is not None else None
    for c in range(cases):
        sl = slice(c * draws, (c + 1) * draws)
        seen = torch.zeros(task.num_states * N, dtype=torch.float64)
        seen.index_add_(0, x2[sl] * N + h2[sl], torch.ones(draws, dtype=torch.float64))
        seen /= draws
        hc = int(y[c]) * M + int(mem[c])
        tx = m.Tx[a[c], x[c], hc]  # (X,)
        joint = tx.unsqueeze(-1) * (Ty[a[c], x[c], hc] if Ty is not None
                                    else torch.eye(N, dtype=torch.float64)[hc])  # fmt: skip
        joint = joint.reshape(-1)
        # binomial standard error of each cell; 5 of them (and 0.005) as the tolerance
        tol = 5 * (joint * (1 - joint) / draws).sqrt() + 0.005
        assert bool(((seen - joint).abs() <= tol).all()), (name, c, seen, joint)
    # every row a distribution
    torch.testing.assert_close(m.Tx.sum(-1), torch.ones_like(m.Tx.sum(-1)))


def test_memory_makes_the_hidden_value_change():
    world = make_task("pace")  # people with a memory of 2 states
    m = true_momdp(world)
    M = world.people.num_memory
    assert M == 2 and m.Ty is not None and m.num_hidden == 3 * M
    assert m.hidden_states[:2] == (f"{world.type_names[0]}/m0", f"{world.type_names[0]}/m1")
    # the type never changes: no mass from one type's block to another's
    block = torch.arange(m.num_hidden) // M
    cross = block.view(-1, 1) != block.view(1, -1)  # (N, N)
    assert float((m.Ty * cross.view(1, 1, *cross.shape[:1], 1, -1)).abs().max()) == 0.0
    # b0: each type's share times its first memory state's probability
    third = torch.full((3,), 1 / 3, dtype=torch.float64)
    torch.testing.assert_close(m.b0.view(3, M).sum(-1), third)


def test_evaluate_task_adds_the_robot_and_the_summary_says_whether_it_pays():
    world, demos, aware, agnostic = learned()
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic, episodes=200,
                           noise=0.2, told_type=True, true_model=True, seed=6)  # fmt: skip
    assert result.robots == ("type-aware", "type-agnostic", TRUE_MODEL, "told the type")
    lines = result.summary().splitlines()
    assert lines[2].startswith("finding the type online pays: true model 0.6"), lines
    # the learned model is exact here: the type-aware robot keeps all of what can be had
    kept = int(lines[2].rsplit("keeps ", 1)[1].split("%")[0])
    assert abs(kept - 100) <= 15, lines[2]
    twin = true_model_controller(world, time_limit=0.5)
    with pytest.raises(ValueError, match="taken by robots="):
        evaluate_task(world, None, robots={TRUE_MODEL: twin}, true_model=True, episodes=2)


def test_summary_when_finding_the_type_online_does_not_pay():
    robots = ("type-aware", "type-agnostic", TRUE_MODEL, "told the type")
    lines = _by_hand([1.0, 1.0, 1.05, 3.0], robots=robots).summary().splitlines()
    assert lines[1].startswith("knowing the type pays: told the type 3.00")
    assert lines[2].startswith("finding the type online does not pay: true model 1.05 ± 0.10, "
                               "level with type-agnostic")  # fmt: skip
    # (2.0 - 1.0) / (3.0 - 1.0) of the online gain
    two = _by_hand([2.0, 1.0, 3.0], robots=robots[:3]).summary().splitlines()
    assert two[1] == ("finding the type online pays: true model 3.00 ± 0.10, ahead of "
                      "type-agnostic; type-aware keeps 50% of that gain")  # fmt: skip


def test_people_without_tables_and_bad_settings_get_clear_errors():
    world = _world()

    class Opaque:  # simulated people that only act
        num_types, type_names = 2, ("left", "right")

        def initial_memory(self, types, generator):
            return torch.zeros(types.shape[0], 0, dtype=torch.long)

        def act(self, types, x_mid, robot_action, memory, generator, *, noise=0.0):
            return torch.full_like(types, -1), memory

    opaque = TaskWithPeople(world.task, Opaque(), world.true_reward, horizon=6, observed=False)
    with pytest.raises(ModelError, match="turn_tables"):
        true_momdp(opaque)
    with pytest.raises(ValueError, match="noise in"):
        true_momdp(world, noise=1.5)
    with pytest.raises(ValueError, match="shares of shape"):
        true_momdp(world, shares=(1.0, 2.0, 3.0))


def _learned(world, eps):
    demos, _ = world.demonstrations(subjects=12, per_subject=3, noise=eps, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return demos, torchhrc.learn(world.task, demos, k=2, solver_time=1.0, seed=0)


def _spoiled(model, demos, **fields):
    """The model with some MOMDP fields replaced, its two learned types ordered so that true
    "left" is learned type 1 (the maps between learned and true types are not the
    identity), solved again."""
    from torchhrc.tasks.pipeline import solve_model

    m = dataclasses.replace(model.momdp, **fields)
    assignments = model.assignments
    left = torch.tensor([t == "left" for t in demos.types])
    if int(assignments[left].mode().values) == 0:  # put left on learned type 1
        m = dataclasses.replace(m, Tx=m.Tx.flip(2), R=m.R.flip(-1), b0=m.b0.flip(-1),
                                Z=m.Z.flip(2))  # fmt: skip
        assignments = 1 - assignments
    relabelled = dataclasses.replace(model, momdp=m, policy=None, assignments=assignments)
    return solve_model(relabelled, time_limit=1.0)


def _parts(world, model, demos, eps):
    result = evaluate_task(world, model, demonstrations=demos, episodes=300, noise=eps,
                           true_model=True, true_parts=True, seed=5)  # fmt: skip
    assert result.robots == ("type-aware", "type-agnostic", TRUE_MODEL, TRUE_BEHAVIOUR,
                             TRUE_REWARDS)  # fmt: skip
    return result, {name: float(v) for name, v in zip(result.robots, result.overall_mean)}


def test_true_rewards_win_back_what_wrong_rewards_lost():
    # the learned model with each type's hand-over rewards swapped: it hands every person the
    # wrong side (-g^2 (1 - eps)); given the true rewards it hands the right one again, and
    # given the true behaviour (with the wrong rewards) it still hands the wrong one
    eps = 0.2
    world = _world()
    demos, model = _learned(world, eps)
    wrong = _spoiled(model, demos, R=model.momdp.R.flip(-1))
    result, m = _parts(world, wrong, demos, eps)
    want = G**2 * (1 - eps)
    se = float(result.overall_ci.max()) / 1.96
    assert abs(m["type-aware"] + want) < 4 * se, result.table()
    assert abs(m[TRUE_REWARDS] - want) < 4 * se and abs(m[TRUE_MODEL] - want) < 4 * se
    assert abs(m[TRUE_BEHAVIOUR] + want) < 4 * se
    line = next(x for x in result.summary().splitlines() if x.startswith("learning lost"))
    assert line.startswith("learning lost 1.3") and line.endswith(
        "the rewards (their features) matter most"
    ), line


def test_the_true_behaviour_wins_back_what_a_wrong_behaviour_lost():
    # the learned model with the two types' behaviours swapped: at side "a" it believes the
    # person is "right" and hands right; the true behaviour puts it right, the true rewards
    # (with the swapped behaviour) do not
    eps = 0.2
    world = _world()
    demos, model = _learned(world, eps)
    wrong = _spoiled(model, demos, Tx=model.momdp.Tx.flip(2))
    result, m = _parts(world, wrong, demos, eps)
    want = G**2 * (1 - eps)
    se = float(result.overall_ci.max()) / 1.96
    assert abs(m["type-aware"] + want) < 4 * se, result.table()
    assert abs(m[TRUE_BEHAVIOUR] - want) < 4 * se and abs(m[TRUE_REWARDS] + want) < 4 * se
    line = next(x for x in result.summary().splitlines() if x.startswith("learning lost"))
    assert line.endswith("the behaviour (the human model) matters most"), line


def test_summary_of_the_parts_worked_by_hand():
    robots = ("type-aware", "type-agnostic", TRUE_MODEL, TRUE_BEHAVIOUR, TRUE_REWARDS)
    # lost 3.0 - 1.0 = 2.0: the behaviour wins back (2.0 - 1.0) / 2 = 50%, the rewards 75%
    line = _by_hand([1.0, 0.5, 3.0, 2.0, 2.5], robots=robots).summary().splitlines()[2]
    assert line == ("learning lost 2.00 (type-aware against true model): true behaviour "
                    "2.00 ± 0.10 wins back 50% of it, true rewards 2.50 ± 0.10 75%; either "
                    "part alone wins back half or more")  # fmt: skip
    line = _by_hand([1.0, 0.5, 3.0, 1.4, 1.6], robots=robots).summary().splitlines()[2]
    assert line.endswith("neither part alone wins back half: both are off")
    # the true model 0.1 ahead of the type-aware robot, within the paired difference's
    # half-width (1.96 * 0.2 / sqrt(2) = 0.28): nothing lost; 0.3 ahead is beyond it
    line = _by_hand([1.0, 0.5, 1.1, 1.0, 1.0], robots=robots).summary().splitlines()[2]
    assert line.startswith("learning lost nothing beyond the 95% interval: true model 1.10")
    line = _by_hand([1.0, 0.5, 1.3, 1.0, 1.0], robots=robots).summary().splitlines()[2]
    assert line.startswith("learning lost 0.30 (type-aware against true model)")


def test_the_maps_are_checked():
    world = _world()
    _, model = _learned(world, 0.05)
    with pytest.raises(ValueError, match=r"type_map of shape \(2,\)"):
        true_behaviour_controller(world, model, torch.tensor([0, 2]))
    with pytest.raises(ValueError, match=r"truth_of of shape \(2,\)"):
        true_reward_controller(world, model, torch.tensor([0]))
    with pytest.raises(ValueError, match="true_parts=True needs a model"):
        evaluate_task(
            world,
            None,
            robots={"x": true_model_controller(world, time_limit=0.5)},
            true_parts=True,
            episodes=2,
        )
