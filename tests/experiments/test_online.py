"""The online case of the place-and-drill study (torchhrc.experiments.online)."""

from __future__ import annotations

import warnings

import pytest
import torch
from _stated_rewards import stated_reward

from torchhrc.errors import ModelError
from torchhrc.experiments.online import (
    expert_online_momdp,
    human_chunk_size,
    learn_turn_taking,
    online_momdp,
    pooled_cross_training,
    turn_taking_transition,
)
from torchhrc.experiments.robustness import POLICY_NAMES, MOMDPPolicy, simulate_subject
from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.tasks.interface import behaviour_from_preferences, chain_preferences
from torchhrc.tasks.pipeline import build_model, transition_from_behaviour
from torchhrc.tasks.place_and_drill.demos import simulate_study
from torchhrc.tasks.place_and_drill.hand_coded import load_expert_model, parse_expert_model
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
from torchhrc.tasks.place_and_drill.simulate import (
    MOMDPController,
    demonstrated_orders,
    run_executions,
)

TASK = PlaceAndDrillTask(3)


class _Always:
    """A controller that always takes one action."""

    def __init__(self, action: int) -> None:
        self.action = action

    def act(self, x, uniform):
        return torch.full_like(x, self.action)

    def observe(self, x, action, x_next):
        return None


def test_efficient_human_waits_for_the_drill_safe_human_does_not():
    """A robot that only waits: the efficient human places one screw and then waits."""
    B = 4
    orders = torch.tensor([[0, 1, 2]]).expand(B, 3)
    eps = torch.zeros(B, dtype=torch.float64)
    score = load_expert_model().reward()[..., 0]
    g = torch.Generator().manual_seed(0)
    chunk = torch.tensor([1, 1, 3, 3])
    trace = run_executions(
        TASK,
        {"wait": _Always(0)},
        orders=orders,
        epsilon=eps,
        score=score,
        generator=g,
        human_chunk=chunk,
    )
    names = [TASK.state_names[x] for x in trace.states["wait"][-1].tolist()]
    assert names == ["PEE", "PEE", "PPP", "PPP"]
    # chunk = n (safe) is the paper's human that always places: the same runs as None
    g1, g2 = torch.Generator().manual_seed(1), torch.Generator().manual_seed(1)
    eps = torch.linspace(0, 1, B, dtype=torch.float64)
    a = run_executions(
        TASK,
        {"w": _Always(0)},
        orders=orders,
        epsilon=eps,
        score=score,
        generator=g1,
        human_chunk=torch.full((B,), 3),
    )
    b = run_executions(
        TASK, {"w": _Always(0)}, orders=orders, epsilon=eps, score=score, generator=g2
    )
    assert torch.equal(a.states["w"], b.states["w"])
    with pytest.raises(ModelError, match="human_chunk"):
        run_executions(
            TASK,
            {"w": _Always(0)},
            orders=orders,
            epsilon=eps,
            score=score,
            human_chunk=torch.zeros(B, dtype=torch.long),
        )


def test_turn_taking_counts_by_hand():
    """Two safe-like demonstrations, hand counted (Laplace pseudo-count 1)."""
    from torchhrc.data import Demonstrations

    h = lambda p: ("human", f"place_{p}")  # noqa: E731
    r = lambda a: ("robot", a)  # noqa: E731
    demos = Demonstrations.from_lists(
        [
            # EEE -wait-> PEE (c=0, placed); PEE -wait-> PPE (c=1, placed);
            # PPE -wait-> PPP (c=1, placed); then drills at a full bench (no turn)
            [
                h("A"),
                r("wait"),
                h("B"),
                r("wait"),
                h("C"),
                r("drill_A"),
                ("human", "wait"),
                r("drill_B"),
                ("human", "wait"),
                r("drill_C"),
            ],
            # EEE -wait-> PEE (c=0); PEE -wait-> PEE (c=1, the human waits);
            # PEE -drill_A-> DPE (c=0, placed); DPE -drill_B-> DDP; DDP -drill_C-> DDD
            [
                h("A"),
                r("wait"),
                ("human", "wait"),
                r("drill_A"),
                h("B"),
                r("drill_B"),
                h("C"),
                r("drill_C"),
            ],
        ]
    )
    q = learn_turn_taking(TASK, demos, torch.tensor([0, 1]), 2)
    # type 0: c=0 1 turn 0 passes -> 1/3; c=1 2 turns 0 passes -> 1/4
    # type 1: c=0 turns EEE, PEE(drill_A -> DEE), DPE(drill_B -> DDE) = 3, 0 passes -> 1/5;
    #         c=1 turn PEE(wait) 1, 1 pass -> 2/3
    torch.testing.assert_close(
        q, torch.tensor([[1 / 3, 1 / 4], [1 / 5, 2 / 3]], dtype=torch.float64)
    )
    with pytest.raises(ModelError, match="assignments"):
        learn_turn_taking(TASK, demos, torch.tensor([0, 2]), 2)


