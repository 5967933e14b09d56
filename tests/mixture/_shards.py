"""Shared helpers of the sharded-corpus tests (test_sharded.py, test_ray_estep.py): shards
written from a corpus in memory, and the comparison of two fits."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.io.parquet import write_parquet


def write_shards(demos: Demonstrations, folder: Path, shards: int, suffix: str) -> Demonstrations:
    """Split by subject into ``shards`` files; return the corpus in shard order."""
    folder.mkdir(parents=True, exist_ok=True)
    subjects = demos.unique_subjects
    parts = [demos.select_subjects(subjects[i::shards]) for i in range(shards)]
    for i, part in enumerate(parts):
        path = folder / f"part{i:02d}{suffix}"
        write_parquet(part, path) if suffix == ".parquet" else part.write_csv(path)
    order = [i for part in parts for i in indices(demos, part)]
    return demos.subset(order)


def indices(demos: Demonstrations, part: Demonstrations) -> list[int]:
    where = {key: i for i, key in enumerate(demos.keys)}
    return [where[key] for key in part.keys]


def same_fit(a, b) -> None:
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
