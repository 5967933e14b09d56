"""The old module torchhrc.io._atomic (before issue 32 moved the helper to torchhrc._atomic):
its name forwards to the new place with a DeprecationWarning."""

from __future__ import annotations

import pytest


def test_old_name_warns_naming_the_new_place_and_is_the_same_object() -> None:
    import torchhrc._atomic as new
    import torchhrc.io._atomic as old

    assert sorted(old._MOVED) == ["atomic_write_bytes"]  # the old module's __all__
    with pytest.warns(DeprecationWarning, match=r"use torchhrc\._atomic\.atomic_write_bytes"):
        alias = old.atomic_write_bytes
    assert alias is new.atomic_write_bytes
