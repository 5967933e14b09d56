"""Tests of torchhrc.kinematics.poses: pose vectors and matrices."""

from __future__ import annotations

import math

import torch

from torchhrc.kinematics import matrix_to_pose, pose_to_matrix

D = torch.float64


def test_pose_conversions_round_trip():
    gen = torch.Generator().manual_seed(4)
    pose = torch.randn(20, 7, generator=gen, dtype=D)
    pose[:, 3:] = pose[:, 3:] / pose[:, 3:].norm(dim=-1, keepdim=True)
    pose[:, 3:] = torch.where(pose[:, 3:4] < 0, -pose[:, 3:], pose[:, 3:])
    mats = pose_to_matrix(pose)
    rot = mats[:, :3, :3]
    assert torch.allclose(
        rot @ rot.transpose(-1, -2), torch.eye(3, dtype=D).expand(20, 3, 3), atol=1e-12
    )
    assert torch.allclose(matrix_to_pose(mats), pose, atol=1e-12)
    # worked by hand: 90 deg about z
    q = torch.tensor(
        [0.0, 0.0, 0.0, math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)], dtype=D
    )
    expected = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=D)
    assert torch.allclose(pose_to_matrix(q)[:3, :3], expected, atol=1e-15)
