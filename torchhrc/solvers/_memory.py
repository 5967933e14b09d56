"""Returning a long solve's freed heap memory to the operating system (internal).

glibc's ``malloc`` keeps freed blocks for reuse, and a heap of many small long-lived blocks
(a SARSOP solve's per-belief caches) among large short-lived ones (a pruning's score blocks)
keeps growing: freed memory that lies between live blocks is never handed back. On Hallway2
(60 CPU-s) the resident memory rose to 351 MB against about 250 MB of interpreter, libraries
and live data; returning the free pages after each pruning (``malloc_trim(0)``, which also
releases whole free pages inside the heap) kept the peak at 326 MB, for about 1 ms a pruning.

Elsewhere (another C library, or none found) :func:`release_free_memory` does nothing.
"""

from __future__ import annotations

import ctypes
from typing import Any

__all__: list[str] = []

_TRIM: Any = None  # the C function once looked up; False where there is none


def release_free_memory() -> bool:
    """Hand the heap's free pages back to the OS; ``True`` where glibc's ``malloc_trim`` ran.

    Example:
        >>> isinstance(release_free_memory(), bool)
        True
    """
    global _TRIM
    if _TRIM is None:
        _TRIM = False
        try:  # the symbols already loaded (libc among them): no ldconfig run to find it
            trim = getattr(ctypes.CDLL(None), "malloc_trim", None)
        except (OSError, TypeError):  # no such handle on this platform
            trim = None
        if trim is not None:
            trim.argtypes = [ctypes.c_size_t]
            trim.restype = ctypes.c_int
            _TRIM = trim
    if _TRIM is False:
        return False
    _TRIM(0)
    return True
