"""The cyclic garbage collector paused while a file is parsed, internal."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["gc_paused"]


@contextmanager
def gc_paused() -> Iterator[None]:
    """Pause the cyclic garbage collector inside the block (restored after, as it was).

    A parse allocates many short-lived containers (the XML elements of a ``.pomdpx``), freed
    by reference counting; their count triggers full collections, each a pass over every
    object the process holds (torch's included): 70 ms of a 110 ms read of APPL's
    ``TagAvoid.pomdpx``. Nothing the parse builds forms a cycle that needs the collector.

    Example:
        >>> import gc
        >>> with gc_paused():
        ...     inside = gc.isenabled()
        >>> inside, gc.isenabled()
        (False, True)
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
