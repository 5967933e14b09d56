"""Where a solve's peak memory comes from: the resident memory over time, and what ran at each
jump.

SARSOP's peak resident memory (issue 33 goal 3) is either the state the search has built (its
vectors, tree and caches) or a moment's temporaries (a pruning's dense rows, a check's
copies), and only a timeline tells which. This script reads a model (``.pomdp`` or
``.pomdpx`` by suffix, ``sparse="auto"`` as ``torchhrc solve``), solves it with SARSOP for
``--limit`` seconds, and meanwhile reads the process's resident memory
(``/proc/self/statm``, Linux) every ``--every`` seconds from a thread. It prints:

* the net peak (``ru_maxrss`` less the resident memory after ``import torchhrc``);
* the timeline: the largest and the last reading in each of ``--bins`` slices of time;
* each *jump*: a reading ``--jump`` MB or more above the least of the last ``--window``
  seconds, with the main thread's innermost frames at that moment
  (``sys._current_frames``), at most one per ``--window``.

A reading is taken when the sampling thread holds the GIL, so a jump inside one long
compiled call is seen when the call returns, and its frames are the caller's. The docs'
section "The 20,000-state model's transients: where its peak came from"
(``docs/benchmarks.md``) was found this way.

Usage::

    python benchmarks/bench_memory_timeline.py FILE.pomdp --limit 10 [--jump 40]
"""

from __future__ import annotations

import argparse
import resource
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import NamedTuple


class Jump(NamedTuple):
    """A reading ``rise`` MB above the least reading of the window before it."""

    at: float  # seconds since the start
    low: float  # the least reading of the window (MB)
    high: float  # this reading (MB)


def _window_low(samples: list[tuple[float, float]], i: int, window: float) -> float:
    """The least reading of ``samples[i]`` and those of the ``window`` seconds before it."""
    t, low = samples[i]
    j = i - 1
    while j >= 0 and samples[j][0] >= t - window:
        low = min(low, samples[j][1])
        j -= 1
    return low


def find_jumps(samples: list[tuple[float, float]], jump: float, window: float) -> list[Jump]:
    """The readings ``(t, mb)`` at least ``jump`` MB above the least reading of the ``window``
    seconds before them (that reading included), at most one per ``window``: the first of a
    run of high readings.

    Example:
        >>> s = [(0.0, 10.0), (0.1, 10.0), (0.2, 80.0), (0.3, 90.0), (0.4, 12.0),
        ...      (1.5, 12.0), (2.0, 70.0)]
        >>> [(j.at, j.low, j.high) for j in find_jumps(s, 50.0, 1.0)]
        [(0.2, 10.0, 80.0), (2.0, 12.0, 70.0)]
    """
    found: list[Jump] = []
    for i, (t, mb) in enumerate(samples):
        low = _window_low(samples, i, window)
        if mb - low >= jump and (not found or t - found[-1].at >= window):
            found.append(Jump(t, low, mb))
    return found


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", type=Path, help="a .pomdp or .pomdpx model")
    parser.add_argument("--limit", type=float, default=10.0, help="SARSOP's time limit (s)")
    parser.add_argument("--every", type=float, default=0.005, help="seconds between readings")
    parser.add_argument("--jump", type=float, default=40.0, help="MB above the window's least")
    parser.add_argument("--window", type=float, default=0.75, help="seconds")
    parser.add_argument("--bins", type=int, default=30, help="slices of the timeline")
    args = parser.parse_args()
    if not Path("/proc/self/statm").exists():
        parser.error("the resident memory is read from /proc/self/statm (Linux only)")

    import torchhrc  # noqa: F401  (the baseline holds the import)
    from torchhrc.io.cassandra import read_pomdp
    from torchhrc.io.pomdpx import read_pomdpx
    from torchhrc.solvers.sarsop import SARSOPConfig, sarsop

    base = _rss_mb()
    t0 = time.perf_counter()
    samples: list[tuple[float, float]] = []
    frames: dict[float, str] = {}
    done = threading.Event()
    main_id = threading.main_thread().ident

    def sample() -> None:
        while not done.is_set():
            t, mb = time.perf_counter() - t0, _rss_mb() - base
            samples.append((t, mb))
            rise = mb - _window_low(samples, len(samples) - 1, args.window)
            if rise >= args.jump and main_id in sys._current_frames():
                stack = traceback.extract_stack(sys._current_frames()[main_id])[-5:]
                frames[t] = " | ".join(f"{Path(f.filename).name}:{f.lineno} {f.name}"
                                       for f in stack)  # fmt: skip
            time.sleep(args.every)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    read = read_pomdpx if args.file.suffix == ".pomdpx" else read_pomdp
    model = read(args.file, sparse="auto")
    read_s = time.perf_counter() - t0
    solution = sarsop(model, SARSOPConfig(time_limit=args.limit))
    done.set()
    thread.join()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    print(f"{args.file.name}: read {read_s:.1f} s, {solution.info['backups']} backups, "
          f"lower {solution.lower:.6g}, upper {solution.upper:.6g}; "
          f"net peak {peak:.1f} MB")  # fmt: skip
    print("\n| s | largest MB | last MB |\n|---|---|---|")
    step = max(1, -(-len(samples) // args.bins))  # (at most --bins rows)
    for i in range(0, len(samples), step):
        part = samples[i : i + step]
        top = max(part, key=lambda s: s[1])
        print(f"| {top[0]:.2f} | {top[1]:.1f} | {part[-1][1]:.1f} |")
    print("\njumps (the window's least -> the reading; the main thread's innermost frames):")
    for j in find_jumps(samples, args.jump, args.window):
        near = min(frames, key=lambda t: abs(t - j.at), default=None)
        where = frames[near] if near is not None and abs(near - j.at) < args.window else ""
        print(f"  {j.at:6.2f} s  {j.low:7.1f} -> {j.high:7.1f} MB  {where}")


if __name__ == "__main__":
    main()
