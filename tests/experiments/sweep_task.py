"""A user's own sweep task, for tests/experiments/test_sweep.py (imported by its path).

``simulate`` stands for a user's study: a seeded computation of a few metrics from two swept
parameters. It also reports the process it ran in (``pid``), so that a test can tell that
a job ran in a worker and not in the driver, and it obeys two test switches read from the
environment (a worker inherits it):

* ``SWEEP_TEST_MARKERS=DIR``: every try writes ``DIR/start-<seed>-<n>`` and, when it
  returns, ``DIR/end-<seed>``, holding the id of the Ray task it ran as (empty outside a Ray
  task: a process pool's worker has other pids than the driver too); the first try of
  seed 0 kills its own process (SIGKILL) when ``SWEEP_TEST_KILL=1`` (unless it is the
  process ``SWEEP_TEST_DRIVER``: then it raises).
* ``SWEEP_TEST_GATE=DIR``: jobs with seed >= 2 wait for ``DIR/go`` (so a test can kill the
  driver after the first jobs finished and before the rest did).
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import torch


def simulate(*, seed: int, subjects: int = 4, noise: float = 0.1, label: str = "a") -> dict:
    """Metrics of ``subjects`` seeded draws at ``noise`` (the same for the same arguments)."""
    markers = os.environ.get("SWEEP_TEST_MARKERS")
    if markers:
        tries = len(list(Path(markers).glob(f"start-{seed}-*")))
        (Path(markers) / f"start-{seed}-{tries}").touch()
        if seed == 0 and tries == 0 and os.environ.get("SWEEP_TEST_KILL") == "1":
            if str(os.getpid()) == os.environ.get("SWEEP_TEST_DRIVER"):
                raise RuntimeError("the job runs in the driver: not killing it")
            os.kill(os.getpid(), signal.SIGKILL)  # the worker dies in the middle of the sweep
    gate = os.environ.get("SWEEP_TEST_GATE")
    if gate and seed >= 2:
        for _ in range(6000):  # at most 5 minutes, should the test not open the gate
            if (Path(gate) / "go").exists():
                break
            time.sleep(0.05)
    generator = torch.Generator().manual_seed(1000 * seed + subjects)
    draws = torch.rand(subjects, generator=generator, dtype=torch.float64)
    result = {
        "error_rate": float((draws < noise).double().mean()),
        "score": {"mean": float(draws.mean()), "per_subject": draws.tolist()},
        "long_label": float(len(label)),
        "pid": os.getpid(),
    }
    if markers:
        (Path(markers) / f"end-{seed}").write_text(_ray_task_id())
    return result


def _ray_task_id() -> str:
    """The id of the Ray task this runs as, or ``""`` (the driver, another process)."""
    ray = sys.modules.get("ray")  # a Ray worker imported it; a pool's worker did not
    if ray is None or not ray.is_initialized():
        return ""
    return ray.get_runtime_context().get_task_id() or ""


def no_seed(*, noise: float = 0.1) -> dict:
    """Not a sweep task: it takes no seed."""
    return {"noise": noise}


def anything(*, seed: int, **options: object) -> dict:
    """Takes any parameter (``**options``): values are read as int, float or text."""
    return {"seed_again": seed, "count": float(len(options))}
