"""Deprecated module path (issue 32): the hand-finishing env lives with its task, in
:mod:`torchhrc.tasks.hand_finishing.env`; this module forwards its names for one release with a
:class:`DeprecationWarning`.

Example:
    >>> import warnings
    >>> import torchhrc.envs.hand_finishing as old
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     old.HandFinishingEnv.__module__
    'torchhrc.tasks.hand_finishing.env'
"""

from __future__ import annotations

import importlib
import warnings

__all__: list[str] = []  # nothing to star-import: every name here is deprecated

_NEW = "torchhrc.tasks.hand_finishing.env"
_MOVED = ("HandFinishingEnv", "quick_hand_finishing_task")


def __getattr__(name: str) -> object:
    if name in _MOVED:
        warnings.warn(
            f"torchhrc.envs.hand_finishing.{name} is deprecated; use {_NEW}.{name}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(_NEW), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
