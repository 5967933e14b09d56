"""Build step: copy the top-level ``assets/`` and ``models/`` (the single source of the
shipped files) into the package of a wheel, as ``torchhrc/assets`` and ``torchhrc/models``.

Metadata lives in pyproject.toml; :mod:`torchhrc.resources` finds the files in a wheel and,
for an editable install or a checkout, at the top level.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
SHIPPED = ("assets", "models")


class BuildPyWithShippedFiles(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return  # an editable install reads them from the checkout
        for kind in SHIPPED:
            source = ROOT / kind
            if source.is_dir():
                shutil.copytree(source, Path(self.build_lib) / "torchhrc" / kind,
                                dirs_exist_ok=True)  # fmt: skip


setup(cmdclass={"build_py": BuildPyWithShippedFiles})
