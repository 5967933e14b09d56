"""Sharded corpora: Parquet IO, exact merge of shard statistics, sharded fit = in-memory fit."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import torch

from torchhrc.cli import main
from torchhrc.corpus import ShardedCorpus, read_parquet, shard_statistics, write_parquet
from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError, ParseError
from torchhrc.mixture import fit_mixture, sufficient_statistics
from torchhrc.tasks.place_and_drill.demos import simulate_study

pa = pytest.importorskip("pyarrow", reason="the [ray] extra (pyarrow) is not installed")


@pytest.fixture(scope="module")
def study() -> Demonstrations:
    return simulate_study(n_subjects=24, n_demos=3, noise=(0.0, 0.2), seed=11)


def _write_shards(demos: Demonstrations, folder: Path, shards: int, suffix: str) -> Demonstrations:
    """Split by subject into ``shards`` files; return the corpus in shard order."""
    folder.mkdir(parents=True, exist_ok=True)
    subjects = demos.unique_subjects
    parts = [demos.select_subjects(subjects[i::shards]) for i in range(shards)]
    for i, part in enumerate(parts):
        path = folder / f"part{i:02d}{suffix}"
        write_parquet(part, path) if suffix == ".parquet" else part.write_csv(path)
    order = [i for part in parts for i in _indices(demos, part)]
    return demos.subset(order)


def _indices(demos: Demonstrations, part: Demonstrations) -> list[int]:
    where = {key: i for i, key in enumerate(demos.keys)}
    return [where[key] for key in part.keys]


def test_parquet_round_trip(study: Demonstrations, tmp_path: Path) -> None:
    write_parquet(study, tmp_path / "d.parquet")
    assert read_parquet(tmp_path / "d.parquet") == study
    no_types = Demonstrations.from_lists(study.to_lists()[:3])
    write_parquet(no_types, tmp_path / "n.parquet")
    assert read_parquet(tmp_path / "n.parquet") == no_types


def _table(rows: list[tuple]) -> object:
    names = ["subject", "sequence", "step", "actor", "action"]
    return pa.table({n: [r[i] for r in rows] for i, n in enumerate(names)})


@pytest.mark.parametrize(
    ("rows", "line", "reason"),
    [
        ([("a", "0", 0, "human", "x"), ("a", "0", 2, "robot", "y")], 2, "out of order"),
        ([("a", "0", 0, "human", "x"), ("a", "0", 1, "cat", "y")], 2, "unknown actor"),
        (
            [("a", "0", 0, "human", "x"), ("b", "0", 0, "robot", "y"), ("b", "0", 1, "robot", "y")],
            1,
            "expected at least 2",
        ),
        (
            [
                ("a", "0", 0, "human", "x"),
                ("a", "0", 1, "robot", "y"),
                ("b", "0", 0, "human", "x"),
                ("b", "0", 1, "human", "x"),
                ("a", "0", 2, "human", "x"),
            ],
            5,
            "not contiguous",
        ),
    ],
)
def test_malformed_parquet_names_file_row_and_reason(
    tmp_path: Path, rows: list[tuple], line: int, reason: str
) -> None:
    path = tmp_path / "bad.parquet"
    pa.parquet.write_table(_table(rows), path)
    with pytest.raises(ParseError, match=reason) as info:
        read_parquet(path)
    assert info.value.path == str(path) and info.value.line == line


def test_parquet_missing_column_and_garbage(tmp_path: Path) -> None:
    pa.parquet.write_table(pa.table({"subject": ["a"], "step": [0]}), tmp_path / "m.parquet")
    with pytest.raises(ParseError, match="missing column"):
        read_parquet(tmp_path / "m.parquet")
    (tmp_path / "g.parquet").write_bytes(b"not parquet at all")
    with pytest.raises(ParseError, match="not a readable Parquet file"):
        read_parquet(tmp_path / "g.parquet")


@pytest.mark.parametrize("unit", ["subject", "sequence"])
@pytest.mark.parametrize("shards", [1, 2, 4])
def test_merged_statistics_equal_the_in_memory_ones(
    study: Demonstrations, tmp_path: Path, shards: int, unit: str
) -> None:
    ordered = _write_shards(study, tmp_path, shards, ".parquet")
    merged = ShardedCorpus.open(tmp_path).statistics(unit=unit, initial=True)
    groups = ordered.subject_index if unit == "subject" else None
    ref = sufficient_statistics(ordered.sequences, ordered.lengths, ordered.num_symbols,
                                initial=True, groups=groups)  # fmt: skip
    s = merged.stats
    assert torch.equal(s.counts, ref.counts) and torch.equal(s.first_counts, ref.first_counts)
    assert torch.equal(s.multiplicity, ref.multiplicity)
    assert torch.equal(s.inverse, ref.inverse)
    assert s.num_units == ref.num_units
    assert merged.vocabulary == ordered.vocabulary


def _same_fit(a, b) -> None:
    """Same k, form, log-likelihood and BIC (to 1e-6) and identical assignments."""
    assert (a.k, a.objects) == (b.k, b.objects)
    assert a.log_likelihood == pytest.approx(b.log_likelihood, abs=1e-6)
    assert a.bic == pytest.approx(b.bic, abs=1e-6)
    assert torch.equal(a.assignments, b.assignments)
    if b.object_comparison is None:
        assert a.object_comparison is None
        return
    assert a.object_comparison.keys() == b.object_comparison.keys()
    for form, scores in b.object_comparison.items():
        assert a.object_comparison[form] == pytest.approx(scores, abs=1e-6), form


@pytest.mark.parametrize("method", ["soft", "paper"])
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
@pytest.mark.parametrize("shards", [1, 2, 4])
def test_sharded_fit_equals_the_in_memory_fit_with_the_same_defaults(
    study: Demonstrations, tmp_path: Path, shards: int, suffix: str, method: str
) -> None:
    """Issue 30: the sharded path fitted raw objects only (BIC -543.30 against -537.53 in
    memory): with the defaults (objects='auto' for soft) both give the same model."""
    ordered = _write_shards(study, tmp_path, shards, suffix)
    options = dict(k_min=1, k_max=4, restarts=4, method=method, seed=3)
    sharded = fit_mixture(ShardedCorpus.open(tmp_path), **options)
    memory = fit_mixture(ordered, **options)
    _same_fit(sharded, memory)
    if method == "soft":  # objects="auto" compared both forms, as in memory
        assert sharded.objects == "exchangeable" and sharded.object_comparison is not None


def test_sharded_auto_on_a_sample_and_forced_forms_equal_the_in_memory_ones(
    study: Demonstrations, tmp_path: Path
) -> None:
    """objects='auto' on a random sample of units (a large corpus), and each form forced."""
    ordered = _write_shards(study, tmp_path, 3, ".csv")
    corpus = ShardedCorpus.open(tmp_path)
    base = dict(k_min=1, k_max=3, restarts=3, seed=4)
    for extra in (dict(objects_sample=9), dict(objects="exchangeable"), dict(objects="raw")):
        _same_fit(fit_mixture(corpus, **base, **extra), fit_mixture(ordered, **base, **extra))
    assert fit_mixture(corpus, objects_sample=9, **base).object_comparison["raw"]["units"] == 9


def test_merged_statistics_cannot_decide_objects_auto_in_silence(
    study: Demonstrations, tmp_path: Path
) -> None:
    """Statistics of the recorded symbols cannot be relabelled: an error, not a raw fit."""
    _write_shards(study, tmp_path, 2, ".csv")
    merged = ShardedCorpus.open(tmp_path).statistics()
    with pytest.raises(ModelError, match="objects='raw'"):
        fit_mixture(merged, k_max=3, restarts=2)
    assert fit_mixture(merged, k_max=3, restarts=2, objects="raw").objects == "raw"
    with pytest.raises(ModelError, match="keep_unused=True"):
        ShardedCorpus.open(tmp_path).relabel_objects(keep_unused=False)


def test_corpus_views_read_the_same_rows_as_in_memory(
    study: Demonstrations, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import torchhrc.corpus as corpus_module

    ordered = _write_shards(study, tmp_path, 4, ".parquet")
    corpus = ShardedCorpus.open(tmp_path)
    assert corpus.keys == ordered.keys and corpus.types == ordered.types
    assert corpus.num_objects() == ordered.num_objects() == 3
    mask = torch.arange(ordered.num_sequences) % 3 == 1
    sub = corpus.subset(mask)
    assert sub.keys == ordered.subset(mask).keys
    relabelled = sub.relabel_objects().statistics(unit="sequence").stats
    ref = ordered.subset(mask).relabel_objects(keep_unused=True)
    ref_stats = sufficient_statistics(ref.sequences, ref.lengths, ref.num_symbols)
    assert torch.equal(relabelled.counts, ref_stats.counts)
    assert torch.equal(relabelled.inverse, ref_stats.inverse)
    # the relabelled read kept the multiplicities: no shard is read again for them
    monkeypatch.setattr(corpus_module, "read_shard", None)
    for first in (True, False):
        expected = ordered.subset(mask).relabel_log_multiplicity(given_first=first)
        assert torch.equal(sub.relabel_log_multiplicity(given_first=first), expected)
    monkeypatch.undo()
    other = corpus.subset(mask.clone())  # another view: read from its shards
    expected = ordered.subset(mask).relabel_log_multiplicity(given_first=False)
    assert torch.equal(other.relabel_log_multiplicity(given_first=False), expected)
    inner = sub.subset(torch.arange(sub.num_sequences) % 2 == 0)  # a subset of a subset
    assert inner.keys == ordered.subset(mask).subset(torch.arange(sub.num_sequences) % 2 == 0).keys


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
    import torchhrc.corpus as corpus_module

    record: dict[str, list] = {"shards": [], "e_steps": []}
    statistics = corpus_module.ShardedCorpus.statistics

    def recorded_statistics(self, **options):
        merged = statistics(self, **options)
        record["shards"].extend(merged.process_ids)
        return merged

    class RecordedEStep(corpus_module.RayEStep):
        calls = 0

        def __call__(self, *args):
            self.calls += 1
            return super().__call__(*args)

        def close(self) -> None:
            record["e_steps"].append((self.calls, self.worker_passes()))
            super().close()

    monkeypatch.setattr(corpus_module.ShardedCorpus, "statistics", recorded_statistics)
    monkeypatch.setattr(corpus_module, "RayEStep", RecordedEStep)
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


# 2 shards with Ray: test_ray_shard_statistics_run_in_ray_workers (each fit here starts actors)
@pytest.mark.parametrize(("shards", "suffix"), [(1, ".csv"), (4, ".parquet")])
def test_ray_shard_tasks_and_e_steps_give_the_in_memory_fit(
    unequal: Demonstrations, tmp_path: Path, where_it_ran, shards: int, suffix: str
) -> None:
    """Shards reduced as Ray tasks, every E-step on Ray actors (a local cluster, 2 CPUs), in
    other processes than the driver (issue 30: a local run in their place passed)."""
    ordered = _write_shards(unequal, tmp_path, shards, suffix)
    options = dict(k_min=1, k_max=3, restarts=3, seed=5)
    memory = fit_mixture(ordered, **options)
    assert not where_it_ran["e_steps"]
    on_ray = fit_mixture(ShardedCorpus.open(tmp_path), ray=True, **options)
    _ran_on_ray_workers(where_it_ran, shards=True)
    _same_fit(on_ray, memory)


def test_cli_on_shards_with_ray_local_gives_the_in_memory_report(
    unequal: Demonstrations, tmp_path: Path, where_it_ran, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 30: `torchhrc cluster SHARDDIR --ray local` fitted raw objects; now the in-memory
    report, its shards reduced and its E-steps run by Ray workers."""
    ordered = _write_shards(unequal, tmp_path / "shards", 4, ".csv")
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
    ordered = _write_shards(study, tmp_path, 2, ".parquet")
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
    _same_fit(on_ray, memory)


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
    _same_fit(on_ray, memory)


