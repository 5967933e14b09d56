"""Tests of torchhrc.experiments.robustness: statistics and the per-subject batch."""

from __future__ import annotations

import math

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.experiments.robustness import (
    EPSILONS,
    MOMDPPolicy,
    RobustnessResult,
    mean_ci95,
    simulate_subject,
    student_t_quantile,
)
from torchhrc.tasks.place_and_drill.cross_training import fit_cross_training
from torchhrc.tasks.place_and_drill.demos import demonstration
from torchhrc.tasks.place_and_drill.hand_coded import build_expert_momdp, load_expert_model


@pytest.mark.parametrize(("dof", "value"), [(1, 12.706), (5, 2.571), (17, 2.110), (100, 1.984)])
def test_student_t_quantiles_match_tables(dof, value):
    assert student_t_quantile(0.975, dof) == pytest.approx(value, abs=1e-3)


def test_mean_ci95_by_hand():
    x = torch.tensor([[1.0, 2.0, 3.0, 4.0]], dtype=torch.float64)
    mean, half = mean_ci95(x)
    sd = math.sqrt(5 / 3)
    assert mean.item() == 2.5 and half.item() == pytest.approx(1.959964 * sd / 2, rel=1e-5)
    _, half_t = mean_ci95(x, over="subjects")
    assert half_t.item() == pytest.approx(3.182446 * sd / 2, rel=1e-4)


def test_result_aggregates():
    r = torch.arange(2 * 3 * 4, dtype=torch.float64).view(2, 3, 4)
    res = RobustnessResult(epsilon=(0.0, 1.0), subjects=("a", "b", "c"), rewards={"p": r})
    assert res.runs_per_subject == 4
    torch.testing.assert_close(res.mean("p"), r.flatten(1).mean(-1))
    torch.testing.assert_close(res.subject_means("p"), r.mean(-1))


class _Rule:
    def __init__(self, task):
        self.task = task

    def action(self, x, belief_y):  # the efficient rule: drill the first placed screw
        placed = self.task.status[x] == 1
        return torch.where(placed.any(-1), placed.long().argmax(-1) + 1, 0)


def test_simulate_subject_shapes_and_shared_randomness():
    expert = load_expert_model()
    task = expert.task
    model = build_expert_momdp(expert)
    b0 = torch.tensor([0.5, 0.5], dtype=torch.float64)
    demos = Demonstrations.from_lists([demonstration("efficient", "ABC")] * 3)
    ct = fit_cross_training(task, demos)
    policies = {
        "one": MOMDPPolicy(model, _Rule(task), b0),
        "two": MOMDPPolicy(model, _Rule(task), b0),
    }
    out = simulate_subject(
        task,
        momdp_policies=policies,
        cross_training=ct,
        subject_index=0,
        orders=torch.tensor([[0, 1, 2]]),
        score=expert.reward()[..., 1],
        runs=7,
        generator=torch.Generator().manual_seed(0),
    )
    assert set(out) == {"one", "two", "cross_training"}
    assert out["one"].shape == (len(EPSILONS), 7)
    assert torch.equal(out["one"], out["two"])  # same policy, same human: same rewards
    assert torch.all(out["one"] == 30.0)
    assert torch.all(out["cross_training"][0] == 30.0)  # it replays its own demonstrations
