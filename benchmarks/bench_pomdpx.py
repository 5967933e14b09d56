"""Reading ``.pomdpx`` files: :func:`torchhrc.io.read_pomdpx` against APPL's load time.

For each ``.pomdpx`` file given (APPL's ``examples/POMDPX/*.pomdpx``, fetched by the user; none
is shipped here), prints the model form and size we read, our read time (median wall time and
median process CPU time of ``--repeats`` reads, after a warm-up read), and APPL's "loading
time" as ``pomdpsol`` prints it (with ``--appl``: ``pomdpsol FILE --timeout 0.01``, median of
``--repeats`` runs; APPL's timer is the process CPU time, ``std::clock``, printed to 0.01 s),
and the ratio of our CPU time to APPL's (goal <= 1; "-" when APPL prints 0.00). The files are
timed one after the other, ours then APPL's, so each pair is measured in the same minute.
Peak RSS of this process is printed at the end. Timings are those of whatever cores the
machine gives: print ``uptime`` beside.

Usage::

    python benchmarks/bench_pomdpx.py APPL/examples/POMDPX/*.pomdpx [--appl APPL/src/pomdpsol]
        [--repeats 3]
"""

from __future__ import annotations

import argparse
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _timing import median_time

from torchhrc.io import read_pomdpx


def appl_load_time(pomdpsol: str, path: Path) -> float | None:
    """APPL's printed "loading time" for ``path`` (None when it does not print one)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            [pomdpsol, str(path), "--timeout", "0.01", "-o", str(Path(tmp) / "p.policy")],
            capture_output=True,
            text=True,
            cwd=tmp,
            check=False,
        ).stdout
    match = re.search(r"loading time\s*:\s*([0-9.]+)", out)
    return float(match.group(1)) if match else None


def describe(model: object) -> str:
    name = type(model).__name__
    if name in ("MOMDP", "SparseMOMDP"):
        return f"MOMDP X={model.num_observed} Y={model.num_hidden}"  # type: ignore[attr-defined]
    return f"{name} S={model.num_states}"  # type: ignore[attr-defined]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path, help=".pomdpx files")
    parser.add_argument("--appl", default=None, help="path to APPL's pomdpsol")
    parser.add_argument("--repeats", type=int, default=3, help="timed reads per file (3)")
    args = parser.parse_args(argv)
    print("| file | read as | ours wall (s) | ours CPU (s) | APPL load CPU (s) | CPU ours / APPL |")
    print("|---|---|---|---|---|---|")
    for path in args.files:
        model = read_pomdpx(path)
        ours = median_time(lambda: read_pomdpx(path), args.repeats)  # noqa: B023
        cpu = median_time(lambda: read_pomdpx(path), args.repeats, time.process_time)  # noqa: B023
        # (CPU time: APPL's printed loading time is CPU time too)
        appl = None
        if args.appl:
            runs = [appl_load_time(args.appl, path) for _ in range(args.repeats)]
            appl = statistics.median(runs) if None not in runs else None  # type: ignore[type-var]
        ratio = f"{cpu / appl:.2f}" if appl else "-"
        shown = f"{appl:.2f}" if appl is not None else "-"
        print(f"| {path.name} | {describe(model)} | {ours:.3f} | {cpu:.3f} | {shown} | {ratio} |")
        sys.stdout.flush()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(f"\npeak RSS of this process: {peak:.2f} GB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
