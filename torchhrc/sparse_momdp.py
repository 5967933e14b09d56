"""Old module path of :mod:`torchhrc.pomdp.sparse_momdp` (issue 32: the models package).

This module re-exports its names for one release.

Every name here is a deprecated alias (a ``DeprecationWarning`` naming its new place); import
from :mod:`torchhrc.pomdp` instead.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

#: Every name of this old path and the module that holds it now.
_MOVED = {
    "SparseMOMDP": "torchhrc.pomdp.sparse_momdp",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
