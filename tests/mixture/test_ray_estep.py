"""Tests of torchhrc.mixture.ray_estep and of the Ray paths of a sharded corpus: shards
reduced in Ray tasks, E-steps on Ray actors, and the same fit as in memory."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import torch
from _shards import same_fit, write_shards

from torchhrc.cli import main
from torchhrc.data import Demonstrations
from torchhrc.mixture import fit_mixture
from torchhrc.mixture.sharded import ShardedCorpus
from torchhrc.tasks.place_and_drill.demos import simulate_study

pytest.importorskip("pyarrow", reason="the [ray] extra (pyarrow) is not installed")


@pytest.fixture(scope="module")
def study() -> Demonstrations:
    return simulate_study(n_subjects=24, n_demos=3, noise=(0.0, 0.2), seed=11)


@pytest.fixture(scope="module")
def unequal(study: Demonstrations) -> Demonstrations:
    """The study without 4 subjects of one type (12 and 8 subjects): with types of equal
    size, the cluster labels follow a tie of sizes that Ray's chunked E-step sums may break
    the other way (the same partition, its labels swapped)."""
    drop = [s for s, t in zip(study.subjects, study.types, strict=True) if t == "safe"][::3][:4]
    return study.select_subjects(set(drop), exclude=True)


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray", reason="the [ray] extra is not installed")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.fixture
def where_it_ran(local_ray, monkeypatch: pytest.MonkeyPatch) -> dict[str, list]:
    """Records the process of every shard reduction and of every E-step actor of a fit."""
    import torchhrc.mixture.ray_estep as ray_estep_module
    import torchhrc.mixture.sharded as sharded_module

    record: dict[str, list] = {"shards": [], "e_steps": []}
    statistics = sharded_module.ShardedCorpus.statistics

    def recorded_statistics(self, **options):
        merged = statistics(self, **options)
        record["shards"].extend(merged.process_ids)
        return merged

    class RecordedEStep(ray_estep_module.RayEStep):
        calls = 0

        def __call__(self, *args):
            self.calls += 1
            return super().__call__(*args)

        def close(self) -> None:
            record["e_steps"].append((self.calls, self.worker_passes()))
            super().close()

    monkeypatch.setattr(sharded_module.ShardedCorpus, "statistics", recorded_statistics)
    monkeypatch.setattr(ray_estep_module, "RayEStep", RecordedEStep)
    return record


def _ran_on_ray_workers(record: dict[str, list], *, shards: bool) -> None:
    driver = os.getpid()
    assert record["e_steps"], "no E-step ran on Ray"
    for calls, workers in record["e_steps"]:
        assert calls > 0 and workers
        # every actor ran every pass, in a process other than this one
        assert all(pid != driver and passes == calls for pid, passes in workers), workers
    if shards:
        assert record["shards"] and all(pid != driver for pid in record["shards"])


# with Ray: 1, 2 and 4 shards, CSV and Parquet (4 CSV shards: the CLI test below; 2 Parquet
# shards' statistics: test_ray_shard_statistics_run_in_ray_workers); each fit starts actors
@pytest.mark.parametrize(("shards", "suffix"), [(1, ".csv"), (2, ".csv"), (4, ".parquet")])
def test_ray_shard_tasks_and_e_steps_give_the_in_memory_fit(
    unequal: Demonstrations, tmp_path: Path, where_it_ran, shards: int, suffix: str
) -> None:
    """Shards reduced as Ray tasks, every E-step on Ray actors (a local cluster, 2 CPUs), in
    other processes than the driver (issue 30: a local run in their place passed)."""
    ordered = write_shards(unequal, tmp_path, shards, suffix)
    # one form (auto fits both, each with its own actors and shard tasks: new Ray worker
    # processes, most of the time here); objects="auto" on shards with Ray: the CLI test below
    options = dict(k_min=1, k_max=3, restarts=3, seed=5, objects="exchangeable")
    memory = fit_mixture(ordered, **options)
    assert not where_it_ran["e_steps"]
    on_ray = fit_mixture(ShardedCorpus.open(tmp_path), ray=True, **options)
    _ran_on_ray_workers(where_it_ran, shards=True)
    same_fit(on_ray, memory)


def test_cli_on_shards_with_ray_local_gives_the_in_memory_report(
    unequal: Demonstrations, tmp_path: Path, where_it_ran, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 30: `torchhrc cluster SHARDDIR --ray local` fitted raw objects; now the in-memory
    report, its shards reduced and its E-steps run by Ray workers."""
    ordered = write_shards(unequal, tmp_path / "shards", 4, ".csv")
    ordered.write_csv(tmp_path / "all.csv")
    argv = ["--k-max", "3", "--restarts", "3", "--json"]
    assert main(["cluster", str(tmp_path / "shards"), "--ray", "local", *argv]) == 0
    sharded = json.loads(capsys.readouterr().out)
    _ran_on_ray_workers(where_it_ran, shards=True)
    assert main(["cluster", str(tmp_path / "all.csv"), *argv]) == 0
    memory = json.loads(capsys.readouterr().out)
    assert sharded["objects"] == memory["objects"] == "exchangeable"
    for key in ("k", "assignments", "adjusted_rand_index"):
        assert sharded[key] == memory[key], key
    for key in ("bic", "log_likelihood"):
        assert sharded[key] == pytest.approx(memory[key], abs=1e-6), key


