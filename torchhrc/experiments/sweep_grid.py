"""A sweep's grid: its parameters (:class:`SweepParameter`, parsed and checked by name), its
jobs (:class:`Job`: one cell and one seed), seeds and the flattening of a job's metrics into
one row (:func:`flatten_scalars`). The lowest layer of the sweep modules
(:mod:`torchhrc.experiments.sweep` re-exports every public name).

Example:
    >>> parse_seeds("0-2,5")
    (0, 1, 2, 5)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from torchhrc.errors import ModelError


@dataclass(frozen=True)
class SweepParameter:
    """A parameter a sweep may vary.

    Attributes:
        kind: ``int`` or ``float``: the type its values are parsed as.
        low, high: inclusive range of valid values (``None``: unbounded).
        help: what it sets in the study.
        choices: the values a ``str`` parameter may take (``None``: any).
    """

    kind: type
    low: float | None
    high: float | None
    help: str
    choices: tuple[str, ...] | None = None

    def parse(self, name: str, text: Any) -> Value:
        """Parse one value (a string, or a Python value given to :func:`sweep`); raise
        :class:`ModelError` naming ``name`` when it is invalid."""
        value: Value
        try:
            if self.kind is bool:
                value = _parse_bool(text)
            elif self.kind is int and not isinstance(text, str):
                if isinstance(text, bool) or float(text) != int(text):
                    raise ValueError
                value = int(text)
            elif self.kind is str:
                if not isinstance(text, str):
                    raise ValueError
                value = text
            else:
                if isinstance(text, bool):
                    raise ValueError
                value = self.kind(text)
        except (TypeError, ValueError):
            raise ModelError(
                f"expected --param {name} values of type {self.kind.__name__}, got {text!r}"
            ) from None
        if self.choices is not None and value not in self.choices:
            raise ModelError(
                f"expected --param {name} values in {{{', '.join(self.choices)}}}, got {value!r}"
            )
        if isinstance(value, float) and not math.isfinite(value):
            raise ModelError(f"expected a finite --param {name} value, got {text!r}")
        if (self.low is not None and value < self.low) or (
            self.high is not None and value > self.high
        ):
            raise ModelError(
                f"expected --param {name} values in [{self.low}, {self.high}], got {value}"
            )
        return value


#: A swept value: parsed by the parameter's kind.
Value = int | float | str | bool


def _parse_bool(text: Any) -> bool:
    if isinstance(text, bool):
        return text
    word = str(text).strip().lower()
    if word in ("true", "1", "yes"):
        return True
    if word in ("false", "0", "no"):
        return False
    raise ValueError(text)


def _infer(text: Any) -> Value:
    """A value of a parameter without a declared type: int, then float, else the string."""
    if not isinstance(text, str):
        return text
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


#: Task -> parameter name -> :class:`SweepParameter`: the names ``--param`` accepts.
PARAMETERS: dict[str, dict[str, SweepParameter]] = {
    "place-and-drill": {
        "subjects": SweepParameter(int, 2, None, "simulated subjects (half per type)"),
        "noise": SweepParameter(
            float, 0.0, 1.0, "demonstration noise: per-step deviation rate of every subject"
        ),
        "runs": SweepParameter(int, 1, None, "simulated executions per subject and epsilon"),
        "demos": SweepParameter(int, 1, None, "demonstrations per subject"),
    },
    "hand-finishing": {
        "noise": SweepParameter(float, 0.001, 2.0, "hand-position noise (m, per axis)"),
        "subjects": SweepParameter(int, 2, None, "demonstrating subjects (half per side)"),
        "episodes": SweepParameter(int, 2, None, "closed-loop episodes (half per type)"),
    },
}


#: Columns that measure time: they differ between runs of the same job.
TIMING_COLUMNS: tuple[str, ...] = ("wall_s",)


_TIMING_MARKERS = ("time", "speedup", "seconds", "wall")


def is_timing_column(name: str) -> bool:
    """True for a column that measures time (excluded when comparing results)."""
    return name in TIMING_COLUMNS or any(m in name for m in _TIMING_MARKERS)


def parse_seeds(text: str) -> tuple[int, ...]:
    """Parse ``"0-4"``, ``"3"`` or ``"0,2,5"`` (ranges and lists mixed) into sorted seeds.

    Example:
        >>> parse_seeds("0-2,5")
        (0, 1, 2, 5)
    """
    seeds: set[int] = set()
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part[1:]:
                lo, hi = part.split("-", 1) if not part.startswith("-") else (part, "")
                a, b = int(lo), int(hi)
                if b < a:
                    raise ValueError
                seeds.update(range(a, b + 1))
            else:
                seeds.add(int(part))
        except ValueError:
            raise ModelError(
                f"expected --seeds as 'A-B' or 'A,B,...' of non-negative integers, got {text!r}"
            ) from None
    if not seeds or min(seeds) < 0:
        raise ModelError(f"expected non-negative --seeds, got {text!r}")
    return tuple(sorted(seeds))


@dataclass(frozen=True)
class Job:
    """One grid cell and one seed.

    Attributes:
        params: ``((name, value), ...)`` in the sweep's parameter order.
        seed: the seed of the job's study.
    """

    params: tuple[tuple[str, Value], ...]
    seed: int

    @property
    def key(self) -> str:
        """A stable identifier, e.g. ``"noise=0.1,subjects=6|seed=2"``."""
        cell = ",".join(f"{k}={v!r}" for k, v in self.params)
        return f"{cell}|seed={self.seed}"


def flatten_scalars(data: Mapping[str, Any], prefix: str = "") -> dict[str, float | int | bool]:
    """Every number of a nested ``metrics.json``-like mapping, keyed ``a.b`` / ``a.b.0``.

    Dicts are walked, lists of numbers are indexed and averaged (``.mean``); strings, ``None``
    and lists of records (e.g. per-fold tables) are left out: a sweep aggregates numbers.

    Example:
        >>> flatten_scalars({"k": 2, "reward": {"learned": [1.0, 2.5]}, "name": "x"})
        {'k': 2, 'reward.learned.0': 1.0, 'reward.learned.1': 2.5, 'reward.learned.mean': 1.75}
    """
    out: dict[str, float | int | bool] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten_scalars(value, prefix=f"{name}."))
        elif isinstance(value, (list, tuple)):
            if value and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
            ):
                out.update({f"{name}.{i}": v for i, v in enumerate(value)})
                out[f"{name}.mean"] = sum(value) / len(value)
        elif isinstance(value, (int, float)) and value is not None:
            if isinstance(value, float) and not math.isfinite(value):
                continue
            out[name] = value
    return out


def _columns(rows: Iterable[Mapping[str, Any]], first: Sequence[str]) -> list[str]:
    columns = list(first)
    seen = set(columns)
    for row in rows:
        for key in row:
            if key not in seen:
                seen.add(key)
                columns.append(key)
    if "wall_s" in seen:  # the timing column last
        columns.remove("wall_s")
        columns.append("wall_s")
    return columns
