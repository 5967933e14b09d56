"""Returning a long solve's freed heap memory to the operating system (internal).

glibc's ``malloc`` keeps freed blocks for reuse, and a heap of many small long-lived blocks
(a SARSOP solve's per-belief caches) among large short-lived ones (a pruning's score blocks)
keeps growing: freed memory that lies between live blocks is never handed back. On Hallway2
(60 CPU-s) the resident memory rose to 351 MB against about 250 MB of interpreter, libraries
and live data; returning the free pages after each pruning (``malloc_trim(0)``, which also
releases whole free pages inside the heap) kept the peak at 326 MB, for about 1 ms a pruning.

Elsewhere (another C library, or none found) :func:`release_free_memory` does nothing.

A solve's memory limit (``SARSOPConfig(memory_limit=...)``, ``PBVIConfig(memory_limit=...)``,
``torchhrc solve --memory MB``) is enforced by a :class:`MemoryGuard`: the process's resident
memory read from ``/proc/self/statm`` (one ``pread``, about 1 us; its file-backed pages counted
at no less than at the guard's start, as evicted ones come back), checked wherever the solver
checks its clock, against the limit less what the next steps are expected to add: the largest
growth seen between two checks, the largest short-lived peak seen above the resident memory
(from the process's own peak: ``getrusage``'s, or ``VmHWM`` where that one is carried over
from the program that started this one), and what the caller knows is coming (the copy a
doubling of the belief tree or the alpha set makes, the final policy's copy of the alpha
vectors).
"""

from __future__ import annotations

import ctypes
import os
import resource
import sys
import time
from collections.abc import Callable
from typing import Any

__all__: list[str] = []

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096

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


_MADVISE: Any = None  # libc's madvise once looked up; False where there is none
_MADV_DONTNEED = 4  # Linux's value (the only system where it is used)


def release_pages(array: Any, start: int) -> int:
    """Drop the resident pages of ``array``'s buffer from byte ``start`` to its end (the whole
    pages in that range; Linux ``madvise(MADV_DONTNEED)``), returning how many bytes were
    released (0 where nothing was, or on another system).

    The contents there are lost: a page reads back as zeros when it is next touched. For the
    unused tail of a store that grows by capacity and shrinks in place (the alpha vectors
    after a pruning): the rows past its size are written before they are read, so their pages
    need not stay resident until then.

    Args:
        array: a C-contiguous numpy array that owns its memory (or a view of one).
        start: the first byte of ``array`` whose page may go (rounded up to a page).

    Example:
        >>> import numpy as np
        >>> a = np.ones(1 << 16)
        >>> release_pages(a, a.nbytes) == 0
        True
    """
    global _MADVISE
    if _MADVISE is None:
        _MADVISE = False
        if sys.platform.startswith("linux"):
            fn = getattr(ctypes.CDLL(None), "madvise", None)
            if fn is not None:
                fn.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
                fn.restype = ctypes.c_int
                _MADVISE = fn
    if _MADVISE is False or not array.flags.c_contiguous:
        return 0
    base = int(array.ctypes.data)
    lo = -(-(base + max(int(start), 0)) // _PAGE) * _PAGE  # the first whole page
    hi = (base + int(array.nbytes)) // _PAGE * _PAGE  # past the last whole page
    if hi <= lo or _MADVISE(lo, hi - lo, _MADV_DONTNEED) != 0:
        return 0
    return hi - lo


def check_memory_limit(limit: object, name: str = "memory_limit", *, reserve: object = 0.0,
                       ) -> None:  # fmt: skip
    """Raise ``ValueError`` unless ``limit`` is ``None`` or a positive finite number of bytes
    and ``reserve`` (``memory_reserve``) a non-negative finite number.

    Example:
        >>> check_memory_limit(2**30, reserve=1.5)
    """
    if (
        not isinstance(reserve, (int, float))
        or isinstance(reserve, bool)
        or not 0 <= reserve < float("inf")
    ):
        raise ValueError(f"expected memory_reserve to be a non-negative number, got {reserve!r}")
    if limit is None:
        return
    if (
        not isinstance(limit, (int, float))
        or isinstance(limit, bool)
        or not 0 < limit < float("inf")
    ):
        raise ValueError(f"expected {name} to be None or a positive number of bytes, got {limit!r}")


def check_checkpoint(interval: object, checkpoint: object) -> None:
    """Raise ``ValueError`` unless ``policy_interval`` (positive finite seconds) and the
    ``checkpoint`` callable are given together or not at all (the solvers' configs).

    Example:
        >>> check_checkpoint(None, None)
    """
    if (interval is None) != (checkpoint is None):
        given, missing = ("policy_interval", "checkpoint") if checkpoint is None else (
            "checkpoint", "policy_interval")  # fmt: skip
        raise ValueError(f"{given} was given without {missing}")
    if interval is None:
        return
    if (
        not isinstance(interval, (int, float))
        or isinstance(interval, bool)
        or not 0 < interval < float("inf")
    ):
        raise ValueError(f"expected policy_interval to be a positive number of seconds, "
                         f"got {interval!r}")  # fmt: skip
    if not callable(checkpoint):
        raise TypeError(f"expected checkpoint to be callable, got {type(checkpoint).__name__}")


_PROC: dict[str, int] = {}  # open descriptors of /proc/self files; -1 where there is none


def _forget_proc() -> None:
    """In a child made by ``fork``: the descriptors name the parent's ``/proc/<pid>`` files
    (``/proc/self`` was resolved when they were opened), so close them; the child opens its
    own on its next read. The carried peak is measured again too."""
    global _INHERITED_PEAK
    for fd in _PROC.values():
        if fd >= 0:
            try:
                os.close(fd)
            except OSError:
                pass
    _PROC.clear()
    _INHERITED_PEAK = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_proc)


