"""``torchhrc solve``: solve a Cassandra ``.pomdp`` or APPL ``.pomdpx`` file, report the bounds.

Reads the model (:func:`torchhrc.io.cassandra.read_pomdp`, or
:func:`torchhrc.io.pomdpx.read_pomdpx` for a ``.pomdpx`` suffix: a MOMDP when the file has
observed state variables and the factored tensors fit, else a flat POMDP), solves it with
SARSOP (default), PBVI, QMDP or FIB through :func:`torchhrc.solvers.solve`, prints the lower
and upper bounds on the optimal value at the initial belief, and optionally writes the policy
(``.policyx``, APPL's format, or ``.safetensors``). Progress (bounds over time) goes to
stderr unless ``--quiet``. With ``--json`` one JSON object is printed with the keys
``lower``, ``upper``, ``gap``, ``time_s``, ``n_alphas``, ``solver``, ``stop_reason``,
``iterations``, ``explore_after`` and ``explored_trials`` (SARSOP's resolved setting and the
trials that drew their children; null for the other solvers), ``policy`` (the written path or
null), ``sparse`` and ``model`` (``"POMDP"``, ``"MOMDP"``, ``"SparseMOMDP"`` or
``"SparsePOMDP"``).

A ``pomdpsol`` command line runs with ``pomdpsol`` replaced by ``torchhrc solve``: its
``--timeout S`` (CPU seconds), ``-p/--precision``, ``-o/--output``, ``--memory``,
``--policy-interval``, ``--randomization``, ``--trial-improvement-factor`` and ``--fast``
(accepted, no effect) are options here too. SARSOP's search has two more:
``--tie-break random|first`` (``random``, the default, is ``pomdpsol --randomization``) and
``--explore-after N|never|auto`` / ``--explore-within F`` (the draw among near-equal children
once the lower bound stalls, by default on models of 10,000 states or more;
:class:`~torchhrc.solvers.SARSOPConfig`). ``--tie-break first --explore-after never`` is
``pomdpsol``'s default search.

``--memory MB`` (as APPL's ``pomdpsol --memory``) bounds the process's resident memory: a
model whose reading would take more than the limit leaves (or more than the machine's
available memory, the default budget) is refused before it is read, and PBVI and SARSOP stop
before the limit, write the policy so far and report ``"stop_reason": "memory"``.
``--policy-interval S`` (as ``pomdpsol --policy-interval``) writes the policy so far to
``--out`` every ``S`` seconds (PBVI and SARSOP, between iterations), atomically: a solve
killed at any moment leaves the last complete policy.

A model whose dense ``T (A, S, S)`` or ``Z (A, S, O)`` would exceed
:data:`torchhrc.pomdp.sparse.MAX_DENSE_ENTRIES` (2e8 entries, 1.6 GB in float64; RockSample(7, 8):
2e9) is read as a :class:`~torchhrc.pomdp.SparsePOMDP` and solved through the solvers'
sparse form (``"sparse": true``), by every solver. A ``.pomdpx`` MOMDP whose dense ``Ty``
would not fit (APPL's RockSample_7_8) is read as a
:class:`~torchhrc.pomdp.SparseMOMDP` and solved as a MOMDP.

Example:
    >>> import argparse
    >>> from torchhrc.commands import solve
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> solve.register(sub)
    >>> sub.choices["solve"].parse_args(["m.pomdp", "--solver", "pbvi"]).solver
    'pbvi'
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from torchhrc.commands._files import add_fast, non_negative_int, policy_path

__all__ = ["make_config", "register", "run"]

SOLVERS = ("sarsop", "pbvi", "qmdp", "fib")


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value >= 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}")
    return value


def _share(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}")
    return value


def _trials(text: str) -> int | str:
    if text in ("never", "auto"):
        return text
    try:
        return non_negative_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected a number of trials >= 0, 'never' or 'auto', got {text!r}"
        ) from None


#: The options only SARSOP reads, as (attribute, option, SARSOPConfig field).
SARSOP_OPTIONS = (
    ("tie_break", "--tie-break/--randomization", "tie_break"),
    ("explore_after", "--explore-after", "explore_after"),
    ("explore_within", "--explore-within", "explore_within"),
    ("trial_improvement_factor", "--trial-improvement-factor", "kappa"),
)


def _search_options(args: argparse.Namespace) -> dict[str, Any]:
    """The SARSOPConfig fields of SARSOP's search options given (a clear error for another
    solver)."""
    search: dict[str, Any] = {}
    for attribute, option, field in SARSOP_OPTIONS:
        value = getattr(args, attribute, None)
        if value is None:
            continue
        if args.solver != "sarsop":
            from torchhrc.errors import TorchHRCError

            raise TorchHRCError(f"{option} applies to --solver sarsop only, not {args.solver}")
        search[field] = None if value == "never" else value
    return search


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``solve`` sub-command."""
    parser = subparsers.add_parser(
        "solve",
        help="solve a .pomdp or .pomdpx file (SARSOP, PBVI, QMDP, FIB) and report the bounds",
        description=(
            "Solve a POMDP in Cassandra's .pomdp format or APPL's .pomdpx format (chosen by the "
            "suffix); print lower and upper bounds on the optimal value at the initial belief, "
            "and optionally write the policy."
        ),
    )
    parser.add_argument(
        "model",
        metavar="FILE.pomdp|FILE.pomdpx",
        help="the model (Cassandra .pomdp; APPL .pomdpx by its suffix)",
    )
    parser.add_argument("--solver", choices=SOLVERS, default="sarsop", help="solver (sarsop)")
    limit = parser.add_mutually_exclusive_group()
    limit.add_argument(
        "--time-limit", type=_positive, default=None, help="seconds (10; PBVI and SARSOP)"
    )
    limit.add_argument(
        "--timeout",
        type=_positive,
        default=None,
        metavar="S",
        help="pomdpsol's --timeout: a time limit of S CPU seconds (--time-limit S --cpu-time)",
    )
    parser.add_argument(
        "--cpu-time",
        action="store_true",
        help="the time limit counts the process's CPU seconds, as APPL's pomdpsol --timeout "
        "(PBVI and SARSOP; default: wall-clock seconds)",
    )
    parser.add_argument(
        "-p",
        "--precision",
        type=_non_negative,
        default=1e-3,
        help="target gap upper - lower (1e-3)",
    )
    parser.add_argument(
        "-o",
        "--out",
        "--output",
        dest="out",
        type=policy_path,
        default=None,
        help="write the policy (.policyx / .safetensors; --output and -o as pomdpsol)",
    )
    parser.add_argument(
        "--memory",
        type=_positive,
        default=None,
        metavar="MB",
        help="memory limit in MB (2^20 bytes) of the whole process, as pomdpsol --memory: a "
        "model that would not fit is refused before it is read, and PBVI and SARSOP stop "
        "before the limit with the policy so far (default: no limit; a model is refused "
        "above the machine's available memory)",
    )
    parser.add_argument(
        "--policy-interval",
        type=_positive,
        default=None,
        metavar="S",
        help="write the policy so far to --out every S seconds (of the time limit's clock), "
        "atomically, as pomdpsol --policy-interval (PBVI and SARSOP; default: at the end only)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--seed", type=int, default=0, help="random seed (0)")
    search = parser.add_argument_group(
        "SARSOP's search (pomdpsol's options where it has them)",
        "By default a trial draws among actions of equal upper bound (as pomdpsol "
        "--randomization) and, on models of 10,000 states or more, among near-equal children "
        "once the lower bound has stalled for 10 trials; '--tie-break first --explore-after "
        "never' is pomdpsol's default search.",
    )
    ties = search.add_mutually_exclusive_group()
    ties.add_argument(
        "--tie-break",
        choices=("random", "first"),
        default=None,
        help="among actions of equal upper bound: draw one (random, the default, seeded) or "
        "take the lowest index (first, pomdpsol's default)",
    )
    ties.add_argument(
        "--randomization",
        dest="tie_break",
        action="store_const",
        const="random",
        help="pomdpsol's --randomization: --tie-break random (the default here)",
    )
    search.add_argument(
        "--explore-after",
        type=_trials,
        default=None,
        metavar="N|never|auto",
        help="draw among near-equal children after N trials without a rise of the lower "
        "bound; never: always the first of largest excess gap, as pomdpsol; auto (the "
        "default): 10 on models of 10,000 states (a MOMDP: hidden values) or more, else never",
    )
    search.add_argument(
        "--explore-within",
        type=_share,
        default=None,
        metavar="F",
        help="a drawn child's excess gap is at least F times the largest, in (0, 1] (0.9)",
    )
    search.add_argument(
        "--trial-improvement-factor",
        type=_share,
        default=None,
        metavar="F",
        help="pomdpsol's option: a trial ends where the gap is F times the gap at the start, "
        "in (0, 1] (0.5)",
    )
    add_fast(parser)
    parser.set_defaults(func=run)


