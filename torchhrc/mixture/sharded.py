"""A demonstration corpus in shards (CSV or Parquet files), reduced to the statistics that
clustering needs, shard by shard, and merged exactly.

A corpus too large for one machine's memory is kept as several files with the columns of the
demonstrations CSV (``subject,sequence,step,actor,action[,type]``, shared/DESIGN.md): CSV
files, or Parquet files (the ``[ray]`` extra installs pyarrow; the readers are in
:mod:`torchhrc.io.shards` and :mod:`torchhrc.io.parquet`). :class:`ShardedCorpus` names
them (a glob, a directory or a list) and computes what clustering needs shard by shard:
every EM step of :func:`torchhrc.mixture.fit_mixture` consumes only the distinct units'
transition counts and their multiplicities (:class:`~torchhrc.mixture.SufficientStatistics`),
so each shard is reduced to its own distinct rows (a Ray task per shard with ``ray=``, or one
shard after the other in this process), and the driver merges them exactly: the merged
statistics equal those of the whole corpus in memory, row for row (distinct rows in the same
lexicographic order, multiplicities summed), so the fit is the in-memory fit. The driver holds
the distinct rows (``U <= N``) and the sequence ids, never the corpus; a worker holds one
shard.

The defaults are those of the corpus in memory, ``objects="auto"`` included: a
:class:`ShardedCorpus` offers ``fit_mixture`` the operations it asks of demonstrations in
memory (``num_objects``, ``subjects``, ``subset``, ``relabel_objects``,
``relabel_log_multiplicity``) as views of its shards (a mask of sequences, a relabelling done
in each shard's task), so the two forms are compared, on the same sample of units, exactly as
in memory. Merged :class:`CorpusStatistics` cannot be relabelled and say so.

Every shard must have the same columns and the same vocabulary (the sorted set of
``(actor, action)`` symbols), and the sequences of one subject must lie in one shard (a
subject is one clustering unit by default).

Example:
    >>> import tempfile, os
    >>> from torchhrc.tasks.place_and_drill.demos import simulate_study
    >>> folder = tempfile.mkdtemp()
    >>> demos = simulate_study(n_subjects=4, n_demos=2, seed=0)
    >>> demos.select_subjects(["S01", "S02"]).write_csv(os.path.join(folder, "a.csv"))
    >>> demos.select_subjects(["S03", "S04"]).write_csv(os.path.join(folder, "b.csv"))
    >>> corpus = ShardedCorpus.open(folder)
    >>> len(corpus.paths), corpus.statistics().stats.num_sequences
    (2, 8)
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from torchhrc.data import Demonstrations, Step
from torchhrc.errors import ModelError
from torchhrc.io.shards import SHARD_SUFFIXES, list_shards, read_shard
from torchhrc.mixture.counts import (
    SufficientStatistics,
    _pack_rows,
    _unique_rows,
    _unique_words,
    transition_counts,
)

__all__ = [
    "CorpusStatistics",
    "ShardStatistics",
    "ShardedCorpus",
    "shard_statistics",
]


@dataclass(frozen=True)
class ShardStatistics:
    """One shard reduced to its distinct units (what a Ray task returns to the driver).

    Attributes:
        path: the shard.
        vocabulary: its sorted ``(actor, action)`` symbols.
        columns: its columns with ``type`` or not (``True`` when it has the column).
        keys: ``(U_s, F)`` distinct unit rows: transition counts ``A * A`` (and first
            symbols ``A`` when modelled), lexicographically sorted, in the smallest integer
            dtype that holds them (``uint8`` for counts below 256: 8x less to send and hold
            than int64).
        multiplicity: ``(U_s,)`` int64 units per distinct row.
        inverse: ``(N_s,)`` int64 distinct row of each sequence.
        num_units: units of the shard (sequences, or subjects).
        subjects: the shard's distinct subject ids (to check that shards do not share one).
        sequence_keys: ``"subject/sequence"`` of each sequence, or None when not asked.
        types: ground-truth label of each sequence, or None.
        process_id: the id of the process that reduced the shard (a Ray worker's with
            ``ray=``, this process's otherwise): where the work ran.
        log_multiplicity: with ``relabel``, ``(2, N_s)`` float64
            :meth:`~torchhrc.data.Demonstrations.relabel_log_multiplicity` of every sequence
            with ``given_first`` True (row 0) and False (row 1), computed in the same read.
    """

    path: str
    vocabulary: tuple[Step, ...]
    has_types: bool
    keys: torch.Tensor
    multiplicity: torch.Tensor
    inverse: torch.Tensor
    num_units: int
    subjects: tuple[str, ...]
    sequence_keys: tuple[str, ...] | None
    types: tuple[str, ...] | None
    process_id: int = 0
    log_multiplicity: torch.Tensor | None = None


def _compact_dtype(largest: int) -> torch.dtype:
    """The smallest of uint8, int16, int32, int64 that holds ``0..largest``."""
    for dtype in (torch.uint8, torch.int16, torch.int32):
        if largest <= torch.iinfo(dtype).max:
            return dtype
    return torch.int64


def _read_view(path: str, keep: torch.Tensor | None, relabel: str | None) -> Demonstrations:
    """One shard as a view of the corpus sees it: its sequences ``keep`` (a ``(N_s,)`` bool
    mask, None: all), with their objects relabelled (``relabel``: the separator) or not."""
    demos = _read_subset(path, keep)
    if relabel is not None:
        demos = demos.relabel_objects(separator=relabel, keep_unused=True)
    return demos


def _read_subset(path: str, keep: torch.Tensor | None) -> Demonstrations:
    demos = read_shard(path)
    if keep is not None:
        if keep.shape != (demos.num_sequences,):
            raise ModelError(
                f"shard {path} has {demos.num_sequences} sequences, but the corpus's subset "
                f"mask gives it {keep.shape[0]}: the shard changed since the corpus was read"
            )
        demos = demos.subset(keep)
    return demos


def shard_statistics(
    path: str,
    *,
    by_subject: bool,
    initial: bool,
    keep_keys: bool = False,
    keep: torch.Tensor | None = None,
    relabel: str | None = None,
) -> ShardStatistics:
    """Read one shard and reduce it to its distinct unit rows (runs in a worker).

    Args:
        path: the shard file.
        by_subject: one unit per subject (a subject's counts added) or per sequence.
        initial: keep first-symbol counts.
        keep_keys: also return each sequence's ``"subject/sequence"`` key and type.
        keep: ``(N_s,)`` bool, the shard's sequences to keep (None: all).
        relabel: relabel every sequence's objects with this separator
            (:meth:`~torchhrc.data.Demonstrations.relabel_objects`, ``keep_unused=True``).
    """
    demos = _read_subset(path, keep)
    log_multiplicity = None
    if relabel is not None:  # the recorded sequences' share of the relabelled likelihood
        log_multiplicity = torch.stack([
            demos.relabel_log_multiplicity(separator=relabel, given_first=first)
            for first in (True, False)
        ]) if demos.num_sequences else torch.zeros(2, 0, dtype=torch.float64)  # fmt: skip
        demos = demos.relabel_objects(separator=relabel, keep_unused=True)
    A = demos.num_symbols
    N = demos.num_sequences
    if N == 0:  # a subset that keeps none of this shard's sequences
        width = A * A + (A if initial else 0)
        return ShardStatistics(
            path=str(path), vocabulary=demos.vocabulary, has_types=demos.types is not None,
            keys=torch.zeros(0, width, dtype=torch.uint8),
            multiplicity=torch.zeros(0, dtype=torch.long),
            inverse=torch.zeros(0, dtype=torch.long), num_units=0, subjects=(),
            sequence_keys=() if keep_keys else None, types=() if keep_keys else None,
            process_id=os.getpid(), log_multiplicity=log_multiplicity,
        )  # fmt: skip
    counts = transition_counts(demos.sequences, demos.lengths, A).view(N, A * A)
    key = counts
    if initial:
        key = torch.cat([counts, torch.nn.functional.one_hot(demos.sequences[:, 0], A)], -1)
    unit_of = torch.arange(N)
    if by_subject:
        _, unit_of = np.unique(np.asarray(demos.subjects, dtype=object), return_inverse=True)
        unit_of = torch.from_numpy(unit_of.astype(np.int64).reshape(-1))
        key = key.new_zeros(int(unit_of.max()) + 1, key.shape[-1]).index_add_(0, unit_of, key)
    uniq, row_of_unit, mult = _unique_rows(key)
    return ShardStatistics(
        path=str(path),
        vocabulary=demos.vocabulary,
        has_types=demos.types is not None,
        keys=uniq.to(_compact_dtype(int(uniq.max()) if uniq.numel() else 0)),
        multiplicity=mult,
        inverse=row_of_unit[unit_of],
        num_units=key.shape[0],
        subjects=tuple(sorted(set(demos.subjects))),
        sequence_keys=demos.keys if keep_keys else None,
        types=demos.types if keep_keys else None,
        process_id=os.getpid(),
        log_multiplicity=log_multiplicity,
    )


@dataclass(frozen=True)
class CorpusStatistics:
    """The merged statistics of a corpus.

    Attributes:
        stats: :class:`~torchhrc.mixture.SufficientStatistics` of the whole corpus (equal to
            the in-memory ones), sequences in shard order.
        vocabulary: the shards' common vocabulary.
        sequence_keys: ``"subject/sequence"`` of every sequence, or None.
        types: ground-truth labels of every sequence (None unless every shard has them).
        unit, initial: the options they were computed with.
        process_ids: the process that reduced each shard (see
            :attr:`ShardStatistics.process_id`).
    """

    stats: Any
    vocabulary: tuple[Step, ...]
    sequence_keys: tuple[str, ...] | None
    types: tuple[str, ...] | None
    unit: str = "subject"
    initial: bool = False
    process_ids: tuple[int, ...] = ()

    def num_objects(self, *, separator: str = "_") -> int:
        """``M``, the objects the vocabulary names (as
        :meth:`~torchhrc.data.Demonstrations.num_objects`).

        Raises:
            ModelError: ``M >= 2``: statistics of the recorded symbols cannot be relabelled,
                so ``fit_mixture(objects="auto")`` cannot compare the two forms on them (it
                would fit the raw form in silence); fit the :class:`ShardedCorpus` itself, or
                pass ``objects="raw"``.
        """
        count = _num_objects(self.vocabulary, separator)
        if count >= 2:
            self.relabel_objects(separator=separator)
        return count

    def relabel_objects(self, *, separator: str = "_", keep_unused: bool = True) -> Any:
        """Raise :class:`ModelError`: merged statistics cannot be relabelled (see
        :meth:`num_objects`); fit the :class:`ShardedCorpus` itself."""
        count = _num_objects(self.vocabulary, separator)
        raise ModelError(
            f"these merged statistics are of the recorded symbols, and the vocabulary names "
            f"{count} objects: objects='auto' (or 'exchangeable') needs the corpus itself to "
            "relabel them; fit the ShardedCorpus, or pass objects='raw'"
        )

    def statistics(
        self,
        *,
        unit: str = "subject",
        initial: bool = False,
        dtype: torch.dtype = torch.float64,
        ray: bool | str | None = None,
        keep_keys: bool = False,
    ) -> CorpusStatistics:
        """These statistics again (so :func:`~torchhrc.mixture.fit_mixture` takes them as
        data); raise :class:`ModelError` when they were computed with other options."""
        del ray, keep_keys  # already computed
        if (unit, bool(initial)) != (self.unit, self.initial):
            raise ModelError(
                f"these statistics were computed with unit={self.unit!r}, initial="
                f"{self.initial}; the fit asks for unit={unit!r}, initial={bool(initial)}"
            )
        return dataclasses.replace(self, stats=dataclasses.replace(
            self.stats, counts=self.stats.counts.to(dtype),
            multiplicity=self.stats.multiplicity.to(dtype),
            first_counts=None if self.stats.first_counts is None
            else self.stats.first_counts.to(dtype),
        ))  # fmt: skip


@dataclass(frozen=True)
class _ShardIndex:
    """A shard's vocabulary and the ids of its sequences (no transitions)."""

    path: str
    vocabulary: tuple[Step, ...]
    subjects: tuple[str, ...]
    sequence_ids: tuple[str, ...]
    types: tuple[str, ...] | None


def _shard_index(path: str) -> _ShardIndex:
    demos = read_shard(path)
    return _ShardIndex(str(path), demos.vocabulary, demos.subjects, demos.sequence_ids,
                       demos.types)  # fmt: skip


def _pick(values: tuple[str, ...], mask: torch.Tensor | None) -> tuple[str, ...]:
    if mask is None:
        return values
    return tuple(values[i] for i in mask.nonzero().flatten().tolist())


def _num_objects(vocabulary: Sequence[Step], separator: str) -> int:
    """``M`` of :meth:`~torchhrc.data.Demonstrations.num_objects` for a vocabulary."""
    if not isinstance(separator, str) or not separator:
        raise TypeError(f"expected separator to be a non-empty str, got {separator!r}")
    split = [a.rpartition(separator) for _, a in vocabulary]
    return len({obj for verb, sep, obj in split if sep and verb and obj})


def _relabelled_vocabulary(vocabulary: tuple[Step, ...], separator: str | None
                           ) -> tuple[Step, ...]:  # fmt: skip
    """The vocabulary ``relabel_objects(keep_unused=True)`` gives (it follows from the
    recorded one)."""
    if separator is None:
        return vocabulary
    probe = Demonstrations.from_lists([[vocabulary[0], vocabulary[0]]], vocabulary=vocabulary)
    return probe.relabel_objects(separator=separator, keep_unused=True).vocabulary


class ShardedCorpus:
    """Demonstration shards on disk (see the module docstring).

    Args:
        paths: the shard files, in order.

    Raises:
        ModelError: no shard, or a file with an unknown suffix.
    """

    def __init__(self, paths: Sequence[str | os.PathLike[str]]) -> None:
        files = tuple(str(p) for p in paths)
        if not files:
            raise ModelError("expected at least one shard, got none")
        for p in files:
            if Path(p).suffix.lower() not in SHARD_SUFFIXES:
                raise ModelError(
                    f"shard {p} has an unknown suffix (expected one of {SHARD_SUFFIXES})"
                )
        self.paths = files
        self._keep: torch.Tensor | None = None  # (N,) bool: a subset view of the corpus
        self._relabel: str | None = None  # a view with relabelled objects (the separator)
        self._index_cache: list[_ShardIndex] | None = None
        self._base_corpus: ShardedCorpus | None = None
        # (id of a view's mask, separator) -> (the mask, (2, N) log multiplicities): filled by
        # a relabelled view's statistics, read by relabel_log_multiplicity (one read fewer)
        self._multiplicities: dict[tuple[int | None, str], tuple[Any, torch.Tensor]] = {}

    def __repr__(self) -> str:
        return f"ShardedCorpus({len(self.paths)} shards, first {self.paths[0]!r})"

    # --- the Demonstrations interface fit_mixture uses (objects="auto" included) ----------
    #
    # fit_mixture reads a corpus in memory through num_objects, subjects, num_sequences,
    # subset (a sample of units), relabel_objects and relabel_log_multiplicity; a sharded
    # corpus implements the same operations as views of its shards (a mask of sequences, a
    # relabelling), computed shard by shard, so every default, objects="auto" included, is
    # decided exactly as for the same rows in memory.

    def _index(self) -> list[_ShardIndex]:
        """What the in-memory checks need from every shard (one pass over the shards here,
        one shard at a time: its vocabulary and sequence ids, no transitions kept)."""
        if self._index_cache is None:
            if self._keep is not None or self._relabel is not None:
                base = self._base()._index()
                masks = self._masks()
                self._index_cache = [
                    dataclasses.replace(
                        b,
                        vocabulary=_relabelled_vocabulary(b.vocabulary, self._relabel),
                        subjects=_pick(b.subjects, m),
                        sequence_ids=_pick(b.sequence_ids, m),
                        types=None if b.types is None else _pick(b.types, m),
                    )
                    for b, m in zip(base, masks, strict=True)
                ]
            else:
                self._index_cache = [_shard_index(p) for p in self.paths]
        return self._index_cache

    def _base(self) -> ShardedCorpus:
        """The whole corpus this view is of (itself when it is no view)."""
        return self if self._base_corpus is None else self._base_corpus

    def _mask_key(self, separator: str) -> tuple[int | None, str]:
        return (None if self._keep is None else id(self._keep), separator)

    def _masks(self) -> list[torch.Tensor | None]:
        """Each shard's ``(N_s,)`` bool mask of this view (None: every sequence)."""
        if self._keep is None:
            return [None] * len(self.paths)
        sizes = [len(b.subjects) for b in self._base()._index()]
        return list(torch.split(self._keep, sizes))

    def _view(self, *, keep: torch.Tensor | None = None, relabel: str | None = None
              ) -> ShardedCorpus:  # fmt: skip
        view = ShardedCorpus(self.paths)
        view._base_corpus = self._base()
        view._keep = self._keep if keep is None else keep
        view._relabel = self._relabel if relabel is None else relabel
        return view

    @property
    def vocabulary(self) -> tuple[Step, ...]:
        """The shards' common vocabulary.

        Raises:
            ModelError: shards with different vocabularies.
        """
        index = self._index()
        for b in index[1:]:
            if b.vocabulary != index[0].vocabulary:
                extra = sorted(set(b.vocabulary) ^ set(index[0].vocabulary))
                raise ModelError(
                    f"shard {b.path} has another vocabulary than {index[0].path} "
                    f"(symbols in one only: {', '.join(f'{a}:{c}' for a, c in extra[:5])})"
                )
        return index[0].vocabulary

    @property
    def num_symbols(self) -> int:
        return len(self.vocabulary)

    @property
    def num_sequences(self) -> int:
        """``N``, the sequences of the corpus (all shards)."""
        return sum(len(b.subjects) for b in self._index())

    @property
    def subjects(self) -> tuple[str, ...]:
        """The subject of every sequence, in shard order."""
        return tuple(x for b in self._index() for x in b.subjects)

    @property
    def sequence_ids(self) -> tuple[str, ...]:
        return tuple(x for b in self._index() for x in b.sequence_ids)

    @property
    def keys(self) -> tuple[str, ...]:
        """``"subject/sequence"`` of every sequence, in shard order."""
        return tuple(f"{a}/{b}" for a, b in zip(self.subjects, self.sequence_ids, strict=True))

    @property
    def types(self) -> tuple[str, ...] | None:
        """Ground-truth labels of every sequence (None unless every shard has them)."""
        index = self._index()
        if any(b.types is None for b in index):
            return None
        return tuple(x for b in index for x in (b.types or ()))

    @property
    def unique_subjects(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(self.subjects))

    def num_objects(self, *, separator: str = "_") -> int:
        """``M``, as :meth:`~torchhrc.data.Demonstrations.num_objects` of the corpus."""
        return _num_objects(self.vocabulary, separator)

    def subset(self, indices: torch.Tensor | Sequence[bool]) -> ShardedCorpus:
        """The sequences of a ``(N,)`` bool mask, as a corpus (a view of the same shards).

        Raises:
            ModelError: not a bool mask of shape ``(N,)`` (a view keeps the shards' order).
        """
        mask = torch.as_tensor(indices)
        N = self.num_sequences
        if mask.dtype != torch.bool or mask.shape != (N,):
            raise ModelError(
                f"a sharded corpus takes a subset as a bool mask of shape (N,) = ({N},) (the "
                f"shards' order is kept), got dtype {mask.dtype}, shape {tuple(mask.shape)}"
            )
        if self._keep is not None:
            full = self._keep.clone()
            full[self._keep.nonzero().flatten()] = mask
            mask = full
        return self._view(keep=mask)

    def relabel_objects(self, *, separator: str = "_", keep_unused: bool = True) -> ShardedCorpus:
        """Every sequence's objects renamed in order of first use, shard by shard (a view).

        :meth:`~torchhrc.data.Demonstrations.relabel_objects` with ``keep_unused=True``: the
        relabelled vocabulary follows from the recorded one, so every shard gets the same.

        Raises:
            ModelError: ``keep_unused=False`` (the symbols the relabelled sequences use are
                known only after every shard is read), or an already relabelled view.
        """
        if not keep_unused:
            raise ModelError(
                "a sharded corpus relabels its objects with keep_unused=True only (the "
                "relabelled vocabulary must follow from the recorded one, the same in every "
                "shard)"
            )
        if self._relabel is not None:
            raise ModelError("this sharded corpus is already relabelled")
        _num_objects(self.vocabulary, separator)  # checks the separator
        return self._view(relabel=separator)

    def relabel_log_multiplicity(
        self, *, separator: str = "_", given_first: bool = True
    ) -> torch.Tensor:
        """``(N,)`` float64 :meth:`~torchhrc.data.Demonstrations.relabel_log_multiplicity` of
        every sequence, shard by shard (in this process, one shard at a time)."""
        if self._relabel is not None:
            raise ModelError("relabel_log_multiplicity of an already relabelled corpus")
        found = self._base()._multiplicities.get(self._mask_key(separator))
        if found is not None and found[0] is self._keep:
            return found[1][0 if given_first else 1]
        parts = [
            _read_view(p, m, None).relabel_log_multiplicity(
                separator=separator, given_first=given_first
            )
            for p, m in zip(self.paths, self._masks(), strict=True)
        ]
        return torch.cat(parts) if parts else torch.zeros(0, dtype=torch.float64)

    @classmethod
    def open(
        cls, source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]]
    ) -> ShardedCorpus:
        """Shards from a directory (its shard files, sorted), a glob pattern, or a list
        (:func:`~torchhrc.io.shards.list_shards`).

        Raises:
            FileNotFoundError: the directory or pattern names no shard.
        """
        return cls(list_shards(source))

    def statistics(
        self,
        *,
        unit: str = "subject",
        initial: bool = False,
        dtype: torch.dtype = torch.float64,
        ray: bool | str | None = None,
        keep_keys: bool = False,
    ) -> CorpusStatistics:
        """Reduce every shard to its distinct units and merge them exactly.

        Args:
            unit: ``"subject"`` (a subject's sequences share a type) or ``"sequence"``.
            initial: keep first-symbol counts.
            dtype: float dtype of the merged counts.
            ray: run each shard as a Ray task: ``True``/``"local"`` (a local cluster unless
                Ray is already initialised) or ``"HOST:PORT"``; ``None``: one shard after the
                other in this process.
            keep_keys: also collect each sequence's key and type (for reports).

        Raises:
            ModelError: shards with different columns or vocabularies, or a subject in two
                shards (with ``unit="subject"``).
        """
        if unit not in ("subject", "sequence"):
            raise ValueError(f"expected unit 'subject' or 'sequence', got {unit!r}")
        options = dict(by_subject=unit == "subject", initial=initial, keep_keys=keep_keys)
        shards = self._run(options, ray)
        first = shards[0]
        for s in shards[1:]:
            if s.vocabulary != first.vocabulary:
                extra = sorted(set(s.vocabulary) ^ set(first.vocabulary))
                raise ModelError(
                    f"shard {s.path} has another vocabulary than {first.path} "
                    f"(symbols in one only: {', '.join(f'{a}:{b}' for a, b in extra[:5])})"
                )
            if s.has_types != first.has_types:
                raise ModelError(
                    f"shard {s.path} has other columns than {first.path} (the 'type' column is "
                    f"{'present' if s.has_types else 'missing'})"
                )
        if unit == "subject":
            owner: dict[str, str] = {}
            for s in shards:
                for subject in s.subjects:
                    if subject in owner:
                        raise ModelError(
                            f"subject {subject} has sequences in two shards ({owner[subject]} "
                            f"and {s.path}); keep a subject's sequences in one shard, or "
                            "cluster with unit='sequence'"
                        )
                    owner[subject] = s.path
        # merge on bit-packed rows (a few int64 words per row), never an int64 copy of all keys
        largest = max((int(s.keys.max()) for s in shards if s.keys.numel()), default=0)
        bits = max(1, largest.bit_length())
        words = torch.cat([_pack_rows(s.keys, bits) for s in shards if s.keys.shape[0]])
        first_row, merged_row, _ = _unique_words(words)
        del words
        mult = torch.cat([s.multiplicity for s in shards])
        multiplicity = torch.zeros(first_row.shape[0], dtype=torch.long).index_add_(
            0, merged_row, mult
        )
        offsets = np.cumsum([0] + [s.keys.shape[0] for s in shards])
        width = first.keys.shape[-1]
        uniq = torch.empty(first_row.shape[0], width, dtype=_compact_dtype(largest))
        for o, s in zip(offsets[:-1], shards, strict=True):
            here = (first_row >= int(o)) & (first_row < int(o) + s.keys.shape[0])
            uniq[here] = s.keys[first_row[here] - int(o)].to(uniq.dtype)
        inverse = torch.cat([merged_row[int(o) + s.inverse] for o, s in
                             zip(offsets[:-1], shards, strict=True)])  # fmt: skip
        A = len(first.vocabulary)
        stats = SufficientStatistics(
            counts=uniq[:, : A * A].to(dtype),
            first_counts=uniq[:, A * A :].to(dtype) if initial else None,
            multiplicity=multiplicity.to(dtype),
            inverse=inverse,
            num_units=sum(s.num_units for s in shards),
            num_symbols=A,
        )
        sequence_keys = types = None
        if keep_keys:
            sequence_keys = tuple(k for s in shards for k in (s.sequence_keys or ()))
            if first.has_types:
                types = tuple(t for s in shards for t in (s.types or ()))
        if self._relabel is not None:  # keep what relabel_log_multiplicity will ask
            parts = [s.log_multiplicity for s in shards if s.log_multiplicity is not None]
            if len(parts) == len(shards):
                self._base()._multiplicities[self._mask_key(self._relabel)] = (
                    self._keep,
                    torch.cat(parts, -1),
                )
        return CorpusStatistics(stats, first.vocabulary, sequence_keys, types, unit, initial,
                                tuple(s.process_id for s in shards))  # fmt: skip

    def _run(self, options: dict[str, Any], ray: bool | str | None) -> list[ShardStatistics]:
        views = [dict(keep=k, relabel=self._relabel) for k in self._masks()]
        if ray is None or ray is False:
            return [shard_statistics(p, **options, **v)
                    for p, v in zip(self.paths, views, strict=True)]  # fmt: skip
        from torchhrc._ray import import_ray, init_ray, task_error

        ray_module = import_ray()
        started = init_ray("local" if ray is True else str(ray))
        try:
            task = ray_module.remote(num_cpus=1, max_retries=2)(shard_statistics)
            return ray_module.get([task.remote(p, **options, **v)
                                   for p, v in zip(self.paths, views, strict=True)])  # fmt: skip
        except Exception as error:  # a shard task failed after its retries
            raise task_error(error) from None
        finally:
            if started:
                ray_module.shutdown()
