"""End-to-end tests of the place-and-drill reproduction (quick settings)."""

from __future__ import annotations

import json

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.experiments.place_and_drill import (
    StudySettings,
    prepare_output_dir,
    reproduce_place_and_drill,
)
from torchhrc.experiments.report import check_metrics
from torchhrc.solvers.type_policies import type_policy_lower_bound


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pd_quick")
    metrics = reproduce_place_and_drill(out, quick=True, seed=0)
    return out, metrics


def test_pipeline_writes_every_file(quick_run):
    out, _ = quick_run
    for name in ("metrics.json", "report.md", "fig3.png", "transitions.png", "type_posterior.png"):
        assert (out / name).stat().st_size > 0, name
    assert (out / "fig3.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (out / "report.md").read_text()
    assert "![reward vs epsilon](fig3.png)" in report and "0.965" in report
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary leftovers


def test_metrics_schema(quick_run):
    out, metrics = quick_run
    on_disk = json.loads((out / "metrics.json").read_text())
    assert on_disk == metrics
    check_metrics(on_disk)
    assert on_disk["subjects"] == 6 and on_disk["runs_per_subject"] == 20
    assert on_disk["epsilon"] == pytest.approx([i / 10 for i in range(11)])
    assert 0.0 <= on_disk["loo_accuracy"] <= 1.0 and on_disk["k"] >= 1
    for key in ("reward_online", "reward_online_ci95", "reward_online_ci95_subjects"):
        assert set(on_disk[key]) == {"learned", "hand_coded", "cross_training"}
        assert all(len(v) == 11 for v in on_disk[key].values())


def test_online_case_is_not_at_the_ceiling(quick_run):
    """Online (uniform prior), a learned or hand-coded robot cannot score the perfect 30."""
    out, m = quick_run
    for name in ("learned", "hand_coded"):
        assert max(m["reward_online"][name]) < 29.0, name
        assert min(m["reward_online"][name]) > 15.0, name
    assert "Online case" in (out / "report.md").read_text()


def test_separation_replay_keeps_the_drill_away_from_a_safe_persons_hand(quick_run):
    """Measured in the SAPIEN workbench: the policies that respect the safe type never drill
    next to the placing hand; with an efficient person they do (drill and hand at once)."""
    pytest.importorskip("sapien", reason="the [sim] extra (SAPIEN 3) is not installed")
    out, m = quick_run
    sep = m["separation"]
    assert sep["available"] and (out / "separation.png").is_file()
    for case in ("offline", "online"):
        for name in ("learned", "hand_coded"):
            safe, efficient = sep[case][name]["safe"], sep[case][name]["efficient"]
            assert safe["fraction_below"] == 0.0 and safe["contacts"] == 0
            assert safe["p5_m"] > sep["threshold_m"]
            assert efficient["p5_m"] < safe["p5_m"]
            assert safe["executions"] == efficient["executions"] == 1


def test_learned_close_to_hand_coded_at_epsilon_zero(quick_run):
    _, m = quick_run
    learned, hand = m["reward"]["learned"][0], m["reward"]["hand_coded"][0]
    assert abs(learned - hand) <= 0.05 * abs(hand)


def test_learned_at_least_cross_training_for_large_epsilon(quick_run):
    _, m = quick_run
    for e, learned, cross in zip(
        m["epsilon"], m["reward"]["learned"], m["reward"]["cross_training"]
    ):
        if e >= 0.5:
            assert learned >= cross, e


def test_same_seed_same_metrics(quick_run, tmp_path):
    # the module's run once more with its seed (one new run, not two: about 20 s saved)
    a_dir, a = quick_run
    b = reproduce_place_and_drill(tmp_path / "b", quick=True, seed=0)
    assert (a_dir / "metrics.json").read_bytes() == (tmp_path / "b" / "metrics.json").read_bytes()
    assert a == b


def test_refuses_a_non_empty_directory(tmp_path):
    (tmp_path / "mine.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="not empty"):
        reproduce_place_and_drill(tmp_path, quick=True)
    assert (tmp_path / "mine.txt").read_text() == "keep me"
    assert prepare_output_dir(tmp_path, force=True) == tmp_path
    with pytest.raises(FileExistsError, match="not a directory"):
        prepare_output_dir(tmp_path / "mine.txt", force=True)


def test_bad_sizes():
    with pytest.raises(ModelError, match="subjects"):
        reproduce_place_and_drill("unused", subjects=1)
    with pytest.raises(TypeError, match="runs"):
        reproduce_place_and_drill("unused", runs=2.5)  # type: ignore[arg-type]


def test_quick_settings_are_small():
    quick, full = StudySettings.quick(), StudySettings()
    assert (full.subjects, full.runs, full.k_max, full.restarts) == (18, 100, 10, 20)
    assert quick.subjects < full.subjects and quick.runs < full.runs


def test_type_policy_lower_bound_is_achievable():
    """Each vector's value equals a Monte-Carlo-free check: it never exceeds the MDP optimum."""
    from torchhrc.solvers.value_iteration import value_iteration
    from torchhrc.tasks.place_and_drill.hand_coded import build_expert_momdp, load_expert_model

    model = build_expert_momdp(load_expert_model())
    policy = type_policy_lower_bound(model)
    assert policy.alphas.shape == (2 * 27, 2)
    optimum = value_iteration(model.Tx.permute(2, 0, 1, 3), model.R.permute(2, 0, 1), 0.95)
    upper = optimum.values.T[policy.observed]  # (N, Y): full-information values
    assert torch.all(policy.alphas <= upper + 1e-6)
    # the vector of type y at x is exactly optimal for type y
    for y in range(2):
        own = policy.alphas[y * 27 : (y + 1) * 27, y]
        torch.testing.assert_close(own, optimum.values[y], atol=1e-5, rtol=0)
