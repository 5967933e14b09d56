"""Build steps: copy the top-level ``assets/`` and ``models/`` (the single source of the
shipped files) into the package of a wheel, as ``torchhrc/assets`` and ``torchhrc/models``;
compile the C inner loop of the sawtooth upper bound (``torchhrc/solvers/_sawtooth.c``, the
CPython API only: no numpy headers, no torch headers).

Metadata lives in pyproject.toml; :mod:`torchhrc.resources` finds the files in a wheel and,
for an editable install or a checkout, at the top level. The extension is optional: without a
C compiler the install goes on and :mod:`torchhrc.solvers.sawtooth_kernel` runs the same loop
in Python (correct, much slower, with a warning).
"""

import shutil
import sys
from pathlib import Path

from setuptools import Extension, setup
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


SAWTOOTH = Extension(
    "torchhrc.solvers._sawtooth",
    sources=["torchhrc/solvers/_sawtooth.c"],
    extra_compile_args=["-O3"] if not sys.platform.startswith("win") else [],
    optional=True,
)

setup(cmdclass={"build_py": BuildPyWithShippedFiles}, ext_modules=[SAWTOOTH])
