"""Tests of torchhrc.tasks.hand_finishing.scene: the SAPIEN hand-finishing scene (physics only,
CPU); and the deprecated aliases left in torchhrc.sim."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("pytorch_kinematics")
pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def scene():
    pytest.importorskip("sapien")
    from torchhrc.tasks.hand_finishing.scene import HandFinishingScene

    return HandFinishingScene()


def test_box_settles_at_the_commanded_pose(scene):
    # Tolerance: 2 mm and 0.01 rad. The drives track IK targets solved to 0.1 mm / 1 mrad;
    # what is left is the drives' steady-state error under the compensated load, measured
    # at ~0.2 mm / 0.3 mrad.
    result = scene.move_box(4, 2, 3)
    assert result.settled
    assert result.position_error < 2e-3
    assert result.rotation_error < 1e-2
    # the box really moved: from the middle configuration to the far left, tilted 30 deg
    assert result.box_pose[1, 3].item() == pytest.approx(scene.geometry.horizontal[4], abs=2e-3)
    assert scene.geometry.horizontal[4] > 0.25
    expected = scene.commanded_box_pose(4, 2, 3)
    assert torch.allclose(result.box_pose, expected, atol=1e-2)
    # and it stays there
    scene.step(50)
    assert (scene.box_pose()[:3, 3] - expected[:3, 3]).norm().item() < 2e-3


def test_bad_configuration_is_rejected(scene):
    from torchhrc.errors import ModelError

    with pytest.raises(ModelError, match="indices"):
        scene.move_box(9, 0, 0)


def test_render_without_gpu_raises_a_clear_error():
    pytest.importorskip("sapien")
    if torch.cuda.is_available():
        pytest.skip("a GPU is present: rendering may work here")
    from torchhrc.sim import RenderUnavailableError
    from torchhrc.tasks.hand_finishing.scene import HandFinishingScene

    with pytest.raises(RenderUnavailableError, match="render=False"):
        HandFinishingScene(render=True)


@pytest.mark.parametrize(
    ("old", "name", "new"),
    [
        ("torchhrc.sim", "HandFinishingScene", "torchhrc.tasks.hand_finishing.scene"),
        ("torchhrc.sim", "MoveResult", "torchhrc.tasks.hand_finishing.scene"),
        ("torchhrc.sim", "ReplayResult", "torchhrc.tasks.hand_finishing.replay"),
        ("torchhrc.sim", "box_moves", "torchhrc.tasks.hand_finishing.replay"),
        ("torchhrc.sim", "replay_box_moves", "torchhrc.tasks.hand_finishing.replay"),
        ("torchhrc.sim.scene", "HandFinishingScene", "torchhrc.tasks.hand_finishing.scene"),
        ("torchhrc.sim.scene", "MoveResult", "torchhrc.tasks.hand_finishing.scene"),
        ("torchhrc.sim.replay", "box_moves", "torchhrc.tasks.hand_finishing.replay"),
        ("torchhrc.sim.replay", "replay_box_moves", "torchhrc.tasks.hand_finishing.replay"),
        ("torchhrc.sim.replay", "ReplayResult", "torchhrc.tasks.hand_finishing.replay"),
    ],
)
def test_old_paths_warn_and_return_the_moved_object(old, name, new):
    import importlib

    old_module, new_module = importlib.import_module(old), importlib.import_module(new)
    with pytest.warns(DeprecationWarning, match=f"{new}.{name}"):
        assert getattr(old_module, name) is getattr(new_module, name)
    with pytest.raises(AttributeError):
        old_module.no_such_name  # noqa: B018
