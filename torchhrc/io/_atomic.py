"""Old module path of :mod:`torchhrc._atomic` (issue 32: one atomic-write helper for every
package, at the bottom layer).

Every name here is a deprecated alias (a ``DeprecationWarning`` naming its new place); import
from :mod:`torchhrc._atomic` instead.
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute

#: Every name of this old path and the module that holds it now.
_MOVED = {"atomic_write_bytes": "torchhrc._atomic"}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED)
