"""Returning freed heap memory to the OS (:mod:`torchhrc.solvers._memory`)."""

from __future__ import annotations

import ctypes.util
import itertools
import sys

import pytest

from torchhrc.solvers import _memory
from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.tasks.classic import tiger


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_malloc_trim_runs_on_glibc() -> None:
    lib = ctypes.CDLL(ctypes.util.find_library("c"))
    assert _memory.release_free_memory() is hasattr(lib, "malloc_trim")


def test_a_solve_returns_memory_after_each_pruning(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []
    module = sys.modules["torchhrc.solvers.sarsop"]  # (the package exports the function)
    monkeypatch.setattr(module, "release_free_memory", lambda: calls.append(1) or True)
    history: list[dict] = []
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=60,
                       callback=lambda e: history.append(e) and False)  # fmt: skip
    sarsop(tiger(), cfg)
    # the alpha vectors were pruned (their count fell between two iterations) and each
    # pruning handed memory back; iterations without one did not
    drops = sum(b["n_alphas"] < a["n_alphas"] for a, b in itertools.pairwise(history))
    assert drops >= 1 and 1 <= len(calls) < len(history)
