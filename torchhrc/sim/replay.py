"""Deprecated module path (issue 32): the replay of box moves lives with the hand-finishing task,
in :mod:`torchhrc.tasks.hand_finishing.replay`; this module forwards its names for one release
with a :class:`DeprecationWarning`.

Example:
    >>> import warnings
    >>> import torchhrc.sim.replay as old
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     old.replay_box_moves.__module__
    'torchhrc.tasks.hand_finishing.replay'
"""

from __future__ import annotations

import importlib
import warnings

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_NEW = "torchhrc.tasks.hand_finishing.replay"
_MOVED = ("ReplayResult", "box_moves", "replay_box_moves")


def __getattr__(name: str) -> object:
    if name in _MOVED:
        warnings.warn(
            f"torchhrc.sim.replay.{name} is deprecated; use {_NEW}.{name}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(_NEW), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
