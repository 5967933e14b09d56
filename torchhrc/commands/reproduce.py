"""``torchhrc reproduce TASK``: reproduce one of the paper's studies into a directory.

Each task maps to a pipeline function in :mod:`torchhrc.experiments` through
:data:`PIPELINES` (``"module:function"``, imported on use), so a second study is one more
entry. A pipeline is called as ``pipeline(out_dir, seed=..., subjects=..., runs=...,
quick=..., force=..., progress=...)`` and returns its metrics (a dict). The command refuses a
non-empty output directory unless ``--force`` and shows a progress bar on stderr (tqdm, when
installed; ``--no-progress`` turns it off).

Example:
    >>> import argparse
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> register(sub)
    >>> args = sub.choices["reproduce"].parse_args(["place-and-drill", "--quick"])
    >>> args.task, args.quick, args.out
    ('place-and-drill', True, None)
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from collections.abc import Callable
from typing import Any

__all__ = ["PIPELINES", "register", "run"]

#: Task name -> ``"module:function"`` of its pipeline (imported lazily).
PIPELINES: dict[str, str] = {
    "place-and-drill": "torchhrc.experiments.place_and_drill:reproduce_place_and_drill",
    "hand-finishing": "torchhrc.experiments.hand_finishing:reproduce_hand_finishing",
}


def _pipeline(task: str) -> Callable[..., dict[str, Any]]:
    module, _, name = PIPELINES[task].partition(":")
    return getattr(importlib.import_module(module), name)


class _Progress:
    """A tqdm bar per stage on stderr, or nothing when tqdm is missing / disabled."""

    def __init__(self, enabled: bool) -> None:
        self._bars: dict[str, Any] = {}
        self._tqdm = None
        if enabled:
            try:
                from tqdm import tqdm
            except ImportError:  # optional dependency
                tqdm = None
            self._tqdm = tqdm

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self._tqdm is None:
            return
        bar = self._bars.get(stage)
        if bar is None:
            bar = self._tqdm(total=total, desc=stage, file=sys.stderr, leave=True)
            self._bars[stage] = bar
        bar.update(done - bar.n)

    def close(self) -> None:
        for bar in self._bars.values():
            bar.close()


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def run(args: argparse.Namespace) -> int:
    """Run the pipeline of ``args.task``; print a one-line summary; return 0."""
    out = args.out or f"results/{args.task}"
    progress = _Progress(not args.no_progress)
    start = time.perf_counter()
    try:
        metrics = _pipeline(args.task)(
            out,
            seed=args.seed,
            subjects=args.subjects,
            runs=args.runs,
            quick=args.quick,
            force=args.force,
            progress=progress,
        )
    finally:
        progress.close()
    elapsed = time.perf_counter() - start
    summary = {
        "out": out,
        "seconds": round(elapsed, 1),
        **{
            k: metrics[k]
            for k in ("subjects", "k", "loo_accuracy", "n_states", "type_accuracy")
            if k in metrics
        },
    }
    print(json.dumps(summary))
    return 0


def register(subparsers: Any) -> None:
    """Add the ``reproduce`` sub-command."""
    parser = subparsers.add_parser(
        "reproduce",
        help="reproduce a study of the paper (report.md, metrics.json, plots)",
        description=(
            "Reproduce a study of the paper: writes report.md, metrics.json and PNG plots "
            "into --out (which must be empty unless --force)."
        ),
    )
    parser.add_argument("task", choices=sorted(PIPELINES), help="the study to reproduce")
    parser.add_argument("--out", metavar="DIR", help="output directory (default results/TASK)")
    parser.add_argument("--seed", type=int, default=0, help="seed of everything (default 0)")
    parser.add_argument(
        "--subjects",
        type=_positive,
        default=None,
        help="number of simulated subjects (default 18; 6 with --quick)",
    )
    parser.add_argument(
        "--runs",
        type=_positive,
        default=None,
        help="simulated executions per subject and epsilon (default 100; 20 with --quick)",
    )
    parser.add_argument("--quick", action="store_true", help="a small version (under a minute)")
    parser.add_argument(
        "--force", action="store_true", help="write into a non-empty output directory"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)
