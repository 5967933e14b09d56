"""Solving a ``.pomdpx`` file with SARSOP under a **CPU-time** limit, as APPL's ``pomdpsol``.

APPL's ``--timeout`` is process CPU time (``std::clock``); on a loaded machine a wall-clock
limit gives our solver fewer CPU seconds than APPL's. This script reads the file with
:func:`torchhrc.io.read_pomdpx` (RockSample_7_8: a
:class:`~torchhrc.pomdp.sparse_momdp.SparseMOMDP`) and runs :func:`torchhrc.solvers.sarsop` until
its own CPU time reaches the limit (``SARSOPConfig(clock="process")``), then prints the form, CPU
seconds, bounds and peak RSS. Run APPL on the same file right before or after
(``pomdpsol FILE --timeout L``).

Usage::

    python benchmarks/bench_pomdpx_solve.py APPL/examples/POMDPX/RockSample_7_8.pomdpx 10
"""

from __future__ import annotations

import argparse
import resource
import time

from torchhrc.io import read_pomdpx
from torchhrc.solvers import SARSOPConfig, sarsop


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", help="a .pomdpx file")
    parser.add_argument("limit", type=float, help="CPU seconds of the solve")
    args = parser.parse_args(argv)
    c0 = time.process_time()
    model = read_pomdpx(args.file)
    c1 = time.process_time()
    w0 = time.perf_counter()
    sol = sarsop(model, SARSOPConfig(time_limit=args.limit, clock="process"))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"{type(model).__name__} read_cpu={c1 - c0:.2f} solve_cpu={time.process_time() - c1:.2f} "
        f"wall={time.perf_counter() - w0:.1f} lower={sol.lower:.4f} upper={sol.upper:.4f} "
        f"gap={sol.upper - sol.lower:.4f} iterations={sol.info.get('iterations')} "
        f"backups={sol.info.get('backups')} "
        f"alphas={sol.policy.num_vectors} peak_rss_MB={rss:.0f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
