"""Tests of torchhrc.kinematics.chain: FK against pinocchio and pytorch-kinematics, IK, reach.

The hand-finishing box (its poses serve here as IK targets) is tested in
tests/tasks/test_hand_finishing_geometry.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

pytest.importorskip("pytorch_kinematics")

from torchhrc.errors import ModelError
from torchhrc.kinematics import (
    SerialArm,
    asset_path,
    matrix_to_pose,
    reach_check,
)
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry

D = torch.float64


def _random_q(arm: SerialArm, n: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    u = torch.rand(n, arm.dof, generator=gen, dtype=D)
    return arm.lower + (arm.upper - arm.lower) * u


# ------------------------------------------------------------------ forward kinematics
@pytest.mark.parametrize(
    ("asset", "end"), [("panda/panda.urdf", "panda_hand_tcp"), ("human_arm/human_arm.urdf", "palm")]
)
def test_forward_kinematics_matches_pinocchio(asset, end):
    pin = pytest.importorskip("pinocchio")
    arm = SerialArm(asset_path(asset), end)
    model = pin.buildModelFromUrdf(str(asset_path(asset)))
    data = model.createData()
    frame = model.getFrameId(end)
    names = [model.names[i] for i in range(1, model.njoints)]
    assert tuple(names) == arm.joint_names
    q = _random_q(arm, 25, seed=0)
    ours = arm.forward(q)
    for n in range(q.shape[0]):
        pin.forwardKinematics(model, data, q[n].numpy())
        pin.updateFramePlacements(model, data)
        ref = torch.from_numpy(np.array(data.oMf[frame].homogeneous))
        assert torch.allclose(ours[n, :3, 3], ref[:3, 3], atol=1e-6)  # positions
        assert torch.allclose(ours[n, :3, :3], ref[:3, :3], atol=1e-6)  # orientations


def test_forward_kinematics_and_jacobian_match_pytorch_kinematics(panda):
    q = _random_q(panda, 50, seed=1)
    ref = panda.chain.forward_kinematics(q).get_matrix()
    assert torch.allclose(panda.forward(q), ref, atol=1e-12)
    assert torch.allclose(panda.jacobian(q), panda.chain.jacobian(q), atol=1e-12)


def test_jacobian_matches_finite_differences(panda):
    q = _random_q(panda, 3, seed=2)
    jac = panda.jacobian(q)
    eps = 1e-6
    for i in range(panda.dof):
        dq = torch.zeros(panda.dof, dtype=D)
        dq[i] = eps
        plus, minus = panda.forward(q + dq), panda.forward(q - dq)
        lin = (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * eps)
        # angular velocity from dR R^T (a skew matrix)
        dr = (plus[:, :3, :3] - minus[:, :3, :3]) / (2 * eps)
        w = dr @ panda.forward(q)[:, :3, :3].transpose(-1, -2)
        ang = torch.stack([w[:, 2, 1], w[:, 0, 2], w[:, 1, 0]], dim=-1)
        assert torch.allclose(
            jac[:, :3, i], lin, atol=1e-7
        )  # central differences: O(eps^2) + roundoff
        assert torch.allclose(jac[:, 3:, i], ang, atol=1e-7)


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_forward_is_batched(panda, batch):
    q = _random_q(panda, int(np.prod(batch)) if batch else 1, seed=3).reshape(*batch, 7)
    out = panda.forward(q)
    assert out.shape == (*batch, 4, 4)
    flat = out.reshape(-1, 4, 4)
    for n, qn in enumerate(q.reshape(-1, 7)):
        assert torch.allclose(flat[n], panda.forward(qn), atol=1e-14)


def test_bad_inputs_are_rejected(panda):
    with pytest.raises(ModelError, match=r"DOF=7"):
        panda.forward(torch.zeros(6, dtype=D))
    with pytest.raises(ModelError, match=r"\(\.\.\., 4, 4\) or \(\.\.\., 7\)"):
        reach_check(torch.zeros(3, 5, dtype=D), arm=panda)
    with pytest.raises(ModelError, match="end_link"):
        SerialArm(asset_path("panda/panda.urdf"), "no_such_link")
    with pytest.raises(FileNotFoundError):
        asset_path("nothing/here.urdf")


# ------------------------------------------------------------------ inverse kinematics
def test_ik_solutions_reach_their_targets_within_limits(panda):
    q = _random_q(panda, 60, seed=5)
    # keep away from the limits' corners, where a random start rarely converges
    q = panda.lower + (q - panda.lower) * 0.8 + 0.1 * (panda.upper - panda.lower)
    targets = panda.forward(q)
    res = panda.inverse(targets, seed=0)
    assert res.success.float().mean() >= 0.95
    ok = res.success
    fk = panda.forward(res.joints[ok])
    assert torch.allclose(fk[:, :3, 3], targets[ok, :3, 3], atol=1e-4)
    cos = ((fk[:, :3, :3] * targets[ok, :3, :3]).sum((-2, -1)) - 1) / 2
    assert (torch.acos(cos.clamp(-1, 1)) <= 1e-3 + 1e-9).all()
    assert ((res.joints >= panda.lower) & (res.joints <= panda.upper)).all()
    assert (res.position_error[ok] <= 1e-4).all()


def test_ik_accepts_pose_vectors_and_positions(panda):
    q = torch.tensor([0.2, -0.4, 0.1, -2.1, 0.2, 1.9, 0.3], dtype=D)
    target = panda.forward(q)
    res = panda.inverse(matrix_to_pose(target))
    assert bool(res.success)
    pos = panda.inverse(target[:3, 3], position_only=True)
    assert bool(pos.success) and float(pos.rotation_error) == 0.0
    assert torch.allclose(panda.forward(pos.joints)[:3, 3], target[:3, 3], atol=1e-4)


def test_ik_batched_equals_one_at_a_time(panda):
    g = BoxGeometry(horizontal=(-0.4, 0.0, 0.6), vertical=(0.05, 0.45), tilt=(0.0, math.pi / 3))
    poses = g.grip_poses().reshape(-1, 4, 4)
    batched = reach_check(poses, arm=panda, seed=3)
    for n in range(poses.shape[0]):
        one = reach_check(poses[n : n + 1], arm=panda, seed=3)
        assert bool(one.reachable[0]) == bool(batched.reachable[n])
        assert torch.allclose(one.joints[0], batched.joints[n], atol=1e-9)
        assert float(one.error[0]) == pytest.approx(float(batched.error[n]), abs=1e-9)


def test_far_poses_are_unreachable_and_near_ones_reachable(panda):
    home = torch.tensor([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8], dtype=D)
    reachable = panda.forward(home)
    far = reachable.clone()
    far[:3, 3] = torch.tensor([2.0, 1.0, 0.5], dtype=D)  # 2.2 m away: outside the workspace
    inside_but_wrong = reachable.clone()
    inside_but_wrong[:3, 3] = torch.tensor([0.0, 0.0, -0.5], dtype=D)  # below the base
    res = reach_check(torch.stack([reachable, far, inside_but_wrong]), arm=panda)
    assert res.reachable.tolist() == [True, False, False]
    assert float(res.error[1]) > 1.0
    assert res.joints.shape == (3, 7)


def test_seeded_restarts_are_deterministic(panda):
    poses = BoxGeometry().grip_poses().reshape(-1, 4, 4)[::10]
    a = reach_check(poses, arm=panda, seed=7)
    b = reach_check(poses, arm=panda, seed=7)
    assert torch.equal(a.joints, b.joints) and torch.equal(a.reachable, b.reachable)


# ------------------------------------------------------------ fast paths of reach_check
def test_wrist_bound_is_the_exact_maximum_for_the_panda(panda):
    # |p_5 - p_0| depends only on joint 4 (index 3) for the Panda: sweep it (no limits).
    q = torch.zeros(4001, 7, dtype=D)
    q[:, 3] = torch.linspace(-math.pi, math.pi, 4001, dtype=D)
    frames, _ = panda._frames(q)
    reach = (frames[:, 5, :3, 3] - frames[:, 0, :3, 3]).norm(dim=-1)
    bound = panda._wrist[0]
    assert float(reach.max()) <= bound + 1e-12
    assert float(reach.max()) == pytest.approx(bound, abs=1e-6)  # tight
    assert bound < panda.max_reach - 0.3  # much tighter than the sum of all the links


def test_wrist_precheck_never_rejects_a_pose_the_arm_reaches(panda):
    # Joint vectors well beyond the limits too: the pre-check ignores limits.
    gen = torch.Generator().manual_seed(11)
    q = (torch.rand(4000, 7, generator=gen, dtype=D) * 2 - 1) * 3.5
    poses = panda.forward(q)
    assert not panda._provably_unreachable(poses, 0.0, 0.0).any()
    # a pose within the tolerances of a reachable one is not rejected either
    shifted = poses.clone()
    shifted[:, :3, 3] += 1e-3 * torch.nn.functional.normalize(
        torch.randn(4000, 3, generator=gen, dtype=D), dim=-1
    )
    assert not panda._provably_unreachable(shifted, 1e-3, 1e-2).any()


def test_fast_reach_check_agrees_with_full_ik(panda):
    # A wide grid, most of it out of reach: the pre-check may only drop poses that the full
    # IK (same starts and tolerances, no pre-check) cannot reach either.
    g = BoxGeometry(
        horizontal=(-0.9, -0.45, 0.0, 0.45, 0.9),
        vertical=(-0.2, 0.3, 0.8),
        tilt=(-math.pi / 2, 0.0, math.pi / 3),
    )
    poses = g.grip_poses().reshape(-1, 4, 4)
    fast = reach_check(poses, arm=panda, seed=1)
    full = panda.inverse(poses, position_tolerance=1e-3, rotation_tolerance=1e-2, seed=1)
    rejected = panda._provably_unreachable(poses, 1e-3, 1e-2)
    assert rejected.sum() >= 10 and fast.reachable.sum() >= 5
    assert torch.equal(fast.reachable, full.success)
    assert not full.success[rejected].any()


def test_staged_restarts_find_the_same_reachable_poses(panda, monkeypatch):
    import torchhrc.kinematics.chain as kin

    g = BoxGeometry(horizontal=(-0.6, 0.0, 0.6), vertical=(0.0, 0.5), tilt=(-1.2, 0.0, 1.2))
    poses = g.grip_poses().reshape(-1, 4, 4)
    staged = panda.inverse(poses, position_tolerance=1e-3, rotation_tolerance=1e-2, seed=2)
    monkeypatch.setattr(kin, "_RESTART_STAGES", ())  # every restart at once
    at_once = panda.inverse(poses, position_tolerance=1e-3, rotation_tolerance=1e-2, seed=2)
    assert torch.equal(staged.success, at_once.success)
    ok = staged.success
    assert (staged.position_error[ok] <= 1e-3).all() and (staged.rotation_error[ok] <= 1e-2).all()
