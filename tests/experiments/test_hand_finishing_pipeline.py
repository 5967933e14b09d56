import json

import pytest

from torchhrc.errors import ModelError
from torchhrc.experiments.hand_finishing import (
    METRIC_KEYS,
    check_hand_finishing_metrics,
    reproduce_hand_finishing,
)

TIMING = {"solve_time_s", "factored_speedup", "speedup_detail"}


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
    assert on_disk["type_accuracy"] >= 0.95  # at the paper-like noise level
    assert on_disk["observation_fit_error"] < 0.05  # metres, learned vs true
    table = on_disk["noise_table"]
    assert [row["noise"] for row in table] == sorted(row["noise"] for row in table)
    assert table[-1]["mean_wait_steps"] > table[0]["mean_wait_steps"]
    assert table[-1]["type_accuracy"] <= table[0]["type_accuracy"]
    assert "| noise (m) |" in (out / "report.md").read_text()


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
    _, first = quick_run
    second = reproduce_hand_finishing(tmp_path, seed=0, quick=True)
    strip = lambda m: {k: v for k, v in m.items() if k not in TIMING}  # noqa: E731
    assert strip(first) == strip(second)
