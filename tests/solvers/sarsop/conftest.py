"""The tests of torchhrc/solvers/sarsop/, one module a file as the package has them; they share
tests/solvers/'s helpers (``_exact_pomdp``), put on the path here so that a file of this folder
also runs alone."""

from __future__ import annotations

import sys
from pathlib import Path

_SOLVER_TESTS = str(Path(__file__).resolve().parents[1])
if _SOLVER_TESTS not in sys.path:
    sys.path.insert(0, _SOLVER_TESTS)
