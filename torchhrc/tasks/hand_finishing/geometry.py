"""The hand-finishing box: its configurations, the person's comfort, and which the task keeps.

The robot (a Franka Emika Panda, :meth:`~torchhrc.kinematics.chain.SerialArm.panda`) holds a
large box for a person who refinishes its side surfaces by hand (paper, "Online estimation of
human type": the robot "can move the box along the horizontal and vertical axis and rotate it in
the tilt direction" and should move it "to a reachable, ergonomically friendly position").
This module decides which box configurations the robot can reach and hold (inverse
kinematics within joint limits, :func:`torchhrc.kinematics.reach_check`) and which are
comfortable for the person (the anthropometric arm of
:func:`torchhrc.kinematics.human_arm_urdf`); the task removes the others from its MOMDP
(:class:`~torchhrc.tasks.hand_finishing.model.HandFinishingTask`).

Frames and units are those of :mod:`torchhrc.kinematics`: metres and radians; the robot base
frame has x forward (towards the person), y to the robot's left, z up.

Box configurations (:class:`BoxGeometry`), a grid ``H x V x T``:

* horizontal index ``h``: the box centre's ``y`` in the base frame, ``geometry.horizontal[h]``;
* vertical index ``v``: the box centre's height ``z`` above the base, ``geometry.vertical[v]``;
* tilt index ``t``: the box's rotation about the base ``x`` axis (the axis pointing at the
  person), ``geometry.tilt[t]`` radians, positive raising the box's left (``+y``) side;
* the box centre's ``x`` is ``geometry.forward``; the hand grips the middle of the box's back
  face (the face towards the robot) with its approach axis (TCP ``z``) along base ``x``.

Example:
    >>> BoxGeometry(horizontal=(0.0,), vertical=(0.2,), tilt=(0.0,)).grip_poses().shape
    torch.Size([1, 1, 1, 4, 4])
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.kinematics import SerialArm, reach_check

__all__ = [
    "BoxFeasibility",
    "BoxGeometry",
    "ComfortResult",
    "PersonModel",
    "comfort_check",
    "feasible_box_configurations",
]


@dataclass(frozen=True)
class PersonModel:
    """The person who finishes the box, for the comfort check.

    Comfort rules (both must hold):

    * working height: the work point is between ``elbow_height - 0.40 m`` and
      ``elbow_height + 0.10 m`` (Grandjean 1988, "Fitting the Task to the Man", 4th ed.,
      working heights for standing work: precision work up to 5-10 cm above elbow height,
      light work 10-15 cm below, heavy work 15-40 cm below); ``elbow_height = 0.630 H``
      (Winter 2009);
    * reach: the right arm (:func:`~torchhrc.kinematics.human_arm_urdf`) reaches the point
      (IK within ``reach_tolerance``) with the upper arm raised at most ``max_elevation``
      (default 90 deg: RULA, McAtamney & Corlett 1993, gives its worst upper-arm score above
      90 deg) in flexion and in abduction, the other joints within their ranges of motion.

    The person stands facing the robot (facing ``-x`` of the robot base), with the right
    shoulder level with the work point sideways (they walk along the box), their body frame
    ``standoff`` metres beyond the box's front face.

    Attributes:
        height: body height ``H`` (m).
        floor_height: height of the robot base above the floor (m); the robot is mounted
            on a table.
        standoff: horizontal distance from the box's front face to the person's body frame (m).
        band_below, band_above: the working-height band around the elbow (m).
        max_elevation: largest comfortable shoulder flexion / abduction (rad).
        reach_tolerance: IK tolerance on the palm position (m).
    """

    height: float = 1.75
    floor_height: float = 0.75
    standoff: float = 0.25
    band_below: float = 0.40
    band_above: float = 0.10
    max_elevation: float = math.pi / 2
    reach_tolerance: float = 0.01

    @property
    def elbow_height(self) -> float:
        """Elbow height above the floor, ``0.630 H`` (Winter 2009)."""
        return 0.630 * self.height


# -------------------------------------------------------------- box configurations
@dataclass(frozen=True)
class BoxGeometry:
    """The grid of box configurations and the box, in the robot base frame (see module doc).

    Attributes:
        horizontal: ``(H,)`` box-centre ``y`` values (m).
        vertical: ``(V,)`` box-centre heights ``z`` above the robot base (m).
        tilt: ``(T,)`` rotations about the base ``x`` axis (rad).
        forward: box-centre ``x`` (m).
        size: box extent ``(depth along x, width along y, height along z)`` (m).

    Example:
        >>> g = BoxGeometry()
        >>> g.shape, g.grip_poses().shape
        ((5, 4, 5), torch.Size([5, 4, 5, 4, 4]))
    """

    horizontal: tuple[float, ...] = (-0.6, -0.3, 0.0, 0.3, 0.6)
    vertical: tuple[float, ...] = (0.0, 0.2, 0.4, 0.6)
    tilt: tuple[float, ...] = (-math.pi / 3, -math.pi / 6, 0.0, math.pi / 6, math.pi / 3)
    forward: float = 0.75
    size: tuple[float, float, float] = (0.3, 0.5, 0.3)

    def __post_init__(self) -> None:
        for name in ("horizontal", "vertical", "tilt"):
            values = tuple(float(v) for v in getattr(self, name))
            if not values:
                raise ModelError(f"expected {name} to have at least one value")
            object.__setattr__(self, name, values)
        if len(self.size) != 3 or min(self.size) <= 0:
            raise ModelError(f"expected size to be three positive lengths, got {self.size!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(H, V, T)``."""
        return (len(self.horizontal), len(self.vertical), len(self.tilt))

    def box_poses(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """``(H, V, T, 4, 4)`` poses of the box centre: ``Trans(forward, h, v) Rot_x(tilt)``."""
        H, V, T = self.shape
        hy = torch.tensor(self.horizontal, dtype=dtype, device=device)
        vz = torch.tensor(self.vertical, dtype=dtype, device=device)
        th = torch.tensor(self.tilt, dtype=dtype, device=device)
        c, s = torch.cos(th), torch.sin(th)
        one, zero = torch.ones_like(th), torch.zeros_like(th)
        rot = torch.stack([one, zero, zero, zero, c, -s, zero, s, c], -1).reshape(T, 3, 3)
        out = torch.zeros(H, V, T, 4, 4, dtype=dtype, device=device)
        out[..., :3, :3] = rot
        out[..., 0, 3] = self.forward
        out[..., 1, 3] = hy.view(H, 1, 1)
        out[..., 2, 3] = vz.view(1, V, 1)
        out[..., 3, 3] = 1.0
        return out

    def grip_transform(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """``(4, 4)`` pose of the gripper (TCP) in the box frame: the middle of the back face,
        approach axis ``z`` along the box's ``x``: ``Trans(-depth/2, 0, 0) Rot_y(pi/2)``."""
        t = torch.zeros(4, 4, dtype=dtype, device=device)
        t[:3, :3] = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]], dtype=dtype)
        t[0, 3] = -self.size[0] / 2
        t[3, 3] = 1.0
        return t

    def grip_poses(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """``(H, V, T, 4, 4)`` end-effector (TCP) targets: ``box_pose @ grip_transform``."""
        return self.box_poses(dtype=dtype, device=device) @ self.grip_transform(
            dtype=dtype, device=device
        )

    def work_points(
        self,
        side: str,
        *,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> torch.Tensor:
        """``(H, V, T, 3)`` centre of the box's ``"left"`` (``+y``) or ``"right"`` (``-y``)
        side surface, the surface the person refinishes, in the base frame."""
        if side not in ("left", "right"):
            raise ModelError(f"expected side 'left' or 'right', got {side!r}")
        sign = 1.0 if side == "left" else -1.0
        local = torch.tensor([0.0, sign * self.size[1] / 2, 0.0, 1.0], dtype=dtype, device=device)
        return (self.box_poses(dtype=dtype, device=device) @ local)[..., :3]

    def index(self, horizontal: int, vertical: int, tilt: int) -> int:
        """Flat configuration index ``(h * V + v) * T + t``."""
        H, V, T = self.shape
        if not (0 <= horizontal < H and 0 <= vertical < V and 0 <= tilt < T):
            raise ModelError(
                f"expected indices in [0, {H}) x [0, {V}) x [0, {T}), "
                f"got ({horizontal}, {vertical}, {tilt})"
            )
        return (horizontal * V + vertical) * T + tilt


# ------------------------------------------------------------------- comfort check
@dataclass(frozen=True)
class ComfortResult:
    """Result of :func:`comfort_check` for points of batch shape ``(...)``.

    Attributes:
        comfortable: ``(...)`` bool, both rules hold.
        height_ok: ``(...)`` bool, within the working-height band.
        reach_ok: ``(...)`` bool, the arm reaches it within the comfortable ranges.
        height: ``(...)`` height of the point above the floor (m).
        joints: ``(..., 6)`` the arm's IK solution.
    """

    comfortable: torch.Tensor
    height_ok: torch.Tensor
    reach_ok: torch.Tensor
    height: torch.Tensor
    joints: torch.Tensor


def comfort_check(
    points: torch.Tensor,
    *,
    front_x: float,
    person: PersonModel | None = None,
    human: SerialArm | None = None,
    seed: int = 0,
) -> ComfortResult:
    """Whether a person can comfortably work at points ``(..., 3)`` of the robot base frame.

    The rules are those of :class:`PersonModel`. The person faces ``-x``; their body frame is
    at ``x = front_x + standoff`` on the floor (``z = -floor_height``), shifted sideways so
    that the right shoulder is level with each point.

    Args:
        points: ``(..., 3)`` work points in the robot base frame.
        front_x: ``x`` of the box's front face (the face towards the person).
        person: the person (default :class:`PersonModel`).
        human: the arm model (default ``SerialArm.human_arm(height=person.height)``).
        seed: seed of the IK restarts.

    Returns:
        :class:`ComfortResult`.

    Example:
        >>> r = comfort_check(torch.tensor([[0.6, 0.0, 0.3], [0.6, 0.0, 1.5]],
        ...                   dtype=torch.float64), front_x=0.75)
        >>> r.comfortable.tolist()
        [True, False]
    """
    person = PersonModel() if person is None else person
    human = SerialArm.human_arm(height=person.height) if human is None else human
    points = check_tensor("points", points).to(dtype=human.dtype, device=human.device)
    check_shape("points", points, (3,), "(..., 3)")
    batch = points.shape[:-1]
    pts = points.reshape(-1, 3)
    height = pts[:, 2] + person.floor_height
    elbow = person.elbow_height
    height_ok = (height >= elbow - person.band_below) & (height <= elbow + person.band_above)
    # Into the person's body frame: facing -x of the base is a rotation by pi about z.
    # Body frame: x_body = -x_base, y_body = -y_base; the person steps sideways so that the
    # right shoulder (y_body = shoulder_y) is level with the point.
    shoulder_y = float(human.first_joint_transform[1, 3])
    local = torch.stack(
        [front_x + person.standoff - pts[:, 0], torch.full_like(height, shoulder_y), height], dim=-1
    )
    lower = human.lower.clone()
    upper = human.upper.clone()
    names = human.joint_names
    for joint in ("shoulder_flexion", "shoulder_abduction"):
        if joint in names:
            upper[names.index(joint)] = min(float(upper[names.index(joint)]), person.max_elevation)
    res = human.inverse(
        local,
        position_only=True,
        restarts=4,
        iterations=30,
        lower=lower,
        upper=upper,
        position_tolerance=person.reach_tolerance,
        seed=seed,
    )
    reach_ok = res.success
    return ComfortResult(
        comfortable=(height_ok & reach_ok).reshape(batch),
        height_ok=height_ok.reshape(batch),
        reach_ok=reach_ok.reshape(batch),
        height=height.reshape(batch),
        joints=res.joints.reshape(*batch, human.dof),
    )


@dataclass(frozen=True)
class BoxFeasibility:
    """Which box configurations the task keeps (shapes over the ``H x V x T`` grid).

    Attributes:
        reachable: ``(H, V, T)`` bool, the robot reaches and holds the grip pose.
        comfortable: ``(H, V, T, 2)`` bool, comfortable for the person working on the
            ``[left, right]`` side surface.
        mask: ``(H, V, T)`` bool, ``reachable & comfortable.any(-1)``: the configurations
            kept in the MOMDP.
        joints: ``(H, V, T, DOF)`` the robot's joint solutions (drive targets for the sim).
        position_error: ``(H, V, T)`` the robot IK's position error (m).
    """

    reachable: torch.Tensor
    comfortable: torch.Tensor
    mask: torch.Tensor
    joints: torch.Tensor
    position_error: torch.Tensor = field(repr=False)

    @property
    def fraction(self) -> float:
        """Fraction of configurations kept."""
        return float(self.mask.double().mean())


def feasible_box_configurations(
    geometry: BoxGeometry | None = None,
    *,
    arm: SerialArm | None = None,
    person: PersonModel | None = None,
    restarts: int = 8,
    seed: int = 0,
) -> BoxFeasibility:
    """Reach and comfort of every box configuration of the hand-finishing task.

    Args:
        geometry: the configuration grid and box (default :class:`BoxGeometry`).
        arm: the robot (default the shipped Panda).
        person: the person (default :class:`PersonModel`).
        restarts: IK restarts per configuration.
        seed: seed of the IK restarts.

    Returns:
        :class:`BoxFeasibility`; ``mask.flatten()`` is indexed by
        :meth:`BoxGeometry.index`.

    Example:
        >>> f = feasible_box_configurations(BoxGeometry(horizontal=(0.0,), vertical=(0.2,),
        ...                                             tilt=(0.0,)))
        >>> f.reachable.tolist(), f.mask.shape
        ([[[True]]], torch.Size([1, 1, 1]))
    """
    geometry = BoxGeometry() if geometry is None else geometry
    arm = SerialArm.panda() if arm is None else arm
    H, V, T = geometry.shape
    grips = geometry.grip_poses(dtype=arm.dtype, device=arm.device).reshape(-1, 4, 4)
    reach = reach_check(grips, arm=arm, restarts=restarts, seed=seed)
    front_x = geometry.forward + geometry.size[0] / 2
    sides = torch.stack(
        [
            geometry.work_points("left", dtype=arm.dtype),
            geometry.work_points("right", dtype=arm.dtype),
        ],
        dim=-2,
    )  # (H, V, T, 2, 3)
    comfort = comfort_check(sides, front_x=front_x, person=person, seed=seed)
    reachable = reach.reachable.reshape(H, V, T)
    return BoxFeasibility(
        reachable=reachable,
        comfortable=comfort.comfortable,
        mask=reachable & comfort.comfortable.any(-1),
        joints=reach.joints.reshape(H, V, T, arm.dof),
        position_error=reach.error.reshape(H, V, T),
    )
