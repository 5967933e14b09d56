"""The documentation site builds with warnings as errors, and documents every public name.

Runs ``mkdocs build --strict`` (mkdocs.yml: the pages of docs/ and the API reference built
from the docstrings by mkdocstrings) into a temporary folder, so a docstring griffe cannot
read, a dead cross-reference (``:func:`torchhrc.nowhere```), a broken link or a page missing
from the navigation fails the suite. Then every name in the ``__all__`` of torchhrc and of
each public module must be in the site's object inventory (``objects.inv``): a name the
generated API pages (docs/_ext/api_pages.py) leave out fails too. Skipped only when the
``docs`` extra is not installed.
"""

from __future__ import annotations

import importlib
import inspect
import os
import pkgutil
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytest.importorskip("mkdocs", reason="the docs build needs the docs extra (mkdocs)")
pytest.importorskip("mkdocstrings_handlers.python", reason="needs mkdocstrings[python]")
pytest.importorskip("material", reason="the docs theme needs mkdocs-material")


def _inventory(site: Path) -> set[str]:
    """Object names of a Sphinx v2 inventory (four header lines, then zlib-compressed)."""
    header_and_body = (site / "objects.inv").read_bytes().split(b"\n", 4)
    body = zlib.decompress(header_and_body[4]).decode()
    return {line.split(" ", 1)[0] for line in body.splitlines() if line}


def _public_names() -> list[tuple[str, str, set[str]]]:
    """``(module, name, accepted paths)`` for every name of every public ``__all__``."""
    import torchhrc

    modules = [torchhrc]
    for info in pkgutil.walk_packages(torchhrc.__path__, "torchhrc."):
        if any(part.startswith("_") for part in info.name.split(".")):
            continue
        try:
            modules.append(importlib.import_module(info.name))
        except ImportError:  # an optional extra (gymnasium) is missing: the build covers it
            continue
    out = []
    for module in modules:
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if inspect.ismodule(obj):
                continue
            paths = {f"{module.__name__}.{name}"}
            owner, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
            if isinstance(owner, str) and isinstance(qualname, str):
                paths.add(f"{owner}.{qualname}")  # documented where it is defined
            out.append((module.__name__, name, paths))
    return out


@pytest.mark.slow
def test_docs_build_strict_and_cover_every_public_name(tmp_path):
    site = tmp_path / "site"
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_MKDOCS_2_WARNING="1")
    completed = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    log = completed.stdout[-3000:] + completed.stderr[-6000:]
    assert completed.returncode == 0, f"mkdocs build --strict failed:\n{log}"
    inventory = _inventory(site)
    missing = [f"{m}.{n}" for m, n, paths in _public_names() if not paths & inventory]
    assert not missing, f"public names missing from the API reference: {missing}"
