"""Torch's intra-op threads, set for a block of work and restored after.

Sequential work on small tensors (a SARSOP search on the CPU, the paper's study) gains nothing
from torch's OpenMP threads: each parallel region wakes them for microseconds of arithmetic,
and they spin-wait after it. On a 2-core machine that spin is CPU time the process pays, so a
solve limited in CPU seconds (``SARSOPConfig(clock="process")``, APPL's measure) made a third
fewer backups with 2 threads than with 1 (bridge-repair, 10 CPU-s: 115,404 against 172,748),
and under a wall-clock limit the same backups (within 3 % on five suite problems) for 6-40 %
more CPU (``docs/benchmarks.md``, "Torch's threads during a solve").

Example:
    >>> import torch
    >>> before = torch.get_num_threads()
    >>> with torch_threads(1):
    ...     torch.get_num_threads()
    1
    >>> torch.get_num_threads() == before
    True
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

__all__ = ["torch_threads"]


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch intra-op threads, then restore the previous count.

    The count is the process's (``torch.set_num_threads``): work that other Python threads do
    in torch meanwhile runs with ``n`` too.

    Args:
        n: the threads, at least 1.

    Raises:
        ValueError: ``n`` below 1.
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"expected n to be an int of at least 1, got {n!r}")
    before = torch.get_num_threads()
    if before == n:
        yield
        return
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)
