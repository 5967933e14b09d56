"""Capsule collision geometry of serial arms, and batched capsule-capsule separation.

Both arms of the place-and-drill scene are modelled as chains of capsules: a link's capsule is
the segment from its frame origin to the origin of its child joint (fixed in the link's frame,
whatever the joint angles), with a radius per link (the ``radii`` table). The same capsules
are the collision shapes of the SAPIEN scene (:func:`add_capsule_collisions`) and the
geometry of the separation measure: the distance between two capsules is the distance
between their segments minus both radii (negative when they overlap).

Segment-segment distance: the closest points of ``p0 + s (p1 - p0)`` and
``q0 + t (q1 - q0)``, ``s, t`` in ``[0, 1]``, by clamping the unconstrained minimiser
and re-projecting (Ericson, "Real-Time Collision Detection", 2005, section 5.1.9), batched
over any leading dims, degenerate (point) segments included.

Example:
    >>> import torch
    >>> p = torch.tensor([[0.0, 0, 0], [1.0, 0, 0]])
    >>> q = torch.tensor([[0.5, 1.0, 0.0], [0.5, 2.0, 0.0]])
    >>> float(segment_distance(p[0], p[1], q[0], q[1]))
    1.0
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from torchhrc.errors import ModelError

__all__ = [
    "Capsule",
    "add_capsule_collisions",
    "capsule_separation",
    "capsules_from_urdf",
    "segment_distance",
]


@dataclass(frozen=True)
class Capsule:
    """A capsule fixed to a link: the segment ``start -> end`` (link frame, m) and a radius.

    Attributes:
        link: the link's name.
        start, end: ``(3,)`` endpoints in the link frame.
        radius: the radius (m).
    """

    link: str
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    radius: float


def _xyz(text: str | None) -> tuple[float, float, float]:
    values = [float(v) for v in (text or "0 0 0").split()]
    return (values[0], values[1], values[2])


def capsules_from_urdf(
    urdf: str,
    radii: Mapping[str, float],
    *,
    extra: Mapping[str, tuple[float, float, float]] | None = None,
) -> tuple[Capsule, ...]:
    """One capsule per link named in ``radii``: from the link's origin to its child joint's.

    Args:
        urdf: URDF text.
        radii: ``{link: radius}``; links not named get no capsule.
        extra: ``{link: end (3,)}`` for a link whose capsule ends elsewhere than its child
            joint (a leaf link such as a tool), in the link frame.

    Raises:
        ModelError: a named link has no child joint and no ``extra`` end, or is unknown.

    Example:
        >>> text = ('<robot name="r"><link name="a"/><link name="b"/><joint name="j" '
        ...         'type="fixed"><parent link="a"/><child link="b"/>'
        ...         '<origin xyz="0 0 0.5"/></joint></robot>')
        >>> capsules_from_urdf(text, {"a": 0.1})[0].end
        (0.0, 0.0, 0.5)
    """
    root = ET.fromstring(urdf)
    links = {link.get("name") for link in root.findall("link")}
    child_joint: dict[str, tuple[float, float, float]] = {}
    for joint in root.findall("joint"):
        parent = joint.find("parent")
        origin = joint.find("origin")
        if parent is None:
            continue
        name = parent.get("link", "")
        xyz = _xyz(origin.get("xyz") if origin is not None else None)
        # a link with several children keeps the farthest (the chain continues there)
        if name not in child_joint or sum(v * v for v in xyz) > sum(
            v * v for v in child_joint[name]
        ):
            child_joint[name] = xyz
    ends = dict(child_joint)
    ends.update(extra or {})
    out = []
    for link, radius in radii.items():
        if link not in links:
            raise ModelError(f"capsule link {link!r} is not a link of the URDF")
        if link not in ends:
            raise ModelError(f"link {link!r} has no child joint: give its capsule end in extra")
        if not radius > 0:
            raise ModelError(f"expected a positive radius for link {link!r}, got {radius}")
        out.append(Capsule(link, (0.0, 0.0, 0.0), ends[link], float(radius)))
    return tuple(out)


def _rpy_of_z_to(direction: tuple[float, float, float]) -> tuple[float, float, float]:
    """URDF ``rpy`` (yaw 0) of a rotation taking ``+z`` to the unit ``direction``."""
    dx, dy, dz = direction
    roll = -math.asin(max(-1.0, min(1.0, dy)))
    pitch = math.atan2(dx, dz) if abs(math.cos(roll)) > 1e-12 else 0.0
    return (roll, pitch, 0.0)


def add_capsule_collisions(urdf: str, capsules: tuple[Capsule, ...]) -> str:
    """The URDF with a ``<collision>`` capsule (SAPIEN's URDF extension) per capsule.

    A segment of zero length becomes a sphere. Capsule axes follow the segments.
    """
    root = ET.fromstring(urdf)
    by_name = {link.get("name"): link for link in root.findall("link")}
    for cap in capsules:
        link = by_name[cap.link]
        start = torch.tensor(cap.start, dtype=torch.float64)
        end = torch.tensor(cap.end, dtype=torch.float64)
        length = float((end - start).norm())
        centre = ((start + end) / 2).tolist()
        collision = ET.SubElement(link, "collision")
        if length < 1e-9:
            ET.SubElement(collision, "origin", xyz=" ".join(f"{v:.9g}" for v in centre))
            geometry = ET.SubElement(collision, "geometry")
            ET.SubElement(geometry, "sphere", radius=f"{cap.radius:.9g}")
            continue
        direction = ((end - start) / length).tolist()
        rpy = _rpy_of_z_to((direction[0], direction[1], direction[2]))
        ET.SubElement(collision, "origin", xyz=" ".join(f"{v:.9g}" for v in centre),
                      rpy=" ".join(f"{v:.12g}" for v in rpy))  # fmt: skip
        geometry = ET.SubElement(collision, "geometry")
        ET.SubElement(geometry, "capsule", radius=f"{cap.radius:.9g}", length=f"{length:.9g}")
    return ET.tostring(root, encoding="unicode")


def segment_distance(
    p0: torch.Tensor, p1: torch.Tensor, q0: torch.Tensor, q1: torch.Tensor
) -> torch.Tensor:
    """Distance between segments ``[p0, p1]`` and ``[q0, q1]``, all ``(..., 3)``; ``(...)``.

    Example:
        >>> import torch
        >>> o = torch.zeros(3)
        >>> float(segment_distance(o, o, torch.tensor([3.0, 4, 0]), torch.tensor([3.0, 4, 0])))
        5.0
    """
    d1, d2 = p1 - p0, q1 - q0
    r = p0 - q0
    a = (d1 * d1).sum(-1)
    e = (d2 * d2).sum(-1)
    f = (d2 * r).sum(-1)
    c = (d1 * r).sum(-1)
    b = (d1 * d2).sum(-1)
    eps = torch.finfo(p0.dtype).eps
    a_safe = torch.where(a > eps, a, torch.ones_like(a))
    e_safe = torch.where(e > eps, e, torch.ones_like(e))
    denom = a * e - b * b
    denom_safe = torch.where(denom > eps, denom, torch.ones_like(denom))
    # general case: s from the unconstrained minimiser (0 when parallel), clamped
    s = torch.where(denom > eps, ((b * f - c * e) / denom_safe).clamp(0, 1), torch.zeros_like(a))
    t = (b * s + f) / e_safe
    # t outside [0, 1]: clamp it and recompute s for that t
    s = torch.where(t < 0, (-c / a_safe).clamp(0, 1), torch.where(t > 1, ((b - c) / a_safe)
                    .clamp(0, 1), s))  # fmt: skip
    t = t.clamp(0, 1)
    # degenerate segments (points)
    p_point, q_point = a <= eps, e <= eps
    s = torch.where(p_point, torch.zeros_like(s), s)
    t = torch.where(q_point, torch.zeros_like(t), t)
    t = torch.where(p_point & ~q_point, (f / e_safe).clamp(0, 1), t)
    s = torch.where(q_point & ~p_point, (-c / a_safe).clamp(0, 1), s)
    closest_p = p0 + s.unsqueeze(-1) * d1
    closest_q = q0 + t.unsqueeze(-1) * d2
    return (closest_p - closest_q).norm(dim=-1)


def capsule_separation(
    a_start: torch.Tensor,
    a_end: torch.Tensor,
    a_radius: torch.Tensor,
    b_start: torch.Tensor,
    b_end: torch.Tensor,
    b_radius: torch.Tensor,
) -> torch.Tensor:
    """Pairwise separations of capsule sets: ``(..., Na, Nb)``, negative where they overlap.

    Args:
        a_start, a_end: ``(..., Na, 3)`` world endpoints; a_radius: ``(Na,)``.
        b_start, b_end: ``(..., Nb, 3)``; b_radius: ``(Nb,)``.

    Example:
        >>> import torch
        >>> z = torch.zeros(1, 3)
        >>> x = torch.tensor([[1.0, 0.0, 0.0]])
        >>> sep = capsule_separation(z, z, torch.tensor([0.1]), x, x, torch.tensor([0.2]))
        >>> round(sep.item(), 6)
        0.7
    """
    d = segment_distance(
        a_start.unsqueeze(-2), a_end.unsqueeze(-2), b_start.unsqueeze(-3), b_end.unsqueeze(-3)
    )
    return d - a_radius.unsqueeze(-1) - b_radius
