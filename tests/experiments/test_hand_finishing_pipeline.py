import itertools
import json

import pytest

from torchhrc.errors import ModelError
from torchhrc.experiments.hand_finishing import (
    METRIC_KEYS,
    TIMING_KEYS,
    HandFinishingSettings,
    check_hand_finishing_metrics,
    reproduce_hand_finishing,
)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("hf")
    metrics = reproduce_hand_finishing(out, seed=0, quick=True)
    return out, metrics


def test_quick_pipeline_writes_report_plots_and_metrics(quick_run):
    out, _ = quick_run
    for name in ("report.md", "metrics.json", "fig4b_belief.png", "observation_model.png",
                 "reachable.png"):  # fmt: skip
        assert (out / name).is_file() and (out / name).stat().st_size > 0
    on_disk = json.loads((out / "metrics.json").read_text())
    assert set(METRIC_KEYS) <= set(on_disk)
    check_hand_finishing_metrics(on_disk)
    assert on_disk["n_states"] == 90  # 9 configurations x (2 * 2 + 1) progress x 2 types
    # types found by clustering: two clusters, mapped to both preferences
    assert on_disk["k"] == 2 and sorted(on_disk["cluster_sides"]) == ["left", "right"]
    # at the paper-like noise level (issue 12: >= 0.98): the quick run's accuracy over seeds
    # 0-9 was 0.995, 0.99, 0.99, 1.0, 1.0, 1.0, 0.99, 0.985, 1.0, 1.0 (docs/hand_finishing.md);
    # seed 0 measured 0.995, the bar 0.98 (margin 0.015); the baseline (static model, cost 2)
    # measured 0.975
    assert on_disk["type_accuracy"] >= 0.98
    assert on_disk["unwanted_cost_priced"] and on_disk["risk_tolerance"] == 0.02
    # the robot moves on beliefs of at least 1 - tolerance there (measured mean 0.994)
    assert on_disk["mean_belief_at_move"] >= 0.98
    assert 0.0 <= on_disk["baseline_type_accuracy"] <= 1.0
    assert on_disk["observation_fit_error"] < 0.05  # metres, learned vs true
    table = on_disk["noise_table"]
    assert [row["noise"] for row in table] == sorted(row["noise"] for row in table)
    # the robot waits longer as the noise grows (measured 1.44, 2.44, 4.72 steps)
    waits = [row["mean_wait_steps"] for row in table]
    assert all(a < b for a, b in itertools.pairwise(waits)), waits
    assert table[-1]["type_accuracy"] <= table[0]["type_accuracy"]
    report = (out / "report.md").read_text()
    assert "| noise (m) |" in report
    # every simulated policy came from a solve that stopped deterministically
    assert on_disk["solve_stop_reason"] in ("precision", "max_iterations")
    assert all(row["solve_iterations"] <= on_disk["settings"]["max_iterations"] for row in table)
    # the arm followed one episode's box moves per true type in SAPIEN, or the report says why
    sim = on_disk["sim"]
    if sim["available"]:
        assert len(sim["episodes"]) == 2 and sim["moves"] >= 2 and sim["all_settled"]
        assert on_disk["sim_settle_error_m"] == sim["max_position_error_m"] < 2e-3
        assert on_disk["sim_settle_rotation_error_rad"] < 1e-2
        for replay in sim["episodes"]:
            assert len(replay["path"]) == replay["moves"] + 1
        assert "Settle error of the box" in report
    else:
        assert on_disk["sim_settle_error_m"] is None and "Not run: SAPIEN" in report


def test_default_settings_stop_on_a_deterministic_criterion():
    for quick in (True, False):
        s = HandFinishingSettings.create(quick=quick)
        # the time limit is a safety net: generous against the iteration cap
        assert s.max_iterations is not None and s.max_iterations >= 50
        assert s.solve_time >= 120.0


def test_refuses_non_empty_directory(quick_run):
    out, _ = quick_run
    with pytest.raises(FileExistsError):
        reproduce_hand_finishing(out, quick=True)


def test_metrics_schema_errors_name_the_key():
    good = {k: 0.5 for k in METRIC_KEYS}
    good["n_states"] = 10
    check_hand_finishing_metrics(good)
    bad = dict(good)
    del bad["type_accuracy"]
    with pytest.raises(ModelError, match="type_accuracy"):
        check_hand_finishing_metrics(bad)
    with pytest.raises(ModelError, match="reachable_fraction"):
        check_hand_finishing_metrics({**good, "reachable_fraction": 1.5})