def make_config(args: argparse.Namespace, callback: Any = None, checkpoint: Any = None) -> Any:
    """The solver configuration the command-line options describe (``checkpoint``: called
    with the solution so far every ``--policy-interval`` seconds, PBVI and SARSOP).

    Example:
        >>> ns = argparse.Namespace(solver="pbvi", time_limit=2.0, precision=0.1, seed=3)
        >>> make_config(ns).time_limit
        2.0
    """
    from torchhrc import solvers

    timeout = getattr(args, "timeout", None)
    cpu_time = getattr(args, "cpu_time", False) or timeout is not None
    clock = "process" if cpu_time else "wall"
    time_limit = timeout if timeout is not None else getattr(args, "time_limit", None)
    time_limit = 10.0 if time_limit is None else time_limit
    search = _search_options(args)
    memory = getattr(args, "memory", None)
    memory_limit = None if memory is None else memory * 2**20
    # kept free per byte of the vectors: the policy's copy and check (1.5), and its file's
    # writing (measured: .policyx text peaks at 5.5 times the vectors, safetensors 0.7)
    out = str(getattr(args, "out", None) or "").lower()
    reserve = 1.5 + (6.0 if out.endswith((".policyx", ".policy", ".xml")) else 1.5 if out else 0.0)
    interval = getattr(args, "policy_interval", None)
    checkpoints = (
        {} if interval is None else {"policy_interval": interval, "checkpoint": checkpoint}
    )
    if args.solver == "qmdp":
        return solvers.QMDPConfig()
    if args.solver == "fib":
        return solvers.FIBConfig()
    config = solvers.PBVIConfig if args.solver == "pbvi" else solvers.SARSOPConfig
    return config(
        time_limit=time_limit,
        precision=args.precision,
        seed=args.seed,
        callback=callback,
        clock=clock,
        memory_limit=memory_limit,
        memory_reserve=reserve,
        **checkpoints,
        **search,
    )


