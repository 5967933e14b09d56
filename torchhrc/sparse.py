"""Old module path of :mod:`torchhrc.pomdp.sparse` (issue 32: the models package).

This module re-exports its names for one release.
"""

from __future__ import annotations

from torchhrc.pomdp.sparse import (
    MAX_DENSE_ENTRIES,
    SparsePOMDP,
    check_dense_size,
    coalesce,
)

__all__ = [
    "MAX_DENSE_ENTRIES",
    "SparsePOMDP",
    "check_dense_size",
    "coalesce",
]