@pytest.mark.slow
def test_same_seed_same_metrics(quick_run, tmp_path):
    out, _ = quick_run
    reproduce_hand_finishing(tmp_path, seed=0, quick=True)
    first = json.loads((out / "metrics.json").read_text())
    second = json.loads((tmp_path / "metrics.json").read_text())
    assert set(TIMING_KEYS) & set(first)
    strip = lambda m: {k: v for k, v in m.items() if k not in TIMING_KEYS}  # noqa: E731
    assert strip(first) == strip(second)


def test_type_accuracy_over_seeds():
    """The quick study's robot (approach model as filter, planning on its stationary part,
    the unwanted cost priced from the risk tolerance 0.02) at 0.2 m over seeds 1-4.

    No setting was tuned on these seeds (the tolerance is the issue's 0.98). Measured over
    seeds 0-9 (docs/hand_finishing.md): 0.995, 0.99, 0.99, 1.0, 1.0, 1.0, 0.99, 0.985, 1.0,
    1.0 (min 0.985, mean 0.995); on seeds 1-4 0.99, 0.99, 1.0, 1.0 (mean 0.995). Bars: every
    seed >= 0.97 (margin 0.015 below the lowest of the ten; the binomial standard error of
    200 episodes at 0.99 is 0.007), the mean >= 0.98, the issue's goal (margin 0.015)."""
    from torchhrc.experiments.hand_finishing import _accuracy, _episodes
    from torchhrc.tasks.hand_finishing.geometry import feasible_box_configurations
    from torchhrc.tasks.hand_finishing.model import HandFinishingTask
    from torchhrc.tasks.hand_finishing.sensing import learn_approach_observation

    accuracies = []
    for seed in (1, 2, 3, 4):
        s = HandFinishingSettings.create(quick=True, seed=seed)
        feas = feasible_box_configurations(s.geometry, seed=seed)
        task = HandFinishingTask.build(first_sides=("left", "right"), feasible=feas.comfortable,
                                       reachable=feas.reachable, geometry=s.geometry,
                                       work_units=s.work_units)  # fmt: skip
        approach, _ = learn_approach_observation(task, task, s.paper_noise, s)
        ep, _, _ = _episodes(task, task.momdp, s.paper_noise, s, approach.stationary,
                             observer=approach)  # fmt: skip
        accuracies.append(_accuracy(ep, ("left", "right"), ("left", "right")))
    assert min(accuracies) >= 0.97, accuracies
    assert sum(accuracies) / len(accuracies) >= 0.98, accuracies


def test_the_generating_motion_as_filter_is_calibrated_at_the_first_move():
    """docs/hand_finishing.md's bound: with the exact filter (the generating hand motion) the
    accuracy of the MAP type at the robot's first move is its mean belief there, so no
    observation model lifts the accuracy above the belief the policy moves on. Quick run,
    seeds 1 and 3 (400 episodes; measured |accuracy - mean belief| < 0.001 pooled, binomial
    standard error about 0.009; bar 0.03)."""
    import torch

    from torchhrc.experiments.hand_finishing import _episodes
    from torchhrc.pomdp.approach_observation import ApproachObservation
    from torchhrc.tasks.hand_finishing.geometry import feasible_box_configurations
    from torchhrc.tasks.hand_finishing.model import HandFinishingTask
    from torchhrc.tasks.hand_finishing.person import simulate_episodes
    from torchhrc.tasks.hand_finishing.sensing import learn_static_observation, true_observation

    correct, belief = [], []
    for seed in (1, 3):
        s = HandFinishingSettings.create(quick=True, seed=seed)
        feas = feasible_box_configurations(s.geometry, seed=seed)
        task = HandFinishingTask.build(first_sides=("left", "right"), feasible=feas.comfortable,
                                       reachable=feas.reachable, geometry=s.geometry,
                                       work_units=s.work_units)  # fmt: skip
        learned, _, _ = learn_static_observation(task, task, s.paper_noise, s)
        _, solution, _ = _episodes(task, task.momdp, s.paper_noise, s, learned)
        true_obs = true_observation(task, s.paper_noise)
        oracle = ApproachObservation(true_obs, approach=s.motion.approach - 1e-12,
                                     start=s.motion.start)  # fmt: skip
        ep = simulate_episodes(task.momdp(learned), solution.policy, task.momdp(true_obs),
                               true_obs, torch.arange(s.episodes) % 2, steps=s.steps,
                               motion=s.motion, seed=s.seed + 7, observer=oracle)  # fmt: skip
        b = ep.belief_at_first_move()
        correct.append((b.argmax(-1) == ep.types).double())
        belief.append(b.max(-1).values)
    accuracy, mean_belief = torch.cat(correct).mean(), torch.cat(belief).mean()
    assert abs(float(accuracy - mean_belief)) <= 0.03, (float(accuracy), float(mean_belief))
