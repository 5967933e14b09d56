"""Tests of torchhrc.io.shards: which files a source names, and reading a shard by its suffix."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from torchhrc.data import Demonstrations
from torchhrc.io.shards import SHARD_SUFFIXES, list_shards, read_shard


@pytest.fixture
def demos() -> Demonstrations:
    return Demonstrations.from_lists(
        [[("human", "a"), ("robot", "b"), ("human", "a")], [("robot", "b"), ("human", "c")]],
        subjects=["S1", "S2"],
        types=["x", "y"],
    )


def test_a_directory_names_its_shard_files_sorted_and_nothing_else(
    demos: Demonstrations, tmp_path: Path
) -> None:
    for name in ("c.csv", "a.json", "b.CSV"):
        (tmp_path / name).write_text("")
    (tmp_path / "notes.txt").write_text("")
    (tmp_path / "sub.csv").mkdir()  # a directory with a shard's suffix is no shard
    got = list_shards(tmp_path)
    assert [os.path.basename(p) for p in got] == ["a.json", "b.CSV", "c.csv"]
    assert all(Path(p).parent == tmp_path for p in got)


def test_a_pattern_a_file_and_a_list_keep_their_order(tmp_path: Path) -> None:
    for name in ("b.csv", "a.csv", "x.parquet"):
        (tmp_path / name).write_text("")
    assert list_shards(str(tmp_path / "*.csv")) == (
        str(tmp_path / "a.csv"),
        str(tmp_path / "b.csv"),
    )
    assert list_shards(tmp_path / "b.csv") == (str(tmp_path / "b.csv"),)
    # a list: its items in the given order, each expanded in place
    got = list_shards([tmp_path / "x.parquet", str(tmp_path / "*.csv")])
    assert [os.path.basename(p) for p in got] == ["x.parquet", "a.csv", "b.csv"]


def test_a_source_that_names_no_shard_is_a_file_not_found_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"no \.csv/\.json/\.parquet shard"):
        list_shards(tmp_path)  # an empty directory
    with pytest.raises(FileNotFoundError, match="no file matches"):
        list_shards(str(tmp_path / "*.parquet"))
    with pytest.raises(FileNotFoundError):
        list_shards(tmp_path / "missing.csv")


@pytest.mark.parametrize("suffix", SHARD_SUFFIXES)
def test_every_suffix_reads_back_the_demonstrations(
    demos: Demonstrations, tmp_path: Path, suffix: str
) -> None:
    path = tmp_path / f"d{suffix}"
    if suffix in (".parquet", ".pq"):
        pytest.importorskip("pyarrow", reason="the [ray] extra (pyarrow) is not installed")
        from torchhrc.io.parquet import write_parquet

        write_parquet(demos, path)
    elif suffix == ".json":
        demos.write_json(path)
    else:
        demos.write_csv(path)
    assert read_shard(path) == demos
