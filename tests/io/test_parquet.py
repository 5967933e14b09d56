"""Tests of torchhrc.io.parquet: demonstrations as Parquet files, read back equal; a
malformed file names the file, the row and the reason."""

from __future__ import annotations

from pathlib import Path

import pytest

from torchhrc.data import Demonstrations
from torchhrc.errors import ParseError
from torchhrc.io.parquet import read_parquet, write_parquet
from torchhrc.tasks.place_and_drill.demos import simulate_study

pa = pytest.importorskip("pyarrow", reason="the [ray] extra (pyarrow) is not installed")


def test_parquet_round_trip(tmp_path: Path) -> None:
    study = simulate_study(n_subjects=24, n_demos=3, noise=(0.0, 0.2), seed=11)
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
