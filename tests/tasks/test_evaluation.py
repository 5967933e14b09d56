"""evaluate_task: robots against simulated people under their true rewards.

The hand-built task (tests/_sides.py): the person first walks to side "a" (type "left") or "b"
(type "right"), then to the middle; there the robot hands over left or right (+1 for the type
that wants it, -1 for the other) and the task ends. In the middle the state no longer shows the
type: only a robot that kept a belief hands over the right side. Values worked by hand (discount g,
people's noise eps, a random legal action at the start with probability eps, the wrong one
half of the time): the type-aware robot gets ``g^2 (1 - eps)`` from either type; a robot that
always hands left gets ``+g^2`` from "left" and ``-g^2`` from "right".
"""

from __future__ import annotations

import dataclasses
import math
import random
import warnings

import pytest
import torch
from _sides import G, learned
from _sides import by_hand as _by_hand
from _sides import world as _world

import torchhrc
from torchhrc.tasks.evaluation import evaluate_task


@pytest.fixture(scope="module")
def fitted():
    return learned()


class AlwaysLeft:
    """A robot that hands over left whatever happens (waits elsewhere)."""

    def reset(self, prior=None, *, batch=None):
        self.batch = batch

    def act(self, x):
        return torch.where(x == 3, 1, 0)


def _reference(world, robot_hand, types, eps, episodes, seed):
    """Plain-Python episodes, one at a time: ``robot_hand(y_belief) -> hand`` at the middle,
    where ``y_belief`` is the side the person walked to (what a perfect filter knows)."""
    rng = random.Random(seed)
    out = []
    for y in types:
        for _ in range(episodes):
            side = y if rng.random() >= eps else rng.randrange(2)  # slip: a random legal move
            hand = robot_hand(side)  # 0: left, 1: right
            out.append(G**2 * (1.0 if hand == y else -1.0))
    return out


def test_type_aware_beats_agnostic_and_matches_hand_values(fitted):
    world, demos, aware, agnostic = fitted
    eps, E = 0.2, 400
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic,
                           robots={"left": AlwaysLeft()}, episodes=E, noise=eps,
                           belief_steps=(0, 1, 3), seed=1)  # fmt: skip
    assert result.robots == ("type-aware", "type-agnostic", "left")
    assert result.returns.shape == (3, 2, E)
    i = result.index("type-aware")
    want = G**2 * (1 - eps)
    se = result.ci / 1.96
    assert torch.all((result.mean[i] - want).abs() < 4 * se[i] + 1e-9), result.table()
    # the fixed robot: +g^2 from "left", -g^2 from "right", exactly (no randomness matters)
    torch.testing.assert_close(result.mean[2], torch.tensor([G**2, -(G**2)], dtype=torch.float64))
    torch.testing.assert_close(result.ci[2], torch.zeros(2, dtype=torch.float64))
    # the agnostic robot cannot tell the types apart in the middle: it hands one side to
    # everyone (+g^2 for one type, -g^2 for the other) or waits for ever (0)
    j = result.index("type-agnostic")
    hand = [(G**2, -(G**2)), (-(G**2), G**2), (0.0, 0.0)]
    assert any(torch.allclose(result.mean[j], torch.tensor(h, dtype=torch.float64)) for h in hand)
    assert int(result.compare("type-aware", "type-agnostic", overall=True)) == 1, result.table()
    assert (result.compare("type-aware", "type-agnostic") > 0).any()
    # the population: (g^2 (1 - eps)) for the aware robot against 0 for always-left
    torch.testing.assert_close(result.overall_mean[2], torch.zeros((), dtype=torch.float64))
    assert abs(float(result.overall_mean[i]) - want) < 4 * float(result.overall_ci[i]) / 1.96
    # an independent plain-Python simulation of a perfect filter agrees within the CIs
    ref = torch.tensor(_reference(world, lambda side: side, (0, 1), eps, E, seed=3))
    ref = ref.view(2, E).mean(-1)
    assert torch.all((result.mean[i] - ref).abs() < 4 * math.sqrt(2) * se[i] + 1e-9)
    # CI half-width = 1.96 s / sqrt(E), recomputed from the returns
    s = result.returns[i].std(-1)
    torch.testing.assert_close(result.ci[i], 1.959963984540054 * s / math.sqrt(E))


