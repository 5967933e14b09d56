"""The online case of the place-and-drill study (torchhrc.experiments.online)."""

from __future__ import annotations

import pytest
import torch

from torchhrc.baselines.hand_coded import load_expert_model, parse_expert_model
from torchhrc.errors import ModelError
from torchhrc.experiments.online import (
    expert_online_momdp,
    human_chunk_size,
    learn_turn_taking,
    online_momdp,
    pooled_cross_training,
    turn_taking_transition,
)
from torchhrc.experiments.robustness import MOMDPPolicy, simulate_subject
from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.tasks.place_and_drill.demos import simulate_study
from torchhrc.tasks.place_and_drill.model import (
    PlaceAndDrillTask,
    build_learned_model,
    placement_transition,
)
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
    placement = torch.rand(2, TASK.num_actions, 3, generator=g, dtype=torch.float64)
    Tx = placement_transition(TASK, placement, noise=0.1)
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

    from torchhrc.baselines.hand_coded import DEFAULT_EXPERT_PATH

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
    learned = build_learned_model(TASK, chains, train, assignments, irl_iterations=10)
    assert learned.type_names == ("safe", "efficient")
    wait = learn_turn_taking(TASK, train, assignments, 2)
    expert = load_expert_model()
    return {
        "demos": demos,
        "train": train,
        "labels": labels,
        "held": held,
        "learned": learned,
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
    R = learned.momdp.R
    models = {
        "learned": online_momdp(TASK, learned.placement, R, wait),
        "swapped_rewards": online_momdp(TASK, learned.placement, R.flip(-1), wait),
        "swapped_turns": online_momdp(TASK, learned.placement, R, wait.flip(0)),
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
    model = online_momdp(TASK, learned.placement, learned.momdp.R, wait)
    pee = TASK.state_names.index("PEE")
    ppe = TASK.state_names.index("PPE")
    b = model.b0.expand(2, -1).clone()
    controller = MOMDPController(model, policy=None, belief=b)  # type: ignore[arg-type]
    x = torch.tensor([pee, pee])
    controller.observe(x, torch.zeros(2, dtype=torch.long), torch.tensor([pee, ppe]))
    efficient, safe = controller.belief[0], controller.belief[1]
    assert efficient[1] > 0.85 and safe[0] > 0.6
