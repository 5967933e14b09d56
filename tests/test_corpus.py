"""The old module torchhrc.corpus: every name forwards to its new place with a warning."""

from __future__ import annotations

import importlib

import pytest

import torchhrc.corpus as old


@pytest.mark.parametrize("name", sorted(old._MOVED))
def test_old_name_warns_naming_the_new_place_and_is_the_same_object(name: str) -> None:
    new = old._MOVED[name]
    with pytest.warns(
        DeprecationWarning, match=rf"torchhrc\.corpus\.{name} is deprecated; use {new}\.{name}"
    ):
        got = getattr(old, name)
    assert got is getattr(importlib.import_module(new), name)


def test_the_moved_names_are_those_the_module_exported() -> None:
    assert sorted(old._MOVED) == sorted([
        "SHARD_SUFFIXES", "CorpusStatistics", "RayEStep", "ShardStatistics", "ShardedCorpus",
        "read_parquet", "read_shard", "shard_statistics", "write_parquet",
    ])  # fmt: skip
