"""What a solver's ``time_limit`` counts: the wall clock, the process's CPU time, or a callable.

APPL's ``pomdpsol --timeout`` counts CPU seconds (``times(2)``: user and system), so on a
shared machine a wall-clock limit gives a solve only the share of the CPU it happens to get;
``"process"`` makes a comparison with it fair. A callable (returning seconds, rising) serves
deterministic clocks in tests.

Example:
    >>> read = clock_function("process")
    >>> read() >= 0.0
    True
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

__all__ = ["NEVER", "Clock", "Deadline", "check_clock", "clock_function"]

Clock = Literal["wall", "process"] | Callable[[], float]
"""``"wall"`` (``time.perf_counter``), ``"process"`` (``time.process_time``) or a callable."""


def check_clock(clock: object) -> None:
    """Raise ``ValueError`` unless ``clock`` is ``"wall"``, ``"process"`` or a callable.

    Example:
        >>> check_clock("wall")
    """
    if clock not in ("wall", "process") and not callable(clock):
        raise ValueError(f"expected clock 'wall', 'process' or a callable, got {clock!r}")


def clock_function(clock: Clock) -> Callable[[], float]:
    """The function that reads ``clock`` in seconds.

    Example:
        >>> clock_function("wall") is time.perf_counter
        True
    """
    check_clock(clock)
    if clock == "wall":
        return time.perf_counter
    if clock == "process":
        return time.process_time
    return clock  # type: ignore[return-value]


@dataclass(frozen=True)
class Deadline:
    """A point in time on a clock: ``at`` seconds of ``clock`` (``math.inf``: never).

    The solvers' inner loops (FIB, QMDP and blind-policy iterations) stop at a ``Deadline``,
    so a budget on the process's CPU time reaches them as it reaches the search.

    Example:
        >>> Deadline.after(60.0, "process").passed()
        False
        >>> NEVER.passed()
        False
    """

    at: float = math.inf
    clock: Callable[[], float] = field(default=time.perf_counter, compare=False)

    @classmethod
    def after(cls, seconds: float, clock: Clock = "wall") -> Deadline:
        """The deadline ``seconds`` from now on ``clock``."""
        read = clock_function(clock)
        return cls(read() + seconds, read)

    def passed(self) -> bool:
        """Whether ``clock`` has passed ``at``."""
        return self.at != math.inf and self.clock() > self.at


NEVER = Deadline()
"""The deadline that never passes."""
