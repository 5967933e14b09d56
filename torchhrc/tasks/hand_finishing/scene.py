"""A SAPIEN 3 scene of the hand-finishing task: the arm holds the box over a table.

Physics only, on the CPU (``sapien.Scene([sapien.physx.PhysxCpuSystem()])``): the Panda
(``assets/panda``) is mounted on a table, the box (a link rigidly fixed to the hand's
TCP, with a box collision shape and the inertia of a solid box) is held at the configurations
of :class:`~torchhrc.tasks.hand_finishing.geometry.BoxGeometry`. The arm follows box moves with
joint position targets: the targets come from :meth:`~torchhrc.kinematics.chain.SerialArm.inverse`,
are interpolated linearly over ``interpolation_steps`` physics steps, and physics is stepped
until the arm settles (joint speeds and tracking errors below tolerances). Gravity and Coriolis
forces are compensated each step with SAPIEN's passive forces, as a torque-controlled arm's
controller would.

No visual bodies are created in physics-only mode. ``render=True`` needs a GPU with a Vulkan
driver (:func:`torchhrc.sim.scene.check_render_device`).

World frame: the floor is ``z = 0``, the robot base sits on the table top at
``(0, 0, table_height)`` with the axes of the robot base frame (x towards the person).

Example:
    >>> from torchhrc.tasks.hand_finishing.scene import HandFinishingScene  # doctest: +SKIP
    >>> scene = HandFinishingScene()  # doctest: +SKIP
    >>> scene.move_box(2, 1, 2).settled  # doctest: +SKIP
    True
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchhrc.errors import ModelError
from torchhrc.kinematics import SerialArm, asset_path, pose_to_matrix
from torchhrc.sim.scene import (
    check_render_device,
    import_sapien,
    load_urdf_text,
    set_joint_positions,
)
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry

__all__ = ["HandFinishingScene", "MoveResult"]


@dataclass(frozen=True)
class MoveResult:
    """The outcome of a commanded move.

    Attributes:
        settled: the arm settled within ``max_steps``.
        steps: physics steps taken.
        box_pose: ``(4, 4)`` the box's pose in the world after the move.
        commanded: ``(4, 4)`` the commanded box pose.
        position_error: distance between the two box centres (m).
        rotation_error: angle between the two orientations (rad).
    """

    settled: bool
    steps: int
    box_pose: torch.Tensor
    commanded: torch.Tensor
    position_error: float
    rotation_error: float


def _box_urdf(geometry: BoxGeometry, box_mass: float) -> str:
    """The Panda URDF with the box appended as a link fixed to the TCP."""
    text = asset_path("panda/panda.urdf").read_text()
    d, w, h = geometry.size
    ixx = box_mass * (w * w + h * h) / 12
    iyy = box_mass * (d * d + h * h) / 12
    izz = box_mass * (d * d + w * w) / 12
    # The box centre in the TCP frame: inverse of BoxGeometry.grip_transform, i.e. depth/2
    # along the TCP's z, rotated by -pi/2 about y (box x = TCP z).
    box = f"""  <joint name="box_joint" type="fixed">
    <parent link="panda_hand_tcp"/>
    <child link="box"/>
    <origin xyz="0 0 {d / 2:.9g}" rpy="0 {-math.pi / 2:.12g} 0"/>
  </joint>
  <link name="box">
    <inertial>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <mass value="{box_mass:.9g}"/>
      <inertia ixx="{ixx:.9g}" ixy="0" ixz="0" iyy="{iyy:.9g}" iyz="0" izz="{izz:.9g}"/>
    </inertial>
    <collision>
      <geometry><box size="{d:.9g} {w:.9g} {h:.9g}"/></geometry>
    </collision>
  </link>
