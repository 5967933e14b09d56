"""Tests of torchhrc._deprecation: the one helper behind every moved name's alias."""

from __future__ import annotations

import math
import types
import warnings

import pytest

from torchhrc._deprecation import moved_attribute


def _old_module() -> types.ModuleType:
    module = types.ModuleType("old.place")
    module.__getattr__ = lambda name: moved_attribute("old.place", name, {"sqrt": "math"})
    return module


def test_moved_name_warns_naming_the_new_place_at_the_caller_and_returns_the_object():
    old = _old_module()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = old.sqrt
    assert got is math.sqrt
    (warning,) = caught
    assert warning.category is DeprecationWarning
    assert str(warning.message) == "old.place.sqrt is deprecated; use math.sqrt"


def test_the_warning_points_at_the_code_that_used_the_old_name():
    import torchhrc.sim.replay as shim  # a module whose __getattr__ calls the helper

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        shim.box_moves  # noqa: B018
    assert caught[0].filename == __file__, caught[0].filename


def test_unknown_name_is_an_attribute_error():
    old = _old_module()
    with pytest.raises(AttributeError, match=r"'old\.place' has no attribute 'cbrt'"):
        old.cbrt  # noqa: B018
    assert not hasattr(old, "cbrt")
