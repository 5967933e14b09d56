"""Build steps: copy the top-level ``assets/`` and ``models/`` (the single source of the
shipped files) into the package of a wheel, as ``torchhrc/assets`` and ``torchhrc/models``;
compile the C inner loops of SARSOP: the sawtooth upper bound (``torchhrc/solvers/_sawtooth.c``)
and the one-belief evaluation of a model with one observed value
(``torchhrc/solvers/_backup.c``), both on the CPython API only: no numpy headers, no torch
headers.

Metadata lives in pyproject.toml; :mod:`torchhrc.resources` finds the files in a wheel and,
for an editable install or a checkout, at the top level. The extensions are optional: without a
C compiler the install goes on; :mod:`torchhrc.solvers.sawtooth_kernel` then runs the same loop
in Python (correct, much slower, with a warning) and SARSOP its numpy evaluation
(:mod:`torchhrc.solvers.backup_kernel`).
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


FLAGS = ["-O3"] if not sys.platform.startswith("win") else []
SHARED = ["torchhrc/solvers/_kernel_util.h"]
EXTENSIONS = [
    Extension(
        f"torchhrc.solvers.{name}",
        sources=[f"torchhrc/solvers/{name}.c"],
        depends=SHARED,
        extra_compile_args=FLAGS,
        optional=True,
    )
    for name in ("_sawtooth", "_backup")
]

setup(cmdclass={"build_py": BuildPyWithShippedFiles}, ext_modules=EXTENSIONS)
