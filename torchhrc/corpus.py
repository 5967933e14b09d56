"""Deprecated module path (issue 32): the sharded corpus lives in the mixture, in
:mod:`torchhrc.mixture.sharded` (the exact merge of shard statistics) and
:mod:`torchhrc.mixture.ray_estep` (the E-step on Ray), and its files are read by
:mod:`torchhrc.io.shards` and :mod:`torchhrc.io.parquet`; this module forwards its names for
one release with a ``DeprecationWarning``.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_MOVED = {
    "CorpusStatistics": "torchhrc.mixture.sharded",
    "ShardStatistics": "torchhrc.mixture.sharded",
    "ShardedCorpus": "torchhrc.mixture.sharded",
    "shard_statistics": "torchhrc.mixture.sharded",
    "RayEStep": "torchhrc.mixture.ray_estep",
    "SHARD_SUFFIXES": "torchhrc.io.shards",
    "read_shard": "torchhrc.io.shards",
    "read_parquet": "torchhrc.io.parquet",
    "write_parquet": "torchhrc.io.parquet",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
