"""The CSV and JSON forms of :class:`~torchhrc.data.Demonstrations`: their columns and
version, the strict one-pass CSV parser and the JSON reader."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from typing import Any

from torchhrc.data.vocabulary import ACTORS, Step, _check_vocabulary
from torchhrc.errors import ModelError, ParseError

__all__ = ["CSV_COLUMNS"]

#: Required CSV columns, in the order :meth:`~torchhrc.data.Demonstrations.write_csv` writes
#: them.
CSV_COLUMNS: tuple[str, ...] = ("subject", "sequence", "step", "actor", "action")
_TYPE_COLUMN = "type"
_JSON_FORMAT = "torchhrc.demonstrations"
_JSON_VERSION = 1


def _from_json_dict(cls: Any, data: Mapping[str, Any], path: str) -> Any:
    """The JSON reader behind :meth:`~torchhrc.data.Demonstrations.from_json_dict` (``cls``: that
    class, not imported here; errors name ``path`` and the JSON location)."""

    def fail(where: str, reason: str) -> ParseError:
        return ParseError(f"{where}: {reason}", path=path)

    if not isinstance(data, Mapping):
        raise fail("$", f"expected a JSON object, got {type(data).__name__}")
    if data.get("format") != _JSON_FORMAT:
        raise fail("$.format", f"expected {_JSON_FORMAT!r}, got {data.get('format')!r}")
    if data.get("version") != _JSON_VERSION:
        raise fail("$.version", f"expected {_JSON_VERSION}, got {data.get('version')!r}")
    unknown = sorted(set(data) - {"format", "version", "vocabulary", "sequences"})
    if unknown:
        raise fail("$", f"unknown keys {unknown}")
    raw_vocab = data.get("vocabulary")
    if not isinstance(raw_vocab, list):
        raise fail("$.vocabulary", "expected a list of [actor, action] pairs")
    try:
        vocab = _check_vocabulary([tuple(v) if isinstance(v, list) else v for v in raw_vocab])
    except (TypeError, ModelError) as error:
        raise fail("$.vocabulary", str(error)) from None
    records = data.get("sequences")
    if not isinstance(records, list):
        raise fail("$.sequences", "expected a list of sequence records")
    seqs: list[list[Step]] = []
    subjects, ids, types = [], [], []
    has_types = bool(records) and isinstance(records[0], Mapping) and "type" in records[0]
    vocab_set = set(vocab)
    for i, record in enumerate(records):
        where = f"$.sequences[{i}]"
        if not isinstance(record, Mapping):
            raise fail(where, "expected an object")
        allowed = {"subject", "sequence", "steps"} | ({"type"} if has_types else set())
        extra = sorted(set(record) - allowed)
        if extra:
            if "type" in extra:
                reason = "type labels must be given for all sequences or none"
            else:
                reason = f"unknown keys {extra}"
            raise fail(where, reason)
        for key in sorted(allowed):
            if key not in record:
                raise fail(where, f"missing key {key!r}")
        for key in ("subject", "sequence") + (("type",) if has_types else ()):
            if not isinstance(record[key], str) or not record[key]:
                raise fail(f"{where}.{key}", f"expected a non-empty string, got {record[key]!r}")
        steps = record["steps"]
        if not isinstance(steps, list):
            raise fail(f"{where}.steps", "expected a list of [actor, action] pairs")
        parsed: list[Step] = []
        for t, step in enumerate(steps):
            if (
                not isinstance(step, list)
                or len(step) != 2
                or not all(isinstance(part, str) for part in step)
            ):
                raise fail(f"{where}.steps[{t}]", f"expected [actor, action], got {step!r}")
            if step[0] not in ACTORS:
                raise fail(
                    f"{where}.steps[{t}]",
                    f"unknown actor {step[0]!r} (expected one of {', '.join(ACTORS)})",
                )
            if (step[0], step[1]) not in vocab_set:
                raise fail(f"{where}.steps[{t}]", f"symbol {step!r} is not in the vocabulary")
            parsed.append((step[0], step[1]))
        if len(parsed) < 2:
            raise fail(f"{where}.steps", f"{len(parsed)} step(s), expected at least 2")
        seqs.append(parsed)
        subjects.append(record["subject"])
        ids.append(record["sequence"])
        if has_types:
            types.append(record["type"])
    try:
        return cls.from_lists(
            seqs,
            subjects=subjects,
            sequence_ids=ids,
            types=types if has_types else None,
            vocabulary=vocab,
        )
    except ModelError as error:
        raise fail("$.sequences", str(error)) from None


def _read_text(path: str, *, encoding: str) -> str:
    """The file's text; undecodable bytes are a :class:`ParseError` naming the line."""
    with open(path, "rb") as handle:
        raw = handle.read()
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        raise ParseError(
            f"not {encoding.split('-sig')[0].upper()} text (byte {error.start})",
            path=path,
            line=line,
        ) from None


class _SafeReader:
    """A ``csv.reader`` whose ``csv.Error`` (e.g. a NUL byte) becomes a ParseError."""

    def __init__(self, reader: Any, path: str) -> None:
        self._reader = reader
        self._path = path

    @property
    def line_num(self) -> int:
        return self._reader.line_num

    def __iter__(self) -> _SafeReader:
        return self

    def __next__(self) -> list[str]:
        try:
            return next(self._reader)
        except csv.Error as error:
            raise ParseError(
                f"malformed CSV: {error}", path=self._path, line=self._reader.line_num + 1
            ) from None


