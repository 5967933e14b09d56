"""Smoke test: every script in examples/ runs to completion (exit 0) within a time limit."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))
TIMEOUT_S = 300  # generous: CI shares 2 cores; each example should take seconds


@pytest.mark.slow
@pytest.mark.parametrize("script", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_runs(script: Path, tmp_path: Path):
    # TORCHHRC_EXAMPLES_QUICK=1: an example that reads it runs the same steps at smaller
    # sizes (cluster_demos.py: about 100 s of CPU at its full size, 22 s quick)
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0", TORCHHRC_EXAMPLES_QUICK="1")
    completed = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,  # examples must not depend on the working directory or litter it
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )
    assert completed.returncode == 0, (
        f"{script.name} exited with {completed.returncode}\n"
        f"stdout:\n{completed.stdout[-2000:]}\nstderr:\n{completed.stderr[-4000:]}"
    )
    assert completed.stdout.strip(), f"{script.name} printed nothing"
