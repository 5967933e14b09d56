"""Simulation benchmark: ``torchhrc simulate``/``evaluate`` against APPL's ``pomdpsim``.

For each problem (Tag and RockSample(7, 8) by default, read from ``problems/`` as the
``torchhrc`` command reads them: Tag dense, RockSample(7, 8) as a sparse POMDP of 12,545
states), one policy is simulated by both: ours runs ``--episodes`` simulations stepped
together on tensors (:func:`torchhrc.solvers.evaluate.evaluate_policy`), APPL's
``pomdpsim`` runs ``--appl-episodes`` one after another. Both run ``--horizon`` steps (APPL's
``--simLen``), both stop a simulation at a terminal state, both on one thread. The rate is
simulations per CPU second of the simulation alone: ours is timed around the call (reading
the files excluded), APPL's as the CPU time of a run of N simulations minus that of a run of
one (its loading), from ``getrusage`` of the child. CPU seconds, not wall, because the
machine may be shared. The table also gives both means with their 95 % intervals (APPL's
action choice is a one-step look-ahead, ours the greedy alpha vector: the means agree within
the intervals, the work per step differs).

The policy is APPL's ``pomdpsol`` output after ``--solve-seconds`` (so both simulate the
very same ``.policyx``), or ours from ``torchhrc solve`` when APPL is not given; ``--policy
NAME=FILE`` uses a file of your own. APPL is found through ``--appl DIR`` or the
``TORCHHRC_APPL_BIN`` environment variable (the folder of the built binaries); without it
only our column is printed.

Usage::

    python benchmarks/problems/make_problems.py --only tag rocksample_7_8
    TORCHHRC_APPL_BIN=APPL/src python benchmarks/bench_simulate.py [--problems tag rocksample_7_8]
        [--episodes 1000] [--appl-episodes 100] [--horizon 100] [--solve-seconds 30]
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

import torch

HERE = Path(__file__).resolve().parent
ROW = re.compile(r"^\s*(\d+)\s+([-0-9.eE+]+)\s+\(([-0-9.eE+]+),\s*([-0-9.eE+]+)\)")


def _child_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _pomdpsim(binary: str, model: Path, policy: Path, runs: int, horizon: int, seed: int,
              ) -> tuple[float, tuple[float, float, float]]:  # fmt: skip
    """CPU seconds of ``runs`` simulations and the (mean, low, high) pomdpsim prints."""
    start = _child_cpu()
    proc = subprocess.run(
        [binary, str(model), "--policy-file", str(policy), "--simLen", str(horizon),
         "--simNum", str(runs), "--srand", str(seed)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    cpu = _child_cpu() - start
    rows = [m for m in map(ROW.match, proc.stdout.splitlines()) if m]
    mean, low, high = (float(rows[-1].group(i)) for i in (2, 3, 4))
    return cpu, (mean, low, high)


def _policy(name: str, model_path: Path, args: argparse.Namespace, folder: Path) -> Path:
    given = dict(item.split("=", 1) for item in args.policy)
    if name in given:
        return Path(given[name])
    out = folder / f"{name}.policyx"
    if args.appl:
        subprocess.run(
            [str(Path(args.appl) / "pomdpsol"), str(model_path), "--timeout",
             str(args.solve_seconds), "--output", str(out)],
            capture_output=True, check=True,
        )  # fmt: skip
    else:
        from torchhrc.cli import main

        main(["solve", str(model_path), "--time-limit", str(args.solve_seconds), "--out",
              str(out), "--quiet"])  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", nargs="+", default=["tag", "rocksample_7_8"])
    parser.add_argument("--problems-dir", type=Path, default=HERE / "problems")
    parser.add_argument("--episodes", type=int, default=1000, help="our simulations (1000)")
    parser.add_argument("--appl-episodes", type=int, default=100, help="pomdpsim's (100)")
    parser.add_argument("--horizon", type=int, default=100, help="steps (APPL --simLen) (100)")
    parser.add_argument("--solve-seconds", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--policy", action="append", default=[], metavar="NAME=FILE")
    parser.add_argument("--appl", default=os.environ.get("TORCHHRC_APPL_BIN"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)  # APPL is single-threaded

    from torchhrc.commands._files import read_model, read_policy
    from torchhrc.solvers.evaluate import evaluate_policy

    load = os.getloadavg()[0]
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}  load {load:.1f}  episodes {args.episodes} "
          f"(APPL {args.appl_episodes})  horizon {args.horizon}")  # fmt: skip
    header = (
        f"{'problem':16s} {'ours sims/CPU-s':>16s} {'APPL sims/CPU-s':>16s} {'ratio':>7s}  "
        f"{'ours mean [95% CI]':>26s}  {'APPL mean [95% CI]':>26s}"
    )
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.problems:
            model_path = args.problems_dir / f"{name}.pomdp"
            if not model_path.exists():
                print(f"{name:16s} missing {model_path}: run problems/make_problems.py")
                continue
            policy_path = _policy(name, model_path, args, Path(tmp))
            model, policy = read_model(str(model_path)), read_policy(str(policy_path))
            start = time.process_time()
            r = evaluate_policy(model, policy, episodes=args.episodes, horizon=args.horizon,
                                seed=args.seed)  # fmt: skip
            ours = args.episodes / (time.process_time() - start)
            ours_text = f"{r.mean:8.3f} [{r.ci_low:7.3f}, {r.ci_high:7.3f}]"
            appl_rate, appl_text, ratio = float("nan"), "-", "-"
            if args.appl:
                binary = str(Path(args.appl) / "pomdpsim")
                one, _ = _pomdpsim(binary, model_path, policy_path, 1, args.horizon, args.seed)
                many, (m, lo, hi) = _pomdpsim(
                    binary, model_path, policy_path, args.appl_episodes, args.horizon, args.seed
                )
                appl_rate = (args.appl_episodes - 1) / max(many - one, 1e-9)
                appl_text = f"{m:8.3f} [{lo:7.3f}, {hi:7.3f}]"
                ratio = f"{ours / appl_rate:6.1f}x"
            print(f"{name:16s} {ours:16.1f} {appl_rate:16.1f} {ratio:>7s}  {ours_text:>26s}  "
                  f"{appl_text:>26s}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
