"""``torchhrc sweep TASK``: a reproduction, a task with simulated people (a suite task's name,
or a user's factory ``module:factory`` / ``file.py:factory`` returning a ``TaskWithPeople``),
or a user's function (``module:function`` or ``file.py:function``), over a parameter grid
and seeds, locally or on Ray.

Thin layer over :mod:`torchhrc.experiments.sweep`: parses ``--param NAME=V1,V2,...``
(repeatable), ``--seeds 0-4``, picks the executor (local processes, one per core, by
default; ``--ray local`` for a local Ray cluster, ``--ray HOST:PORT`` for a running one) and
streams rows into ``DIR/results.csv`` with a progress bar on stderr. Bad input (an unknown
parameter, a value of the wrong type, a non-empty ``--out`` without ``--resume``, an
unreachable Ray address, no Ray installed) prints one line and exits with status 2 before
anything is written. Exit status 1 when some job failed after its retries (``--resume``
runs it again).

Example:
    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> register(sub)
    >>> a = sub.choices["sweep"].parse_args(
    ...     ["place-and-drill", "--param", "noise=0,0.1", "--out", "d", "--seeds", "0-2"])
    >>> a.param, a.seeds, a.ray
    (['noise=0,0.1'], '0-2', None)
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from torchhrc.commands.reproduce import _positive
from torchhrc.errors import ModelError

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """Run the sweep of ``args``; print a JSON summary line; return 0, or 1 if jobs failed."""
    from torchhrc.experiments.sweep import LocalExecutor, SweepSpec, canonical_task, run_sweep

    if args.retries < 0:
        raise ModelError(f"expected --retries >= 0, got {args.retries}")
    task = canonical_task(args.task)
    spec = SweepSpec.create(task, args.param or [], seeds=args.seeds, quick=args.quick)
    executor: Any
    if args.ray is not None:
        from torchhrc._ray import check_reachable, import_ray
        from torchhrc.experiments.sweep_ray import RayExecutor

        import_ray()
        executor = RayExecutor(address=args.ray, num_cpus=args.workers, max_retries=args.retries)
        if args.ray != "local":  # fail before anything is written
            check_reachable(args.ray)
    else:
        executor = LocalExecutor(workers=args.workers, retries=args.retries)
    bar = None
    if not args.no_progress:
        try:
            from tqdm import tqdm

            bar = tqdm(total=len(spec.jobs()), desc=f"sweep {args.task}", file=sys.stderr)
        except ImportError:  # optional
            bar = None

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.update(done - bar.n)

    try:
        result = run_sweep(spec, args.out, executor=executor, resume=args.resume,
                           progress=progress)  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    print(json.dumps({
        "out": str(result.out_dir),
        "jobs": len(spec.jobs()),
        "finished": len(result.rows),
        "ran": len(result.rows) - result.skipped,
        "skipped": result.skipped,
        "failed": sorted(result.failed),
    }))  # fmt: skip
    for key, message in result.failed.items():
        print(f"torchhrc sweep: job {key} failed: {message}", file=sys.stderr)
    return 1 if result.failed else 0


def register(subparsers: Any) -> None:
    """Add the ``sweep`` sub-command."""
    from torchhrc.experiments.sweep import PARAMETERS
    from torchhrc.experiments.task_sweep import TASK_PARAMETERS

    names = "; ".join(f"{task}: {', '.join(sorted(p))}" for task, p in PARAMETERS.items())
    studies = ", ".join(sorted(PARAMETERS))
    parser = subparsers.add_parser(
        "sweep",
        help="run a reproduction, a task with simulated people or your own function over a "
        "parameter grid and seeds (local processes or Ray)",
        description=(
            "Run a reproduction; a task with simulated people (a suite task such as "
            "fetch_order, or your own: MODULE:FACTORY or FILE.py:FACTORY, a function of no "
            "argument returning a TaskWithPeople), whose every job draws demonstrations, "
            "learns and evaluates; or your own function (MODULE:FUNCTION or FILE.py:FUNCTION, "
            "called as function(seed=..., **params) and returning a mapping of metrics), for "
            "every cell of a parameter grid and every seed; rows stream into OUT/results.csv, "
            "then OUT/summary.md and a PNG per metric. "
            f"Study parameters: {names}; a task's: {', '.join(TASK_PARAMETERS)}; a "
            "function's are its keyword arguments."
        ),
    )
    parser.add_argument(
        "task",
        metavar="TASK",
        help=f"the study ({studies}), a suite task, MODULE:FACTORY or MODULE:FUNCTION, or "
        "FILE.py:FACTORY or FILE.py:FUNCTION",
    )
    parser.add_argument(
        "--param",
        action="append",
        metavar="NAME=V1,V2,...",
        help="a swept parameter and its values (repeatable; the grid is their product)",
    )
    parser.add_argument("--seeds", default="0", help="seeds, e.g. 0-4 or 0,3,7 (default 0)")
    parser.add_argument("--out", required=True, metavar="DIR", help="the sweep directory")
    parser.add_argument(
        "--ray",
        metavar="local|HOST:PORT",
        default=None,
        help="run each job as a Ray task on a local cluster or a running one",
    )
    parser.add_argument(
        "--workers",
        type=_positive,
        default=None,
        help="worker processes / Ray CPUs (default: cores)",
    )
    parser.add_argument(
        "--retries",
        type=int,
        default=2,
        help="extra tries of a job that raised or whose worker died (default 2)",
    )
    parser.add_argument(
        "--resume", action="store_true", help="skip the jobs OUT already holds, run the rest"
    )
    parser.add_argument("--quick", action="store_true", help="each job runs the quick study")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)