def test_turn_taking_transition_is_a_distribution_and_the_mixture():
    g = torch.Generator().manual_seed(0)
    placement = torch.rand(2, TASK.num_actions, 1, 3, generator=g, dtype=torch.float64)
    Tx = transition_from_behaviour(TASK, behaviour_from_preferences(TASK, placement, noise=0.1))
    wait = torch.tensor([[0.1, 0.2], [0.3, 0.9]], dtype=torch.float64)
    out = turn_taking_transition(TASK, Tx, wait)
    torch.testing.assert_close(out.sum(-1), torch.ones_like(out.sum(-1)))
    # wait at PEE (index 9): a screw waits; type 1 stays with 0.9 + 0.1 * 0 (Tx never stays)
    x = TASK.state_names.index("PEE")
    assert out[0, x, 1, x].item() == pytest.approx(0.9)
    torch.testing.assert_close(out[0, x, 1, :x], 0.1 * Tx[0, x, 1, :x])
    # drill_A at PEE -> DEE: nothing waits; type 0 stays with 0.1
    dee = TASK.state_names.index("DEE")
    assert out[1, x, 0, dee].item() == pytest.approx(0.1)
    # a full bench: nothing to place, unchanged
    full = TASK.state_names.index("PPP")
    torch.testing.assert_close(out[:, full], Tx[:, full])


def test_expert_online_model_reads_the_file():
    expert = load_expert_model()
    assert expert.waits_while_pending == (0.05, 0.95)
    model = expert_online_momdp(expert)
    x = TASK.state_names.index("PEE")
    assert model.Tx[0, x, 1, x].item() == pytest.approx(0.95)
    import json

    from torchhrc.tasks.place_and_drill.hand_coded import DEFAULT_EXPERT_PATH

    data = json.loads(DEFAULT_EXPERT_PATH.read_text())
    data["human"]["waits_while_pending"]["safe"] = 1.5
    with pytest.raises(ModelError, match=r"waits_while_pending\.safe"):
        parse_expert_model(data)
    del data["human"]["waits_while_pending"]
    with pytest.raises(ModelError, match="waits_while_pending"):
        expert_online_momdp(parse_expert_model(data))


def _solve(model):
    span = float(model.R.max() - model.R.min())
    config = SARSOPConfig(
        time_limit=2.0, precision=1e-3 * span, seed=0, lower_bound_init=type_policy_lower_bound
    )
    return sarsop(model, config)


@pytest.fixture(scope="module")
def online_setup():
    """A learned model from 14 labelled training subjects; 4 held out (2 safe, 2 efficient)."""
    demos = simulate_study(n_subjects=18, n_demos=3, seed=0)
    labels = dict(zip(demos.subjects, demos.types))
    held = ["S01", "S02", "S03", "S10"]
    assert [labels[s] for s in held] == ["safe", "safe", "efficient", "efficient"]
    train = demos.select_subjects(held, exclude=True)
    assignments = torch.tensor([t == "efficient" for t in train.types]).long()
    counts = torch.stack(
        [train.subset(assignments == k).transition_counts() + 0.1 for k in range(2)]
    )
    chains = counts / counts.sum(-1, keepdim=True)
    learned = build_model(TASK, train, chains, assignments, irl_iterations=10)
    assert learned.type_names == ("safe", "efficient")
    placement = chain_preferences(chains, train.vocabulary, TASK.robot_actions,
                                  TASK.human_actions)  # fmt: skip
    wait = learn_turn_taking(TASK, train, assignments, 2)
    expert = load_expert_model()
    return {
        "demos": demos,
        "train": train,
        "labels": labels,
        "held": held,
        "learned": learned,
        "placement": placement,
        "wait": wait,
        "expert": expert,
        "orders": demonstrated_orders(TASK, demos),
    }


