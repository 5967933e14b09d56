"""The memory budget of a file reader (internal): refuse up front what would not fit.

A ``.pomdp`` or ``.pomdpx`` file declares its sizes before its tables, and a short file can
declare a huge model: ``states: 200000000`` with ``T: * : * : * 0.0`` took 46 s and 7 GB
before failing with ``MemoryError``. The readers estimate, from the declared sizes and
before allocating, the bytes each form would take (a dense table's cells, a sparse table's
coordinate lists at their peak), and raise a :class:`~torchhrc.errors.ParseError` naming the
cells, the bytes and the budget when they exceed it. The budget is the reader's
``memory_budget=`` (bytes), by default the machine's available memory (``MemAvailable`` of
``/proc/meminfo``; no limit where it cannot be read).

Example:
    >>> resolve_budget(2**30)
    1073741824.0
    >>> format_bytes(3.5 * 2**30)
    '3.5 GiB'
"""

from __future__ import annotations

import math

from torchhrc.errors import ParseError

__all__ = ["available_memory", "check_budget", "format_bytes", "resolve_budget"]


def available_memory() -> int | None:
    """The machine's available memory in bytes (``MemAvailable``), ``None`` where unknown.

    Example:
        >>> m = available_memory()
        >>> m is None or m > 0
        True
    """
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def resolve_budget(memory_budget: float | None) -> float:
    """``memory_budget`` checked (a positive number of bytes, ``math.inf`` for none), or the
    machine's available memory when ``None`` (``math.inf`` where it is unknown).

    Example:
        >>> resolve_budget(math.inf)
        inf
    """
    if memory_budget is None:
        available = available_memory()
        return math.inf if available is None else float(available)
    if (
        not isinstance(memory_budget, (int, float))
        or isinstance(memory_budget, bool)
        or not memory_budget > 0
    ):
        raise ValueError(
            "expected memory_budget to be None or a positive number of bytes, "
            f"got {memory_budget!r}"
        )
    return float(memory_budget)


def format_bytes(n: float) -> str:
    """``n`` bytes in binary units, 2 significant digits at least (``'1.6 GiB'``).

    Example:
        >>> format_bytes(1536)
        '1.5 KiB'
    """
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"  # pragma: no cover


def check_budget(need: float, budget: float, what: str, *, path: str,
                 line: int | None = None, column: int | None = None) -> None:  # fmt: skip
    """Raise :class:`ParseError` when ``need`` bytes exceed ``budget``.

    ``what`` says what would be allocated (the cells and the form); the message adds the
    bytes and the budget.

    Example:
        >>> check_budget(10, 100, "10 cells", path="m.pomdp")
        >>> try:
        ...     check_budget(8e9, 2**30, "1e+09 cells of T", path="m.pomdp")
        ... except ParseError as e:
        ...     print(str(e)[:79])
        m.pomdp: 1e+09 cells of T would take about 7.45 GiB (8e+09 bytes), more than th
    """
    if need <= budget:
        return
    raise ParseError(
        f"{what} would take about {format_bytes(need)} ({need:.3g} bytes), more than the "
        f"memory budget of {format_bytes(budget)} ({budget:.0f} bytes); pass a larger "
        "memory_budget (torchhrc solve --memory MB) if the machine has it",
        path=path,
        line=line,
        column=column,
    )
