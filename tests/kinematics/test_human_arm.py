"""Tests of torchhrc.kinematics.human_arm: the anthropometric arm's URDF."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("pytorch_kinematics")

from torchhrc.kinematics import asset_path, human_arm_urdf

D = torch.float64


def test_shipped_human_arm_is_the_generator_output():
    assert asset_path("human_arm/human_arm.urdf").read_text() == human_arm_urdf()


def test_human_arm_lengths_follow_winter(human):
    # arm hanging: the palm is below the shoulder by upper arm + forearm + half a hand
    # = (0.186 + 0.146 + 0.054) H, at shoulder height 0.818 H
    pose = human.forward(torch.zeros(human.dof, dtype=D))
    H = 1.75
    assert pose[2, 3].item() == pytest.approx(
        (0.818 - 0.186 - 0.146 - 0.054) * H, abs=1e-6
    )  # the URDF has 6 digits
    assert pose[1, 3].item() == pytest.approx(-0.259 * H / 2, abs=1e-6)
