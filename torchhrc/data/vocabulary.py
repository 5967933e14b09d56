"""The symbols of joint-action demonstrations: the two :data:`ACTORS`, a :data:`Step`
``(actor, action)``, and the checks and canonical order of a vocabulary of steps."""

from __future__ import annotations

from collections.abc import Iterable

from torchhrc.errors import ModelError

__all__ = ["ACTORS", "Step"]

#: The two actors of a joint-action demonstration, in vocabulary order.
ACTORS: tuple[str, str] = ("human", "robot")

#: One step of a demonstration: ``(actor, action)``.
Step = tuple[str, str]


def _sorted_vocabulary(symbols: Iterable[Step]) -> tuple[Step, ...]:
    """Canonical order: human symbols first, then robot; action names sorted."""
    return tuple(sorted(set(symbols), key=lambda s: (ACTORS.index(s[0]), s[1])))


def _check_vocabulary(vocabulary: object) -> tuple[Step, ...]:
    if isinstance(vocabulary, (str, bytes)) or not isinstance(vocabulary, Iterable):
        raise TypeError(
            f"expected vocabulary to be a sequence of (actor, action) pairs, "
            f"got {type(vocabulary).__name__}"
        )
    vocab: list[Step] = []
    for i, entry in enumerate(vocabulary):
        if (
            not isinstance(entry, (tuple, list))
            or len(entry) != 2
            or not all(isinstance(part, str) for part in entry)
        ):
            raise TypeError(
                f"expected vocabulary[{i}] to be an (actor, action) pair, got {entry!r}"
            )
        actor, action = entry
        if actor not in ACTORS:
            raise ModelError(
                f"vocabulary[{i}] has actor {actor!r}, expected one of {', '.join(ACTORS)}"
            )
        if not action:
            raise ModelError(f"vocabulary[{i}] has an empty action name")
        vocab.append((actor, action))
    seen: dict[Step, int] = {}
    for i, symbol in enumerate(vocab):
        if symbol in seen:
            raise ModelError(
                f"vocabulary[{i}] = {symbol!r} repeats vocabulary[{seen[symbol]}]; "
                "symbols must be distinct"
            )
        seen[symbol] = i
    return tuple(vocab)


def _check_strings(name: str, values: object, size: int) -> tuple[str, ...]:
    if isinstance(values, (str, bytes)) or not isinstance(values, Iterable):
        raise TypeError(f"expected {name} to be a sequence of strings, got {type(values).__name__}")
    out = tuple(values)
    if len(out) != size:
        raise ModelError(f"expected {name} to have one entry per sequence ({size}), got {len(out)}")
    for i, value in enumerate(out):
        if not isinstance(value, str):
            raise TypeError(f"expected {name}[{i}] to be a string, got {type(value).__name__}")
        if not value:
            raise ModelError(f"{name}[{i}] is an empty string")
    return out
