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

import time
from collections.abc import Callable
from typing import Literal

__all__ = ["Clock", "check_clock", "clock_function"]

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
