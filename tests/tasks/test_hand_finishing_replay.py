"""Tests of torchhrc.tasks.hand_finishing.replay: replaying box moves in the SAPIEN scene
(physics only, CPU)."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
from torchhrc.tasks.hand_finishing.replay import box_moves

# a small grid: the moves of a quick hand-finishing episode
GEOMETRY = BoxGeometry(horizontal=(-0.3, 0.0, 0.3), vertical=(0.2,), tilt=(-0.5, 0.0, 0.5))
PATH = torch.tensor([[1, 0, 1], [1, 0, 1], [1, 0, 2], [1, 0, 2], [2, 0, 2], [1, 0, 1]])


def test_box_moves_drops_repeats_only():
    assert box_moves(PATH).tolist() == [[1, 0, 1], [1, 0, 2], [2, 0, 2], [1, 0, 1]]
    # a return to an earlier configuration is a move; a single row is a path without moves
    assert box_moves(torch.tensor([[0, 0, 0], [1, 0, 0], [0, 0, 0]])).shape == (3, 3)
    assert box_moves(torch.tensor([[2, 0, 1]])).tolist() == [[2, 0, 1]]


def test_box_moves_rejects_bad_shapes():
    with pytest.raises(ModelError, match=r"\(L, 3\)"):
        box_moves(torch.zeros(4, 2, dtype=torch.long))
    with pytest.raises(ModelError, match=r"\(L, 3\)"):
        box_moves(torch.zeros(0, 3, dtype=torch.long))


@pytest.mark.sim
def test_replay_settles_at_every_commanded_pose_and_is_reproducible():
    pytest.importorskip("pytorch_kinematics")
    pytest.importorskip("sapien")
    from torchhrc.tasks.hand_finishing.replay import replay_box_moves
    from torchhrc.tasks.hand_finishing.scene import HandFinishingScene

    first = replay_box_moves(PATH, geometry=GEOMETRY)
    assert first.num_moves == 3
    assert first.path.tolist() == box_moves(PATH).tolist()
    assert bool(first.settled.all())
    # tolerance of test_scene: 2 mm and 0.01 rad
    assert float(first.position_error.max()) < 2e-3
    assert float(first.rotation_error.max()) < 1e-2
    summary = first.summary()
    assert summary["moves"] == 3 and summary["all_settled"] is True
    assert summary["max_position_error_m"] == pytest.approx(float(first.position_error.max()))
    # a fresh scene replays the same physics
    second = replay_box_moves(PATH, geometry=GEOMETRY)
    assert torch.equal(first.position_error, second.position_error)
    assert torch.equal(first.steps, second.steps)
    # reset_box puts the box at rest at a configuration without a move
    scene = HandFinishingScene(GEOMETRY, start=(1, 0, 1))
    scene.reset_box(2, 0, 2)
    commanded = scene.commanded_box_pose(2, 0, 2)
    assert (scene.box_pose()[:3, 3] - commanded[:3, 3]).norm().item() < 1e-3
    with pytest.raises(TypeError, match="HandFinishingScene"):
        replay_box_moves(PATH, scene=object())
