"""Torch's intra-op threads and the BLAS libraries' threads, set for a block of work and
restored after.

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

The same holds for the BLAS that numpy calls (OpenBLAS spins its threads after each small
product: RockSample(7, 8), 28 ms against 1.6 ms per lower-bound evaluation on 2 busy cores):
:func:`blas_threads` limits them through threadpoolctl.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import torch
from threadpoolctl import ThreadpoolController

__all__ = ["blas_threads", "torch_threads"]

#: The process's BLAS libraries as threadpoolctl found them, at the first :func:`blas_threads`
_CONTROLLER: list[ThreadpoolController] = []


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


def blas_threads(n: int) -> Any:
    """A context manager: run the block with ``n`` threads in every BLAS library loaded
    (``threadpoolctl``'s ``user_api="blas"``), then restore their counts.

    The libraries are looked up once per process, at the first call: the lookup reads the
    path of every loaded shared library (78 with torch), which ``threadpool_limits`` does
    at every call (0.8 CPU-ms each after the first, against 0.02 ms here; a tiger solve to
    precision 1e-3 takes about 100 ms). A BLAS library loaded after that call is not
    limited (the solvers call numpy's, loaded with torchhrc).

    Args:
        n: the threads, at least 1.

    Raises:
        ValueError: ``n`` below 1.

    Example:
        >>> from threadpoolctl import threadpool_info
        >>> with blas_threads(1):
        ...     all(lib["num_threads"] == 1 for lib in threadpool_info()
        ...         if lib["user_api"] == "blas")
        True
    """
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"expected n to be an int of at least 1, got {n!r}")
    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=n, user_api="blas")
