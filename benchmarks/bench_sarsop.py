"""SARSOP benchmark: torchhrc's SARSOP against APPL's ``pomdpsol`` at equal time limits.

For each problem and time limit, prints our lower bound, upper bound and gap at ``b0`` beside
APPL SARSOP's (Kurniawati, Hsu & Lee 2008; built from its public source, path given with
``--appl``; the column is skipped without it), the ratio of the lower bounds and of the gaps.
Then the MOMDP-factored against the flat solve of RockSample (robot position observed): the
time each needs to reach the same gap, as a ratio; and batched backups of all tree beliefs
against one belief at a time.

pomdp-py is not a separate column: its offline solver ``pomdp_py.sarsop`` runs the same
``pomdpsol`` binary (so it would repeat APPL's figures), its ``ValueIteration`` enumerates
policy trees (exponential, infeasible beyond Tiger-sized problems) and ``POUCT``/``POMCP``
are online planners without bounds at ``b0``; none is a fair bound-for-bound comparison.

RockSample(7, 8) (12545 states) is read from ``problems/rocksample_7_8.pomdp`` (regenerate it
with ``problems/make_problems.py``) as a :class:`~torchhrc.sparse.SparsePOMDP` and solved by
SARSOP's sparse path: its dense transition tensor would have ``13 * 12545^2`` entries (16 GB)
and its MOMDP form a dense ``Ty`` of 2.1e9 entries. Reading the file (about 5 s) is outside
the time limit, as APPL's own loading is. The script limits numpy's BLAS to one thread
(``OPENBLAS_NUM_THREADS=1``): the sequential path multiplies small matrices, where a
multi-threaded BLAS is several times slower on a busy machine. Timings are wall-clock on
whatever cores the machine gives; print ``uptime`` beside the table.

Usage::

    python benchmarks/bench_sarsop.py [--limits 10 60] [--problems tiger rocksample_4_4 ...]
        [--appl /path/to/pomdpsol] [--precision 1e-3] [--no-momdp] [--no-batch]
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is imported (see above)

import numpy as np
import torch

from torchhrc.io.cassandra import read_pomdp
from torchhrc.solvers.sarsop import _SARSOP, SARSOPConfig, sarsop
from torchhrc.tasks.classic import rock_sample, rock_sample_momdp, tag, tiger

HERE = Path(__file__).resolve().parent
PROBLEMS = {
    "tiger": lambda: tiger(),
    "rocksample_4_4": lambda: rock_sample(4, 4),
    "rocksample_5_5": lambda: rock_sample(5, 5),
    # sparse: see the module docstring
    "rocksample_7_8": lambda: read_pomdp(HERE / "problems" / "rocksample_7_8.pomdp", sparse=True),
    "tag": lambda: tag(),
}
_ROW = re.compile(
    r"^\s*([0-9.eE+-]+)\s+(\d+)\s+(\d+)\s+([-0-9.eE+]+)\s+([-0-9.eE+]+)\s+([-0-9.eE+]+)"
)


def run_appl(binary: str, problem: Path, limit: float, precision: float) -> dict | None:
    """Run ``pomdpsol`` and parse its last progress row (time, trials, backups, bounds)."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [binary, str(problem), "--timeout", str(limit), "--precision", str(precision),
               "-o", str(Path(tmp) / "out.policy")]  # fmt: skip
        start = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=limit * 3 + 120)
        except subprocess.TimeoutExpired:
            return None
        wall = time.perf_counter() - start
    rows = [m for m in map(_ROW.match, proc.stdout.splitlines()) if m]
    if not rows:
        print(
            f"  (pomdpsol printed no bounds; stderr: {proc.stderr.strip()[:200]})", file=sys.stderr
        )
        return None
    last = rows[-1]
    return {
        "lower": float(last.group(4)),
        "upper": float(last.group(5)),
        "time_s": float(last.group(1)),
        "wall_s": wall,
        "backups": int(last.group(3)),
    }