def test_belief_accuracy_and_split(fitted):
    world, demos, aware, _ = fitted
    eps = 0.2
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=False, episodes=400,
                           noise=eps, belief_steps=(0, 1), seed=2)  # fmt: skip
    assert result.map_source == "assignments"
    assert sorted(result.type_map.tolist()) == [0, 1]  # the two true types on two learned ones
    # before any step the belief is the prior b0 (learn(): the types' shares of the
    # demonstrations): its largest entry, credited to the type it names (half each on a tie)
    b0 = aware.momdp.b0
    top = b0 >= b0.max() - 1e-12
    want = top[result.type_map].double() / top.sum()
    torch.testing.assert_close(result.belief_accuracy[:, 0], want)
    torch.testing.assert_close(result.belief_max[:, 0], b0.max().expand(2))
    torch.testing.assert_close(b0.sum(), torch.ones((), dtype=b0.dtype))
    assert aware.info["prior"]["rule"] == "shares"
    counts = torch.bincount(aware.assignments, minlength=2).double()
    torch.testing.assert_close(b0, counts / counts.sum())
    # after one step the first move tells the type, except on a slip to the other side
    # (probability eps / 2): accuracy 0.9 within sampling error
    acc = result.belief_accuracy[:, 1]
    assert torch.all((acc - (1 - eps / 2)).abs() < 4 * math.sqrt(0.9 * 0.1 / 400)), acc
    assert result.belief_status == ("identified", "identified")
    at0 = evaluate_task(world, aware, demonstrations=demos, agnostic=False, episodes=10,
                        belief_steps=0, seed=2)  # fmt: skip
    assert at0.belief_status == ("split", "split")
    # without true labels the map comes from the belief's posterior mass: the same map
    unlabelled = evaluate_task(world, aware, agnostic=False, episodes=50, belief_steps=3, seed=2)
    assert unlabelled.map_source == "posterior"
    assert torch.equal(unlabelled.type_map, result.type_map)
    assert "identified" in result.table()


def test_told_the_type_gets_the_right_hand_every_time(fitted):
    world, demos, aware, _ = fitted
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=False, episodes=50,
                           noise=0.2, told_type=True, seed=4)  # fmt: skip
    assert result.robots == ("type-aware", "told the type")
    # its belief sits on the person's type whatever their first move: +g^2 for both types
    torch.testing.assert_close(result.mean[1], torch.full((2,), G**2, dtype=torch.float64))
    assert bool((result.mean[0] < result.mean[1]).all())  # slips mislead the filter only


def test_seeded_and_validated(fitted):
    world, _, aware, agnostic = fitted
    a = evaluate_task(world, aware, agnostic=agnostic, episodes=20, seed=5)
    b = evaluate_task(world, aware, agnostic=agnostic, episodes=20, seed=5)
    assert torch.equal(a.returns, b.returns)
    with pytest.raises(ValueError, match="episodes"):
        evaluate_task(world, aware, agnostic=False, episodes=1)
    with pytest.raises(ValueError, match="noise"):
        evaluate_task(world, aware, agnostic=False, noise=2.0)
    with pytest.raises(ValueError, match="nothing to evaluate"):
        evaluate_task(world, None)
    # a robot without reset/act is named at once (it was "'object' object has no attribute")
    with pytest.raises(TypeError, match=r"robots\['lazy'\] \(object\) has no reset\(\) or act\(\)"):
        evaluate_task(world, None, robots={"lazy": object()})


