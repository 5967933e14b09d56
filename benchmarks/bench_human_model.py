"""Which human model ``learn()``'s ``"auto"`` picks, task by task (issue 31 goal 4).

For every task and seed: demonstrations (``--subjects`` x ``--per-subject``, noise 0.05),
``learn()``'s clustering (``fit_mixture`` with ``bench_heldout.LEARN_CLUSTER_OPTIONS``), then
:func:`torchhrc.tasks.pipeline.compare_human_models` on those types, as ``build_model`` calls
it (noise 0.05, pause 0.01, the fold split's seed = the seed). Prints the table of
``docs/clustering.md`` ("Which human model `learn()` uses"): the model picked on the first
seed, the held-out log-likelihood per human turn of both models on the first seed (the
score that chooses, then the score with the demonstrated partner moves everywhere), the
share of turns in states where the partner's move depends on the type (scored under the
pooled partner), the seeds picking that model, and the state model's smoothing chosen on
each seed (``habit_weight/prior_strength``, ``docs/your_own_task.md`` section 4).

Usage::

    python benchmarks/bench_human_model.py                      # the suite, seeds 0-2
    python benchmarks/bench_human_model.py --heldout            # the held-out tasks
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_heldout import LEARN_CLUSTER_OPTIONS
from heldout_tasks import HELDOUT

from torchhrc.mixture import fit_mixture
from torchhrc.tasks.pipeline import compare_human_models
from torchhrc.tasks.suite import SUITE


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heldout", action="store_true", help="the held-out tasks")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--subjects", type=int, default=30)
    parser.add_argument("--per-subject", type=int, default=4)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    makers = HELDOUT if args.heldout else SUITE
    print("| task | types | auto picks | chain (nats/turn) | state (nats/turn) | "
          "demonstrated moves: chain / state | confounded turns | "
          f"seeds 0-{args.seeds - 1} picking it | state smoothing per seed |\n"
          "|---|---|---|---|---|---|---|---|---|")  # fmt: skip
    for name, make in makers.items():
        world = make()
        picks, first, smoothing = [], None, []
        for seed in range(args.seeds):
            demos, _ = world.demonstrations(subjects=args.subjects, per_subject=args.per_subject,
                                            noise=0.05, seed=seed)  # fmt: skip
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fit = fit_mixture(demos, seed=seed, **LEARN_CLUSTER_OPTIONS)
            record = compare_human_models(world.task, demos, fit.assignments, noise=0.05,
                                          pause=0.01, seed=seed)  # fmt: skip
            picks.append(record["used"])
            chosen = record["state_smoothing"]
            smoothing.append(f"{chosen['habit_weight']:g}/{chosen['prior_strength']:g}")
            first = first or record
        per = first["per_step"]
        chain = f"{per['chain']:.3f}" if "chain" in per else "-"
        state = f"{per['state']:.3f}" if "state" in per else "-"
        shown = first.get("per_step_demonstrated", {})
        shown = " / ".join(f"{shown[m]:.3f}" for m in ("chain", "state")) if shown else "-"
        conf = f"{first['confounded']:.2f}" if "confounded" in first else "-"
        print(f"| {name} | {world.num_types} | {first['used']} | {chain} | {state} | {shown} | "
              f"{conf} | {picks.count(first['used'])}/{len(picks)} | {' '.join(smoothing)} |",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
