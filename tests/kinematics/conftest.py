"""Shared fixtures of the kinematics tests: the shipped Panda and the default human arm."""

from __future__ import annotations

import pytest

pytest.importorskip("pytorch_kinematics")

from torchhrc.kinematics import SerialArm


@pytest.fixture(scope="module")
def panda() -> SerialArm:
    return SerialArm.panda()


@pytest.fixture(scope="module")
def human() -> SerialArm:
    return SerialArm.human_arm()