class _Progress:
    """Prints the bounds to stderr at most every ``interval`` seconds."""

    def __init__(self, interval: float = 0.5) -> None:
        self.interval = interval
        self.last = -math.inf

    def __call__(self, entry: dict[str, Any]) -> None:
        now = time.perf_counter()
        if now - self.last < self.interval:
            return None
        self.last = now
        lower, upper = entry.get("lower", math.nan), entry.get("upper", math.nan)
        print(
            f"  {entry.get('time_s', 0.0):8.2f}s  lower {lower:.6g}  upper {upper:.6g}  "
            f"gap {upper - lower:.4g}  "
            f"alphas {entry.get('n_alphas', '-')}  beliefs {entry.get('n_beliefs', '-')}",
            file=sys.stderr,
        )
        return None


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def run(args: argparse.Namespace) -> int:
    """Read, solve, print and write; return the exit status."""
    _search_options(args)  # a SARSOP option given to another solver: refused before reading
    if getattr(args, "policy_interval", None) is not None and args.out is None:
        from torchhrc.errors import TorchHRCError

        raise TorchHRCError("--policy-interval needs --out (the policy file to write)")
    if args.out is not None:  # its folder must exist before the solve, not after it
        from torchhrc.commands._files import check_new_file

        check_new_file(args.out, force=True)  # (an existing policy is replaced, as pomdpsol)
    from torchhrc.io.cassandra import read_pomdp
    from torchhrc.pomdp import SparsePOMDP
    from torchhrc.solvers import solve

    # every solver has a sparse form: a model whose dense T (A, S, S) or Z would exceed
    # MAX_DENSE_ENTRIES (2e8 entries, 1.6 GB) is read and solved sparsely
    mode = "auto"
    # the read's budget: what the memory limit leaves to the process as it is now, or (by
    # default, and at most) the machine's available memory
    budget = None
    if getattr(args, "memory", None) is not None:
        from torchhrc.errors import TorchHRCError
        from torchhrc.io._budget import available_memory, format_bytes
        from torchhrc.solvers._memory import resident_bytes

        held = resident_bytes() or 0
        if held >= args.memory * 2**20:
            raise TorchHRCError(
                f"--memory {args.memory:g} is below what the process holds before reading the "
                f"model ({format_bytes(held)})"
            )
        budget = min(args.memory * 2**20 - held, available_memory() or math.inf)
    if Path(args.model).suffix.lower() == ".pomdpx":
        from torchhrc.io.pomdpx import read_pomdpx

        model = read_pomdpx(args.model, sparse=mode, memory_budget=budget)
    else:
        model = read_pomdp(args.model, sparse=mode, memory_budget=budget)
    from torchhrc.pomdp import SparseMOMDP
    from torchhrc.solvers._memory import release_free_memory

    release_free_memory()  # the reader's temporaries (the tokens), back to the OS
    sparse = isinstance(model, (SparsePOMDP, SparseMOMDP))
    callback = None if args.quiet else _Progress()
    checkpoint = None
    if getattr(args, "policy_interval", None) is not None:
        from torchhrc.io.policyx import save_policy

        def checkpoint(solution: Any) -> None:  # an atomic write (temp file + rename)
            save_policy(solution.policy, args.out)

    config = make_config(args, callback, checkpoint)
    start = time.perf_counter()
    solution = solve(model, config)
    elapsed = time.perf_counter() - start
    written = None
    if args.out is not None:
        from torchhrc.io.policyx import save_policy

        written = str(save_policy(solution.policy, args.out))
    report = {
        "lower": _finite(solution.lower),
        "upper": _finite(solution.upper),
        "gap": _finite(solution.gap),
        "time_s": elapsed,
        "n_alphas": solution.policy.num_vectors,
        "solver": args.solver,
        "stop_reason": solution.info.get("stop_reason"),
        "iterations": solution.info.get("iterations"),
        "explore_after": solution.info.get("explore_after"),
        "explored_trials": solution.info.get("explored_trials"),
        "policy": written,
        "sparse": sparse,
        "model": type(model).__name__,
    }
    if args.json:
        print(json.dumps(report))
    else:
        print(f"solver     {args.solver}")
        print(f"lower      {solution.lower:.6g}")
        print(f"upper      {solution.upper:.6g}")
        print(f"gap        {solution.gap:.6g}")
        print(f"time_s     {elapsed:.3f}")
        print(f"n_alphas   {solution.policy.num_vectors}")
        print(f"model      {type(model).__name__}")
        if sparse:
            print("           sparse (dense T would exceed 2e8 entries)")
        if written is not None:
            print(f"policy     {written}")
    return 0
