"""Arm kinematics: serial chains from URDF, batched FK, Jacobians and IK, reach checks.

The robot (a Franka Emika Panda, URDF shipped in ``assets/panda``) and an anthropometric human
arm (``assets/human_arm``, :func:`human_arm_urdf`) are serial chains: :class:`SerialArm`
computes their forward kinematics, Jacobians and inverse kinematics within joint limits, and
:func:`reach_check` says which end-effector poses an arm reaches. A task's geometry lives with
the task (the hand-finishing box: :mod:`torchhrc.tasks.hand_finishing.geometry`).

Modules: :mod:`.chain` (the chains, FK, IK, reach), :mod:`.poses` (pose vectors and
matrices), :mod:`.human_arm` (the anthropometric arm's URDF); every public name is
re-exported here.

Kinematic chains are read from URDF by pytorch-kinematics (the ``full`` extra) and compiled
into a flat serial chain (one fixed transform per joint and the joint axes) whose forward
kinematics and geometric Jacobian are a few batched tensor products; this is what makes the
batched inverse kinematics fast (tests compare it with pytorch-kinematics and pinocchio).

Frames and units: metres and radians; the robot base frame has x forward (towards the
person), y to the robot's left, z up. Poses are ``(..., 4, 4)`` homogeneous matrices or
``(..., 7)`` vectors ``(x, y, z, qw, qx, qy, qz)`` (unit quaternion, scalar first).

Example:
    >>> import torch
    >>> arm = SerialArm.panda()
    >>> arm.dof, arm.forward(torch.zeros(7, dtype=torch.float64)).shape
    (7, torch.Size([4, 4]))
"""

from __future__ import annotations

from torchhrc._deprecation import moved_attribute
from torchhrc.kinematics.chain import IKResult, ReachResult, SerialArm, asset_path, reach_check
from torchhrc.kinematics.human_arm import human_arm_urdf
from torchhrc.kinematics.poses import matrix_to_pose, pose_to_matrix

__all__ = [
    "IKResult",
    "ReachResult",
    "SerialArm",
    "asset_path",
    "human_arm_urdf",
    "matrix_to_pose",
    "pose_to_matrix",
    "reach_check",
]


#: Names that moved to :mod:`torchhrc.tasks.hand_finishing.geometry` (issue 32): deprecated
#: aliases here for one release.
_MOVED_TO_TASK = {
    name: "torchhrc.tasks.hand_finishing.geometry"
    for name in (
        "BoxFeasibility",
        "BoxGeometry",
        "ComfortResult",
        "PersonModel",
        "comfort_check",
        "feasible_box_configurations",
    )
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED_TO_TASK)
