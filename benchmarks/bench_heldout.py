"""learn()'s defaults on held-out tasks nobody tuned for (issue 31 goals 2 and 3).

The tasks: :mod:`heldout_tasks` (benchmarks/, not shipped), our stand-in for the tasks the
issue's author runs. Per task:

* ``--goal 2``: demonstrations (``--subjects`` x ``--per-subject``, noise ``--noise``) for
  every seed, clustered with :func:`torchhrc.mixture.fit_mixture` under the options
  ``learn()`` passes it (:func:`torchhrc.tasks.pipeline.cluster_options`, with ``--cluster``'s
  fields; that is what decides k: the IRL and the solver come after), then learn()'s split
  of divided types (:func:`torchhrc.tasks.pipeline.find_types`; ``--no-split``:
  the clustering alone); the k found,
  the true k, the ARI against the true types, and on a miss the record of every k (gain,
  exact ICL, BIC, held-out gain, subject consistency) that chose it. ``--subjects 300`` is 10
  times the data.
* ``--goal 3``: one seed through ``bench_evaluation.evaluate_world`` (``learn()`` type-aware
  and with ``k=1``, ``evaluate_task`` against the simulated people under their true rewards);
  the same Markdown row as ``benchmarks/bench_evaluation.py``.

Usage::

    python benchmarks/bench_heldout.py --goal 2 --seeds 0-9
    python benchmarks/bench_heldout.py --goal 2 --seeds 0-2 --subjects 300
    python benchmarks/bench_heldout.py --goal 2 --tasks suite --cluster strong_gain=0.02
    python benchmarks/bench_heldout.py --goal 3 --tasks twins,finish_late --json out.json
    python benchmarks/bench_heldout.py --goal 3 --seeds 0-9 --solver-time 5 --episodes 100
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_evaluation import TABLE_HEADER, _seeds, evaluate_world, seeds_table
from heldout_tasks import HELDOUT

from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import ClusterConfig
from torchhrc.tasks.pipeline import cluster_options, find_types
from torchhrc.tasks.suite import SUITE

#: The clustering options ``torchhrc.tasks.learn`` passes to ``fit_mixture`` when given no
#: clustering settings.
LEARN_CLUSTER_OPTIONS: dict[str, Any] = cluster_options()


def _world(name: str):
    return HELDOUT[name]() if name in HELDOUT else SUITE[name]()


def cluster_row(name: str, seed: int, *, subjects: int, per_subject: int, noise: float,
                cluster: ClusterConfig | None = None,
                split: bool = True) -> dict[str, Any]:  # fmt: skip
    """One clustering of task ``name`` (held-out or suite) at ``seed`` as ``learn()`` does it
    (``fit_mixture`` with learn()'s options, then ``split``: its split of divided types): k,
    true k, ARI, the chain order and the reading of the objects kept, the record of every k
    and the splits; ``cluster`` replaces learn()'s
    clustering defaults field by field."""
    world = _world(name)
    demos, types = world.demonstrations(subjects=subjects, per_subject=per_subject, noise=noise,
                                        seed=seed)  # fmt: skip
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit, z, splits = find_types(world.task, demos, cluster_options(cluster), seed=seed,
                                    split=split)  # fmt: skip
    k = int(fit.k) + len(splits)
    ari = adjusted_rand_index(types.tolist(), z.tolist())
    return dict(task=name, states=world.task.num_states, seed=seed, true_k=world.num_types,
                k=k, k_clustered=int(fit.k), splits=splits, ari=float(ari),
                hit=k == world.num_types and ari >= 0.9, order=int(fit.order),
                objects=fit.objects,
                seconds=time.perf_counter() - start,
                per_k={int(k): dict(v) for k, v in fit.per_k.items()})  # fmt: skip


def _per_k_text(per_k: dict[int, dict[str, float]]) -> str:
    keys = ("gain", "exact_icl", "bic", "heldout", "consistency", "split_consistency")
    return "; ".join(f"k={k}: " + ", ".join(f"{c} {v[c]:.4g}" for c in keys if c in v)
                     for k, v in sorted(per_k.items()))  # fmt: skip


def goal2(tasks: list[str], seeds: list[int], args: argparse.Namespace) -> list[dict[str, Any]]:
    rows = []
    for name in tasks:
        for seed in seeds:
            row = cluster_row(name, seed, subjects=args.subjects, per_subject=args.per_subject,
                              noise=args.noise, cluster=args.cluster,
                              split=not args.no_split)  # fmt: skip
            rows.append(row)
            mark = "" if row["hit"] else "   MISS: " + _per_k_text(row["per_k"])
            if row["splits"]:
                mark += f"   (clustered k {row['k_clustered']}, split {row['splits']})"
            print(f"{name:16s} seed {seed:2d}  k {row['k']} (true {row['true_k']})  ARI "
                  f"{row['ari']:.3f}  {row['seconds']:.1f} s{mark}", flush=True)  # fmt: skip
    print(f"\n{args.subjects} subjects x {args.per_subject} demonstrations, noise {args.noise}, "
          f"learn()'s clustering defaults {args.cluster or ''}\n")  # fmt: skip
    print("| task | X | true k | true k with ARI >= 0.9 | k per seed | ARI (min over hits) "
          "| s/run |\n|---|---|---|---|---|---|---|")  # fmt: skip
    for name in tasks:
        rs = [r for r in rows if r["task"] == name]
        hits = [r for r in rs if r["hit"]]
        low = min((r["ari"] for r in hits), default=float("nan"))
        print(f"| {name} | {rs[0]['states']} | {rs[0]['true_k']} | {len(hits)}/{len(rs)} | "
              f"{' '.join(str(r['k']) for r in rs)} | {low:.3f} | "
              f"{sum(r['seconds'] for r in rs) / len(rs):.1f} |")  # fmt: skip
    return rows


def goal3(tasks: list[str], args: argparse.Namespace) -> dict[str, Any]:
    if args.seeds is not None:  # every seed: bench_evaluation's two-sign table
        return seeds_table(tasks, _seeds(args.seeds), _world, subjects=args.subjects,
                           per_subject=args.per_subject, noise=args.noise,
                           episodes=args.episodes, belief_steps=args.belief_steps,
                           solver_time=args.solver_time)  # fmt: skip
    rows, records = [], {}
    for name in tasks:
        world = _world(name)
        demos, _ = world.demonstrations(subjects=args.subjects, per_subject=args.per_subject,
                                        noise=args.noise, seed=args.seed)  # fmt: skip
        row, record = evaluate_world(name, world, demos, episodes=args.episodes,
                                     belief_steps=args.belief_steps,
                                     solver_time=args.solver_time, seed=args.seed)  # fmt: skip
        rows.append(row)
        records[name] = record
        print(row, flush=True)
    print()
    print(TABLE_HEADER.format(steps=args.belief_steps))
    print("\n".join(rows))
    return records


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--goal", type=int, choices=(2, 3), default=2)
    parser.add_argument("--tasks", default=",".join(HELDOUT),
                        help="held-out or suite task names, comma-separated; "
                             "'suite': the suite's")  # fmt: skip
    parser.add_argument(
        "--cluster",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="goal 2: a ClusterConfig field (repeatable), e.g. strong_gain=0.02",
    )
    parser.add_argument("--seeds", default=None,
                        help="e.g. 0-9 or 0,3,5 (goal 2's default: 0-9; goal 3: every seed "
                             "as bench_evaluation --seeds, instead of --seed)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="goal 3's seed")
    parser.add_argument("--no-split", action="store_true",
                        help="goal 2: the clustering alone, without learn()'s split of "
                             "divided types")  # fmt: skip
    parser.add_argument("--subjects", type=int, default=30)
    parser.add_argument("--per-subject", type=int, default=4)
    parser.add_argument("--noise", type=float, default=0.05)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--belief-steps", type=int, default=5)
    parser.add_argument("--solver-time", type=float, default=10.0)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    fields = dict(item.partition("=")[::2] for item in args.cluster)
    config = ClusterConfig(**{k: ast.literal_eval(v) for k, v in fields.items()})
    args.cluster = config if fields else None
    tasks = [t for item in args.tasks.split(",")
             for t in (list(SUITE) if item == "suite" else [item])]  # fmt: skip
    if args.goal == 2:
        out: Any = goal2(tasks, _seeds(args.seeds or "0-9"), args)
    else:
        out = goal3(tasks, args)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
