"""Where the shipped files are: one lookup for a source checkout, an editable install and a wheel.

The repository keeps the shipped files in two top-level folders, the single source:

* ``models/``: model files (JSON / safetensors), e.g. the hand-coded expert MOMDP
  ``models/place_and_drill_expert.json``;
* ``assets/``: URDFs and meshes, e.g. ``assets/panda/panda.urdf``.

The build (``setup.py``'s ``build_py`` step) copies both into the package, so a wheel holds
them as ``torchhrc/models/`` and ``torchhrc/assets/``. :func:`shipped_path` looks inside the
installed package first and then in the checkout the package was imported from (a source
tree on ``PYTHONPATH`` or an editable install, where nothing is copied).

Example:
    >>> shipped_path("assets", "panda/panda.urdf").name
    'panda.urdf'
    >>> shipped_path("models", "place_and_drill_expert.json").name
    'place_and_drill_expert.json'
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Literal

__all__ = ["SHIPPED_KINDS", "shipped_path", "shipped_root"]

#: The top-level folders of shipped files.
SHIPPED_KINDS: tuple[str, ...] = ("assets", "models")


def _candidates(kind: str) -> list[Path]:
    package = Path(str(resources.files("torchhrc")))
    return [package / kind, package.parent / kind]


def shipped_root(kind: Literal["assets", "models"]) -> Path:
    """The folder that holds the shipped ``kind`` (``"assets"`` or ``"models"``).

    Raises:
        ValueError: an unknown ``kind``.
        FileNotFoundError: neither the package nor its checkout has the folder.
    """
    if kind not in SHIPPED_KINDS:
        raise ValueError(f"expected kind in {SHIPPED_KINDS}, got {kind!r}")
    places = _candidates(kind)
    for place in places:
        if place.is_dir():
            return place
    raise FileNotFoundError(
        f"no shipped {kind!r} folder: looked in {', '.join(str(p) for p in places)} "
        "(an installed wheel has it inside the package; a checkout at its top level)"
    )


def shipped_path(kind: Literal["assets", "models"], name: str) -> Path:
    """Path of the shipped file ``name`` (``/``-separated, relative to the ``kind`` folder).

    Args:
        kind: ``"assets"`` (URDFs, meshes) or ``"models"`` (model files).
        name: e.g. ``"panda/panda.urdf"``.

    Raises:
        ValueError: an unknown ``kind`` or a name leaving the folder.
        FileNotFoundError: no such file.
    """
    parts = [p for p in name.split("/") if p]
    if not parts or any(p == ".." for p in parts):
        raise ValueError(f"expected a relative name inside {kind}/, got {name!r}")
    root = shipped_root(kind)
    path = root.joinpath(*parts)
    if not path.is_file():
        raise FileNotFoundError(f"no shipped file {name!r} under {root}")
    return path
