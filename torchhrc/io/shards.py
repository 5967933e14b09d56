"""The files of a demonstration corpus in shards: which files a source names, and reading one.

A shard is a file with the columns of the demonstrations CSV
(``subject,sequence,step,actor,action[,type]``, shared/DESIGN.md): CSV, JSON as
:class:`~torchhrc.data.Demonstrations` writes it, or Parquet
(:mod:`torchhrc.io.parquet`). :class:`torchhrc.mixture.sharded.ShardedCorpus` reduces a
corpus of shards to the statistics clustering needs, one shard at a time.

Example:
    >>> import tempfile, os
    >>> folder = tempfile.mkdtemp()
    >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]])
    >>> d.write_csv(os.path.join(folder, "b.csv")); d.write_csv(os.path.join(folder, "a.csv"))
    >>> [os.path.basename(p) for p in list_shards(folder)]
    ['a.csv', 'b.csv']
    >>> read_shard(list_shards(folder)[0]) == d
    True
"""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from pathlib import Path

from torchhrc.data import Demonstrations
from torchhrc.io.parquet import read_parquet

__all__ = ["SHARD_SUFFIXES", "list_shards", "read_shard"]

#: File suffixes a shard may have (CSV, JSON as :class:`Demonstrations` writes it, Parquet).
SHARD_SUFFIXES: tuple[str, ...] = (".csv", ".json", ".parquet", ".pq")


def read_shard(path: str | os.PathLike[str]) -> Demonstrations:
    """Read one shard by its suffix: ``.parquet``/``.pq``, ``.json`` or CSV."""
    suffix = Path(path).suffix.lower()
    if suffix in (".parquet", ".pq"):
        return read_parquet(path)
    if suffix == ".json":
        return Demonstrations.read_json(path)
    return Demonstrations.read_csv(path)


def list_shards(
    source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
) -> tuple[str, ...]:
    """The shard files a source names: a directory (its shard files, sorted), a glob pattern
    (the files it matches, sorted), a file, or a list of these (in its order).

    Raises:
        FileNotFoundError: the directory or pattern names no shard, or the file is missing.
    """
    if isinstance(source, (list, tuple)):
        return tuple(p for item in source for p in list_shards(item))
    text = str(source)
    if os.path.isdir(text):
        found = sorted(
            str(p) for p in Path(text).iterdir()
            if p.is_file() and p.suffix.lower() in SHARD_SUFFIXES
        )  # fmt: skip
        if not found:
            raise FileNotFoundError(2, "no .csv/.json/.parquet shard in directory", text)
        return tuple(found)
    if glob.has_magic(text):
        found = sorted(glob.glob(text))
        if not found:
            raise FileNotFoundError(2, "no file matches the pattern", text)
        return tuple(found)
    if not os.path.exists(text):
        raise FileNotFoundError(2, "No such file or directory", text)
    return (text,)