def _online_rewards(setup, policies, *, runs=40, epsilons=(0.0, 0.3)):
    """``{name: (E, S)}`` mean online reward of each held-out subject."""
    expert = setup["expert"]
    score = expert.reward()
    out: dict[str, list[torch.Tensor]] = {}
    for subject in setup["held"]:
        label = setup["labels"][subject]
        result = simulate_subject(
            TASK,
            momdp_policies=policies,
            cross_training=pooled_cross_training(TASK, setup["train"]),
            subject_index=0,
            orders=setup["orders"][subject],
            score=score[..., expert.type_names.index(label)],
            epsilons=epsilons,
            runs=runs,
            generator=torch.Generator().manual_seed(0),
            human_chunk=human_chunk_size(TASK, label),
        )
        for name, r in result.items():
            out.setdefault(name, []).append(r.mean(-1))
    return {name: torch.stack(v, -1) for name, v in out.items()}


def test_turn_taking_learned_where_the_data_show_it(online_setup):
    q = online_setup["wait"]
    # a safe person places while a screw waits (the data show it: small); no efficient
    # demonstration leaves a screw waiting, so that cell stays at the prior's 1/2
    assert q[0, 1] < 0.2
    assert q[1, 1] == pytest.approx(0.5)
    assert (q[:, 0] < 0.2).all()


def test_online_is_below_the_ceiling_and_a_degraded_model_scores_lower(online_setup):
    """The online comparison can fail: swapped rewards or swapped turn taking lose reward.

    Margin: measured (seed 0, 40 runs) learned 26.4 / 24.6 at epsilon 0 / 0.3, swapped
    rewards -6.2 / 10.2, swapped turn taking -12.5 / 8.5: a loss of 14+ reward units per
    run; the test asks for 5.
    """
    learned, wait = online_setup["learned"], online_setup["wait"]
    R, placement = learned.momdp.R, online_setup["placement"]
    models = {
        "learned": online_momdp(TASK, placement, R, wait),
        "swapped_rewards": online_momdp(TASK, placement, R.flip(-1), wait),
        "swapped_turns": online_momdp(TASK, placement, R, wait.flip(0)),
        "hand_coded": expert_online_momdp(online_setup["expert"]),
    }
    policies = {n: MOMDPPolicy(m, _solve(m).policy, m.b0) for n, m in models.items()}
    rewards = _online_rewards(online_setup, policies)  # {name: (E, S)}
    mean = {name: r.mean(-1) for name, r in rewards.items()}  # (E,)
    for name in ("learned", "hand_coded"):
        # not at the ceiling: the efficient subjects pay for the robot's first wait
        assert (mean[name] < 30.0 - 1.0).all(), (name, mean[name])
        assert (mean[name] > 15.0).all(), (name, mean[name])
    for bad in ("swapped_rewards", "swapped_turns"):
        assert (mean[bad] < mean["learned"] - 5.0).all(), (bad, mean[bad], mean["learned"])


def test_online_belief_moves_toward_the_true_type(online_setup):
    """A robot that waits at PEE: the learned filter's belief goes to the human's true type."""
    learned, wait = online_setup["learned"], online_setup["wait"]
    model = online_momdp(TASK, online_setup["placement"], learned.momdp.R, wait)
    pee = TASK.state_names.index("PEE")
    ppe = TASK.state_names.index("PPE")
    b = model.b0.expand(2, -1).clone()
    controller = MOMDPController(model, policy=None, belief=b)  # type: ignore[arg-type]
    x = torch.tensor([pee, pee])
    controller.observe(x, torch.zeros(2, dtype=torch.long), torch.tensor([pee, ppe]))
    efficient, safe = controller.belief[0], controller.belief[1]
    assert efficient[1] > 0.85 and safe[0] > 0.6


# --------------------------------------------------------------------------------------------
# The online Fig. 3 against a second, plain-Python computation (issue 30, goal 5)


