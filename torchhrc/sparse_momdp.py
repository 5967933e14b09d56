"""Old module path of :mod:`torchhrc.pomdp.sparse_momdp` (issue 32: the models package).

This module re-exports its names for one release.
"""

from __future__ import annotations

from torchhrc.pomdp.sparse_momdp import (
    SparseMOMDP,
)

__all__ = [
    "SparseMOMDP",
]
