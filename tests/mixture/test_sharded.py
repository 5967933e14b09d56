"""Tests of torchhrc.mixture.sharded: the exact merge of shard statistics, views of a corpus,
and the sharded fit = the in-memory fit."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from _shards import same_fit, write_shards

from torchhrc.cli import main
from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.io.parquet import write_parquet
from torchhrc.mixture import fit_mixture, sufficient_statistics
from torchhrc.mixture.sharded import ShardedCorpus, shard_statistics
from torchhrc.tasks.place_and_drill.demos import simulate_study

pytest.importorskip("pyarrow", reason="the [ray] extra (pyarrow) is not installed")


@pytest.fixture(scope="module")
def study() -> Demonstrations:
    return simulate_study(n_subjects=24, n_demos=3, noise=(0.0, 0.2), seed=11)


@pytest.mark.parametrize("unit", ["subject", "sequence"])
@pytest.mark.parametrize("shards", [1, 2, 4])
def test_merged_statistics_equal_the_in_memory_ones(
    study: Demonstrations, tmp_path: Path, shards: int, unit: str
) -> None:
    ordered = write_shards(study, tmp_path, shards, ".parquet")
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
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
@pytest.mark.parametrize("shards", [1, 2, 4])
def test_sharded_fit_equals_the_in_memory_fit_with_the_same_defaults(
    study: Demonstrations, tmp_path: Path, shards: int, suffix: str, method: str
) -> None:
    """Issue 30: the sharded path fitted raw objects only (BIC -543.30 against -537.53 in
    memory): with the defaults (objects='auto' for soft) both give the same model."""
    ordered = write_shards(study, tmp_path, shards, suffix)
    options = dict(k_min=1, k_max=4, restarts=4, method=method, seed=3)
    sharded = fit_mixture(ShardedCorpus.open(tmp_path), **options)
    memory = fit_mixture(ordered, **options)
    same_fit(sharded, memory)
    if method == "soft":  # objects="auto" compared both forms, as in memory
        assert sharded.objects == "exchangeable" and sharded.object_comparison is not None


def test_sharded_auto_on_a_sample_and_forced_forms_equal_the_in_memory_ones(
    study: Demonstrations, tmp_path: Path
) -> None:
    """objects='auto' on a random sample of units (a large corpus), and each form forced."""
    ordered = write_shards(study, tmp_path, 3, ".csv")
    corpus = ShardedCorpus.open(tmp_path)
    base = dict(k_min=1, k_max=3, restarts=3, seed=4)
    for extra in (dict(objects_sample=9), dict(objects="exchangeable"), dict(objects="raw")):
        same_fit(fit_mixture(corpus, **base, **extra), fit_mixture(ordered, **base, **extra))
    assert fit_mixture(corpus, objects_sample=9, **base).object_comparison["raw"]["units"] == 9


def test_merged_statistics_cannot_decide_objects_auto_in_silence(
    study: Demonstrations, tmp_path: Path
) -> None:
    """Statistics of the recorded symbols cannot be relabelled: an error, not a raw fit."""
    write_shards(study, tmp_path, 2, ".csv")
    merged = ShardedCorpus.open(tmp_path).statistics()
    with pytest.raises(ModelError, match="objects='raw'"):
        fit_mixture(merged, k_max=3, restarts=2)
    assert fit_mixture(merged, k_max=3, restarts=2, objects="raw").objects == "raw"
    with pytest.raises(ModelError, match="keep_unused=True"):
        ShardedCorpus.open(tmp_path).relabel_objects(keep_unused=False)


def test_corpus_views_read_the_same_rows_as_in_memory(
    study: Demonstrations, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import torchhrc.mixture.sharded as sharded_module

    ordered = write_shards(study, tmp_path, 4, ".parquet")
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
    monkeypatch.setattr(sharded_module, "read_shard", None)
    for first in (True, False):
        expected = ordered.subset(mask).relabel_log_multiplicity(given_first=first)
        assert torch.equal(sub.relabel_log_multiplicity(given_first=first), expected)
    monkeypatch.undo()
    other = corpus.subset(mask.clone())  # another view: read from its shards
    expected = ordered.subset(mask).relabel_log_multiplicity(given_first=False)
    assert torch.equal(other.relabel_log_multiplicity(given_first=False), expected)
    inner = sub.subset(torch.arange(sub.num_sequences) % 2 == 0)  # a subset of a subset
    assert inner.keys == ordered.subset(mask).subset(torch.arange(sub.num_sequences) % 2 == 0).keys


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
    ordered = write_shards(study, tmp_path / "shards", 2, ".parquet")
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