def test_ray_shard_statistics_run_in_ray_workers(
    study: Demonstrations, tmp_path: Path, local_ray
) -> None:
    ordered = write_shards(study, tmp_path, 2, ".parquet")
    corpus = ShardedCorpus.open(tmp_path)
    here, there = corpus.statistics(), corpus.statistics(ray=True)
    assert set(here.process_ids) == {os.getpid()}
    assert len(there.process_ids) == 2 and os.getpid() not in there.process_ids
    assert torch.equal(here.stats.counts, there.stats.counts)
    assert torch.equal(here.stats.inverse, there.stats.inverse)
    assert ordered.num_sequences == there.stats.num_sequences


def test_ray_e_steps_for_data_in_memory(unequal: Demonstrations, where_it_ran) -> None:
    """``ray=`` with demonstrations in memory runs the E-steps on Ray actors (not ignored)."""
    options = dict(k_min=1, k_max=3, restarts=3, seed=2)  # the defaults, objects="auto"
    memory = fit_mixture(unequal, **options)
    on_ray = fit_mixture(unequal, ray=True, **options)
    _ran_on_ray_workers(where_it_ran, shards=False)
    same_fit(on_ray, memory)


def test_ray_e_steps_keep_the_labels_of_types_of_equal_size(
    study: Demonstrations, where_it_ran
) -> None:
    """Two types of 36 sequences each: restarts that reach the one partition with its
    clusters in another order tie in log-likelihood up to the last bits, which Ray's chunked
    E-step sums change; the chosen run (the first within 1e-9 of the best) and so the labels
    are the same with and without Ray (seed 2 swapped them when the plain argmax chose)."""
    options = dict(k_min=1, k_max=3, restarts=3, seed=2)
    memory = fit_mixture(study, **options)
    on_ray = fit_mixture(study, ray=True, **options)
    _ran_on_ray_workers(where_it_ran, shards=False)
    assert memory.assignments.bincount().tolist() == [36, 36]
    same_fit(on_ray, memory)


def test_ray_where_it_cannot_apply_is_an_error(study: Demonstrations, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="method='paper'"):
        fit_mixture(study, method="paper", ray=True)
    with pytest.raises(TypeError, match="ray"):
        fit_mixture(study, ray=3)
    write_shards(study, tmp_path, 2, ".csv")
    merged = ShardedCorpus.open(tmp_path).statistics(unit="sequence")
    with pytest.raises(ValueError, match="method='paper'"):  # merged: no shard to reduce
        fit_mixture(merged, method="paper", objects="raw", ray=True)
