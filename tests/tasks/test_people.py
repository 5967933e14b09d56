"""torchhrc.tasks.people: TabularPeople worked by hand, the noise, legality, validation, and
TaskWithPeople's seeded demonstrations."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.tasks import check_task
from torchhrc.tasks.people import SimulatedPeople, TabularPeople, TaskWithPeople, sample_legal
from torchhrc.tasks.suite import TaskSpec, build

# A hand-sized world: X = 3 states, A = 2 robot actions, H = 2 human actions.
# legal[x, h]: in x = 0 both, in x = 1 only h = 1, in x = 2 none.
LEGAL = torch.tensor([[True, True], [False, True], [False, False]])


def _lagging_people() -> TabularPeople:
    """Type 0 "steady": always h = 1 where legal. Type 1 "lagging": h = 0 in x = 0 and h = 1
    in x = 1, but only in memory 0; memory flips after every turn in which it acted."""
    Y, M, X, A, H = 2, 2, 3, 2, 2
    policy = torch.zeros(Y, M, X, A, H + 1, dtype=torch.float64)
    policy[:, :, 0:2, :, 1] = 1.0  # steady (and the default): h = 1 in x = 0, 1
    policy[:, :, 2, :, H] = 1.0  # nothing legal in x = 2
    policy[1, 0, 0, :, :] = torch.tensor([1.0, 0.0, 0.0])  # lagging, memory 0, x = 0: h = 0
    policy[1, 1, 0:2, :, :] = torch.tensor([0.0, 0.0, 1.0])  # lagging, memory 1: rests
    update = torch.zeros(Y, M, X, A, H + 1, dtype=torch.long)
    update[1, 0, :, :, 0:2] = 1  # acted -> rest next turn
    update[1, 1] = 0  # rested -> act next turn
    return TabularPeople(("steady", "lagging"), policy, LEGAL, update=update)


def test_tabular_people_worked_by_hand():
    people = _lagging_people()
    assert isinstance(people, SimulatedPeople)
    g = torch.Generator().manual_seed(0)
    types = torch.tensor([0, 1])
    memory = people.initial_memory(types, g)
    assert memory.tolist() == [[0], [0]]
    # turn 1 in x = 0: steady h = 1; lagging h = 0 (memory 0) and then memory 1
    h, memory = people.act(types, torch.tensor([0, 0]), torch.tensor([1, 1]), memory, g)
    assert h.tolist() == [1, 0] and memory.tolist() == [[0], [1]]
    # turn 2 in x = 1: steady h = 1; lagging rests (-1), memory back to 0
    h, memory = people.act(types, torch.tensor([1, 1]), torch.tensor([0, 0]), memory, g)
    assert h.tolist() == [1, -1] and memory.tolist() == [[0], [0]]
    # turn 3 in x = 1: lagging acts again (h = 1), in x = 2 nobody can act
    h, memory = people.act(types, torch.tensor([2, 1]), torch.tensor([0, 0]), memory, g)
    assert h.tolist() == [-1, 1] and memory.tolist() == [[0], [1]]


def test_stochastic_rows_are_sampled_with_their_probabilities():
    policy = torch.zeros(1, 1, 3, 2, 3, dtype=torch.float64)
    policy[..., 2] = 1.0
    policy[0, 0, 0, 1] = torch.tensor([0.2, 0.5, 0.3])
    people = TabularPeople(("p",), policy, LEGAL)
    g = torch.Generator().manual_seed(1)
    B = 20000
    types = torch.zeros(B, dtype=torch.long)
    h, _ = people.act(types, torch.zeros(B, dtype=torch.long), torch.ones(B, dtype=torch.long),
                      people.initial_memory(types, g), g)  # fmt: skip
    freq = torch.stack([(h == 0).double().mean(), (h == 1).double().mean(),
                        (h == -1).double().mean()])  # fmt: skip
    # binomial standard error <= 0.0036 at B = 20000: 5 sigma
    assert torch.allclose(freq, torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64), atol=0.02)


def test_noise_zero_is_the_table_and_noise_one_is_uniform_over_legal_actions():
    people = _lagging_people()
    B = 12000
    types = torch.ones(B, dtype=torch.long)  # lagging, memory 0, x = 0: the table says h = 0
    x = torch.zeros(B, dtype=torch.long)
    a = torch.zeros(B, dtype=torch.long)
    g = torch.Generator().manual_seed(2)
    memory = torch.zeros(B, 1, dtype=torch.long)
    h0, _ = people.act(types, x, a, memory, g, noise=0.0)
    assert (h0 == 0).all()
    h1, m1 = people.act(types, x, a, memory, g, noise=1.0)
    assert set(h1.tolist()) == {0, 1}  # both legal in x = 0, never -1 (an action is legal)
    assert abs(float((h1 == 1).double().mean()) - 0.5) < 0.03
    # the memory follows the action taken, the noisy one included
    assert (m1.squeeze(-1) == 1).all()
    hp, _ = people.act(types, x, a, memory, g, noise=0.3)
    # deviates with probability 0.3 * (1 - 1/2) = 0.15
    assert abs(float((hp == 1).double().mean()) - 0.15) < 0.02
    # where only h = 1 is legal the noise never produces h = 0; where none is, -1
    for state, allowed in ((1, {1}), (2, {-1})):
        hs, _ = people.act(types, torch.full((B,), state), a, memory, g, noise=1.0)
        assert set(hs.tolist()) <= allowed | {-1} and set(hs.tolist()) >= allowed


def test_sample_legal_is_uniform_and_minus_one_without_legal_actions():
    g = torch.Generator().manual_seed(3)
    x = torch.tensor([0] * 4000 + [2] * 10)
    h = sample_legal(LEGAL, x, g)
    assert (h[4000:] == -1).all()
    assert abs(float((h[:4000] == 0).double().mean()) - 0.5) < 0.04


def test_tabular_people_validation_names_the_problem():
    policy = torch.zeros(1, 1, 3, 2, 3, dtype=torch.float64)
    policy[..., 2] = 1.0
    bad = policy.clone()
    bad[0, 0, 1, 0] = torch.tensor([1.0, 0.0, 0.0])  # h = 0 illegal in x = 1
    with pytest.raises(ModelError, match=r"\(type 'p'\).*illegal in state 1.*after the robot's"):
        TabularPeople(("p",), bad, LEGAL)

    class Names:  # the names a task gives the indices (the error reads only these)
        state_names, robot_actions, human_actions = ("s0", "s1", "s2"), ("wait", "go"), ("u", "v")

    with pytest.raises(
        ModelError, match=r"human action 'u' in state 's1', after robot action 'wait'"
    ):
        TabularPeople(("p",), bad, LEGAL, task=Names())
    with pytest.raises(ModelError, match="summing to 1"):
        TabularPeople(("p",), policy * 0.5, LEGAL)
    with pytest.raises(ModelError, match="type_names"):
        TabularPeople(("p", "q"), policy, LEGAL)
    with pytest.raises(ModelError, match="update entries"):
        TabularPeople(("p",), policy, LEGAL, update=torch.ones(1, 1, 3, 2, 3, dtype=torch.long))
    # a policy without the "no action" column is named as such, not blamed on legal
    with pytest.raises(ModelError, match=r"\(\.\.\., 3\) for legal's H = 2 .*'no action'"):
        TabularPeople(("p",), policy[..., :2] / policy[..., :2].sum(-1, keepdim=True).clamp_min(1),
                      LEGAL)  # fmt: skip


def _toggle_spec(**kw) -> TaskSpec:
    """Two switches; the robot flips switch 0 on, the person switch 1 (legal when off);
    type "quick" acts at once (and wants the robot to wait for it), type "slow" only when
    switch 0 is on (and wants the robot to go first)."""
    base = dict(
        name="toggles", description="test", initial=(0, 0), robot_actions=("wait", "on"),
        human_actions=("flip",), robot_step=lambda s, a: (1, s[1]) if a == 1 else s,
        human_step=lambda s, h: (s[0], 1) if s[1] == 0 else None,
        terminal=lambda s: s == (1, 1), state_name=lambda s: f"{s[0]}{s[1]}",
        type_names=("quick", "slow"),
        behaviour=lambda y, m, s, a: {0: 1.0} if s[1] == 0 and (y == 0 or s[0] == 1) else {-1: 1.0},
        reward=lambda y, s, a: float(a == 1) if y == 1 else float(a == s[1]), horizon=4,
    )  # fmt: skip
    base.update(kw)
    return TaskSpec(**base)


def test_task_with_people_demonstrations_by_hand():
    twp = build(_toggle_spec())
    check_task(twp.task)
    assert twp.task.state_names == ("00", "01", "10", "11")  # reachable, in BFS order
    demos, types = twp.demonstrations(subjects=4, per_subject=2, noise=0.0, seed=0)
    assert types.tolist() == [0, 0, 1, 1, 0, 0, 1, 1]
    assert demos.subjects == ("s000",) * 2 + ("s001",) * 2 + ("s002",) * 2 + ("s003",) * 2
    assert demos.types == tuple(("quick", "slow")[t] for t in types.tolist())
    lists = demos.to_lists()
    # quick: the robot waits (its best action), the person flips; then the robot turns on
    assert lists[0] == [("robot", "wait"), ("human", "flip"), ("robot", "on")]
    # slow: the robot turns on, then the person flips
    assert lists[2] == [("robot", "on"), ("human", "flip")]
    steps = twp.task.read_steps(demos)
    assert steps.lengths.tolist() == [2, 2, 1, 1, 2, 2, 1, 1]


def test_demonstrations_are_deterministic_under_the_seed():
    twp = build(_toggle_spec())
    a, ya = twp.demonstrations(subjects=6, per_subject=3, noise=0.4, seed=5)
    b, yb = twp.demonstrations(subjects=6, per_subject=3, noise=0.4, seed=5)
    assert a == b and torch.equal(ya, yb)
    others = [twp.demonstrations(subjects=6, per_subject=3, noise=0.4, seed=s)[0]
              for s in range(6, 10)]  # fmt: skip
    assert any(o != a for o in others)


def test_task_with_people_validation():
    twp = build(_toggle_spec())
    # fewer subjects than types: a type would have no demonstrations
    with pytest.raises(ValueError, match=r"expected subjects >= 2 \(one per type"):
        twp.demonstrations(subjects=1, per_subject=2, seed=0)
    with pytest.raises(ModelError, match="true_reward"):
        TaskWithPeople(twp.task, twp.people, torch.zeros(2, 4, 3), 4, False)
    with pytest.raises(ModelError, match="horizon"):
        TaskWithPeople(twp.task, twp.people, twp.true_reward, 1, False)
    with pytest.raises(ModelError, match="true_observation"):
        TaskWithPeople(twp.task, twp.people, twp.true_reward, 4, True)
    with pytest.raises(ModelError, match="where it cannot happen"):
        build(_toggle_spec(behaviour=lambda y, m, s, a: {0: 1.0}))  # flips when already on


def test_shares_split_the_subjects_by_largest_remainders():
    """30 subjects at 35/25/20/12/8 %: floors 10, 7, 6, 3, 2 (remainders .5, .5, 0, .6, .4),
    one more each to the two largest remainders (.6: the 4th type; .5: the first of the tied
    two) until 30: 11, 7, 6, 4, 2, the subjects of one type in a row."""
    from torchhrc.tasks.people import _split

    assert _split(30, (0.35, 0.25, 0.20, 0.12, 0.08)) == [11, 7, 6, 4, 2]
    assert _split(30, (7, 2, 1)) == [21, 6, 3]  # any positive sum
    assert _split(4, (1, 0, 1)) == [2, 0, 2]  # a type of share 0 gets no subject
    assert _split(3, (0.9, 0.05, 0.05)) == [1, 1, 1]  # one each, then no more than asked
    twp = build(_toggle_spec())
    skew = TaskWithPeople(twp.task, twp.people, twp.true_reward, 4, False, shares=(3, 1))
    demos, types = skew.demonstrations(subjects=8, per_subject=2, noise=0.0, seed=0)
    assert types.tolist() == [0] * 12 + [1] * 4  # 6 subjects to 2, in a row
    assert demos.subjects[:2] == ("s000", "s000") and len(demos.unique_subjects) == 8
    # a type's demonstrations are its people's whatever the split: the same sequences as the
    # balanced split's for that type (the people are deterministic at noise 0)
    even, even_types = twp.demonstrations(subjects=8, per_subject=2, noise=0.0, seed=0)
    assert even_types.tolist()[:4] == [0, 0, 1, 1]  # balanced: s mod Y, as before
    lists, even_lists = demos.to_lists(), even.to_lists()
    assert lists[0] == even_lists[0] and lists[-1] == even_lists[2]
    assert skew.shares == (3.0, 1.0) and twp.shares is None
    with pytest.raises(ValueError, match=r"subjects >= 2"):
        skew.demonstrations(subjects=1)
    for bad, match in (
        ((1.0,), r"shares of shape \(Y=2,\)"),
        ((1.0, -1.0), "non-negative"),
        ((0.0, 0.0), "not all zero"),
        ((float("nan"), 1.0), "finite"),
        (("a", "b"), "shares to be a sequence of 2 numbers"),
    ):
        with pytest.raises(ModelError, match=match):
            TaskWithPeople(twp.task, twp.people, twp.true_reward, 4, False, shares=bad)


def test_initial_memory_is_drawn_per_type():
    policy = torch.zeros(2, 2, 3, 2, 3, dtype=torch.float64)
    policy[..., 2] = 1.0
    initial = torch.tensor([[1.0, 0.0], [0.25, 0.75]], dtype=torch.float64)
    people = TabularPeople(("a", "b"), policy, LEGAL, initial=initial)
    g = torch.Generator().manual_seed(4)
    types = torch.tensor([0] * 8000 + [1] * 8000)
    memory = people.initial_memory(types, g)
    assert memory.shape == (16000, 1) and (memory[:8000] == 0).all()
    assert abs(float(memory[8000:].double().mean()) - 0.75) < 0.02  # 4 sigma
