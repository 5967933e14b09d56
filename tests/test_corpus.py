"""Sharded corpora: Parquet IO, exact merge of shard statistics, sharded fit = in-memory fit."""

from __future__ import annotations

import json
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


@pytest.mark.parametrize("method", ["soft", "paper"])
@pytest.mark.parametrize(("shards", "suffix"), [(1, ".csv"), (2, ".parquet"), (4, ".csv")])
def test_sharded_fit_equals_the_in_memory_fit(
    study: Demonstrations, tmp_path: Path, shards: int, suffix: str, method: str
) -> None:
    ordered = _write_shards(study, tmp_path, shards, suffix)
    options = dict(k_min=1, k_max=4, restarts=4, method=method, seed=3)
    sharded = fit_mixture(ShardedCorpus.open(tmp_path), **options)
    memory = fit_mixture(ordered, objects="raw", **options)  # a sharded corpus is fitted raw
    assert sharded.k == memory.k
    assert sharded.log_likelihood == pytest.approx(memory.log_likelihood, abs=1e-6)
    assert sharded.bic == pytest.approx(memory.bic, abs=1e-6)
    assert torch.equal(sharded.assignments, memory.assignments)


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray", reason="the [ray] extra is not installed")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.parametrize("shards", [1, 2, 4])
def test_ray_shard_tasks_and_e_steps_give_the_in_memory_fit(
    study: Demonstrations, tmp_path: Path, local_ray, shards: int
) -> None:
    """Shards reduced as Ray tasks, every E-step on Ray actors (a local cluster, 2 CPUs)."""
    ordered = _write_shards(study, tmp_path, shards, ".parquet")
    options = dict(k_min=1, k_max=4, restarts=4, seed=5)
    memory = fit_mixture(ordered, objects="raw", **options)  # a sharded corpus is fitted raw
    on_ray = fit_mixture(ShardedCorpus.open(tmp_path), ray=True, **options)
    assert local_ray.is_initialized()  # the fit leaves a cluster it did not start
    assert on_ray.k == memory.k
    assert on_ray.log_likelihood == pytest.approx(memory.log_likelihood, abs=1e-6)
    assert on_ray.bic == pytest.approx(memory.bic, abs=1e-6)
    assert torch.equal(on_ray.assignments, memory.assignments)


def test_ray_e_steps_for_data_in_memory(study: Demonstrations, local_ray) -> None:
    """``ray=`` with demonstrations in memory runs the E-steps on Ray (not ignored)."""
    # raw: the two types are of equal size, and exchangeable chains tie in cluster order up to
    # float rounding, which Ray's chunked sums may flip
    options = dict(k_min=1, k_max=3, restarts=3, seed=2, objects="raw")
    memory = fit_mixture(study, **options)
    on_ray = fit_mixture(study, ray=True, **options)
    assert on_ray.k == memory.k
    assert on_ray.log_likelihood == pytest.approx(memory.log_likelihood, abs=1e-6)
    assert torch.equal(on_ray.assignments, memory.assignments)


def test_ray_with_the_paper_method_in_memory_is_an_error(study: Demonstrations) -> None:
    with pytest.raises(ValueError, match="method='paper'"):
        fit_mixture(study, method="paper", ray=True)
    with pytest.raises(TypeError, match="ray"):
        fit_mixture(study, ray=3)


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
    assert main(["cluster", str(tmp_path / "all.csv"), *argv, "--objects", "raw"]) == 0
    memory = json.loads(capsys.readouterr().out)
    assert sharded["objects"] == memory["objects"] == "raw"
    for key in ("k", "bic", "log_likelihood", "assignments", "adjusted_rand_index"):
        assert sharded[key] == memory[key], key
    assert sharded["num_shards"] == 2
    assert main(["cluster", str(tmp_path / "shards"), "--loo"]) == 2
    assert "sharded corpus" in capsys.readouterr().err
    assert main(["cluster", str(tmp_path / "shards"), "--objects", "exchangeable"]) == 2
    assert "sharded corpus" in capsys.readouterr().err
