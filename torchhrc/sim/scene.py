"""SAPIEN 3 scene machinery shared by the tasks' scenes: the render-device check, URDF loading,
joint poses.

Physics only, on the CPU (``sapien.Scene([sapien.physx.PhysxCpuSystem()])``) by default.
``render=True`` needs a GPU with a Vulkan driver: without CUDA :func:`check_render_device`
raises :class:`RenderUnavailableError` at once; with CUDA the render system is first probed in
a subprocess (a failing Vulkan driver can crash the process that tries it), and the probe's
failure is raised the same way. The scenes themselves live with their tasks (the
hand-finishing box held by the arm: :mod:`torchhrc.tasks.hand_finishing.scene`; the
place-and-drill workbench: :mod:`torchhrc.tasks.place_and_drill.workbench`).

Example:
    >>> issubclass(RenderUnavailableError, RuntimeError)
    True
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from torchhrc._deprecation import moved_attribute
from torchhrc.errors import TorchHRCError

__all__ = [
    "RenderUnavailableError",
    "check_render_device",
    "import_sapien",
    "load_urdf_text",
    "set_joint_positions",
]

_SIM_EXTRA = "pip install torchhrc[sim]"


class RenderUnavailableError(TorchHRCError, RuntimeError):
    """Rendering was asked for but no GPU / Vulkan render device is usable."""


def import_sapien():
    """The ``sapien`` module; an ImportError naming the ``sim`` extra when it is missing."""
    try:
        import sapien
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(f"torchhrc.sim needs SAPIEN 3: {_SIM_EXTRA}") from exc
    return sapien


_PROBE = "import sapien; sapien.render.RenderSystem(); print('ok')"


def check_render_device(*, timeout: float = 60.0) -> None:
    """Raise :class:`RenderUnavailableError` unless SAPIEN can render here.

    Refuses at once without CUDA; otherwise creates a SAPIEN render system in a subprocess,
    so that a crashing Vulkan driver cannot take this process down.

    Example:
        >>> import torch
        >>> if not torch.cuda.is_available():
        ...     try:
        ...         check_render_device()
        ...     except RenderUnavailableError as e:
        ...         print("GPU" in str(e))
        True
    """
    if not torch.cuda.is_available():
        raise RenderUnavailableError(
            "render=True needs a GPU with a Vulkan driver, and no CUDA device is available "
            "here; use render=False (physics only, CPU)"
        )
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE],
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise RenderUnavailableError(
            f"probing the SAPIEN render device timed out after {timeout:.0f} s; use render=False"
        ) from None
    if proc.returncode != 0 or "ok" not in proc.stdout:
        last = (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
        raise RenderUnavailableError(
            f"SAPIEN cannot create a render device on this GPU ({last}); use render=False"
        )


def load_urdf_text(scene: object, text: str, *, render: bool = False) -> object:
    """Load URDF ``text`` into a SAPIEN ``scene`` as an articulation with a fixed root
    (collision shapes also drawn when ``render``); the text goes through a temporary file."""
    loader = scene.create_urdf_loader()  # type: ignore[attr-defined]
    loader.fix_root_link = True
    if render:
        loader.collision_is_visual = True
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.urdf"
        path.write_text(text)
        return loader.load(str(path))


def set_joint_positions(articulation: object, q: torch.Tensor, joints: list | None = None) -> None:
    """Place ``articulation``'s joints at ``q (DOF,)`` at rest; with ``joints`` (its active
    joints), also set their drive targets there (the arm holds the pose)."""
    import numpy as np

    arr = np.asarray(q.tolist(), dtype=np.float32)
    articulation.set_qpos(arr)  # type: ignore[attr-defined]
    articulation.set_qvel(np.zeros_like(arr))  # type: ignore[attr-defined]
    for joint, value in zip(joints or (), arr.tolist(), strict=False):
        joint.set_drive_target(value)


#: Names that moved to :mod:`torchhrc.tasks.hand_finishing.scene` (issue 32: the generic
#: scene machinery imports no task): deprecated aliases here for one release.
_MOVED_TO_TASK = {
    "HandFinishingScene": "torchhrc.tasks.hand_finishing.scene",
    "MoveResult": "torchhrc.tasks.hand_finishing.scene",
}


def __getattr__(name: str) -> object:
    return moved_attribute(__name__, name, _MOVED_TO_TASK)
