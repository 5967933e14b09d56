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
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

__all__ = ["NEVER", "Clock", "Deadline", "check_clock", "clock_function", "deadline_watch"]

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


def deadline_watch(clock: Clock, at: float) -> Callable[[], bool]:
    """A function telling whether ``clock`` has reached ``at``, cheap to call often.

    The wall clock and a given callable are read at every call. The process's CPU time is a
    system call (about 1 us, against 0.1 us for the wall clock: on a small model a search
    asks at every step and after every backup, about 2 % of its time); it can rise at most
    ``os.cpu_count()`` seconds per wall second, so after a reading ``c`` at wall time ``w``
    the watch answers "not yet" without reading it until the wall clock reaches
    ``w + (at - c) / os.cpu_count()``. It never answers "not yet" once the limit has
    passed: the readings thin out as the limit nears, and the answer is the CPU clock's.

    Example:
        >>> deadline_watch("process", math.inf)()
        False
        >>> deadline_watch(lambda: 5.0, 4.0)()
        True
    """
    read = clock_function(clock)
    if clock != "process":
        return lambda: read() >= at
    cpus = max(1, os.cpu_count() or 1)
    wall = time.perf_counter
    quiet_until = [-math.inf]  # the wall time before which the CPU time cannot reach ``at``

    def passed() -> bool:
        if wall() < quiet_until[0]:
            return False
        now = read()
        if now >= at:
            return True
        quiet_until[0] = wall() + (at - now) / cpus
        return False

    return passed


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
