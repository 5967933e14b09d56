"""Tests of torchhrc.tasks.place_and_drill.simulate: the batched execution simulator."""

from __future__ import annotations

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.tasks.interface import behaviour_from_preferences
from torchhrc.tasks.pipeline import task_momdp, transition_from_behaviour
from torchhrc.tasks.place_and_drill.demos import demonstration
from torchhrc.tasks.place_and_drill.hand_coded import build_expert_momdp, load_expert_model
from torchhrc.tasks.place_and_drill.model import EMPTY, PLACED, PlaceAndDrillTask
from torchhrc.tasks.place_and_drill.simulate import (
    MOMDPController,
    demonstrated_orders,
    run_executions,
    step_human,
)


class RulePolicy:
    """The ideal policy of a type, by rule: drill the first placed screw when allowed."""

    def __init__(self, task: PlaceAndDrillTask, safe: bool) -> None:
        self.task, self.safe = task, safe

    def action(self, x: torch.Tensor, belief_y: torch.Tensor) -> torch.Tensor:
        status = self.task.status[x]
        placed = status == PLACED
        allowed = placed.any(-1)
        if self.safe:
            allowed &= ~(status == EMPTY).any(-1)
        return torch.where(allowed, placed.long().argmax(-1) + 1, 0)


def _loop_human(task, x_mid, order, eps, u, keys):
    status = task.status[x_mid].tolist()
    empty = [i for i, s in enumerate(status) if s == EMPTY]
    if not empty:
        return x_mid
    if u < eps:
        pos = max(empty, key=lambda i: keys[i])
    else:
        pos = next(i for i in order if status[i] == EMPTY)
    return int(task.place_effect[x_mid, pos])


def test_step_human_batched_equals_loop():
    task = PlaceAndDrillTask(3)
    g = torch.Generator().manual_seed(3)
    B = 200
    x_mid = torch.randint(27, (B,), generator=g)
    order = torch.stack([torch.randperm(3, generator=g) for _ in range(B)])
    eps = torch.rand(B, generator=g, dtype=torch.float64)
    u = torch.rand(B, generator=g, dtype=torch.float64)
    keys = torch.rand(B, 3, generator=g, dtype=torch.float64)
    got = step_human(task, x_mid, order, eps, u, keys)
    want = [
        _loop_human(task, int(x_mid[b]), order[b].tolist(), eps[b], u[b], keys[b].tolist())
        for b in range(B)
    ]
    assert got.tolist() == want


def test_demonstrated_orders():
    demos = Demonstrations.from_lists(
        [demonstration("safe", "CAB"), demonstration("efficient", "BCA")], subjects=["s", "s"]
    )
    assert demonstrated_orders(PlaceAndDrillTask(3), demos)["s"].tolist() == [
        [2, 0, 1],
        [1, 2, 0],
    ]


@pytest.mark.parametrize("safe", [True, False])
def test_ideal_policy_scores_the_maximum_at_every_epsilon(safe):
    expert = load_expert_model()
    task = expert.task
    y = expert.type_names.index("safe" if safe else "efficient")
    model = build_expert_momdp(expert)
    B = 300
    eps = torch.linspace(0, 1, B, dtype=torch.float64)
    belief = torch.full((B, 2), 0.5, dtype=torch.float64)
    trace = run_executions(
        task,
        {"rule": MOMDPController(model, RulePolicy(task, safe), belief)},
        orders=torch.tensor([[0, 1, 2]]).expand(B, 3),
        epsilon=eps,
        score=expert.reward()[..., y],
        generator=torch.Generator().manual_seed(0),
    )
    assert torch.all(trace.rewards["rule"] == 30.0)  # 3 drills of +10, never a penalty
    assert torch.all(trace.states["rule"][-1] == task.terminal_state)


def test_wrong_type_policy_is_penalised():
    expert = load_expert_model()
    task = expert.task
    model = build_expert_momdp(expert)
    belief = torch.full((1, 2), 0.5, dtype=torch.float64)
    trace = run_executions(
        task,
        {"eff": MOMDPController(model, RulePolicy(task, safe=False), belief)},
        orders=torch.tensor([[0, 1, 2]]),
        epsilon=torch.zeros(1, dtype=torch.float64),
        score=expert.reward()[..., expert.type_names.index("safe")],
    )
    # efficient behaviour under a safe human: 2 early drills (-10), 1 ready drill (+10)
    assert trace.rewards["eff"].item() == -10.0


def test_controller_belief_is_bayes_rule():
    """The online belief equals the product of Tx likelihoods along the path, normalised."""
    task = PlaceAndDrillTask(3)
    g = torch.Generator().manual_seed(1)
    p = torch.rand(2, 4, 1, 3, generator=g, dtype=torch.float64)  # (Y, A, X, H)
    Tx = transition_from_behaviour(task, behaviour_from_preferences(task, p, noise=0.1))
    R = torch.zeros(4, 27, 2, dtype=torch.float64)
    b0 = torch.tensor([0.3, 0.7], dtype=torch.float64)
    model = task_momdp(task, Tx, R, b0)
    B = 64
    ctrl = MOMDPController(model, RulePolicy(task, safe=True), b0.expand(B, 2).clone(), record=True)
    trace = run_executions(
        task,
        {"c": ctrl},
        orders=torch.tensor([[2, 1, 0]]).expand(B, 3),
        epsilon=torch.full((B,), 0.7, dtype=torch.float64),
        score=torch.zeros(4, 27, dtype=torch.float64),
        generator=g,
    )
    xs, acts = trace.states["c"], trace.actions["c"]
    log_like = torch.zeros(B, 2, dtype=torch.float64)
    for t in range(acts.shape[0]):
        log_like += Tx[acts[t], xs[t], :, xs[t + 1]].log()
    expected = torch.softmax(log_like + b0.log(), -1)
    torch.testing.assert_close(ctrl.belief, expected)
    assert len(ctrl.beliefs) == acts.shape[0] + 1


def test_run_executions_validates():
    task = PlaceAndDrillTask(3)
    with pytest.raises(ModelError, match="orders"):
        run_executions(
            task, {}, orders=torch.zeros(2, 2, dtype=torch.long),
            epsilon=torch.zeros(2, dtype=torch.float64), score=torch.zeros(4, 27),
        )  # fmt: skip


def test_the_execution_protocol_is_not_named_controller_and_the_old_name_warns() -> None:
    import torchhrc.tasks.place_and_drill.simulate as simulate
    from torchhrc.tasks import Controller as OnlineController

    # one public class named Controller: the simulation's protocol has its own name
    assert simulate.ExecutionController is not OnlineController
    assert "Controller" not in simulate.__all__
    with pytest.warns(DeprecationWarning, match="ExecutionController"):
        old = simulate.Controller  # type: ignore[attr-defined]
    assert old is simulate.ExecutionController
    # both simulation controllers implement the protocol's two methods
    for cls in (simulate.MOMDPController, simulate.CrossTrainingController):
        assert callable(cls.act) and callable(cls.observe)
    with pytest.raises(AttributeError):
        simulate.NoSuchName  # type: ignore[attr-defined]  # noqa: B018
