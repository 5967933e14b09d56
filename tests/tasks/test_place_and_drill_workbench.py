"""The place-and-drill workbench in SAPIEN: drills settle, separation is right, replays."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.sim.capsules import Capsule
from torchhrc.tasks.place_and_drill.workbench import WorkbenchLayout, human_urdf, robot_urdf

pytestmark = pytest.mark.sim
sapien = pytest.importorskip("sapien", reason="the [sim] extra (SAPIEN 3) is not installed")


@pytest.fixture(scope="module")
def scene():
    from torchhrc.tasks.place_and_drill.workbench import PlaceAndDrillScene

    return PlaceAndDrillScene()


def test_layout_validation() -> None:
    with pytest.raises(ModelError, match="n_positions"):
        WorkbenchLayout(n_positions=0)
    with pytest.raises(ModelError, match="person_x"):
        WorkbenchLayout(person_x=0.3)
    assert WorkbenchLayout(n_positions=4).screw_positions().shape == (4, 3)
    wide = WorkbenchLayout(n_positions=8).screw_positions()
    assert float(wide[-1, 1] - wide[0, 1]) == pytest.approx(0.6)  # narrowed to stay in reach


def test_every_task_size_is_reachable() -> None:
    from torchhrc.tasks.place_and_drill.workbench import PlaceAndDrillScene

    for n in (1, 8):
        scene = PlaceAndDrillScene(WorkbenchLayout(n_positions=n))
        assert scene.robot_drill.shape == (n, 7) and scene.human_place.shape[0] == n


def test_drill_settles_on_every_screw(scene) -> None:
    scene.reset()
    for p in range(scene.layout.n_positions):
        result = scene.drill(p)
        assert result.settled
        assert result.tip_error < 2e-3  # m: the drill's tip on the screw
        assert scene.contacts() == 0  # the person's arm rests away from the bench


def _pk_link_poses(urdf: str, q: torch.Tensor) -> dict[str, torch.Tensor]:
    """World-independent link poses by pytorch-kinematics (an implementation of its own)."""
    import pytorch_kinematics as pk

    chain = pk.build_chain_from_urdf(urdf.encode()).to(dtype=torch.float64)
    frames = chain.forward_kinematics(q.unsqueeze(0))
    return {name: t.get_matrix()[0] for name, t in frames.items()}


def _independent_separation(scene, q_robot: torch.Tensor, q_human: torch.Tensor) -> float:
    """Capsules placed by pytorch-kinematics FK, distance by dense sampling of the segments."""
    lay = scene.layout

    def world(urdf: str, caps: tuple[Capsule, ...], base: torch.Tensor, q: torch.Tensor):
        poses = _pk_link_poses(urdf, q)
        pts, radii = [], []
        s = torch.linspace(0, 1, 401, dtype=torch.float64)[:, None]
        for c in caps:
            pose = base @ poses[c.link]
            a = pose[:3, :3] @ torch.tensor(c.start, dtype=torch.float64) + pose[:3, 3]
            b = pose[:3, :3] @ torch.tensor(c.end, dtype=torch.float64) + pose[:3, 3]
            pts.append(a + s * (b - a))
            radii.append(c.radius)
        return pts, radii

    r_text, r_caps = robot_urdf(lay)
    h_text, h_caps = human_urdf(lay)
    r_pts, r_rad = world(r_text, r_caps, lay.robot_base(), q_robot)
    h_pts, h_rad = world(h_text, h_caps, scene._person_base, q_human)
    best = float("inf")
    for a, ra in zip(r_pts, r_rad):
        for b, rb in zip(h_pts, h_rad):
            best = min(best, float(torch.cdist(a, b).min()) - ra - rb)
    return best


@pytest.mark.parametrize(("drill", "place"), [(0, 2), (1, 0), (2, 1)])
def test_separation_of_poses_set_by_hand_matches_an_independent_computation(
    scene, drill: int, place: int
) -> None:
    q_robot, q_human = scene.robot_drill[drill], scene.human_above[place]
    scene.set_poses(q_robot, q_human)
    measured = scene.separation()
    expected = _independent_separation(scene, q_robot, q_human)
    # float32 joints in SAPIEN, sampling step of 1/400 segment: agreement to 2 mm
    assert measured == pytest.approx(expected, abs=2e-3)
    assert measured > 0.0


def test_drilling_where_the_hand_is_is_below_threshold_or_in_contact(scene) -> None:
    scene.reset()
    first, c1 = scene.move(scene.robot_drill[1], (scene.human_rest, scene.human_place[1]), 80)
    held, c2 = scene.move(None, (scene.human_place[1], scene.human_place[1]), 100)
    assert min(first, held) < 0.10 or c1 + c2 > 0
    scene.reset()
    far, touching = scene.move(None, (scene.human_rest, scene.human_place[2]), 80)
    assert far > 0.10 and touching == 0  # the robot at home while the person places


def test_replay_of_an_execution(scene) -> None:
    from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
    from torchhrc.tasks.place_and_drill.replay import execution_steps, replay_execution

    task = PlaceAndDrillTask(3)
    # efficient turn taking: place A; drill A while placing B; drill B while placing C; drill C
    x = [task.initial_state]
    x.append(int(task.place_effect[x[-1], 0]))
    x.append(int(task.place_effect[task.robot_effect[1, x[-1]], 1]))
    x.append(int(task.place_effect[task.robot_effect[2, x[-1]], 2]))
    x.append(int(task.robot_effect[3, x[-1]]))
    x.append(x[-1])  # a step after the end: not replayed
    states, actions = torch.tensor(x), torch.tensor([0, 1, 2, 3, 0])
    drill, place = execution_steps(task, states, actions)
    assert drill.tolist() == [-1, 0, 1, 2] and place.tolist() == [0, 1, 2, -1]
    replay = replay_execution(scene, drill, place)
    assert replay.separation.shape == (4,) and replay.contacts.shape == (4,)
    assert float(replay.separation[0]) > 0.10  # the robot waits at home
    assert float(replay.separation[1:3].min()) < float(replay.separation[0])
    with pytest.raises(ModelError, match="expected states"):
        execution_steps(task, states, actions[:2])


def test_rendering_without_a_gpu_fails_clearly() -> None:
    from torchhrc.sim.scene import RenderUnavailableError
    from torchhrc.tasks.place_and_drill.workbench import PlaceAndDrillScene

    if torch.cuda.is_available():
        pytest.skip("a GPU is present: the render path is checked on the device machine")
    with pytest.raises(RenderUnavailableError, match="GPU"):
        PlaceAndDrillScene(render=True)