def test_ray_where_it_cannot_apply_is_an_error(study: Demonstrations, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="method='paper'"):
        fit_mixture(study, method="paper", ray=True)
    with pytest.raises(TypeError, match="ray"):
        fit_mixture(study, ray=3)
    _write_shards(study, tmp_path, 2, ".csv")
    merged = ShardedCorpus.open(tmp_path).statistics(unit="sequence")
    with pytest.raises(ValueError, match="method='paper'"):  # merged: no shard to reduce
        fit_mixture(merged, method="paper", objects="raw", ray=True)


def test_shards_must_agree(study: Demonstrations, tmp_path: Path) -> None:
    safe = study.select_subjects([s for s, t in zip(study.subjects, study.types) if t == "safe"])
    other = Demonstrations.from_lists([[("human", "x"), ("robot", "y")]], subjects=["Z"])
    safe.write_csv(tmp_path / "a.csv")
    other.write_csv(tmp_path / "b.csv")
    with pytest.raises(ModelError, match="another vocabulary"):
        ShardedCorpus.open(tmp_path).statistics()
    untyped = Demonstrations.from_lists(study.select_subjects(["S01"]).to_lists(),
                                        subjects=["Q"] * 3, vocabulary=safe.vocabulary)  # fmt: skip
    untyped.write_csv(tmp_path / "b.csv")
    with pytest.raises(ModelError, match="other columns"):
        ShardedCorpus.open(tmp_path).statistics()
    safe.write_csv(tmp_path / "b.csv")  # the same subjects in two shards
    with pytest.raises(ModelError, match="two shards"):
        ShardedCorpus.open(tmp_path).statistics(unit="subject")
    assert ShardedCorpus.open(tmp_path).statistics(unit="sequence").stats.num_units == 2 * len(safe)


