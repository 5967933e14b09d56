"""A SAPIEN 3 scene of the place-and-drill task: the Panda drills, a person places screws.

Physics only, on the CPU (as :mod:`torchhrc.sim.scene`). The layout (:class:`WorkbenchLayout`,
world frame: floor ``z = 0``, x from the robot towards the person):

- a bench whose top is at ``bench_height``; the Panda stands on it at the origin of the bench
  top, with a drill (a capsule along the hand's approach axis, ``tool_length`` long) fixed
  to its TCP;
- ``n`` screw positions in a row across the bench at ``x = screw_x``, ``spacing`` apart;
- the person's right arm (the anthropometric arm of :func:`torchhrc.kinematics.human_arm_urdf`)
  standing across the bench at ``person_x``, facing the robot, its shoulder above the row.

Both arms are chains of capsules (:mod:`torchhrc.sim.capsules`): the same capsules are the
collision shapes in SAPIEN and the geometry of the separation measure. Robot and person
collide with each other only (collision groups): the arms' own links and the bench are never
in contact, so every contact SAPIEN reports is a robot-person contact.

Motions. The robot follows joint position targets from :meth:`SerialArm.inverse` (drive
gains, gravity and Coriolis compensation as the hand-finishing scene), interpolated linearly;
the person's arm is kinematic: its joints are set, step by step, along a linear
interpolation between inverse-kinematics solutions (reach above the screw, place, retract).
The robot's poses: ``home`` (the drill above the bench, clear of the row), ``hover(p)``
(the drill ``hover`` above screw ``p``), ``drill(p)`` (the drill's tip on the screw). The
person's: ``rest`` (arm hanging beside the bench), ``above(q)`` and ``place(q)`` (the palm
``hover`` above, and ``palm_height`` above, screw ``q``).

Example:
    >>> layout = WorkbenchLayout(n_positions=3)
    >>> [round(float(p[1]), 3) for p in layout.screw_positions()]
    [-0.15, 0.0, 0.15]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from torchhrc.errors import ModelError
from torchhrc.kinematics import SerialArm, asset_path, human_arm_urdf
from torchhrc.sim.capsules import Capsule, add_capsule_collisions, capsules_from_urdf
from torchhrc.sim.scene import (
    check_render_device,
    import_sapien,
    load_urdf_text,
    set_joint_positions,
)

__all__ = ["DrillResult", "PlaceAndDrillScene", "WorkbenchLayout"]

#: Capsule radii (m) of the Panda's links (their volumes, rounded up) and of the drill.
PANDA_RADII: dict[str, float] = {
    "panda_link0": 0.09,
    "panda_link1": 0.08,
    "panda_link2": 0.07,
    "panda_link3": 0.065,
    "panda_link4": 0.065,
    "panda_link5": 0.06,
    "panda_link6": 0.055,
    "panda_link7": 0.05,
    "panda_hand": 0.045,
    "drill": 0.02,
}
#: Capsule radii (m) of the person's arm: upper arm, forearm, hand (Winter 2009 girths / 2pi).
HUMAN_RADII: dict[str, float] = {"upper_arm": 0.045, "forearm": 0.038, "hand": 0.035}
_ROBOT_GROUP = [1, 2, 0, 0]  # collides with shapes whose group 0 has bit 2 (the person)
_HUMAN_GROUP = [2, 1, 0, 0]


@dataclass(frozen=True, kw_only=True)
class WorkbenchLayout:
    """Where things are (m); see the module docstring.

    Attributes:
        n_positions: screw positions ``n`` (1 to 8).
        bench_height: the bench top's height.
        screw_x: the row's distance from the robot's base.
        spacing: distance between neighbouring screws (``None``: 0.15 m, narrowed so that
            the row stays within the person's reach, 0.6 m wide at most).
        person_x: where the person stands (their body frame, facing ``-x``).
        person_height: the person's height (sizes the arm).
        tool_length: the drill's length past the TCP.
        hover: height of the hover poses above a screw.
        palm_height: height of the palm above a screw while placing it.
        home: ``(3,)`` the drill's TCP at home, bench-top frame.
    """

    n_positions: int = 3
    bench_height: float = 0.9
    screw_x: float = 0.5
    spacing: float | None = None
    person_x: float = 0.85
    person_height: float = 1.75
    tool_length: float = 0.12
    hover: float = 0.12
    palm_height: float = 0.04
    home: tuple[float, float, float] = (0.3, 0.0, 0.55)

    def __post_init__(self) -> None:
        if not isinstance(self.n_positions, int) or not 1 <= self.n_positions <= 8:
            raise ModelError(f"expected n_positions in [1, 8], got {self.n_positions!r}")
        if self.spacing is None:
            pitch = 0.15 if self.n_positions <= 5 else 0.6 / (self.n_positions - 1)
            object.__setattr__(self, "spacing", pitch)
        for name in ("bench_height", "screw_x", "spacing", "tool_length", "hover"):
            if not getattr(self, name) > 0:
                raise ModelError(f"expected {name} > 0, got {getattr(self, name)}")
        if not self.person_x > self.screw_x:
            raise ModelError(f"expected person_x > screw_x (across the bench), got {self.person_x}")

    def screw_positions(self) -> torch.Tensor:
        """``(n, 3)`` world positions of the screw heads (on the bench top)."""
        n = self.n_positions
        y = (torch.arange(n, dtype=torch.float64) - (n - 1) / 2) * float(self.spacing or 0.0)
        return torch.stack(
            [torch.full_like(y, self.screw_x), y, torch.full_like(y, self.bench_height)], -1
        )

    def robot_base(self) -> torch.Tensor:
        """``(4, 4)`` the robot base's world pose (on the bench top, at its origin)."""
        base = torch.eye(4, dtype=torch.float64)
        base[2, 3] = self.bench_height
        return base

    def person_base(self, shoulder_offset: float) -> torch.Tensor:
        """``(4, 4)`` the person's body frame: at ``person_x``, facing ``-x``, the right
        shoulder (``shoulder_offset`` to the body's right) above the row's centre."""
        pose = torch.eye(4, dtype=torch.float64)
        pose[:3, :3] = torch.tensor([[-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
        pose[0, 3] = self.person_x
        pose[1, 3] = -shoulder_offset
        return pose


@dataclass(frozen=True)
class DrillResult:
    """The outcome of :meth:`PlaceAndDrillScene.drill`.

    Attributes:
        settled: the arm settled within the step budget.
        steps: physics steps taken.
        tip_error: distance (m) between the drill's tip and its commanded point.
    """

    settled: bool
    steps: int
    tip_error: float


def _transform(pose: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``pose (..., 4, 4)`` applied to ``points (..., K, 3)``."""
    return points @ pose[..., :3, :3].transpose(-1, -2) + pose[..., None, :3, 3]


def _pose_matrix(pose: object) -> torch.Tensor:
    """A ``sapien.Pose`` as a ``(4, 4)`` float64 matrix."""
    from torchhrc.kinematics import pose_to_matrix

    p, q = pose.p.tolist(), pose.q.tolist()  # type: ignore[attr-defined]
    return pose_to_matrix(torch.tensor([*p, *q], dtype=torch.float64))


@dataclass
class _Chain:
    """An articulation's capsules: links, endpoints in link frames, radii."""

    links: list[object]
    start: torch.Tensor  # (C, 3)
    end: torch.Tensor  # (C, 3)
    radius: torch.Tensor  # (C,)
    names: tuple[str, ...] = field(default=())

    def world(self) -> tuple[torch.Tensor, torch.Tensor]:
        poses = torch.stack([_pose_matrix(link.entity_pose) for link in self.links])  # type: ignore[attr-defined]
        rot, pos = poses[:, :3, :3], poses[:, :3, 3]
        start = (rot @ self.start.unsqueeze(-1)).squeeze(-1) + pos
        end = (rot @ self.end.unsqueeze(-1)).squeeze(-1) + pos
        return start, end


def _chain(articulation: object, capsules: tuple[Capsule, ...]) -> _Chain:
    links = [articulation.find_link_by_name(c.link) for c in capsules]  # type: ignore[attr-defined]
    return _Chain(
        links=links,
        start=torch.tensor([c.start for c in capsules], dtype=torch.float64),
        end=torch.tensor([c.end for c in capsules], dtype=torch.float64),
        radius=torch.tensor([c.radius for c in capsules], dtype=torch.float64),
        names=tuple(c.link for c in capsules),
    )


def robot_urdf(layout: WorkbenchLayout) -> tuple[str, tuple[Capsule, ...]]:
    """The Panda URDF with the drill link, and the robot's capsules."""
    text = asset_path("panda/panda.urdf").read_text()
    drill = """  <joint name="drill_joint" type="fixed">
    <parent link="panda_hand_tcp"/>
    <child link="drill"/>
    <origin xyz="0 0 0" rpy="0 0 0"/>
  </joint>
  <link name="drill">
    <inertial>
      <origin xyz="0 0 0.05" rpy="0 0 0"/>
      <mass value="1.0"/>
      <inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.0005"/>
    </inertial>
  </link>
</robot>"""
    text = text.replace("</robot>", drill)
    capsules = capsules_from_urdf(
        text,
        PANDA_RADII,
        extra={"drill": (0.0, 0.0, layout.tool_length), "panda_hand": (0.0, 0.0, 0.1034)},
    )
    return text, capsules


def human_urdf(layout: WorkbenchLayout) -> tuple[str, tuple[Capsule, ...]]:
    """The person's arm URDF and its capsules (the hand's reaches the fingertips)."""
    text = human_arm_urdf(height=layout.person_height)
    hand = 0.108 * layout.person_height
    capsules = capsules_from_urdf(text, HUMAN_RADII, extra={"hand": (0.0, 0.0, -0.8 * hand)})
    return text, capsules


class PlaceAndDrillScene:
    """The workbench, the drilling Panda and the person's arm in SAPIEN (CPU physics).

    Args:
        layout: positions and sizes (default :class:`WorkbenchLayout`).
        timestep: physics step (s).
        stiffness, damping: the robot's joint drive gains.
        render: also create a render system (needs a GPU; see
            :func:`~torchhrc.sim.scene.check_render_device`).
        seed: seed of the inverse kinematics.

    Raises:
        ImportError: SAPIEN is missing (``pip install torchhrc[sim]``).
        RenderUnavailableError: ``render=True`` without a GPU render device.
        ModelError: a pose of the layout is out of reach.
    """

    def __init__(
        self,
        layout: WorkbenchLayout | None = None,
        *,
        timestep: float = 1.0 / 250.0,
        stiffness: float = 4000.0,
        damping: float = 400.0,
        render: bool = False,
        seed: int = 0,
    ) -> None:
        if render:
            check_render_device()
        sapien = import_sapien()
        self.layout = WorkbenchLayout() if layout is None else layout
        self.seed = int(seed)
        systems = [sapien.physx.PhysxCpuSystem()]
        if render:
            systems.append(sapien.render.RenderSystem())
        self.scene = sapien.Scene(systems)
        self.scene.set_timestep(float(timestep))
        lay = self.layout
        builder = self.scene.create_actor_builder()
        half = [0.45, 0.6, lay.bench_height / 2]
        builder.add_box_collision(half_size=half)
        if render:
            builder.add_box_visual(half_size=half)
        builder.set_initial_pose(sapien.Pose([0.35, 0.0, lay.bench_height / 2]))
        self.bench = builder.build_static(name="bench")
        for shape in self.bench.find_component_by_type(
            sapien.physx.PhysxRigidStaticComponent
        ).collision_shapes:
            shape.set_collision_groups([0, 0, 0, 0])  # the arms pass over the bench
        robot_text, self.robot_capsules = robot_urdf(lay)
        human_text, self.human_capsules = human_urdf(lay)
        self.robot = self._load(robot_text, self.robot_capsules, _ROBOT_GROUP, render)
        self.human = self._load(human_text, self.human_capsules, _HUMAN_GROUP, render)
        self.robot.set_root_pose(sapien.Pose([0.0, 0.0, lay.bench_height]))
        self.arm = SerialArm.panda()
        self.person = SerialArm(human_text, "palm")
        offset = -float(_shoulder_y(human_text))
        base = lay.person_base(offset)
        self._person_base = base
        self.human.set_root_pose(_to_sapien_pose(sapien, base))
        self.joints = self.robot.get_active_joints()
        self.human_joints = self.human.get_active_joints()
        for joint in self.joints:
            joint.set_drive_properties(float(stiffness), float(damping))
        for link in self.human.get_links():
            link.set_disable_gravity(True)
        self._robot_chain = _chain(self.robot, self.robot_capsules)
        self._human_chain = _chain(self.human, self.human_capsules)
        self._solve_poses()
        self._set_robot(self.robot_home)
        self._set_human(self.human_rest)

    # ------------------------------------------------------------------ construction
    def _load(self, text: str, capsules: tuple[Capsule, ...], groups: list[int],
              render: bool) -> object:  # fmt: skip
        articulation = load_urdf_text(self.scene, add_capsule_collisions(text, capsules),
                                      render=render)  # fmt: skip
        for link in articulation.get_links():  # type: ignore[attr-defined]
            for shape in link.collision_shapes:
                shape.set_collision_groups(groups)
        return articulation

    def _solve_poses(self) -> None:
        """Joint solutions of every pose of the layout, batched (robot and person)."""
        lay = self.layout
        screws = lay.screw_positions()  # (n, 3) world
        n = lay.n_positions
        down = torch.tensor([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]], dtype=torch.float64)
        base_inv = torch.linalg.inv(lay.robot_base())
        tcp = torch.eye(4, dtype=torch.float64).repeat(2 * n + 1, 1, 1)
        tcp[:, :3, :3] = down
        tip = lay.tool_length + 0.005
        world = torch.cat([
            screws + torch.tensor([0.0, 0.0, tip + lay.hover], dtype=torch.float64),
            screws + torch.tensor([0.0, 0.0, tip], dtype=torch.float64),
            (lay.robot_base()[:3, 3] + torch.tensor(lay.home, dtype=torch.float64))[None],
        ])  # fmt: skip
        tcp[:, :3, 3] = world
        targets = base_inv @ tcp
        res = self.arm.inverse(targets, restarts=8, seed=self.seed,
                               position_tolerance=1e-4, rotation_tolerance=1e-3)  # fmt: skip
        if not bool(res.success.all()):
            bad = int(torch.nonzero(~res.success)[0])
            raise ModelError(f"robot pose {bad} of the layout is out of reach (IK error "
                             f"{float(res.position_error[bad]):.3g} m)")  # fmt: skip
        self.robot_hover, self.robot_drill = res.joints[:n], res.joints[n : 2 * n]
        self.robot_home = res.joints[2 * n]
        self.drill_tips = screws + torch.tensor([0.0, 0.0, 0.005], dtype=torch.float64)
        person_inv = torch.linalg.inv(self._person_base)
        palms = torch.cat([screws + torch.tensor([0.0, 0.0, lay.hover + lay.palm_height]),
                           screws + torch.tensor([0.0, 0.0, lay.palm_height])])  # fmt: skip
        local = _transform(person_inv, palms.unsqueeze(0)).squeeze(0)
        res = self.person.inverse(local, position_only=True, restarts=8, seed=self.seed,
                                  position_tolerance=1e-3)  # fmt: skip
        if not bool(res.success.all()):
            bad = int(torch.nonzero(~res.success)[0])
            raise ModelError(
                f"the person cannot reach pose {bad} of the layout (IK error "
                f"{float(res.position_error[bad]):.3g} m); move person_x closer"
            )
        self.human_above, self.human_place = res.joints[:n], res.joints[n:]
        self.human_rest = torch.zeros(self.person.dof, dtype=torch.float64)

    # ------------------------------------------------------------------ state
    def _set_robot(self, q: torch.Tensor) -> None:
        set_joint_positions(self.robot, q, self.joints)
        self._robot_target = q.clone()

    def _set_human(self, q: torch.Tensor) -> None:
        set_joint_positions(self.human, q)  # kinematic: no drives

    def reset(self) -> None:
        """The robot at home, at rest; the person's arm at rest."""
        self._set_robot(self.robot_home)
        self._set_human(self.human_rest)

    def robot_joints(self) -> torch.Tensor:
        """``(7,)`` the robot's joint positions."""
        return torch.tensor(self.robot.get_qpos().tolist(), dtype=torch.float64)

    def set_poses(self, robot: torch.Tensor, human: torch.Tensor) -> None:
        """Set both arms' joints directly (no motion): for measurements of given poses."""
        self._set_robot(torch.as_tensor(robot, dtype=torch.float64))
        self._set_human(torch.as_tensor(human, dtype=torch.float64))

    # ------------------------------------------------------------------ measurements
    def capsules_world(self) -> dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """``{"robot"|"human": (start (C, 3), end (C, 3), radius (C,))}`` in the world."""
        out = {}
        for name, chain in (("robot", self._robot_chain), ("human", self._human_chain)):
            start, end = chain.world()
            out[name] = (start, end, chain.radius)
        return out

    def separation(self) -> float:
        """The minimum distance (m) between any robot capsule (drill included) and any of the
        person's, at the current poses; negative when they overlap."""
        from torchhrc.sim.capsules import capsule_separation

        caps = self.capsules_world()
        return float(capsule_separation(*caps["robot"], *caps["human"]).min())

    def contacts(self) -> int:
        """Robot-person contact points of the last physics step that touch or penetrate
        (separation <= 0; only robot-person shape pairs collide in this scene)."""
        return sum(1 for c in self.scene.get_contacts() for p in c.points if p.separation <= 0.0)

    def tip_position(self) -> torch.Tensor:
        """``(3,)`` the drill's tip in the world."""
        _, end = self._robot_chain.world()
        return end[self._robot_chain.names.index("drill")]

    # ------------------------------------------------------------------ motion
    def step(self, human: torch.Tensor | None = None) -> None:
        """One physics step (the person's joints set to ``human`` first, if given)."""
        if human is not None:
            self._set_human(human)
        self.robot.set_qf(self.robot.compute_passive_force(True, True))
        self.scene.step()

    def move(
        self,
        robot: torch.Tensor | None,
        human: tuple[torch.Tensor, torch.Tensor] | None,
        steps: int,
        *,
        sample_every: int = 5,
    ) -> tuple[float, int]:
        """Move both arms at once for ``steps`` physics steps.

        The robot's drive targets go linearly from its current target to ``robot`` (``None``:
        hold); the person's joints from ``human[0]`` to ``human[1]`` (``None``: hold still).

        Returns:
            ``(minimum separation over the samples, robot-person contact points)``.
        """
        start = self._robot_target
        low, contacts = math.inf, 0
        for k in range(1, steps + 1):
            if robot is not None:
                q = start + (robot - start) * (k / steps)
                for joint, value in zip(self.joints, q.tolist(), strict=True):
                    joint.set_drive_target(value)
            h = None if human is None else human[0] + (human[1] - human[0]) * (k / steps)
            self.step(h)
            contacts += self.contacts()
            if k % sample_every == 0 or k == steps:
                low = min(low, self.separation())
        if robot is not None:
            self._robot_target = robot.clone()
        return low, contacts

    def settle(self, *, max_steps: int = 1500, velocity_tolerance: float = 1e-2,
               position_tolerance: float = 1e-3) -> int:  # fmt: skip
        """Step until the robot's joints are still and on target; return the steps taken."""
        for k in range(1, max_steps + 1):
            self.step()
            qvel = self.robot.get_qvel()
            err = float((self.robot_joints() - self._robot_target).abs().max())
            if float(abs(qvel).max()) < velocity_tolerance and err < position_tolerance:
                return k
        return max_steps

    def drill(self, position: int, *, steps: int = 120, max_steps: int = 1500) -> DrillResult:
        """Move the drill over screw ``position`` and down onto it, and let the arm settle.

        Raises:
            ModelError: ``position`` out of range.
        """
        if not 0 <= int(position) < self.layout.n_positions:
            raise ModelError(
                f"expected a position in [0, {self.layout.n_positions}), got {position}"
            )
        self.move(self.robot_hover[position], None, steps)
        self.move(self.robot_drill[position], None, steps // 2)
        taken = self.settle(max_steps=max_steps)
        error = float((self.tip_position() - self.drill_tips[position]).norm())
        return DrillResult(settled=taken < max_steps, steps=taken + steps + steps // 2,
                           tip_error=error)  # fmt: skip


def _shoulder_y(urdf: str) -> float:
    import xml.etree.ElementTree as ET

    for joint in ET.fromstring(urdf).findall("joint"):
        if joint.get("name") == "shoulder_mount":
            origin = joint.find("origin")
            return float((origin.get("xyz") if origin is not None else "0 0 0").split()[1])
    raise ModelError("the person's URDF has no shoulder_mount joint")


def _to_sapien_pose(sapien: object, matrix: torch.Tensor) -> object:
    from torchhrc.kinematics import matrix_to_pose

    v = matrix_to_pose(matrix).tolist()
    return sapien.Pose(v[:3], v[3:])  # type: ignore[attr-defined]
