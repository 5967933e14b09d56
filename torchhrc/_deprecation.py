"""Deprecated aliases of names that moved (issue 32): one helper for every module's
``__getattr__``.

A module whose names moved keeps a table ``{name: new module}`` and forwards to it::

    _MOVED = {"BoxGeometry": "torchhrc.tasks.hand_finishing.geometry"}

    def __getattr__(name: str) -> object:
        return moved_attribute(__name__, name, _MOVED)

The new module is imported only when an old name is used (by its dotted path, so the old
module does not import it), with a ``DeprecationWarning`` naming the new place.

Example:
    >>> import warnings
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     f = moved_attribute("old.place", "sqrt", {"sqrt": "math"})
    >>> f(4.0), str(caught[0].message)
    (2.0, 'old.place.sqrt is deprecated; use math.sqrt')
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Mapping

__all__ = ["moved_attribute"]


def moved_attribute(module: str, name: str, moved: Mapping[str, str]) -> object:
    """``name`` from the module that holds it now (``moved[name]``), with a
    ``DeprecationWarning`` naming that place.

    Args:
        module: the old module's ``__name__``.
        name: the attribute asked for.
        moved: ``{name: the dotted path of the module that holds it now}``.

    Raises:
        AttributeError: ``name`` is not in ``moved`` (the module has no such attribute).
    """
    if name not in moved:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    new = moved[name]
    # stacklevel 3: the warning points at the code that used the old name, past __getattr__
    warnings.warn(
        f"{module}.{name} is deprecated; use {new}.{name}", DeprecationWarning, stacklevel=3
    )
    return getattr(importlib.import_module(new), name)