def test_population_shares_weigh_the_overall_figures(fitted):
    """A population of 3 "left" people to 1 "right": the always-left robot's return is
    ``+g^2`` or ``-g^2`` exactly, so its population mean is ``(3 g^2 - g^2) / 4 = g^2 / 2`` and
    the spread about it, worked by hand, ``3/4 (g^2/2)^2 + 1/4 (3 g^2/2)^2 = 3/4 g^4``; with
    equal shares the plain mean (0) and standard error of all ``N`` returns."""
    world, _, _, _ = fitted
    E = 50
    N = 2 * E
    even = evaluate_task(world, None, robots={"left": AlwaysLeft()}, episodes=E, seed=2)
    skew = evaluate_task(world, None, robots={"left": AlwaysLeft()}, episodes=E, seed=2,
                         shares=[3.0, 1.0])  # fmt: skip
    g2 = G**2
    torch.testing.assert_close(skew.mean, even.mean)  # per type: the shares change nothing
    torch.testing.assert_close(skew.overall_mean, torch.tensor([g2 / 2], dtype=torch.float64))
    want = 1.959963984540054 * math.sqrt(0.75 * g2**2 / (N - 1))
    torch.testing.assert_close(skew.overall_ci, torch.tensor([want], dtype=torch.float64))
    torch.testing.assert_close(skew.shares, torch.tensor([0.75, 0.25], dtype=torch.float64))
    assert skew.to_dict()["shares"] == [0.75, 0.25]
    # equal shares, given or not: the mean and standard error of all N returns
    pooled = even.returns.view(1, -1)
    torch.testing.assert_close(even.overall_mean, pooled.mean(-1))
    torch.testing.assert_close(even.overall_ci, 1.959963984540054 * pooled.std(-1) / math.sqrt(N))
    assert even.shares is None
    given = evaluate_task(world, None, robots={"left": AlwaysLeft()}, episodes=E, seed=2,
                          shares=torch.tensor([2.0, 2.0]))  # fmt: skip
    torch.testing.assert_close(given.overall_mean, even.overall_mean)
    torch.testing.assert_close(given.overall_ci, even.overall_ci)
    # a world that declares its population is weighed by it unless told otherwise
    own = evaluate_task(dataclasses.replace(world, shares=(3.0, 1.0)), None,
                        robots={"left": AlwaysLeft()}, episodes=E, seed=2)  # fmt: skip
    torch.testing.assert_close(own.overall_mean, skew.overall_mean)
    torch.testing.assert_close(own.overall_ci, skew.overall_ci)
    robots = {"left": AlwaysLeft()}
    with pytest.raises(ValueError, match=r"shares of shape \(Y=2,\)"):
        evaluate_task(world, None, robots=robots, episodes=5, shares=[1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="shares to be finite, non-negative"):
        evaluate_task(world, None, robots=robots, episodes=5, shares=[1.0, -0.5])
    with pytest.raises(ValueError, match="not all zero"):
        evaluate_task(world, None, robots=robots, episodes=5, shares=[0.0, 0.0])
    with pytest.raises(TypeError, match="shares to be a sequence of 2 numbers"):
        evaluate_task(world, None, robots=robots, episodes=5, shares=["a", "b"])


def test_summary_says_how_much_of_knowing_the_type_the_robot_keeps(fitted):
    world, demos, aware, agnostic = fitted
    eps = 0.2
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic, episodes=200,
                           noise=eps, told_type=True, seed=6)  # fmt: skip
    lines = result.summary().splitlines()
    assert lines[0].startswith("type-aware ") and "ahead by" in lines[0]
    assert lines[1].startswith("knowing the type pays: told the type 0.81")
    # by hand: told g^2, type-aware g^2 (1 - eps) (a slip to the other side misleads it),
    # the pooled robot 0 over the population (one hand for everyone, or none): it keeps
    # 1 - eps = 80% of the gain, within sampling error (4 standard errors, about 12 points)
    kept = int(lines[1].rsplit("keeps ", 1)[1].split("%")[0])
    assert abs(kept - 100 * (1 - eps)) <= 12, lines[1]
    assert len(lines) == 2  # every true type identified: no third line


def test_summary_when_knowing_the_type_does_not_pay():
    # both types want the left hand: a robot told the type can do no better than the pooled
    # one, and the summary says that level is the expected result
    world = _world()
    world.true_reward[2, 3] = torch.tensor([-1.0, -1.0], dtype=torch.float64)
    world.true_reward[1, 3] = torch.tensor([1.0, 1.0], dtype=torch.float64)
    demos, _ = world.demonstrations(subjects=12, per_subject=3, noise=0.05, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        aware = torchhrc.learn(world.task, demos, k=2, solver_time=1.0, seed=0)
        agnostic = torchhrc.learn(world.task, demos, k=1, solver_time=1.0, seed=0)
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic, episodes=100,
                           told_type=True, seed=7)  # fmt: skip
    lines = result.summary().splitlines()
    assert "level: " in lines[0], result.table()
    assert lines[1].startswith("knowing the type does not pay: told the type"), lines[1]
    assert "level with type-agnostic" in lines[1]


