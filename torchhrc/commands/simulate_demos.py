"""``torchhrc simulate-demos``: write a simulated place-and-drill demonstration study.

A thin layer over :func:`torchhrc.tasks.place_and_drill.simulate_study`; writes the CSV
format of shared/DESIGN.md (or JSON when ``--out`` ends in ``.json``), atomically, and
refuses to overwrite an existing file unless ``--force`` is given.

Example:
    >>> import argparse
    >>> from torchhrc.commands import simulate_demos
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> simulate_demos.register(sub)
    >>> sub.choices["simulate-demos"].parse_args(["--out", "d.csv"]).subjects
    18
"""

from __future__ import annotations

import argparse
import errno
import os
import sys

__all__ = ["parse_noise", "register", "run"]


def parse_noise(text: str) -> float | tuple[float, float]:
    """``"0.1"`` -> 0.1 (every subject), ``"0,0.15"`` -> (0.0, 0.15) (a range per subject).

    Example:
        >>> parse_noise("0,0.15"), parse_noise("0.1")
        ((0.0, 0.15), 0.1)
    """
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a rate like 0.1 or a range like 0,0.15, got {text!r}"
        ) from None
    if len(values) == 1:
        return values[0]
    if len(values) == 2:
        return (values[0], values[1])
    raise argparse.ArgumentTypeError(f"expected one rate or a low,high range, got {text!r}")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``simulate-demos`` sub-command."""
    parser = subparsers.add_parser(
        "simulate-demos",
        help="simulate a place-and-drill demonstration study (CSV with true types)",
        description=(
            "Simulate the paper's place-and-drill study: subjects of the given strategies "
            "(safe: place all then drill; efficient: place and drill alternately; pairs: "
            "place two, drill two), each with a preferred placement order and a noise rate "
            "(a step replaced by another legal action of the same actor; human-role steps by "
            "default, robot-role steps with --robot-noise)."
        ),
    )
    parser.add_argument("--subjects", type=int, default=18, help="number of subjects (18)")
    parser.add_argument("--demos", type=int, default=3, help="demonstrations per subject (3)")
    parser.add_argument("--positions", type=int, default=3, help="screw positions (3)")
    parser.add_argument(
        "--strategies",
        default="safe,efficient",
        help="comma-separated strategies, split evenly between subjects (safe,efficient)",
    )
    parser.add_argument(
        "--noise",
        type=parse_noise,
        default=(0.0, 0.15),
        help=(
            "per-step deviation rate of the human-role steps, or a low,high range each "
            "subject draws from (0,0.15)"
        ),
    )
    parser.add_argument(
        "--robot-noise",
        type=parse_noise,
        default=0.0,
        help="the same for the robot-role (preference) steps (0)",
    )
    parser.add_argument(
        "--order-change",
        type=float,
        default=0.1,
        help="probability a demonstration uses a fresh placement order (0.1)",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (0)")
    parser.add_argument(
        "--out", required=True, metavar="FILE", help="output file (.csv, or .json for JSON)"
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Simulate and write the study; return the exit status."""
    from torchhrc.tasks.place_and_drill import simulate_study

    out = args.out
    if os.path.exists(out) and not args.force:
        raise FileExistsError(errno.EEXIST, "file exists (use --force to overwrite)", out)
    demos = simulate_study(
        n_subjects=args.subjects,
        n_demos=args.demos,
        n_positions=args.positions,
        strategies=[s.strip() for s in args.strategies.split(",") if s.strip()],
        noise=args.noise,
        robot_noise=args.robot_noise,
        order_change=args.order_change,
        seed=args.seed,
    )
    if out.lower().endswith(".json"):
        demos.write_json(out)
    else:
        demos.write_csv(out)
    assert demos.types is not None
    counts = {t: demos.types.count(t) // args.demos for t in dict.fromkeys(demos.types)}
    summary = ", ".join(f"{n} {t}" for t, n in counts.items())
    print(
        f"wrote {demos.num_sequences} sequences ({args.subjects} subjects x {args.demos}; "
        f"{summary}) to {out}",
        file=sys.stdout,
    )
    return 0
