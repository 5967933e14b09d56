"""The :class:`Demonstrations` container: ``N`` joint-action sequences padded into one
tensor, with their vocabulary, subjects and types; selection, relabelling of objects,
transition counts; its CSV and JSON forms are parsed in :mod:`torchhrc.data.formats`."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import operator
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch

from torchhrc._atomic import atomic_write_text
from torchhrc.data.formats import (
    _JSON_FORMAT,
    _JSON_VERSION,
    _TYPE_COLUMN,
    CSV_COLUMNS,
    _from_json_dict,
    _parse_csv,
    _read_text,
)
from torchhrc.data.vocabulary import (
    ACTORS,
    Step,
    _check_strings,
    _check_vocabulary,
    _sorted_vocabulary,
)
from torchhrc.errors import ModelError, ParseError

__all__ = ["Demonstrations"]


@dataclass(frozen=True, eq=False)
class Demonstrations:
    """A set of joint-action demonstrations, padded into one tensor.

    Args:
        vocabulary: ``(A,)`` symbols, ``vocabulary[a] = (actor, action)``, actor in
            ``{"human", "robot"}``; distinct.
        sequences: ``(N, L)`` int64, ``sequences[n, t]`` the symbol index of step ``t`` of
            sequence ``n``, padded with 0 beyond ``lengths[n]``.
        lengths: ``(N,)`` int64, every length in ``[2, L]``.
        subjects: ``(N,)`` subject id of each sequence.
        sequence_ids: ``(N,)`` sequence id within its subject; ``(subject, sequence_id)``
            pairs are distinct.
        types: ``(N,)`` optional ground-truth type labels (never used for learning).

    Raises:
        ModelError: shapes, ranges, lengths or ids are inconsistent (the message names
            the field, what was expected and what was given).
        TypeError: a field has the wrong type.

    Example:
        >>> demos = Demonstrations.from_lists(
        ...     [[("human", "place_A"), ("robot", "wait"), ("robot", "drill_A")]])
        >>> demos.num_symbols, demos.mask.tolist()
        (3, [[True, True, True]])
    """

    vocabulary: tuple[Step, ...]
    sequences: torch.Tensor
    lengths: torch.Tensor
    subjects: tuple[str, ...]
    sequence_ids: tuple[str, ...]
    types: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check every field (called once at construction)."""
        set_ = object.__setattr__
        vocab = _check_vocabulary(self.vocabulary)
        set_(self, "vocabulary", vocab)
        seqs, lengths = self.sequences, self.lengths
        for name, value in (("sequences", seqs), ("lengths", lengths)):
            if not isinstance(value, torch.Tensor):
                raise TypeError(f"expected {name} to be a torch.Tensor, got {type(value).__name__}")
            if value.dtype != torch.int64:
                raise TypeError(f"expected {name} to have dtype torch.int64, got {value.dtype}")
        if seqs.dim() != 2:
            raise ModelError(
                f"expected sequences to have shape (N, L), actual shape = {tuple(seqs.shape)}"
            )
        n, max_len = seqs.shape
        if lengths.shape != (n,):
            raise ModelError(
                f"expected lengths to have shape (N,) = ({n},), actual shape = "
                f"{tuple(lengths.shape)}"
            )
        if lengths.device != seqs.device:
            raise ModelError(
                f"lengths is on {lengths.device} but sequences is on {seqs.device}; "
                "expected one device"
            )
        if n:
            bad = (lengths < 2) | (lengths > max_len)
            if bad.any():
                i = int(torch.nonzero(bad)[0])
                raise ModelError(
                    f"lengths[{i}] = {int(lengths[i])}, expected a length in [2, L = {max_len}] "
                    "(a sequence needs at least one transition)"
                )
            num_symbols = len(vocab)
            real = torch.arange(max_len, device=seqs.device) < lengths[:, None]
            out_of_range = real & ((seqs < 0) | (seqs >= num_symbols))
            if out_of_range.any():
                i, t = (int(v) for v in torch.nonzero(out_of_range)[0])
                raise ModelError(
                    f"sequences[{i}, {t}] = {int(seqs[i, t])} is not a symbol index "
                    f"(expected 0 <= index < A = {num_symbols})"
                )
            padded = ~real & (seqs != 0)
            if padded.any():
                i, t = (int(v) for v in torch.nonzero(padded)[0])
                raise ModelError(
                    f"sequences[{i}, {t}] = {int(seqs[i, t])} lies beyond lengths[{i}] = "
                    f"{int(lengths[i])}; expected padding 0"
                )
        set_(self, "subjects", _check_strings("subjects", self.subjects, n))
        set_(self, "sequence_ids", _check_strings("sequence_ids", self.sequence_ids, n))
        if self.types is not None:
            set_(self, "types", _check_strings("types", self.types, n))
        seen: dict[tuple[str, str], int] = {}
        for i, key in enumerate(zip(self.subjects, self.sequence_ids)):
            if key in seen:
                raise ModelError(
                    f"sequence {key[0]}/{key[1]} appears twice (indices {seen[key]} and {i}); "
                    "(subject, sequence_id) pairs must be distinct"
                )
            seen[key] = i

    # ------------------------------------------------------------------ properties
    @property
    def mask(self) -> torch.Tensor:
        """``(N, L)`` bool, ``mask[n, t] = t < lengths[n]`` (True on real steps)."""
        steps = torch.arange(self.sequences.shape[-1], device=self.sequences.device)
        return steps < self.lengths[:, None]

    @property
    def num_symbols(self) -> int:
        """``A``, the size of the vocabulary."""
        return len(self.vocabulary)

    @property
    def num_sequences(self) -> int:
        """``N``, the number of sequences."""
        return int(self.sequences.shape[0])

    @property
    def max_length(self) -> int:
        """``L``, the padded length."""
        return int(self.sequences.shape[1])

    @property
    def symbol_names(self) -> tuple[str, ...]:
        """``(A,)`` readable symbol names ``"actor:action"``, e.g. ``"human:place_A"``."""
        return tuple(f"{actor}:{action}" for actor, action in self.vocabulary)

    @property
    def keys(self) -> tuple[str, ...]:
        """``(N,)`` sequence keys ``"subject/sequence_id"`` (used by the CLI's JSON)."""
        return tuple(f"{s}/{q}" for s, q in zip(self.subjects, self.sequence_ids))

    @property
    def unique_subjects(self) -> tuple[str, ...]:
        """The distinct subject ids, in order of first appearance."""
        return tuple(dict.fromkeys(self.subjects))

    @property
    def subject_index(self) -> torch.Tensor:
        """``(N,)`` int64, index of each sequence's subject in :attr:`unique_subjects`."""
        lookup = {s: i for i, s in enumerate(self.unique_subjects)}
        return torch.tensor(
            [lookup[s] for s in self.subjects], dtype=torch.int64, device=self.sequences.device
        )

    @property
    def device(self) -> torch.device:
        """The device of :attr:`sequences`."""
        return self.sequences.device

    def __len__(self) -> int:
        return self.num_sequences

    def __getitem__(self, index: int | slice) -> list[Step] | Demonstrations:
        """``d[i]``: demonstration ``i`` as a list of ``(actor, action)`` steps (its subject:
        ``d.subjects[i]``); ``d[a:b]``: those demonstrations as a :class:`Demonstrations`
        (:meth:`subset`; for a list of indices or a mask, call :meth:`subset`).

        Example:
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")],
            ...                                [("robot", "b"), ("human", "a"), ("robot", "b")]])
            >>> d[0], len(d[1:]), [len(steps) for steps in d]
            ([('human', 'a'), ('robot', 'b')], 1, [2, 3])
        """
        n = self.num_sequences
        if isinstance(index, slice):
            return self.subset(list(range(n))[index])
        try:
            if isinstance(index, bool):
                raise TypeError
            i = operator.index(index)
        except TypeError:
            what = type(index).__name__
            raise TypeError(f"expected an integer index or a slice, got {what} (for a list of "
                            "indices or a bool mask, use .subset)") from None  # fmt: skip
        if not -n <= i < n:
            raise IndexError(f"index {i} out of range for {n} demonstrations")
        i %= n
        row = self.sequences[i, : int(self.lengths[i])].cpu().tolist()
        return [self.vocabulary[a] for a in row]

    def __iter__(self) -> Iterator[list[Step]]:
        """The demonstrations, each a list of ``(actor, action)`` steps (:meth:`to_lists`)."""
        return iter(self.to_lists())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Demonstrations):
            return NotImplemented
        return (
            self.vocabulary == other.vocabulary
            and self.subjects == other.subjects
            and self.sequence_ids == other.sequence_ids
            and self.types == other.types
            and self.sequences.shape == other.sequences.shape
            and bool(torch.equal(self.lengths.cpu(), other.lengths.cpu()))
            and bool(torch.equal(self.sequences.cpu(), other.sequences.cpu()))
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        subjects = len(self.unique_subjects)
        typed = "" if self.types is None else f", types={sorted(set(self.types))}"
        return (
            f"Demonstrations(N={self.num_sequences}, L={self.max_length}, A={self.num_symbols}, "
            f"subjects={subjects}{typed})"
        )

    # ------------------------------------------------------------------ construction
    @classmethod
    def check(cls, value: object, name: str = "demonstrations") -> Demonstrations:
        """``value`` itself if it is a :class:`Demonstrations`, else a TypeError naming
        ``name`` and the two ways to build one (:meth:`from_lists`, :meth:`read_csv`).

        Example:
            >>> Demonstrations.check([[("robot", "go"), ("human", "take")]])
            Traceback (most recent call last):
            ...
            TypeError: expected demonstrations to be a torchhrc.Demonstrations, got list; ...
        """
        if not isinstance(value, cls):
            raise TypeError(
                f"expected {name} to be a torchhrc.Demonstrations, got {type(value).__name__}; "
                "build one from lists of (actor, action) steps with "
                "Demonstrations.from_lists(sequences, subjects=...), or read a CSV with "
                "Demonstrations.read_csv(path)"
            )
        return value

    @classmethod
    def from_lists(
        cls,
        sequences: Sequence[Sequence[Step]],
        *,
        subjects: Sequence[str] | None = None,
        sequence_ids: Sequence[str] | None = None,
        types: Sequence[str] | None = None,
        vocabulary: Sequence[Step] | None = None,
        device: torch.device | str | None = None,
    ) -> Demonstrations:
        """Build from Python lists of ``(actor, action)`` steps.

        Args:
            sequences: ``N`` lists of steps ``(actor, action)``, each of length >= 2.
            subjects: ``(N,)`` subject ids; default: each sequence its own subject ``"0"``,
                ``"1"``, ...
            sequence_ids: ``(N,)`` ids within the subject; default: the running number of
                the sequence within its subject (``"0"``, ``"1"``, ...).
            types: ``(N,)`` optional ground-truth labels.
            vocabulary: fixed symbol order; default: the symbols present, human symbols
                first, then robot, action names sorted.
            device: where to put the tensors.

        Raises:
            ModelError: a step uses a symbol outside ``vocabulary``, an unknown actor, or a
                sequence is shorter than 2 steps.

        Example:
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]] * 2,
            ...                               subjects=["s1", "s1"])
            >>> d.keys
            ('s1/0', 's1/1')
        """
        if isinstance(sequences, (str, bytes)) or not isinstance(sequences, Sequence):
            raise TypeError(
                f"expected sequences to be a list of lists of (actor, action), "
                f"got {type(sequences).__name__}"
            )
        seqs: list[list[Step]] = []
        for i, seq in enumerate(sequences):
            if isinstance(seq, (str, bytes)) or not isinstance(seq, Sequence):
                raise TypeError(f"expected sequences[{i}] to be a list of steps, got {seq!r}")
            steps: list[Step] = []
            for t, step in enumerate(seq):
                if (
                    not isinstance(step, (tuple, list))
                    or len(step) != 2
                    or not all(isinstance(part, str) for part in step)
                ):
                    raise TypeError(
                        f"expected sequences[{i}][{t}] to be an (actor, action) pair of "
                        f"strings, got {step!r}"
                    )
                if step[0] not in ACTORS:
                    raise ModelError(
                        f"sequences[{i}][{t}] has actor {step[0]!r}, expected one of "
                        f"{', '.join(ACTORS)}"
                    )
                steps.append((step[0], step[1]))
            if len(steps) < 2:
                raise ModelError(
                    f"sequences[{i}] has {len(steps)} step(s), expected at least 2 "
                    "(a sequence needs at least one transition)"
                )
            seqs.append(steps)
        n = len(seqs)
        if vocabulary is None:
            vocab = _sorted_vocabulary(step for seq in seqs for step in seq)
        else:
            vocab = _check_vocabulary(vocabulary)
        index = {symbol: a for a, symbol in enumerate(vocab)}
        if subjects is None:
            subjects = [str(i) for i in range(n)]
        subjects = _check_strings("subjects", subjects, n)
        if sequence_ids is None:
            counter: dict[str, int] = {}
            ids = []
            for s in subjects:
                ids.append(str(counter.get(s, 0)))
                counter[s] = counter.get(s, 0) + 1
            sequence_ids = ids
        max_len = max((len(seq) for seq in seqs), default=0)
        table = [[0] * max_len for _ in range(n)]
        for i, seq in enumerate(seqs):
            for t, step in enumerate(seq):
                if step not in index:
                    raise ModelError(
                        f"sequences[{i}][{t}] = {step!r} is not in the vocabulary "
                        f"({len(vocab)} symbols)"
                    )
                table[i][t] = index[step]
        return cls(
            vocabulary=vocab,
            sequences=torch.tensor(table, dtype=torch.int64, device=device).reshape(n, max_len),
            lengths=torch.tensor([len(seq) for seq in seqs], dtype=torch.int64, device=device),
            subjects=tuple(subjects),
            sequence_ids=tuple(sequence_ids),
            types=None if types is None else tuple(types),
        )

    def to_lists(self) -> list[list[Step]]:
        """The sequences as lists of ``(actor, action)`` steps (inverse of from_lists)."""
        rows = self.sequences.cpu().tolist()
        return [
            [self.vocabulary[a] for a in row[:length]]
            for row, length in zip(rows, self.lengths.cpu().tolist())
        ]

    def to(self, device: torch.device | str) -> Demonstrations:
        """The same demonstrations with the tensors on ``device``."""
        return Demonstrations(
            vocabulary=self.vocabulary,
            sequences=self.sequences.to(device),
            lengths=self.lengths.to(device),
            subjects=self.subjects,
            sequence_ids=self.sequence_ids,
            types=self.types,
        )

    def symbol(self, actor: str, action: str) -> int:
        """The index of the symbol ``(actor, action)``.

        Raises:
            KeyError: the symbol is not in the vocabulary.
        """
        try:
            return self.vocabulary.index((actor, action))
        except ValueError:
            raise KeyError(
                f"symbol ({actor!r}, {action!r}) is not in the vocabulary {self.symbol_names}"
            ) from None

    # ------------------------------------------------------------------ selection
    def subset(self, indices: Sequence[int] | torch.Tensor) -> Demonstrations:
        """The sequences at ``indices`` (ints or a ``(N,)`` bool mask), same vocabulary.

        The padded length shrinks to the longest selected sequence.

        Example:
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]] * 3)
            >>> d.subset([2, 0]).subjects
            ('2', '0')
        """
        idx = torch.as_tensor(indices, device=torch.device("cpu"))
        if idx.dtype == torch.bool:
            if idx.shape != (self.num_sequences,):
                raise ModelError(
                    f"expected a bool mask of shape (N,) = ({self.num_sequences},), "
                    f"got shape {tuple(idx.shape)}"
                )
            idx = torch.nonzero(idx).flatten()
        if idx.numel() == 0:
            idx = idx.reshape(0).long()
        if idx.dtype not in (torch.int64, torch.int32, torch.int16, torch.int8, torch.uint8):
            raise TypeError(f"expected integer indices or a bool mask, got dtype {idx.dtype}")
        idx = idx.long().flatten()
        n = self.num_sequences
        if idx.numel() and (int(idx.min()) < -n or int(idx.max()) >= n):
            raise IndexError(f"index out of range for {n} sequences: {idx.tolist()}")
        idx = idx % max(n, 1)
        picks = idx.tolist()
        lengths = self.lengths[idx.to(self.device)]
        max_len = int(lengths.max()) if picks else 0
        return Demonstrations(
            vocabulary=self.vocabulary,
            sequences=self.sequences[idx.to(self.device), :max_len].contiguous(),
            lengths=lengths,
            subjects=tuple(self.subjects[i] for i in picks),
            sequence_ids=tuple(self.sequence_ids[i] for i in picks),
            types=None if self.types is None else tuple(self.types[i] for i in picks),
        )

    def select_subjects(self, subjects: Iterable[str], *, exclude: bool = False) -> Demonstrations:
        """The sequences of the given subjects (or of all others, with ``exclude=True``).

        Raises:
            ModelError: a named subject has no sequence.

        Example:
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]] * 3,
            ...                               subjects=["x", "y", "x"])
            >>> d.select_subjects(["x"], exclude=True).subjects
            ('y',)
        """
        if isinstance(subjects, str):
            subjects = [subjects]
        wanted = set(subjects)
        missing = sorted(wanted - set(self.subjects))
        if missing:
            raise ModelError(f"no sequences for subject(s) {missing}")
        keep = [(s in wanted) != exclude for s in self.subjects]
        return self.subset(torch.tensor(keep, dtype=torch.bool).reshape(self.num_sequences))

    def map_actions(self, mapping: Callable[[str, str], str] | Mapping[str, str]) -> Demonstrations:
        """The same demonstrations with action names mapped; symbols that meet are merged.

        Ties the parameters of symbols a user considers equivalent, e.g. every placement
        position: ``place_A, place_B, ... -> place``. The actor of a step never changes.

        Args:
            mapping: ``mapping(actor, action) -> new action``, or a dict from old to new
                action names (names it lacks stay as they are).

        Returns:
            Demonstrations over the merged vocabulary (canonical order), same steps.

        Example:
            >>> d = Demonstrations.from_lists([[("human", "place_A"), ("human", "place_B")]])
            >>> d.map_actions(lambda actor, action: action.split("_")[0]).symbol_names
            ('human:place',)
        """
        if isinstance(mapping, Mapping):
            table = dict(mapping)

            def rename(actor: str, action: str) -> str:
                return table.get(action, action)

        elif callable(mapping):
            rename = mapping
        else:
            raise TypeError(
                f"expected mapping to be a callable or a dict, got {type(mapping).__name__}"
            )
        steps = []
        for actor, action in self.vocabulary:
            new = rename(actor, action)
            if not isinstance(new, str) or not new:
                raise ModelError(
                    f"mapping({actor!r}, {action!r}) returned {new!r}; expected an action name"
                )
            steps.append((actor, new))
        vocabulary = _sorted_vocabulary(steps)
        lut = torch.tensor([vocabulary.index(s) for s in steps], device=self.device)
        return dataclasses.replace(
            self, vocabulary=vocabulary, sequences=torch.where(self.mask, lut[self.sequences], 0)
        )

    def relabel_objects(self, *, separator: str = "_", keep_unused: bool = False) -> Demonstrations:
        """The same demonstrations with interchangeable objects renamed in order of first use.

        An action ``<verb><separator><object>`` (split at the last separator, e.g.
        ``place_A``) acts on an object; actions without the separator (``wait``) act on none.
        In every sequence the objects are renamed ``1, 2, ...`` in the order the sequence first
        touches them (objects it never touches follow in vocabulary order), so
        ``place_B drill_B place_A drill_A`` and ``place_A drill_A place_B drill_B`` both become
        ``place_1 drill_1 place_2 drill_2``. The relation between steps (same object as
        before, a new one, the one touched first) is kept; which physical object it was is
        dropped.

        This is the model assumption that the objects are exchangeable, as the paper's study
        found for the screw positions ("the order of screw placement did not affect the
        clustering"): a type is then a strategy, not a strategy times a placement order. A
        first-order chain over position-specific symbols cannot express that: on data where
        every subject keeps its own placement order, partitions by placement order explain
        those symbols better than the strategies do (see ``docs/clustering.md``).

        Args:
            separator: the string between verb and object in an action name (non-empty).
            keep_unused: the relabelled vocabulary holds every symbol the original one can
                relabel to (each verb with objects ``1..M``, every symbol without an object),
                used or not, as the original vocabulary may hold symbols no sequence uses
                (a model fitted on it can then score new demonstrations that use them).
                Default: only the symbols the relabelled sequences use.

        Returns:
            Demonstrations over the relabelled vocabulary (canonical order), same steps,
            subjects, ids and types.

        Example:
            >>> d = Demonstrations.from_lists([
            ...     [("human", "place_B"), ("robot", "drill_B"), ("human", "place_A")]])
            >>> r = d.relabel_objects()
            >>> [r.symbol_names[i] for i in r.sequences[0].tolist()]
            ['human:place_1', 'robot:drill_1', 'human:place_2']
        """
        obj_t, M = self._object_of_symbol(separator)  # (A,) object index or -1; M objects
        n_obj = max(M, 1)
        # Each symbol: its (actor, verb) group, or its own group when it acts on no object.
        groups: dict[tuple[str, str], int] = {}
        sym_group = []
        for (actor, action), o in zip(self.vocabulary, obj_t.tolist(), strict=True):
            key = (actor, action.rpartition(separator)[0]) if o >= 0 else (actor, action + "\0")
            sym_group.append(groups.setdefault(key, len(groups)))
        group_t = torch.tensor(sym_group, device=self.device)  # (A,)
        N, L = self.sequences.shape
        obj = torch.where(self.mask, obj_t[self.sequences], -1)  # (N, L)
        # First step at which each sequence touches each object (L: never).
        first = torch.full((N, n_obj + 1), L, dtype=torch.long, device=self.device)
        steps = torch.arange(L, device=self.device).expand(N, L)
        first.scatter_reduce_(1, obj + 1, steps, reduce="amin")  # column 0: no object
        first = first[:, 1:]  # (N, n_obj)
        key = first * n_obj + torch.arange(n_obj, device=self.device)  # ties: vocabulary order
        rank = key.argsort(-1).argsort(-1)  # (N, n_obj): rank[n, o] = new name of o - 1
        new_obj = torch.where(obj >= 0, rank.gather(1, obj.clamp(min=0)), -1)  # (N, L)
        code = group_t[self.sequences] * (n_obj + 1) + new_obj + 1  # (N, L)
        used, inverse = torch.unique(code[self.mask], return_inverse=True)
        names = {g: k for k, g in groups.items()}

        def name(c: int) -> Step:
            (actor, verb), r = names[c // (n_obj + 1)], c % (n_obj + 1)
            return (actor, f"{verb}{separator}{r}") if r else (actor, verb[:-1])

        codes = used.tolist()
        if keep_unused:  # every (group, object rank) the original vocabulary allows
            ranks = range(1, M + 1)
            codes = [g * (n_obj + 1) + r for (_, v), g in groups.items()
                     for r in ((0,) if v.endswith("\0") else ranks)]  # fmt: skip
        vocabulary = _sorted_vocabulary(name(c) for c in codes)
        lut = torch.tensor([vocabulary.index(name(c)) for c in used.tolist()], device=self.device)
        sequences = torch.zeros_like(self.sequences)
        sequences[self.mask] = lut[inverse]
        return dataclasses.replace(self, vocabulary=vocabulary, sequences=sequences)

    def _object_of_symbol(self, separator: str) -> tuple[torch.Tensor, int]:
        """``(A,)`` int64 object index of every symbol (-1: acts on none), and the number
        ``M`` of distinct objects (``relabel_objects``'s split at the last separator)."""
        if not isinstance(separator, str) or not separator:
            raise TypeError(f"expected separator to be a non-empty str, got {separator!r}")
        split = [a.rpartition(separator) for _, a in self.vocabulary]
        objects = sorted({obj for verb, sep, obj in split if sep and verb and obj})
        index = [objects.index(o) if (s and v and o) else -1 for v, s, o in split]
        return torch.tensor(index, dtype=torch.long, device=self.device), len(objects)

    def num_objects(self, *, separator: str = "_") -> int:
        """``M``, the number of distinct objects named by ``<verb><separator><object>`` actions.

        Example:
            >>> d = Demonstrations.from_lists([[("human", "place_A"), ("robot", "drill_B")]])
            >>> d.num_objects(), d.num_objects(separator=":")
            (2, 0)
        """
        return self._object_of_symbol(separator)[1]

    def relabel_log_multiplicity(
        self, *, separator: str = "_", given_first: bool = True
    ) -> torch.Tensor:
        """Log of the number of demonstrations :meth:`relabel_objects` maps onto each one's image.

        A sequence that touches ``m`` of the ``M`` objects is one of ``M! / (M - m)!``
        sequences (one per injective renaming of its objects) with the same relabelled form,
        so if the objects are exchangeable (each demonstration's objects a uniformly random
        injection of its relabelled ones) ``log p(x) = log p(relabel(x)) - log(M! / (M - m)!)``
        for every sequence ``x``: a likelihood of the original demonstrations, comparable with
        a model of the original symbols. With ``given_first`` the first step is given (models
        that do not score the first symbol, the paper's Eq. 1): if it touches an object, that
        object is fixed and the count is ``(M - 1)! / (M - m)!``.

        Args:
            separator: as in :meth:`relabel_objects`.
            given_first: condition on the first step (see above).

        Returns:
            ``(N,)`` float64, ``log((M - f)! / (M - m)!)``, ``f`` = 1 if the first step is
            given and touches an object, else 0.

        Example:
            >>> d = Demonstrations.from_lists([
            ...     [("human", "place_A"), ("robot", "drill_A"), ("human", "place_C")],
            ...     [("human", "wait"), ("human", "place_B")]],
            ...     vocabulary=[("human", "place_A"), ("human", "place_B"), ("human", "place_C"),
            ...                 ("human", "wait"), ("robot", "drill_A")])
            >>> d.relabel_log_multiplicity().exp().round().tolist()  # (3-1)!/1!, 3!/2!
            [2.0, 3.0]
            >>> d.relabel_log_multiplicity(given_first=False).exp().round().tolist()  # 3!/1!
            [6.0, 3.0]
        """
        obj_t, M = self._object_of_symbol(separator)
        N = self.num_sequences
        obj = torch.where(self.mask, obj_t[self.sequences], -1)  # (N, L)
        touched = torch.zeros(N, M + 1, dtype=torch.bool, device=self.device)
        touched.scatter_(1, obj + 1, True)  # column 0: no object
        m = touched[:, 1:].sum(-1).double()  # (N,)
        f = (obj[:, 0] >= 0).double() if (given_first and N) else torch.zeros_like(m)
        return torch.lgamma(M - f + 1) - torch.lgamma(M - m + 1)

    def with_vocabulary(self, vocabulary: Iterable[Step]) -> Demonstrations:
        """The same steps over another vocabulary (which must hold every symbol used).

        Used to score new demonstrations with a model fitted over ``vocabulary``.

        Raises:
            ModelError: a symbol used by a sequence is not in ``vocabulary`` (named).

        Example:
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]])
            >>> d.with_vocabulary([("robot", "b"), ("robot", "c"), ("human", "a")]).sequences
            tensor([[2, 0]])
        """
        vocab = _check_vocabulary(vocabulary)
        if vocab == self.vocabulary:
            return self
        where = {s: i for i, s in enumerate(vocab)}
        used = torch.unique(self.sequences[self.mask]).tolist()
        missing = [self.symbol_names[u] for u in used if self.vocabulary[u] not in where]
        if missing:
            raise ModelError(
                f"symbol(s) {missing} used by the demonstrations are not in the vocabulary "
                f"{tuple(f'{a}:{b}' for a, b in vocab)}"
            )
        lut = torch.tensor([where.get(s, 0) for s in self.vocabulary], device=self.device)
        return dataclasses.replace(
            self, vocabulary=vocab, sequences=torch.where(self.mask, lut[self.sequences], 0)
        )

    # ------------------------------------------------------------------ statistics
    def transition_counts(self, *, per_sequence: bool = False) -> torch.Tensor:
        """Counts of transitions ``a -> b`` (paper's ``n_{b|a}``), by one bincount.

        Returns:
            ``(A, A)`` float64 (or ``(N, A, A)`` with ``per_sequence=True``);
            ``counts[..., a, b]`` = number of steps ``t`` with ``x_t = a, x_{t+1} = b``.

        Example:
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b"), ("human", "a")]])
            >>> d.transition_counts().tolist()
            [[0.0, 1.0], [1.0, 0.0]]
        """
        num = self.num_symbols
        n = self.num_sequences
        prev, nxt = self.sequences[:, :-1], self.sequences[:, 1:]
        valid = self.mask[:, 1:]  # (N, L-1): transition t -> t+1 is real
        flat = prev * num + nxt  # (N, L-1)
        if per_sequence:
            flat = flat + torch.arange(n, device=self.device)[:, None] * (num * num)
            size = n * num * num
        else:
            size = num * num
        counts = torch.bincount(flat[valid], minlength=size).to(torch.float64)
        return counts.reshape((n, num, num) if per_sequence else (num, num))

    # ------------------------------------------------------------------ CSV
    def to_csv_string(self) -> str:
        """The CSV text (header ``subject,sequence,step,actor,action[,type]``)."""
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        header = list(CSV_COLUMNS) + ([_TYPE_COLUMN] if self.types is not None else [])
        writer.writerow(header)
        for i, steps in enumerate(self.to_lists()):
            for t, (actor, action) in enumerate(steps):
                row = [self.subjects[i], self.sequence_ids[i], t, actor, action]
                if self.types is not None:
                    row.append(self.types[i])
                writer.writerow(row)
        return buffer.getvalue()

    def write_csv(self, path: str | os.PathLike[str]) -> None:
        """Write the CSV file atomically (temporary file + ``os.replace``).

        Example:
            >>> import tempfile, os
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]])
            >>> path = os.path.join(tempfile.mkdtemp(), "demos.csv")
            >>> d.write_csv(path); Demonstrations.read_csv(path) == d
            True
        """
        atomic_write_text(path, self.to_csv_string())

    @classmethod
    def read_csv(
        cls,
        path: str | os.PathLike[str],
        *,
        vocabulary: Sequence[Step] | None = None,
    ) -> Demonstrations:
        """Read the CSV format of shared/DESIGN.md.

        Rows of one (subject, sequence) are contiguous with steps ``0, 1, ...`` in order;
        the columns may come in any order; blank lines are ignored; nothing else is skipped.

        Args:
            path: the file.
            vocabulary: fixed symbol order (a step outside it is an error); default: the
                symbols present, in the canonical order of :meth:`from_lists`.

        Raises:
            ParseError: with file, line and reason, for an empty file, missing, unknown or
                repeated columns, a wrong number of fields, an empty field, a
                non-integer, duplicate or missing step, an unknown actor or symbol, a
                sequence shorter than 2 steps, a sequence id that changes subject within
                a sequence, rows of one sequence that are not contiguous, or a type label
                that changes within a sequence.
            FileNotFoundError: no such file.
        """
        name = os.fspath(path)
        text = _read_text(name, encoding="utf-8-sig")
        return cls.from_csv_string(text, path=name, vocabulary=vocabulary)

    @classmethod
    def from_csv_string(
        cls,
        text: str,
        *,
        path: str = "<string>",
        vocabulary: Sequence[Step] | None = None,
    ) -> Demonstrations:
        """Parse CSV text; see :meth:`read_csv` (``path`` names the source in errors).

        Example:
            >>> text = "subject,sequence,step,actor,action\\ns,0,0,human,a\\ns,0,1,robot,b\\n"
            >>> Demonstrations.from_csv_string(text).symbol_names
            ('human:a', 'robot:b')
        """
        return _parse_csv(cls, text, path, vocabulary)

    # ------------------------------------------------------------------ JSON
    def to_json_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: format tag, vocabulary and one record per sequence."""
        records = []
        for i, steps in enumerate(self.to_lists()):
            record: dict[str, Any] = {
                "subject": self.subjects[i],
                "sequence": self.sequence_ids[i],
                "steps": [[actor, action] for actor, action in steps],
            }
            if self.types is not None:
                record["type"] = self.types[i]
            records.append(record)
        return {
            "format": _JSON_FORMAT,
            "version": _JSON_VERSION,
            "vocabulary": [[actor, action] for actor, action in self.vocabulary],
            "sequences": records,
        }

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any], *, path: str = "<dict>") -> Demonstrations:
        """Inverse of :meth:`to_json_dict`; errors name ``path`` and the JSON location."""
        return _from_json_dict(cls, data, path)

    def write_json(self, path: str | os.PathLike[str]) -> None:
        """Write the JSON form atomically (temporary file + ``os.replace``)."""
        atomic_write_text(path, json.dumps(self.to_json_dict(), indent=1) + "\n")

    @classmethod
    def read_json(cls, path: str | os.PathLike[str]) -> Demonstrations:
        """Read the JSON form written by :meth:`write_json`.

        Raises:
            ParseError: invalid JSON (with line and column) or an invalid structure (with
                the JSON location, e.g. ``$.sequences[3].steps[1]``).

        Example:
            >>> import tempfile, os
            >>> d = Demonstrations.from_lists([[("human", "a"), ("robot", "b")]], types=["t"])
            >>> path = os.path.join(tempfile.mkdtemp(), "demos.json")
            >>> d.write_json(path); Demonstrations.read_json(path) == d
            True
        """
        name = os.fspath(path)
        text = _read_text(name, encoding="utf-8")
        if not text.strip():
            raise ParseError("empty file (expected a JSON object)", path=name, line=1)
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise ParseError(
                f"invalid JSON: {error.msg}", path=name, line=error.lineno, column=error.colno
            ) from None
        return cls.from_json_dict(data, path=name)