def _parse_csv(
    cls: Any,
    text: str,
    path: str,
    vocabulary: Sequence[Step] | None,
) -> Any:
    """The CSV parser behind :meth:`~torchhrc.data.Demonstrations.read_csv` (one pass, strict;
    ``cls``: that class, not imported here)."""
    if text.startswith("\ufeff"):
        text = text[1:]
    reader = _SafeReader(csv.reader(io.StringIO(text, newline="")), path)
    header: list[str] | None = None
    header_line = 0
    for row in reader:
        if row and any(cell.strip() for cell in row):
            header = [cell.strip() for cell in row]
            header_line = reader.line_num
            break
    if header is None:
        raise ParseError(
            "empty file (expected the header subject,sequence,step,actor,action[,type])",
            path=path,
            line=1,
        )
    for j, col in enumerate(header):
        if header.index(col) != j:
            raise ParseError(
                f"column {col!r} appears twice", path=path, line=header_line, column=j + 1
            )
    allowed = set(CSV_COLUMNS) | {_TYPE_COLUMN}
    unknown = [c for c in header if c not in allowed]
    if unknown:
        raise ParseError(
            f"unknown column {unknown[0]!r} (expected subject,sequence,step,actor,action[,type])",
            path=path,
            line=header_line,
            column=header.index(unknown[0]) + 1,
        )
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise ParseError(
            f"missing column(s) {', '.join(missing)} "
            "(expected subject,sequence,step,actor,action[,type])",
            path=path,
            line=header_line,
        )
    col = {name: header.index(name) for name in header}
    has_types = _TYPE_COLUMN in col
    fixed_vocab = None if vocabulary is None else set(_check_vocabulary(vocabulary))

    seqs: list[list[Step]] = []
    subjects: list[str] = []
    ids: list[str] = []
    types: list[str] = []
    first_line: list[int] = []
    done: dict[tuple[str, str], int] = {}  # finished sequence -> its first line
    current: tuple[str, str] | None = None
    last_step = -1

    def close_current() -> None:
        if current is not None and len(seqs[-1]) < 2:
            raise ParseError(
                f"sequence {current[0]}/{current[1]} has {len(seqs[-1])} step, expected at "
                "least 2 (a sequence needs at least one transition)",
                path=path,
                line=first_line[-1],
            )

    for row in reader:
        line = reader.line_num
        if not row or not any(cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise ParseError(
                f"expected {len(header)} fields ({','.join(header)}), got {len(row)}",
                path=path,
                line=line,
            )
        cells = [cell.strip() for cell in row]
        for name, j in col.items():
            if not cells[j]:
                raise ParseError(f"empty {name!r} field", path=path, line=line, column=j + 1)
        subject, seq_id = cells[col["subject"]], cells[col["sequence"]]
        actor, action = cells[col["actor"]], cells[col["action"]]
        raw_step = cells[col["step"]]
        try:
            step = int(raw_step)
        except ValueError:
            step = -1
        if step < 0 or not raw_step.lstrip("+").isdigit():
            raise ParseError(
                f"step {raw_step!r} is not a non-negative integer",
                path=path,
                line=line,
                column=col["step"] + 1,
            )
        if actor not in ACTORS:
            raise ParseError(
                f"unknown actor {actor!r} (expected one of {', '.join(ACTORS)})",
                path=path,
                line=line,
                column=col["actor"] + 1,
            )
        if fixed_vocab is not None and (actor, action) not in fixed_vocab:
            raise ParseError(
                f"symbol {actor}:{action} is not in the given vocabulary",
                path=path,
                line=line,
                column=col["action"] + 1,
            )
        key = (subject, seq_id)
        if key != current:
            if key in done:
                raise ParseError(
                    f"rows of sequence {subject}/{seq_id} are not contiguous (it started at "
                    f"line {done[key]} and another sequence came in between)",
                    path=path,
                    line=line,
                )
            if (
                current is not None
                and seq_id == current[1]
                and subject != current[0]
                and step == last_step + 1
                and step > 0
            ):
                raise ParseError(
                    f"sequence {seq_id!r} changes subject from {current[0]!r} to {subject!r} "
                    f"at step {step}",
                    path=path,
                    line=line,
                    column=col["subject"] + 1,
                )
            close_current()
            if step != 0:
                raise ParseError(
                    f"sequence {subject}/{seq_id} starts at step {step}; missing step(s) "
                    f"0..{step - 1}",
                    path=path,
                    line=line,
                    column=col["step"] + 1,
                )
            current = key
            done[key] = line
            last_step = -1
            seqs.append([])
            subjects.append(subject)
            ids.append(seq_id)
            first_line.append(line)
            if has_types:
                types.append(cells[col[_TYPE_COLUMN]])
        if step <= last_step:
            raise ParseError(
                f"duplicate step {step} in sequence {subject}/{seq_id} "
                f"(steps must be 0, 1, ... in order)",
                path=path,
                line=line,
                column=col["step"] + 1,
            )
        if step != last_step + 1:
            gap = f"{last_step + 1}" if step == last_step + 2 else f"{last_step + 1}..{step - 1}"
            raise ParseError(
                f"missing step(s) {gap} in sequence {subject}/{seq_id} before step {step}",
                path=path,
                line=line,
                column=col["step"] + 1,
            )
        if has_types and cells[col[_TYPE_COLUMN]] != types[-1]:
            raise ParseError(
                f"type label changes within sequence {subject}/{seq_id}: "
                f"{types[-1]!r} then {cells[col[_TYPE_COLUMN]]!r}",
                path=path,
                line=line,
                column=col[_TYPE_COLUMN] + 1,
            )
        last_step = step
        seqs[-1].append((actor, action))
    close_current()
    if not seqs:
        raise ParseError(
            "no data rows after the header (expected one row per step)",
            path=path,
            line=header_line + 1,
        )
    return cls.from_lists(
        seqs,
        subjects=subjects,
        sequence_ids=ids,
        types=types if has_types else None,
        vocabulary=None if vocabulary is None else tuple(vocabulary),
    )