def test_open_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        ShardedCorpus.open(tmp_path)  # an empty directory
    with pytest.raises(FileNotFoundError):
        ShardedCorpus.open(str(tmp_path / "*.parquet"))
    with pytest.raises(ModelError, match="unknown suffix"):
        ShardedCorpus([tmp_path / "x.txt"])


def test_shard_statistics_keep_keys(study: Demonstrations, tmp_path: Path) -> None:
    write_parquet(study, tmp_path / "s.parquet")
    s = shard_statistics(str(tmp_path / "s.parquet"), by_subject=True, initial=False,
                         keep_keys=True)  # fmt: skip
    assert s.sequence_keys == study.keys and s.types == study.types
    assert s.num_units == len(study.unique_subjects)
    assert int(s.multiplicity.sum()) == s.num_units


def test_cli_clusters_a_directory_of_shards(
    study: Demonstrations, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ordered = _write_shards(study, tmp_path / "shards", 2, ".parquet")
    ordered.write_csv(tmp_path / "all.csv")
    argv = ["--k-max", "4", "--restarts", "4", "--json"]
    assert main(["cluster", str(tmp_path / "shards"), *argv]) == 0
    sharded = json.loads(capsys.readouterr().out)
    assert main(["cluster", str(tmp_path / "all.csv"), *argv]) == 0
    memory = json.loads(capsys.readouterr().out)
    assert sharded["objects"] == memory["objects"] == "exchangeable"  # the same defaults
    for key in ("k", "num_subjects", "symbols", "assignments", "adjusted_rand_index"):
        assert sharded[key] == memory[key], key
    for key in ("bic", "log_likelihood"):
        assert sharded[key] == pytest.approx(memory[key], abs=1e-6), key
    assert sharded["num_shards"] == 2
    assert main(["cluster", str(tmp_path / "shards"), "--loo"]) == 2
    assert "sharded corpus" in capsys.readouterr().err