def _read_proc(name: str, size: int) -> bytes | None:
    """The first ``size`` bytes of ``/proc/self/<name>`` (one ``pread`` on a descriptor kept
    open), ``None`` where it cannot be read."""
    fd = _PROC.get(name)
    if fd is None:
        try:
            fd = os.open(f"/proc/self/{name}", os.O_RDONLY)
        except OSError:
            fd = -1
        _PROC[name] = fd
    if fd < 0:
        return None
    try:
        return os.pread(fd, size, 0)
    except OSError:
        return None


def _statm_bytes() -> tuple[int, int] | None:
    """``/proc/self/statm``'s resident and file-backed (or shared) memory in bytes, from one
    read, ``None`` where unknown."""
    text = _read_proc("statm", 128)
    if text is None:
        return None
    fields = text.split()
    try:
        return int(fields[1]) * _PAGE, int(fields[2]) * _PAGE
    except (IndexError, ValueError):
        return None


def resident_bytes() -> int | None:
    """The process's resident memory in bytes (``/proc/self/statm``), ``None`` where unknown.

    Example:
        >>> r = resident_bytes()
        >>> r is None or r > 0
        True
    """
    both = _statm_bytes()
    return None if both is None else both[0]


def shared_resident_bytes() -> int | None:
    """The part of :func:`resident_bytes` backed by files or shared memory (the libraries'
    code and data mapped from disk: ``RssFile + RssShmem``, ``/proc/self/statm``'s third
    field), ``None`` where unknown. The kernel may evict these pages under memory pressure
    (without swap they are the only ones it can), and a process refaults them as it runs.

    Example:
        >>> shared, rss = shared_resident_bytes(), resident_bytes()
        >>> shared is None or 0 <= shared <= rss
        True
    """
    both = _statm_bytes()
    return None if both is None else both[1]


_INHERITED_PEAK: int | None = None  # ru_maxrss (bytes) carried over exec; 0: none was


def _own_peak_bytes() -> int | None:
    """``VmHWM`` of ``/proc/self/status``: the peak resident memory of this process's own
    address space (since its ``exec``), ``None`` where unknown."""
    text = _read_proc("status", 8192)
    if text is None:
        return None
    try:
        at = text.index(b"\nVmHWM:") + 7
        return int(text[at : text.index(b"kB", at)]) * 1024
    except ValueError:
        return None


def peak_resident_bytes() -> int:
    """The process's own peak resident memory in bytes so far.

    ``getrusage``'s ``ru_maxrss`` (one system call, about 1 us) is that peak unless the
    process was started by a larger one: Linux carries the peak of the address space an
    ``exec`` replaces over to the new program, and ``subprocess`` starts a child through
    ``vfork`` (or ``posix_spawn``), so a child of a pytest run that once held 1.1 GB read
    1.1 GB as its peak from its start. Where ``ru_maxrss`` is above the process's own peak
    (``VmHWM`` of ``/proc/self/status``, a few us to read) at the first call, that own peak
    is read instead until it passes the carried one.

    Example:
        >>> peak_resident_bytes() > 0
        True
    """
    global _INHERITED_PEAK
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak = int(peak) if sys.platform == "darwin" else int(peak) * 1024  # macOS: bytes
    if _INHERITED_PEAK is None:
        own = _own_peak_bytes()
        _INHERITED_PEAK = peak if own is not None and peak > own else 0
    if peak > _INHERITED_PEAK:  # the process's own peak (ru_maxrss is the larger of the two)
        return peak
    own = _own_peak_bytes()
    return peak if own is None else own