</robot>"""
    return text.replace("</robot>", box)


class HandFinishingScene:
    """The arm, a table and the held box in a SAPIEN 3 physics scene (CPU).

    Args:
        geometry: the box configurations and the box (default :class:`BoxGeometry`).
        table_height: height of the table top the robot stands on (m).
        box_mass: mass of the box (kg).
        timestep: physics time step (s).
        stiffness, damping: joint drive gains (N m / rad, N m s / rad).
        render: also create a render system (needs a GPU; see :func:`check_render_device`).
        seed: seed of the inverse kinematics.
        start: ``(h, v, t)`` configuration the arm holds the box at initially (default: the
            reachable configuration nearest the grid's centre, found by solving the IK of
            every configuration).
        arm: the robot's kinematics (default ``SerialArm.panda()``; pass one to share its
            start table with other checks). Must be the shipped Panda's chain.

    Raises:
        ImportError: SAPIEN is missing (``pip install torchhrc[sim]``).
        RenderUnavailableError: ``render=True`` and no render device.
    """

    def __init__(
        self,
        geometry: BoxGeometry | None = None,
        *,
        table_height: float = 0.75,
        box_mass: float = 2.0,
        timestep: float = 1.0 / 250.0,
        stiffness: float = 4000.0,
        damping: float = 400.0,
        render: bool = False,
        seed: int = 0,
        start: tuple[int, int, int] | None = None,
        arm: SerialArm | None = None,
    ) -> None:
        if render:
            check_render_device()
        sapien = import_sapien()
        if not table_height > 0 or not box_mass > 0 or not timestep > 0:
            raise ModelError(
                "expected table_height, box_mass and timestep > 0, got "
                f"{table_height}, {box_mass}, {timestep}"
            )
        self.geometry = BoxGeometry() if geometry is None else geometry
        self.table_height = float(table_height)
        self.timestep = float(timestep)
        self.seed = int(seed)
        self.arm = SerialArm.panda() if arm is None else arm
        if start is not None:
            self.geometry.index(*start)  # validates the indices
        systems = [sapien.physx.PhysxCpuSystem()]
        if render:
            systems.append(sapien.render.RenderSystem())
        self.scene = sapien.Scene(systems)
        self.scene.set_timestep(self.timestep)
        # The table: a static box from the floor to the table top around the robot base.
        builder = self.scene.create_actor_builder()
        half = [0.3, 0.3, self.table_height / 2]
        builder.add_box_collision(half_size=half)
        if render:
            builder.add_box_visual(half_size=half)
        builder.set_initial_pose(sapien.Pose([0.0, 0.0, self.table_height / 2]))
        self.table = builder.build_static(name="table")
        self.robot = load_urdf_text(
            self.scene, _box_urdf(self.geometry, float(box_mass)), render=render
        )
        self.robot.set_root_pose(sapien.Pose([0.0, 0.0, self.table_height]))
        self.joints = self.robot.get_active_joints()
        if len(self.joints) != self.arm.dof:
            raise ModelError(
                f"expected {self.arm.dof} active joints, SAPIEN loaded {len(self.joints)}"
            )
        for joint in self.joints:
            joint.set_drive_properties(float(stiffness), float(damping))
        self.box_link = self.robot.find_link_by_name("box")
        home = self._home() if start is None else self._solve(self._grip(*start), None)
        self._set_qpos(home)
        self._target = home

    # ------------------------------------------------------------------ helpers
    def _set_qpos(self, q: torch.Tensor) -> None:
        set_joint_positions(self.robot, q, self.joints)

    def _home(self) -> torch.Tensor:
        """Joints holding the box at the reachable configuration nearest the grid's centre."""
        H, V, T = self.geometry.shape
        grid = torch.stack(
            torch.meshgrid(torch.arange(H), torch.arange(V), torch.arange(T), indexing="ij"), -1
        ).reshape(-1, 3)
        centre = torch.tensor([(H - 1) / 2, (V - 1) / 2, (T - 1) / 2])
        order = ((grid - centre) ** 2).sum(-1).argsort(stable=True)
        grips = self.geometry.grip_poses().reshape(-1, 4, 4)[order]
        res = self.arm.inverse(
            grips, restarts=8, seed=self.seed, position_tolerance=1e-4, rotation_tolerance=1e-3
        )
        if not bool(res.success.any()):
            raise ModelError("no box configuration of the geometry is reachable")
        first = int(torch.nonzero(res.success)[0])
        return res.joints[first]

    def _grip(self, horizontal: int, vertical: int, tilt: int) -> torch.Tensor:
        """``(4, 4)`` the TCP target holding the box at ``(h, v, t)`` (robot base frame)."""
        box = self.geometry.box_poses()[horizontal, vertical, tilt]
        return box @ self.geometry.grip_transform()

    def _solve(self, grip: torch.Tensor, initial: torch.Tensor | None) -> torch.Tensor:
        res = self.arm.inverse(
            grip,
            initial=initial,
            restarts=8,
            seed=self.seed,
            position_tolerance=1e-4,
            rotation_tolerance=1e-3,
        )
        if not bool(res.success):
            raise ModelError(
                "the box pose is not reachable (IK position error "
                f"{float(res.position_error):.3g} m, "
                f"rotation error {float(res.rotation_error):.3g} rad)"
            )
        return res.joints

    def _base(self) -> torch.Tensor:
        base = torch.eye(4, dtype=torch.float64)
        base[2, 3] = self.table_height
        return base

    # ------------------------------------------------------------------ queries
    def joint_positions(self) -> torch.Tensor:
        """``(DOF,)`` current joint positions."""
        return torch.tensor(self.robot.get_qpos().tolist(), dtype=torch.float64)

    def box_pose(self) -> torch.Tensor:
        """``(4, 4)`` the box centre's pose in the world frame."""
        pose = self.box_link.entity_pose
        vec = torch.tensor([*pose.p.tolist(), *pose.q.tolist()], dtype=torch.float64)
        return pose_to_matrix(vec)

    def commanded_box_pose(self, horizontal: int, vertical: int, tilt: int) -> torch.Tensor:
        """``(4, 4)`` world pose of the box centre at configuration ``(h, v, t)``."""
        self.geometry.index(horizontal, vertical, tilt)  # validates the indices
        return self._base() @ self.geometry.box_poses()[horizontal, vertical, tilt]

    # ------------------------------------------------------------------ motion
    def reset_box(self, horizontal: int, vertical: int, tilt: int) -> None:
        """Place the arm at rest holding the box at configuration ``(h, v, t)`` (no motion).

        The joints are set to the IK solution (seeded from the current target), velocities
        to zero, and the drive targets to the same joints: the start of a replay.

        Raises:
            ModelError: the configuration is out of range or not reachable.
        """
        self.geometry.index(horizontal, vertical, tilt)
        target = self._solve(self._grip(horizontal, vertical, tilt), self._target)
        self._set_qpos(target)
        self._target = target

    def step(self, steps: int = 1) -> None:
        """Advance physics by ``steps`` steps, compensating gravity and Coriolis forces."""
        for _ in range(int(steps)):
            self.robot.set_qf(self.robot.compute_passive_force(True, True))
            self.scene.step()

    def move_joints(
        self,
        target: torch.Tensor,
        *,
        interpolation_steps: int = 150,
        max_steps: int = 1500,
        velocity_tolerance: float = 1e-2,
        position_tolerance: float = 1e-3,
    ) -> int:
        """Drive the joints to ``target (DOF,)``; returns the physics steps taken (or
        ``max_steps`` if the arm did not settle).

        The drive targets move linearly from the previous target over
        ``interpolation_steps`` steps; then physics runs until every joint speed is below
        ``velocity_tolerance`` (rad/s) and every joint within ``position_tolerance`` (rad) of
        its target.
        """
        target = torch.as_tensor(target, dtype=torch.float64)
        start = self._target
        steps = 0
        for k in range(1, interpolation_steps + 1):  # time is sequential in a simulator
            q = start + (target - start) * (k / interpolation_steps)
            for joint, value in zip(self.joints, q.tolist()):
                joint.set_drive_target(value)
            self.step()
            steps += 1
        self._target = target
        while steps < max_steps:
            self.step()
            steps += 1
            qvel = self.robot.get_qvel()
            err = (self.joint_positions() - target).abs().max().item()
            if float(abs(qvel).max()) < velocity_tolerance and err < position_tolerance:
                return steps
        return max_steps

    def move_box(
        self,
        horizontal: int,
        vertical: int,
        tilt: int,
        *,
        interpolation_steps: int = 150,
        max_steps: int = 1500,
    ) -> MoveResult:
        """Move the box to configuration ``(h, v, t)`` of the geometry and let it settle.

        Raises:
            ModelError: the configuration is out of range or not reachable.
        """
        self.geometry.index(horizontal, vertical, tilt)
        target = self._solve(self._grip(horizontal, vertical, tilt), self._target)
        steps = self.move_joints(
            target, interpolation_steps=interpolation_steps, max_steps=max_steps
        )
        commanded = self.commanded_box_pose(horizontal, vertical, tilt)
        reached = self.box_pose()
        pos_err = float((reached[:3, 3] - commanded[:3, 3]).norm())
        cos = ((reached[:3, :3] * commanded[:3, :3]).sum() - 1) / 2
        rot_err = float(torch.acos(cos.clamp(-1.0, 1.0)))
        return MoveResult(
            settled=steps < max_steps,
            steps=steps,
            box_pose=reached,
            commanded=commanded,
            position_error=pos_err,
            rotation_error=rot_err,
        )
