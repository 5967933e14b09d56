"""The solvers' clocks: :func:`deadline_watch` answers as the clock would, reading the
process's CPU time only when the wall clock allows it to have reached the limit."""

from __future__ import annotations

import math
import os
import time

import pytest

from torchhrc.solvers.clock import deadline_watch


class _FakeTime:
    """A wall clock set by the test and a CPU clock that rises ``rate`` times as fast."""

    def __init__(self, rate: float) -> None:
        self.wall, self.rate, self.cpu_reads = 0.0, rate, 0

    def perf_counter(self) -> float:
        return self.wall

    def process_time(self) -> float:
        self.cpu_reads += 1
        return self.rate * self.wall


@pytest.mark.parametrize("share", [1.0, 0.5, 0.01])
def test_process_watch_answers_as_the_cpu_clock(monkeypatch, share):
    """With the CPU time rising at the most the machine allows (``os.cpu_count()`` times the
    wall clock) the watch says "passed" at the first call after the limit; at a lower rate,
    never before it; and it reads the CPU clock far less often than it is asked."""
    fake = _FakeTime(share * max(1, os.cpu_count() or 1))
    monkeypatch.setattr(time, "perf_counter", fake.perf_counter)
    monkeypatch.setattr(time, "process_time", fake.process_time)
    at = 10.0
    passed = deadline_watch("process", at)
    calls, dt = 0, at / fake.rate / 100_000  # the limit at about the 100,000th call
    for step in range(200_000):
        fake.wall = step * dt
        calls += 1
        if passed():
            break
    else:
        pytest.fail("the watch never saw the limit")
    cpu = fake.rate * fake.wall
    assert cpu >= at  # never early
    assert fake.rate * (fake.wall - dt) < at  # the first call after the limit
    assert fake.cpu_reads < calls / 20


def test_other_clocks_are_read_at_every_call():
    reads = [0]

    def clock() -> float:
        reads[0] += 1
        return float(reads[0])

    passed = deadline_watch(clock, 3.0)
    assert [passed() for _ in range(4)] == [False, False, True, True]
    assert reads[0] == 4
    assert not deadline_watch("wall", math.inf)()
    assert deadline_watch("wall", time.perf_counter())()


def test_bad_clock_is_refused():
    with pytest.raises(ValueError, match="clock"):
        deadline_watch("cpu", 1.0)  # type: ignore[arg-type]
