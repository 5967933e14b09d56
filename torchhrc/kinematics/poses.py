"""Rigid poses: ``(..., 7)`` vectors ``(x, y, z, qw, qx, qy, qz)`` and ``(..., 4, 4)``
homogeneous matrices, and the rotation helpers of the chains' kinematics.

Example:
    >>> pose = torch.tensor([0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    >>> matrix_to_pose(pose_to_matrix(pose)).tolist()
    [0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0]
"""

from __future__ import annotations

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError

__all__ = ["matrix_to_pose", "pose_to_matrix"]


def pose_to_matrix(pose: torch.Tensor) -> torch.Tensor:
    """``(..., 7)`` poses ``(x, y, z, qw, qx, qy, qz)`` to ``(..., 4, 4)`` matrices.

    The quaternion is normalised first.

    Example:
        >>> pose_to_matrix(torch.tensor([1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0]))[:3, 3].tolist()
        [1.0, 2.0, 3.0]
    """
    pose = check_tensor("pose", pose)
    check_shape("pose", pose, (7,), "(..., 7)")
    q = pose[..., 3:]
    norm = q.norm(dim=-1, keepdim=True)
    if not (norm > 0).all():
        raise ModelError("pose has a zero quaternion")
    w, x, y, z = (q / norm).unbind(-1)
    rot = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*pose.shape[:-1], 3, 3)
    out = pose.new_zeros(*pose.shape[:-1], 4, 4)
    out[..., :3, :3] = rot
    out[..., :3, 3] = pose[..., :3]
    out[..., 3, 3] = 1.0
    return out


def matrix_to_pose(matrix: torch.Tensor) -> torch.Tensor:
    """``(..., 4, 4)`` matrices to ``(..., 7)`` poses ``(x, y, z, qw, qx, qy, qz)``, ``qw >= 0``.

    Example:
        >>> matrix_to_pose(torch.eye(4)).tolist()
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    """
    matrix = check_tensor("matrix", matrix)
    check_shape("matrix", matrix, (4, 4), "(..., 4, 4)")
    r = matrix[..., :3, :3]
    # Shepperd's method: pick the largest of 4 q_i^2 candidates for stability.
    tr = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    cands = torch.stack(
        [
            1 + tr,
            1 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2],
            1 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2],
            1 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2],
        ],
        dim=-1,
    )
    best = cands.argmax(-1, keepdim=True)
    s = 2 * cands.gather(-1, best).clamp_min(1e-30).sqrt().squeeze(-1)  # 4 |q_best|
    w_, x_, y_, z_ = (
        torch.stack(
            [
                s / 4,
                (r[..., 2, 1] - r[..., 1, 2]) / s,
                (r[..., 0, 2] - r[..., 2, 0]) / s,
                (r[..., 1, 0] - r[..., 0, 1]) / s,
            ],
            -1,
        ),
        torch.stack(
            [
                (r[..., 2, 1] - r[..., 1, 2]) / s,
                s / 4,
                (r[..., 0, 1] + r[..., 1, 0]) / s,
                (r[..., 0, 2] + r[..., 2, 0]) / s,
            ],
            -1,
        ),
        torch.stack(
            [
                (r[..., 0, 2] - r[..., 2, 0]) / s,
                (r[..., 0, 1] + r[..., 1, 0]) / s,
                s / 4,
                (r[..., 1, 2] + r[..., 2, 1]) / s,
            ],
            -1,
        ),
        torch.stack(
            [
                (r[..., 1, 0] - r[..., 0, 1]) / s,
                (r[..., 0, 2] + r[..., 2, 0]) / s,
                (r[..., 1, 2] + r[..., 2, 1]) / s,
                s / 4,
            ],
            -1,
        ),
    )
    q = torch.stack([w_, x_, y_, z_], dim=-2)  # (..., 4 candidates, 4 components)
    q = q.gather(-2, best.unsqueeze(-1).expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    q = torch.where(q[..., :1] < 0, -q, q)
    return torch.cat([matrix[..., :3, 3], q / q.norm(dim=-1, keepdim=True)], dim=-1)


def _as_matrices(name: str, poses: torch.Tensor) -> torch.Tensor:
    poses = check_tensor(name, poses)
    if poses.dim() >= 2 and poses.shape[-2:] == (4, 4):
        return poses
    if poses.shape[-1:] == (7,):
        return pose_to_matrix(poses)
    raise ModelError(
        f"expected {name} to have shape (..., 4, 4) or (..., 7), "
        f"actual shape = {tuple(poses.shape)}"
    )


def _frame_with_z(axis: torch.Tensor) -> torch.Tensor:
    """A ``(4, 4)`` rotation whose ``z`` column is the unit ``axis (3,)``."""
    out = torch.eye(4, dtype=axis.dtype, device=axis.device)
    if float(axis[2]) > 1 - 1e-12:  # already z: keep the frame as it is
        return out
    helper = torch.zeros_like(axis)
    helper[int(axis.abs().argmin())] = 1.0
    x = torch.linalg.cross(helper, axis)
    x = x / x.norm()
    y = torch.linalg.cross(axis, x)
    out[:3, :3] = torch.stack([x, y, axis], dim=-1)
    return out


def _rotation_angle(r_target: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Geodesic angle ``(...)`` between rotation matrices ``(..., 3, 3)``."""
    cos = ((r_target * r).sum(dim=(-2, -1)) - 1) / 2
    return torch.acos(cos.clamp(-1.0, 1.0))