def _human_moves(bench: str, order: tuple[int, ...], epsilon: float, label: str):
    """``[(probability, bench after)]``: the stated online human after the robot's move.

    With probability epsilon a uniformly random empty position; otherwise its turn taking:
    an efficient person waits while a placed screw is not drilled yet, a safe person places
    every screw first, in its demonstrated order.
    """
    empty = [p for p, c in enumerate(bench) if c == "E"]
    if not empty:
        return [(1.0, bench)]
    place = lambda p: bench[:p] + "P" + bench[p + 1 :]  # noqa: E731
    out: dict[str, float] = {}
    if label == "efficient" and "P" in bench:
        own = bench
    else:
        own = place(next(p for p in order if bench[p] == "E"))
    out[own] = out.get(own, 0.0) + 1.0 - epsilon
    for p in empty:
        out[place(p)] = out.get(place(p), 0.0) + epsilon / len(empty)
    return [(w, b) for b, w in out.items() if w > 0]


class _PlainMOMDPRobot:
    """The solved MOMDP policy and its type filter, in plain Python lists."""

    def __init__(self, policy: MOMDPPolicy) -> None:
        alpha = policy.policy
        self.vectors = [
            (int(x), int(a), [float(v) for v in row])
            for x, a, row in zip(alpha.observed.tolist(), alpha.actions.tolist(), alpha.alphas)
        ]
        self.Tx = policy.model.Tx.tolist()  # [a][x][y][x2]
        self.b0 = tuple(float(v) for v in policy.b0)

    def start(self):
        return self.b0

    def choices(self, x: int, belief):
        best = max(
            (sum(p * v for p, v in zip(belief, row)), a) for x_, a, row in self.vectors if x_ == x
        )
        return [(1.0, best[1])]

    def update(self, belief, x: int, a: int, x2: int):
        post = [b * self.Tx[a][x][y][x2] for y, b in enumerate(belief)]
        total = sum(post)
        assert total > 0, "an impossible move under the robot's model"
        return tuple(p / total for p in post)


class _PlainCrossTraining:
    """Cross-training: uniform among the tied best actions of its MDP; no belief."""

    def __init__(self, policy) -> None:
        self.best = policy.best[0].tolist()  # [x][a] the pooled subject's tied best actions

    def start(self):
        return ()

    def choices(self, x: int, belief):
        tied = [a for a, ok in enumerate(self.best[x]) if ok]
        return [(1.0 / len(tied), a) for a in tied]

    def update(self, belief, x, a, x2):
        return ()


def _exact_moments(robot, names, order, epsilon, label, horizon):
    """``(E[G], E[G^2])`` of the run's score G, by enumerating every run (no sampling)."""
    index = {name: i for i, name in enumerate(names)}
    memo: dict = {}

    def visit(t: int, bench: str, belief) -> tuple[float, float]:
        if t == horizon:
            return 0.0, 0.0
        key = (t, bench, belief)
        if key in memo:
            return memo[key]
        m1 = m2 = 0.0
        x = index[bench]
        for pa, a in robot.choices(x, belief):
            r = stated_reward(bench, a, label)
            after = bench if a == 0 or bench[a - 1] != "P" else (
                bench[: a - 1] + "D" + bench[a:])  # fmt: skip
            for ph, bench2 in _human_moves(after, order, epsilon, label):
                f1, f2 = visit(t + 1, bench2, robot.update(belief, x, a, index[bench2]))
                w = pa * ph
                m1 += w * (r + f1)
                m2 += w * (r * r + 2 * r * f1 + f2)
        memo[key] = (m1, m2)
        return m1, m2

    return visit(0, "E" * len(order), robot.start())


@pytest.fixture(scope="module")
def online_study():
    """A small study (4 subjects, 50 runs) and the policies its online folds ran."""
    import torchhrc.experiments.place_and_drill as pd

    calls = []
    real = pd.simulate_subject

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    settings = pd.StudySettings(subjects=4, runs=50, epsilons=(0.0, 0.5, 1.0), k_max=3,
                                restarts=2, irl_iterations=3, separation=False)  # fmt: skip
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with pytest.MonkeyPatch.context() as mp, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # IRL stops at 3 iterations: it says so
            mp.setattr(pd, "simulate_subject", spy)
            study = pd.run_study(settings)
    finally:
        torch.set_num_threads(threads)
    assert len(calls) == 2 * settings.subjects  # per fold: the offline run, then the online
    return study, calls[1::2], pd.metrics_from_study(study)


