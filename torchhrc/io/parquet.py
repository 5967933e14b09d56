"""Demonstrations as Parquet files: the columns of the demonstrations CSV, read and written
vectorised (the ``[ray]`` extra installs pyarrow).

One row per step with the columns ``subject,sequence,step,actor,action[,type]``
(shared/DESIGN.md), dictionary-encoded: the columnar form of
:class:`~torchhrc.data.Demonstrations`, for corpora in shards
(:class:`torchhrc.mixture.sharded.ShardedCorpus`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from torchhrc._atomic import atomic_write_bytes
from torchhrc.data import CSV_COLUMNS, Demonstrations, Step
from torchhrc.errors import ModelError, ParseError

__all__ = ["read_parquet", "write_parquet"]

_COLUMNS = (*CSV_COLUMNS, "type")


def _pyarrow() -> Any:
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise ModelError(
            "Parquet shards need pyarrow: pip install 'torchhrc[ray]' (or pyarrow)"
        ) from None
    return pyarrow


def write_parquet(demos: Demonstrations, path: str | os.PathLike[str]) -> None:
    """Write ``demos`` as a Parquet file with the CSV's columns, atomically.

    One row per step, dictionary-encoded string columns; :func:`read_parquet` reads it back
    to equal :class:`Demonstrations`.

    Example:
        >>> import tempfile, os
        >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]])
        >>> p = os.path.join(tempfile.mkdtemp(), "d.parquet")
        >>> write_parquet(d, p); read_parquet(p) == d
        True
    """
    pa = _pyarrow()
    mask = demos.mask.cpu().numpy()
    n_idx, t_idx = np.nonzero(mask)  # row-major: sequences in order, steps 0, 1, ...
    symbols = demos.sequences.cpu().numpy()[n_idx, t_idx]
    vocab = demos.vocabulary

    def dictionary(indices: np.ndarray, values: Sequence[str]) -> Any:
        return pa.DictionaryArray.from_arrays(
            pa.array(indices, type=pa.int32()), pa.array(list(values), type=pa.string())
        )

    subjects, subject_code = np.unique(np.asarray(demos.subjects, dtype=object),
                                       return_inverse=True)  # fmt: skip
    seq_ids, seq_code = np.unique(np.asarray(demos.sequence_ids, dtype=object),
                                  return_inverse=True)  # fmt: skip
    actor_names = sorted({a for a, _ in vocab})
    action_names = sorted({b for _, b in vocab})
    actor_of = np.array([actor_names.index(a) for a, _ in vocab], dtype=np.int32)
    action_of = np.array([action_names.index(b) for _, b in vocab], dtype=np.int32)
    columns = {
        "subject": dictionary(subject_code[n_idx], subjects.tolist()),
        "sequence": dictionary(seq_code[n_idx], seq_ids.tolist()),
        "step": pa.array(t_idx.astype(np.int64)),
        "actor": dictionary(actor_of[symbols], actor_names),
        "action": dictionary(action_of[symbols], action_names),
    }
    if demos.types is not None:
        types, type_code = np.unique(np.asarray(demos.types, dtype=object), return_inverse=True)
        columns["type"] = dictionary(type_code[n_idx], types.tolist())
    table = pa.table(columns)
    sink = pa.BufferOutputStream()
    pa.parquet.write_table(table, sink)
    atomic_write_bytes(path, sink.getvalue().to_pybytes())


def _codes(column: Any, pa: Any) -> tuple[np.ndarray, list[str]]:
    """``(codes (R,) int64, values)`` of a string-like Arrow column."""
    if pa.types.is_dictionary(column.type):
        column = column.cast(pa.string()) if column.num_chunks != 1 else column
    encoded = column.cast(pa.string()).dictionary_encode().combine_chunks()
    return (
        encoded.indices.to_numpy(zero_copy_only=False).astype(np.int64),
        [str(v) for v in encoded.dictionary.to_pylist()],
    )


def read_parquet(
    path: str | os.PathLike[str], *, vocabulary: Sequence[Step] | None = None
) -> Demonstrations:
    """Read a Parquet file with the demonstrations CSV's columns (vectorised, no row loop).

    The same rules as :meth:`Demonstrations.read_csv`: rows of a sequence contiguous, steps
    ``0, 1, ...`` in order, at least 2 steps, actor ``human`` or ``robot``, a constant type
    within a sequence. A violation raises :class:`ParseError` naming the file, the row
    (1-based, as ``line``) and the reason.
    """
    pa = _pyarrow()
    name = str(path)
    try:
        table = pa.parquet.read_table(name)
    except FileNotFoundError:
        raise
    except Exception as error:  # pyarrow raises its own error types for a bad file
        raise ParseError(f"not a readable Parquet file ({error})", path=name) from None
    header = table.column_names
    unknown = [c for c in header if c not in _COLUMNS]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if unknown or missing:
        what = f"unknown column {unknown[0]!r}" if unknown else f"missing column(s) {missing}"
        raise ParseError(f"{what} (expected subject,sequence,step,actor,action[,type])",
                         path=name)  # fmt: skip
    rows = table.num_rows
    if rows == 0:
        raise ParseError("no data rows (expected one row per step)", path=name)
    for column in header:
        if table.column(column).null_count:
            first = int(np.nonzero(table.column(column).is_null().to_numpy(
                zero_copy_only=False))[0][0])  # fmt: skip
            raise ParseError(f"empty {column!r} field", path=name, line=first + 1)
    subj, subj_names = _codes(table.column("subject"), pa)
    seq, seq_names = _codes(table.column("sequence"), pa)
    actor, actor_names = _codes(table.column("actor"), pa)
    action, action_names = _codes(table.column("action"), pa)
    try:
        step = table.column("step").cast(pa.int64()).to_numpy(zero_copy_only=False)
    except Exception:
        raise ParseError("column 'step' is not integer", path=name) from None
    bad_actor = [i for i, a in enumerate(actor_names) if a not in ("human", "robot")]
    if bad_actor:
        row = int(np.nonzero(actor == bad_actor[0])[0][0])
        raise ParseError(f"unknown actor {actor_names[bad_actor[0]]!r} (expected one of "
                         "human, robot)", path=name, line=row + 1)  # fmt: skip
    pair = subj * len(seq_names) + seq  # (R,) one code per (subject, sequence)
    start = np.ones(rows, dtype=bool)
    start[1:] = pair[1:] != pair[:-1]
    group = np.cumsum(start) - 1  # (R,) sequence index of each row
    starts = np.nonzero(start)[0]
    n = len(starts)
    if len(np.unique(pair)) != n:
        codes, first = np.unique(pair[starts], return_index=True)
        counts = np.bincount(np.searchsorted(codes, pair[starts]), minlength=len(codes))
        again = starts[np.nonzero(counts[np.searchsorted(codes, pair[starts])] > 1)[0][1]]
        raise ParseError(
            f"rows of sequence {subj_names[subj[again]]}/{seq_names[seq[again]]} are not "
            "contiguous", path=name, line=int(again) + 1,
        )  # fmt: skip
    position = np.arange(rows) - starts[group]
    wrong = np.nonzero(step != position)[0]
    if len(wrong):
        r = int(wrong[0])
        raise ParseError(
            f"step {int(step[r])} of sequence {subj_names[subj[r]]}/{seq_names[seq[r]]} is out "
            f"of order (expected {int(position[r])}: steps 0, 1, ... in order)",
            path=name, line=r + 1,
        )  # fmt: skip
    lengths = np.bincount(group, minlength=n)
    short = np.nonzero(lengths < 2)[0]
    if len(short):
        r = int(starts[short[0]])
        raise ParseError(f"sequence {subj_names[subj[r]]}/{seq_names[seq[r]]} has 1 step, "
                         "expected at least 2", path=name, line=r + 1)  # fmt: skip
    symbol_pair = actor * len(action_names) + action
    present = np.unique(symbol_pair)
    found = [(actor_names[p // len(action_names)], action_names[p % len(action_names)])
             for p in present]  # fmt: skip
    vocab = tuple(sorted(found)) if vocabulary is None else tuple(vocabulary)
    index = {s: i for i, s in enumerate(vocab)}
    missing_symbols = [s for s in found if s not in index]
    if missing_symbols:
        a, b = missing_symbols[0]
        r = int(np.nonzero(symbol_pair == present[found.index((a, b))])[0][0])
        raise ParseError(f"symbol {a}:{b} is not in the given vocabulary", path=name,
                         line=r + 1)  # fmt: skip
    lookup = np.zeros(len(actor_names) * len(action_names), dtype=np.int64)
    lookup[present] = [index[s] for s in found]
    sequences = np.zeros((n, int(lengths.max())), dtype=np.int64)
    sequences[group, position] = lookup[symbol_pair]
    types = None
    if "type" in header:
        type_code, type_names = _codes(table.column("type"), pa)
        changed = np.nonzero(type_code != type_code[starts][group])[0]
        if len(changed):
            r = int(changed[0])
            raise ParseError(f"type label changes within sequence {subj_names[subj[r]]}/"
                             f"{seq_names[seq[r]]}", path=name, line=r + 1)  # fmt: skip
        types = tuple(np.asarray(type_names, dtype=object)[type_code[starts]].tolist())
    return Demonstrations(
        vocabulary=vocab,
        sequences=torch.from_numpy(sequences),
        lengths=torch.from_numpy(lengths.astype(np.int64)),
        subjects=tuple(np.asarray(subj_names, dtype=object)[subj[starts]].tolist()),
        sequence_ids=tuple(np.asarray(seq_names, dtype=object)[seq[starts]].tolist()),
        types=types,
    )
