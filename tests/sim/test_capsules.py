"""Capsule geometry: segment distance against brute force, URDF capsules, collisions text."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.sim.capsules import (
    Capsule,
    add_capsule_collisions,
    capsule_separation,
    capsules_from_urdf,
    segment_distance,
)


def _brute(p0, p1, q0, q1, n: int = 801) -> torch.Tensor:
    s = torch.linspace(0, 1, n, dtype=torch.float64)
    a = p0[..., None, :] + s[:, None] * (p1 - p0)[..., None, :]  # (..., n, 3)
    b = q0[..., None, :] + s[:, None] * (q1 - q0)[..., None, :]
    return torch.cdist(a, b).amin((-1, -2))


@pytest.mark.parametrize("batch", [(), (7,), (3, 4)])
def test_segment_distance_matches_brute_force(batch: tuple[int, ...]) -> None:
    g = torch.Generator().manual_seed(0)
    p0, p1, q0, q1 = (torch.randn(*batch, 3, generator=g, dtype=torch.float64) for _ in range(4))
    exact = segment_distance(p0, p1, q0, q1)
    assert exact.shape == batch
    # the exact distance is a lower bound of sampled distances, within the sampling step
    brute = _brute(p0, p1, q0, q1)
    assert (exact <= brute + 1e-12).all()
    assert torch.allclose(exact, brute, atol=5e-3)


def test_degenerate_and_parallel_segments() -> None:
    o = torch.zeros(3, dtype=torch.float64)
    x = torch.tensor([1.0, 0, 0], dtype=torch.float64)
    y = torch.tensor([0, 1.0, 0], dtype=torch.float64)
    assert float(segment_distance(o, o, y, y)) == pytest.approx(1.0)  # two points
    assert float(segment_distance(o, x, y, y + x)) == pytest.approx(1.0)  # parallel
    assert float(segment_distance(o, x, 2 * x, 3 * x)) == pytest.approx(1.0)  # collinear gap
    assert float(segment_distance(o, x, x / 2 - y, x / 2 + y)) == pytest.approx(0.0)  # crossing
    assert float(segment_distance(o, x, 2 * x + y, 2 * x + y)) == pytest.approx(2**0.5)


def test_capsule_separation_is_pairwise_minus_radii() -> None:
    a = torch.tensor([[0.0, 0, 0], [0.0, 0, 1.0]], dtype=torch.float64)
    b = torch.tensor([[2.0, 0, 0]], dtype=torch.float64)
    sep = capsule_separation(a, a, torch.tensor([0.1, 0.2]), b, b, torch.tensor([0.5]))
    assert sep.shape == (2, 1)
    assert torch.allclose(sep, torch.tensor([[1.4], [5**0.5 - 0.7]], dtype=torch.float64))


URDF = """<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
<origin xyz="0 0 0.5" rpy="0 0 0"/><axis xyz="0 0 1"/></joint>
<joint name="j2" type="fixed"><parent link="b"/><child link="c"/>
<origin xyz="0.3 0 0" rpy="0 0 0"/></joint></robot>"""


def test_capsules_from_urdf_follow_child_joints() -> None:
    caps = capsules_from_urdf(URDF, {"a": 0.1, "b": 0.05, "c": 0.02}, extra={"c": (0, 0, 0.1)})
    assert caps == (
        Capsule("a", (0.0, 0.0, 0.0), (0.0, 0.0, 0.5), 0.1),
        Capsule("b", (0.0, 0.0, 0.0), (0.3, 0.0, 0.0), 0.05),
        Capsule("c", (0.0, 0.0, 0.0), (0, 0, 0.1), 0.02),
    )
    with pytest.raises(ModelError, match="no child joint"):
        capsules_from_urdf(URDF, {"c": 0.1})
    with pytest.raises(ModelError, match="not a link"):
        capsules_from_urdf(URDF, {"zz": 0.1})
    with pytest.raises(ModelError, match="positive radius"):
        capsules_from_urdf(URDF, {"a": 0.0})


def test_collision_capsules_point_along_their_segments() -> None:
    caps = capsules_from_urdf(URDF, {"a": 0.1, "b": 0.05})
    text = add_capsule_collisions(URDF, caps)
    root = ET.fromstring(text)
    for cap in caps:
        link = next(x for x in root.findall("link") if x.get("name") == cap.link)
        collision = link.find("collision")
        shape = collision.find("geometry/capsule")
        assert float(shape.get("radius")) == pytest.approx(cap.radius)
        rpy = [float(v) for v in collision.find("origin").get("rpy").split()]
        r, p, _ = rpy  # R = Ry(p) Rx(r): its z column must be the segment's direction
        z = torch.tensor([torch.sin(torch.tensor(p)) * torch.cos(torch.tensor(r)),
                          -torch.sin(torch.tensor(r)),
                          torch.cos(torch.tensor(p)) * torch.cos(torch.tensor(r))])  # fmt: skip
        d = torch.tensor(cap.end) - torch.tensor(cap.start)
        assert torch.allclose(z.double(), (d / d.norm()).double(), atol=1e-6)
        assert float(shape.get("length")) == pytest.approx(float(d.norm()))
