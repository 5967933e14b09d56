"""Tests of torchhrc.tasks.hand_finishing.geometry: the box's poses, the person's comfort, and
which configurations the task keeps; and the deprecated aliases in torchhrc.kinematics."""

from __future__ import annotations

import math

import pytest
import torch

pytest.importorskip("pytorch_kinematics")

from torchhrc.errors import ModelError
from torchhrc.kinematics import SerialArm
from torchhrc.tasks.hand_finishing import geometry
from torchhrc.tasks.hand_finishing.geometry import (
    BoxGeometry,
    PersonModel,
    comfort_check,
    feasible_box_configurations,
)

D = torch.float64


def test_bad_side_is_rejected():
    with pytest.raises(ModelError, match="side"):
        BoxGeometry().work_points("top")


def test_box_and_grip_poses_follow_the_documented_geometry():
    g = BoxGeometry()
    box = g.box_poses()
    grip = g.grip_poses()
    h, v, t = 1, 2, 4
    assert torch.allclose(
        box[h, v, t, :3, 3], torch.tensor([g.forward, g.horizontal[h], g.vertical[v]], dtype=D)
    )
    # the gripper approaches along +x of the base, from the box's back face
    assert torch.allclose(grip[h, v, t, :3, 2], torch.tensor([1.0, 0.0, 0.0], dtype=D), atol=1e-12)
    assert torch.allclose(
        grip[h, v, t, :3, 3], box[h, v, t, :3, 3] - torch.tensor([g.size[0] / 2, 0, 0], dtype=D)
    )
    # positive tilt raises the left (+y) side surface by width/2 * sin(tilt)
    left, right = g.work_points("left"), g.work_points("right")
    rise = g.size[1] / 2 * math.sin(g.tilt[t])
    assert left[h, v, t, 2].item() == pytest.approx(g.vertical[v] + rise)
    assert right[h, v, t, 2].item() == pytest.approx(g.vertical[v] - rise)
    assert g.index(1, 2, 4) == (1 * 4 + 2) * 5 + 4


# ---------------------------------------------------------------- human comfort
def test_comfort_check_rules():
    human = SerialArm.human_arm()
    person = PersonModel()
    front_x = 0.75
    body_x = front_x + person.standoff
    elbow = person.elbow_height - person.floor_height  # elbow height in the robot base frame
    pts = torch.tensor(
        [
            [body_x - 0.40, 0.0, elbow - 0.15],  # in the band, 40 cm ahead: comfortable
            [body_x - 0.40, 0.0, elbow + 0.30],  # above the band
            [body_x - 0.40, 0.0, elbow - 0.60],  # below the band
            [body_x - 0.80, 0.0, elbow - 0.15],  # beyond the arm's reach (0.67 m)
        ],
        dtype=D,
    )
    r = comfort_check(pts, front_x=front_x, person=person, human=human)
    assert r.height_ok.tolist() == [True, False, False, True]
    assert r.reach_ok[0] and not r.reach_ok[3]
    assert r.comfortable.tolist() == [True, False, False, False]
    # the comfortable solution keeps the upper arm at or below 90 degrees
    names = human.joint_names
    q = r.joints[0]
    assert q[names.index("shoulder_flexion")] <= math.pi / 2 + 1e-9
    palm = human.forward(q)[:3, 3]
    assert palm[0].item() == pytest.approx(0.40, abs=0.011)


def test_feasible_configurations_combine_reach_and_comfort():
    panda = SerialArm.panda()
    g = BoxGeometry(horizontal=(0.0, 0.9), vertical=(0.05, 0.45, 1.2), tilt=(0.0,))
    f = feasible_box_configurations(g, arm=panda)
    assert f.mask.shape == (2, 3, 1) and f.comfortable.shape == (2, 3, 1, 2)
    # 0.9 m to the side or 1.2 m up is beyond the Panda's reach (0.855 m from the shoulder)
    assert not f.reachable[1].any() and not f.reachable[:, 2].any()
    assert f.reachable[0, 0, 0] and f.reachable[0, 1, 0]
    assert torch.equal(f.mask, f.reachable & f.comfortable.any(-1))
    # the solutions of reachable configurations put the box where it should be
    fk = panda.forward(f.joints[f.reachable])
    assert torch.allclose(fk[:, :3, 3], g.grip_poses()[f.reachable][:, :3, 3], atol=1e-3)
    assert 0.0 <= f.fraction <= 1.0


# ------------------------------------------------------------- deprecated aliases
@pytest.mark.parametrize("name", sorted(geometry.__all__))
def test_kinematics_aliases_warn_and_return_the_moved_object(name):
    import torchhrc.kinematics as kinematics

    with pytest.warns(DeprecationWarning, match=f"torchhrc.tasks.hand_finishing.geometry.{name}"):
        old = getattr(kinematics, name)
    assert old is getattr(geometry, name)
    with pytest.raises(AttributeError):
        kinematics.no_such_name  # noqa: B018