def test_summary_branches_worked_by_hand():
    # behind: the paired difference -0.5 +- 0.1 per episode, whose 95% half-width over the
    # two types is 1.96 * 0.1 / sqrt(2) = 0.139; told (-0.3) behind the pooled robot too
    lines = _by_hand([1.0, 1.5, 1.2], ("merged", "wrong")).summary().splitlines()
    assert lines[0] == ("type-aware 1.00 ± 0.10 against type-agnostic 1.50 ± 0.10: behind by "
                        "0.50 ± 0.14 (the paired difference, 95%)")  # fmt: skip
    assert lines[1].startswith("knowing the type does not pay: told the type 1.20 ± 0.10, "
                               "behind type-agnostic")  # fmt: skip
    assert lines[2] == ("not identified after 3 steps: a (merged: the learning joined it with "
                        "another type), b (wrong: the belief settles on another type)")  # fmt: skip
    # a difference within its half-width is level (0.13 < 0.139; 0.15 is not)
    assert ": level: -0.13 ± 0.14" in _by_hand([1.0, 1.13, 3.0]).summary().splitlines()[0]
    assert ": behind by 0.15 ± 0.14" in _by_hand([1.0, 1.15, 3.0]).summary().splitlines()[0]
    # the gain kept: (1.5 - 1.0) / (3.0 - 1.0) = 25%
    assert _by_hand([1.5, 1.0, 3.0]).summary().splitlines()[1].endswith("keeps 25% of that gain")
    # without a told robot, one line; another pair of robots is compared as asked
    two = _by_hand([1.0, 2.0], robots=("type-aware", "type-agnostic"))
    assert two.summary().count("\n") == 0
    assert _by_hand([1.0, 2.0, 3.0]).summary("told the type").startswith("told the type 3.00")
    with pytest.raises(ValueError, match="expected robot in"):
        two.summary("oracle")
    # evaluated without demonstrations or a pooled robot: the type-aware robot alone, said so
    alone = _by_hand([1.0], ("split", "identified"), robots=("type-aware",)).summary()
    assert alone.splitlines() == [
        "type-aware 1.00 ± 0.10; no type-agnostic robot to compare with (evaluate_task learns "
        "one from demonstrations=, or takes agnostic=)",
        "not identified after 3 steps: a (split: its actions do not tell it apart yet)",
    ]