def test_online_curves_match_an_independent_simulation(online_study):
    """Every online curve (learned, hand-coded, cross-training) of ``run_study`` against the
    exact expected score of each subject, enumerated in plain Python from the stated human
    (turn taking, epsilon deviations), the stated rewards and the policies the folds solved.

    Bug this catches (issue 30): the online human's turn taking removed from the
    place-and-drill online fold (``human_chunk`` not passed in ``_online_fold``): the learned
    and hand-coded curves went flat at 25.0 and cross-training at epsilon 0 moved from -20.4
    to +17.1, and every reward test passed.
    """
    study, calls, metrics = online_study
    online = study["online"]
    labels = dict(zip(study["demonstrations"].subjects, study["demonstrations"].types))
    names = study["task"].state_names
    R = online.runs_per_subject
    E, S = len(online.epsilon), len(online.subjects)
    exact = {}  # name -> (E, S, 2)
    for s, (subject, call) in enumerate(zip(online.subjects, calls)):
        label = labels[subject]
        robots = {n: _PlainMOMDPRobot(p) for n, p in call["momdp_policies"].items()}
        robots["cross_training"] = _PlainCrossTraining(call["cross_training"])
        orders = [tuple(o) for o in call["orders"].tolist()]
        for name, robot in robots.items():
            for e, eps in enumerate(online.epsilon):
                moments = [_exact_moments(robot, names, o, eps, label, 12) for o in orders]
                m1 = sum(m[0] for m in moments) / len(orders)  # the run's order: uniform
                m2 = sum(m[1] for m in moments) / len(orders)
                table = exact.setdefault(name, torch.zeros(E, S, 2, dtype=torch.float64))
                table[e, s] = torch.tensor([m1, m2], dtype=torch.float64)
    for name in POLICY_NAMES:
        mu, m2 = exact[name][..., 0].double(), exact[name][..., 1].double()
        var = (m2 - mu**2).clamp_min(0.0)
        # each subject's mean of R runs: within 4.5 standard errors of its exact expectation
        got = online.subject_means(name)
        bound = 4.5 * (var / R).sqrt() + 1e-6
        assert ((got - mu).abs() <= bound).all(), (name, got, mu, bound)
        # the reported curve is the mean over subjects and runs
        pooled_mu = mu.mean(-1)
        pooled_var = m2.mean(-1) - pooled_mu**2
        N = R * len(online.subjects)
        assert metrics["reward_online"][name] == pytest.approx(
            online.rewards[name].flatten(1).mean(-1).tolist(), abs=1e-5)  # fmt: skip
        ci_exact = 1.959964 * pooled_var.clamp_min(0).sqrt() / N**0.5
        got_ci = torch.tensor(metrics["reward_online_ci95"][name], dtype=torch.float64)
        assert ((got_ci - ci_exact).abs() <= 0.35 * ci_exact + 0.02).all(), (name, got_ci)


def test_online_confidence_intervals_by_formula(online_study):
    """``reward_online_ci95`` is 1.96 sd / sqrt(S R) over every run of an epsilon and
    ``reward_online_ci95_subjects`` the Student-t half-width over the S subject means,
    recomputed here from the raw runs with the standard library and scipy."""
    import statistics

    from scipy import stats

    study, _, metrics = online_study
    online = study["online"]
    S = len(online.subjects)
    for name in POLICY_NAMES:
        runs = online.rewards[name]  # (E, S, R)
        for e in range(runs.shape[0]):
            flat = runs[e].flatten().tolist()
            half = 1.959963984540054 * statistics.stdev(flat) / len(flat) ** 0.5
            assert metrics["reward_online"][name][e] == pytest.approx(
                statistics.fmean(flat), abs=1e-5)  # fmt: skip
            assert metrics["reward_online_ci95"][name][e] == pytest.approx(half, abs=1e-5)
            means = runs[e].mean(-1).tolist()
            t = stats.t.ppf(0.975, S - 1) * statistics.stdev(means) / S**0.5
            assert metrics["reward_online_ci95_subjects"][name][e] == pytest.approx(
                t, abs=1e-4)  # fmt: skip
