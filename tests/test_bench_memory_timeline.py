"""``benchmarks/bench_memory_timeline.py``: the jumps it reports, and one run end to end."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "bench_memory_timeline.py"


def _module():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("bench_memory_timeline", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_jumps_are_rises_above_the_window_least_one_per_window():
    """By hand: a rise of 70 MB at 0.2 s (90 at 0.3 s is the same run), then the memory back
    at 12; a steady climb of 10 MB a reading never rises 50 within 1 s; 70 at 5.0 s is 58
    above the 12 of 4.5 s."""
    find_jumps = _module().find_jumps
    samples = [(0.0, 10.0), (0.1, 10.0), (0.2, 80.0), (0.3, 90.0), (0.4, 12.0)]
    samples += [(1.0 + 0.25 * i, 12.0 + 10.0 * i) for i in range(8)]  # 12 .. 82 by 2.75 s
    samples += [(4.5, 12.0), (5.0, 70.0)]
    got = [(j.at, j.low, j.high) for j in find_jumps(samples, 50.0, 1.0)]
    assert got == [(0.2, 10.0, 80.0), (5.0, 12.0, 70.0)]
    assert find_jumps(samples, 100.0, 1.0) == []
    # a window shorter than the readings' gap holds one reading: nothing rises within it
    assert find_jumps(samples, 50.0, 0.05) == []


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="Linux's /proc only")
def test_a_short_solve_prints_its_peak_and_timeline():
    tiger = ROOT / "benchmarks" / "problems" / "tiger.pomdp"
    out = subprocess.run(
        [sys.executable, str(SCRIPT), str(tiger), "--limit", "0.3", "--bins", "5"],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    ).stdout
    head = out.splitlines()[0]
    assert head.startswith("tiger.pomdp: read ") and "net peak" in head
    peak = float(head.rsplit("net peak ", 1)[1].split()[0])
    rows = [line for line in out.splitlines() if line.startswith("| ") and "largest" not in line]
    assert 1 <= len(rows) <= 5
    largest = max(float(r.split("|")[2]) for r in rows)
    assert 0.0 <= largest <= peak + 1.0  # a reading is never above the process's peak
    assert "jumps" in out
