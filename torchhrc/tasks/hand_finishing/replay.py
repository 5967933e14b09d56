"""Replay a path of box configurations in the SAPIEN scene and measure where the box settles.

A policy's box moves (e.g. one simulated hand-finishing episode) are a path of
configurations ``(h, v, t)`` of
:class:`~torchhrc.tasks.hand_finishing.geometry.BoxGeometry`, one per step. The replay starts
the arm at rest at the first configuration
(:meth:`~torchhrc.tasks.hand_finishing.scene.HandFinishingScene.reset_box`), then commands
every change of configuration with joint position targets from the arm's inverse kinematics
(:meth:`~torchhrc.tasks.hand_finishing.scene.HandFinishingScene.move_box`), and records after
each move how far the box settled from the commanded pose (position and rotation error) and
whether the arm settled within the step budget. Steps where the configuration does not change
are skipped (the arm holds the box still).

Example:
    >>> path = torch.tensor([[1, 0, 1], [1, 0, 1], [1, 0, 2], [2, 0, 2]])
    >>> box_moves(path).tolist()
    [[1, 0, 1], [1, 0, 2], [2, 0, 2]]
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry

__all__ = ["ReplayResult", "box_moves", "replay_box_moves"]


@dataclass(frozen=True)
class ReplayResult:
    """The outcome of :func:`replay_box_moves` over ``M`` moves.

    Attributes:
        path: ``(M + 1, 3)`` int64 configurations ``(h, v, t)`` visited, the start first.
        position_error: ``(M,)`` distance (m) between the settled and the commanded box
            centre after each move.
        rotation_error: ``(M,)`` angle (rad) between the settled and the commanded box
            orientation after each move.
        settled: ``(M,)`` bool, the arm settled within the step budget.
        steps: ``(M,)`` int64 physics steps each move took.
    """

    path: torch.Tensor
    position_error: torch.Tensor
    rotation_error: torch.Tensor
    settled: torch.Tensor
    steps: torch.Tensor

    @property
    def num_moves(self) -> int:
        """``M``."""
        return int(self.position_error.shape[0])

    def summary(self) -> dict[str, float | int | bool]:
        """JSON-ready ``{"moves", "max_position_error_m", "max_rotation_error_rad",
        "all_settled", "physics_steps"}`` (maxima are 0 when there was no move)."""
        m = self.num_moves
        return {
            "moves": m,
            "max_position_error_m": float(self.position_error.max()) if m else 0.0,
            "max_rotation_error_rad": float(self.rotation_error.max()) if m else 0.0,
            "all_settled": bool(self.settled.all()),
            "physics_steps": int(self.steps.sum()),
        }


def box_moves(configurations: torch.Tensor) -> torch.Tensor:
    """The configurations ``(M + 1, 3)`` of a per-step path ``(L, 3)`` with repeats removed.

    A row is kept when it differs from the row before it (the first row is always kept).
    """
    configurations = torch.as_tensor(configurations)
    if configurations.dim() != 2 or configurations.shape[-1] != 3 or not len(configurations):
        raise ModelError(
            "expected configurations of shape (L, 3) with L >= 1, actual shape = "
            f"{tuple(configurations.shape)}"
        )
    changed = (configurations[1:] != configurations[:-1]).any(-1)
    keep = torch.cat([changed.new_ones(1), changed])
    return configurations[keep].long()


def replay_box_moves(
    configurations: torch.Tensor,
    *,
    scene: object | None = None,
    geometry: BoxGeometry | None = None,
    interpolation_steps: int = 150,
    max_steps: int = 1500,
    seed: int = 0,
) -> ReplayResult:
    """Replay a path of box configurations with joint position targets in the SAPIEN scene.

    Args:
        configurations: ``(L, 3)`` int ``(h, v, t)`` grid indices of the box at each step
            (consecutive repeats are no move).
        scene: a :class:`~torchhrc.tasks.hand_finishing.scene.HandFinishingScene` to use
            (default: a new one for ``geometry``, starting at the path's first
            configuration); it is reset to the path's first configuration. A new scene makes
            the replay reproducible: a used one carries the solver state of its past moves.
        geometry: the configuration grid of a new scene (default :class:`BoxGeometry`).
        interpolation_steps: physics steps over which each move's joint targets are
            interpolated.
        max_steps: physics step budget of each move (settling included).
        seed: seed of a new scene's inverse kinematics.

    Returns:
        :class:`ReplayResult`.

    Raises:
        ImportError: SAPIEN is missing (``pip install torchhrc[sim]``).
        ModelError: a configuration is out of range or not reachable.

    Example:
        >>> path = torch.tensor([[2, 1, 2], [2, 1, 3]])
        >>> replay_box_moves(path).position_error.shape  # doctest: +SKIP
        torch.Size([1])
    """
    from torchhrc.tasks.hand_finishing.scene import HandFinishingScene

    path = box_moves(configurations)
    if scene is None:
        scene = HandFinishingScene(geometry, seed=seed, start=tuple(path[0].tolist()))
    if not isinstance(scene, HandFinishingScene):
        raise TypeError(f"expected scene to be a HandFinishingScene, got {type(scene).__name__}")
    scene.reset_box(*path[0].tolist())
    pos, rot, settled, steps = [], [], [], []
    for h, v, t in path[1:].tolist():  # a replay is sequential in time
        r = scene.move_box(h, v, t, interpolation_steps=interpolation_steps, max_steps=max_steps)
        pos.append(r.position_error)
        rot.append(r.rotation_error)
        settled.append(r.settled)
        steps.append(r.steps)
    return ReplayResult(
        path=path,
        position_error=torch.tensor(pos, dtype=torch.float64),
        rotation_error=torch.tensor(rot, dtype=torch.float64),
        settled=torch.tensor(settled, dtype=torch.bool),
        steps=torch.tensor(steps, dtype=torch.long),
    )