class MemoryGuard:
    """Says when a solve should stop so that its resident memory stays below ``limit`` bytes.

    :meth:`exceeded` reads the resident memory ``rss`` and answers whether
    ``rss + pending + margin >= limit``, where ``pending`` is the caller's estimate of what
    it is about to allocate and ``margin`` what the guard has learned: the largest growth
    between two of its checks, and the largest short-lived peak above the resident memory of
    the check before (a pruning's or an expansion's temporaries, seen through the process's
    own peak, :func:`peak_resident_bytes`). Once it has answered ``True`` it keeps answering
    ``True``. Where the resident memory cannot be read (no ``/proc``), it never stops a solve.

    ``rss`` counts the file-backed pages (:func:`shared_resident_bytes`: the libraries' code
    and data) at no less than at the guard's start: under memory pressure the kernel evicts
    them, and a reading then falls by up to their size (about 100 MB with torch) while the
    memory the solve holds does not; the process refaults them as it runs, so a limit
    checked against the lower reading would be passed by that much.

    Args:
        limit: bytes of resident memory (the whole process: interpreter, libraries, model).
        min_interval: seconds between two readings of the process's memory; a check sooner
            compares the last reading (plus ``pending`` and the margin) with the limit, with
            no system call (SARSOP checks at every step of a trial: reading at each cost
            RockSample(4, 4) 14 % of its time, at most every millisecond about 1 %; what a
            millisecond's work adds is in the margin, as the growth between two readings).

    Example:
        >>> MemoryGuard(1 << 50).exceeded(), MemoryGuard(1).exceeded()
        (False, True)
    """

    def __init__(self, limit: float, *, min_interval: float = 0.0) -> None:
        self.limit = float(limit)
        self.min_interval = float(min_interval)
        self._next = 0.0  # when the next reading is due (time.perf_counter)
        self._pending = 0  # the pending bytes of the last check
        both = _statm_bytes()
        self.enabled = both is not None
        rss, shared = both if both is not None else (0, 0)
        self._shared = shared  # the file-backed pages at the start, counted at no less
        self._read = rss  # the resident memory read at the last check
        self._rss = self._read  # ... and as counted (file-backed pages at no less than above)
        self._peak = peak_resident_bytes()
        self._step = 0  # the largest growth between two checks
        self._transient = 0  # the largest peak above the resident memory of the check before
        self.tripped = False
        self.last = self._rss  # the resident memory counted at the last check

    @property
    def margin(self) -> int:
        """Bytes kept free below the limit for what the next steps add."""
        return max(2 * self._step, self._transient)

    def exceeded(self, pending: int | Callable[[], int] = 0) -> bool:
        """Whether the resident memory plus ``pending`` bytes and the margin reach the limit
        (``pending`` a callable: evaluated at a reading only, its last value between)."""
        if self.tripped:
            return True
        if not self.enabled:
            return False
        if self.min_interval > 0:
            now = time.perf_counter()
            if now < self._next:  # the last reading
                if not callable(pending):
                    self._pending = pending
                if self._rss + self._pending + self.margin >= self.limit:
                    self.tripped = True
                return self.tripped
            self._next = now + self.min_interval
        pending = self._pending = pending() if callable(pending) else pending
        both, rss = _statm_bytes(), self._rss
        if both is None:
            read = self._read
        else:  # evicted file-backed pages count as held: the process will fault them back
            read, shared = both
            rss = read + max(0, self._shared - shared)
        peak = peak_resident_bytes()
        if peak > self._peak:  # a new peak since the last check: how far above it went
            self._transient = max(self._transient, peak - self._read)
            self._peak = peak
        self._step = max(self._step, rss - self._rss)
        self._read, self._rss, self.last = read, rss, rss
        if rss + pending + self.margin >= self.limit:
            self.tripped = True
        return self.tripped