def test_the_told_robot_acts_optimally_for_the_type_it_is_told():
    """``told_type_controller``: at every state and for every learned type, its first action
    from a one-hot belief is optimal in that type's MDP, by value iteration written here
    (a plain loop over the learned model's tensors), even where the model's own policy, from
    a solve of one iteration started from the blind lower bound, is not."""
    from torchhrc.solvers import blind_policy
    from torchhrc.solvers.sarsop import SARSOPConfig
    from torchhrc.tasks.evaluation import told_type_controller
    from torchhrc.tasks.suite import make_task

    world = make_task("fetch_order")
    demos, _ = world.demonstrations(subjects=12, per_subject=2, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = torchhrc.learn(world.task, demos, k=3, seed=0,
                               solver=SARSOPConfig(time_limit=5.0, max_iterations=1,
                                                   lower_bound_init=blind_policy))  # fmt: skip
    m = model.momdp
    Tx, R, g = m.Tx.double(), m.R.double(), float(m.discount)  # (A, X, Y, X), (A, X, Y)
    A, X, Y = R.shape
    V = torch.zeros(Y, X, dtype=torch.float64)
    for _ in range(2000):
        Q = torch.stack(
            [R[a].T + g * torch.stack([Tx[a, :, y] @ V[y] for y in range(Y)]) for a in range(A)], -1
        )  # (Y, X, A)
        new = Q.max(-1).values
        if float((new - V).abs().max()) < 1e-10:
            break
        V = new
    told, plain = told_type_controller(model), torchhrc.Controller.from_model(model)
    worse = 0
    for y in range(Y):
        prior = torch.nn.functional.one_hot(torch.tensor(y), Y).double()
        for x in range(X):
            if bool(world.task.terminal[x]):
                continue
            told.reset(prior)
            a = int(told.act(x))
            assert float(Q[y, x, a]) >= float(Q[y, x].max()) - 1e-6, (y, x, a)
            plain.reset(prior)
            worse += int(float(Q[y, x, int(plain.act(x))]) < float(Q[y, x].max()) - 1e-6)
    assert worse > 0  # the one-iteration policy is not optimal at every corner: a real check


def _two_robots(returns, shares=None):
    """A TaskEvaluation of two robots "a", "b" from their returns ``(2, Y, E)``."""
    returns = torch.as_tensor(returns, dtype=torch.float64)
    _, Y, E = returns.shape
    sd = returns.std(-1, correction=1)
    return torchhrc.tasks.evaluation.TaskEvaluation(
        robots=("a", "b"), type_names=tuple(f"t{y}" for y in range(Y)), returns=returns,
        mean=returns.mean(-1), ci=1.96 * sd / math.sqrt(E),
        overall_mean=returns.mean((-1, -2)),
        overall_ci=1.96 * returns.view(2, -1).std(-1) / math.sqrt(Y * E),
        steps=torch.zeros(2, Y), belief_steps=(), type_map=torch.arange(Y),
        map_source="assignments", belief_accuracy=torch.zeros(Y, 0), belief_max=torch.zeros(Y, 0),
        belief_status=(), split_threshold=0.8, episodes=E, noise=0.0, seed=0, discount=0.9,
        horizon=5, shares=None if shares is None else torch.tensor(shares, dtype=torch.float64),
    )  # fmt: skip


def test_the_paired_difference_worked_by_hand():
    # a - b per episode: type 0 [0.1, 0.3, 0.1, 0.3] (mean 0.2, variance 0.04 / 3), type 1
    # [-1] * 4 (variance 0); shares 3/4, 1/4: overall mean 0.75 * 0.2 - 0.25 = -0.1, and
    # half-width 1.96 sqrt(0.75^2 * 0.04 / 3 / 4) = 0.0849; per type 1.96 sqrt(0.04 / 12)
    b = torch.tensor([[2.0, 5.0, -1.0, 0.5], [1.0, 1.0, 3.0, 3.0]], dtype=torch.float64)
    d = torch.tensor([[0.1, 0.3, 0.1, 0.3], [-1.0, -1.0, -1.0, -1.0]], dtype=torch.float64)
    result = _two_robots(torch.stack([b + d, b]), shares=[0.75, 0.25])
    mean, half = result.difference("a", "b", overall=True)
    assert abs(float(mean) + 0.1) < 1e-12
    assert abs(float(half) - 1.959963984540054 * math.sqrt(0.5625 * 0.04 / 12)) < 1e-12
    assert int(result.compare("a", "b", overall=True)) == -1
    per_mean, per_half = result.difference("a", "b")
    torch.testing.assert_close(per_mean, torch.tensor([0.2, -1.0], dtype=torch.float64))
    assert abs(float(per_half[0]) - 1.959963984540054 * math.sqrt(0.04 / 12)) < 1e-12
    assert result.compare("a", "b").tolist() == [1, -1]
    # the other way round: the same interval, the opposite sign
    back, back_half = result.difference("b", "a", overall=True)
    assert float(back) == -float(mean) and float(back_half) == float(half)


def test_pairing_removes_the_noise_the_robots_share():
    # the people's draws move both robots' returns together (+-5); "a" gains 0.1 in every
    # episode: the robots' own intervals overlap widely, their paired difference does not
    noise = 5.0 * torch.tensor([1.0, -1.0] * 10, dtype=torch.float64).view(1, 20)
    result = _two_robots(torch.stack([noise + 1.1, noise + 1.0]))
    m, c = result.overall_mean, result.overall_ci
    assert float(m[0] - c[0]) < float(m[1] + c[1])  # overlapping intervals: no verdict there
    assert int(result.compare("a", "b", overall=True)) == 1
    mean, half = result.difference("a", "b", overall=True)
    assert abs(float(mean) - 0.1) < 1e-12 and float(half) < 1e-6


def test_returns_equal_but_for_the_last_bits_are_level():
    # deterministic episodes (no variance): a difference of round-off is no difference, a
    # difference of 1e-6 is one
    base = torch.full((2, 3), 3.215, dtype=torch.float64)
    assert int(_two_robots(torch.stack([base + 1e-13, base])).compare("a", "b", overall=True)) == 0
    assert int(_two_robots(torch.stack([base - 1e-6, base])).compare("a", "b", overall=True)) == -1


def test_the_difference_on_an_evaluation(fitted):
    # every robot against itself is level; the difference is antisymmetric and its
    # half-width symmetric; a robot that serves one type beats the type-aware one there only
    world, demos, aware, agnostic = fitted
    result = evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic, episodes=60,
                           robots={"always left": AlwaysLeft()}, seed=3)  # fmt: skip
    for name in result.robots:
        assert int(result.compare(name, name, overall=True)) == 0
        assert (result.compare(name, name) == 0).all()
    m1, h1 = result.difference("type-aware", "always left")
    m2, h2 = result.difference("always left", "type-aware")
    torch.testing.assert_close(m1, -m2)
    torch.testing.assert_close(h1, h2)
    # by hand: the type-aware robot g^2 (1 - eps) from both types, "always left" +g^2 from
    # "left", -g^2 from "right": level or behind on "left", ahead on "right" and overall
    per = result.compare("type-aware", "always left")
    assert int(per[1]) == 1 and int(per[0]) <= 0, result.table()
    assert int(result.compare("type-aware", "always left", overall=True)) == 1