def run_ours(model, limit: float, precision: float) -> dict:
    start = time.perf_counter()
    sol = sarsop(model, SARSOPConfig(time_limit=limit, precision=precision))
    return {
        "lower": sol.lower,
        "upper": sol.upper,
        "time_s": time.perf_counter() - start,
        "backups": sol.info["backups"],
        "history": sol.history,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _fmt(v: float | None, width: int = 10) -> str:
    return f"{'-':>{width}}" if v is None else f"{v:>{width}.4f}"


def quality_table(
    names: list[str], limits: list[float], appl: str | None, precision: float
) -> None:
    print("\n## SARSOP vs APPL: bounds at b0 at equal time limits")
    head = (f"{'problem':<16}{'limit':>6} | {'ours low':>10}{'ours up':>10}{'ours gap':>10}"
            f"{'backups':>9} | {'APPL low':>10}{'APPL up':>10}{'APPL gap':>10}{'backups':>9}"
            f" | {'low short':>9}{'gap/APPL':>9}")  # fmt: skip
    print(head)
    print("-" * len(head))
    for name in names:
        build = PROBLEMS[name]
        model = None if build is None else build()
        for limit in limits:
            ours = None
            if model is not None:
                ours = run_ours(model, limit, precision)
            ref = None
            if appl is not None:
                ref = run_appl(appl, HERE / "problems" / f"{name}.pomdp", limit, precision)
            cells = [f"{name:<16}{limit:>6.0f} |"]
            if ours is None:
                cells.append(f"{'(not run: dense model too large)':>39} |")
            else:
                gap = ours["upper"] - ours["lower"]
                cells.append(_fmt(ours["lower"]) + _fmt(ours["upper"]) + _fmt(gap)
                             + f"{ours['backups']:>9d} |")  # fmt: skip
            if ref is None:
                cells.append(f"{'-':>10}{'-':>10}{'-':>10}{'-':>9} |")
            else:
                ref_gap = ref["upper"] - ref["lower"]
                cells.append(
                    _fmt(ref["lower"]) + _fmt(ref["upper"]) + _fmt(ref_gap)
                    + f"{ref['backups']:>9d} |"
                )  # fmt: skip
            if ours is not None and ref is not None:
                ref_gap = ref["upper"] - ref["lower"]
                # shortfall of our lower bound, relative to |APPL's| (goal: <= 1%)
                short = (ref["lower"] - ours["lower"]) / max(abs(ref["lower"]), 1e-12)
                gap_ratio = (
                    (ours["upper"] - ours["lower"]) / ref_gap if ref_gap > 0 else float("inf")
                )
                cells.append(f"{100 * short:>8.2f}%{gap_ratio:>9.2f}")
            print(" ".join(cells), flush=True)


def _time_to_gap(history: list[dict], gap: float) -> float | None:
    for entry in history:
        if entry["upper"] - entry["lower"] <= gap:
            return entry["time_s"]
    return None


def momdp_table(limit: float, precision: float, sizes: list[int] | None = None) -> None:
    """Time to the same gap: the flat solve runs ``limit`` seconds, the factored one to the gap
    the flat one reached (at most ``limit`` seconds); both with SARSOP's default initialisers."""
    print("\n## MOMDP-factored vs flat SARSOP on RockSample (robot position observed)")
    head = (f"{'problem':<16}{'target gap':>11}{'flat s':>9}{'MOMDP s':>9}{'ratio':>8}"
            f"{'flat low':>10}{'MOMDP low':>10}")  # fmt: skip
    print(head)
    print("-" * len(head))
    for n in sizes or [4, 5]:
        k = n
        flat = sarsop(rock_sample(n, k), SARSOPConfig(time_limit=limit, precision=precision))
        target = max(flat.upper - flat.lower, precision)
        t_flat = _time_to_gap(flat.history, target)
        fact = sarsop(rock_sample_momdp(n, k), SARSOPConfig(time_limit=limit, precision=target))
        t_fact = _time_to_gap(fact.history, target)
        ratio = f"{t_flat / t_fact:>8.1f}" if t_flat and t_fact else f"{'-':>8}"
        print(f"{f'RockSample({n},{k})':<16}{target:>11.4f}{_fmt(t_flat, 9)}{_fmt(t_fact, 9)}"
              f"{ratio}{_fmt(flat.lower)}{_fmt(fact.lower)}", flush=True)  # fmt: skip


def batch_table(limit: float) -> None:
    print("\n## Batched backups of all tree beliefs vs one belief at a time")
    head = f"{'problem':<16}{'beliefs':>9}{'one-by-one s':>14}{'batched s':>11}{'ratio':>8}"
    print(head)
    print("-" * len(head))
    for name in ["tiger", "rocksample_4_4", "tag"]:
        solver = _SARSOP(
            PROBLEMS[name](), SARSOPConfig(time_limit=limit, precision=1e-9), time.perf_counter()
        )
        solver.run()
        tree = solver.tree
        act = np.flatnonzero(tree.active[: tree.size])
        start = time.perf_counter()
        for node in act.tolist():
            solver.backup(int(tree.x[node]), np.array([node]))
        one = time.perf_counter() - start
        start = time.perf_counter()
        solver.sweep()
        batched = time.perf_counter() - start
        print(
            f"{name:<16}{act.size:>9d}{one:>14.3f}{batched:>11.3f}{one / batched:>8.1f}", flush=True
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limits", type=float, nargs="+", default=[10.0, 60.0])
    parser.add_argument("--problems", nargs="+", choices=list(PROBLEMS), default=list(PROBLEMS))
    parser.add_argument("--appl", default=None, help="path of APPL's pomdpsol binary")
    parser.add_argument("--precision", type=float, default=1e-3)
    parser.add_argument("--no-quality", action="store_true", help="skip the APPL table")
    parser.add_argument("--no-momdp", action="store_true")
    parser.add_argument("--no-batch", action="store_true")
    parser.add_argument(
        "--momdp-sizes", type=int, nargs="+", default=[4, 5], help="RockSample(n, n) sizes"
    )
    parser.add_argument("--repeats", type=int, default=1, help="repeats of the MOMDP table")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)  # the tree search is sequential; APPL is single-threaded too
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, limits {args.limits}")
    print(f"load average before: {os.getloadavg()}")
    if not args.no_quality:
        quality_table(args.problems, args.limits, args.appl, args.precision)
    print(f"load average after: {os.getloadavg()}; peak RSS of this process "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")  # fmt: skip
    if not args.no_momdp:
        for _ in range(args.repeats):
            momdp_table(min(args.limits), args.precision, args.momdp_sizes)
    if not args.no_batch:
        batch_table(min(args.limits))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
