"""learn() on the task suite: does the default model selection find the true number of types?

For every suite task (:mod:`torchhrc.tasks.suite`) and seed: generate demonstrations
(``--subjects`` x ``--per-subject`` at ``--noise``, seeded), run
``torchhrc.tasks.learn(task, demos, seed=seed, solve=False)`` with the library's defaults
(or with ``--learn key=value`` settings), and report the number of types found, whether it
is the true one, and the adjusted Rand index of the learned assignments against the true
types (issue 31 goal 2: the true k on at least 9 of 10 seeds with ARI >= 0.9 at 30 x 4 and
noise 0.05; 10 of 10 with 10 times the data).

Usage::

    python benchmarks/bench_suite.py                       # all tasks, seeds 0-9, 30 x 4, 0.05
    python benchmarks/bench_suite.py --tasks pace,fetch_order --seeds 0-2
    python benchmarks/bench_suite.py --subjects 300 --per-subject 4 --seeds 0-9
    python benchmarks/bench_suite.py --learn k_max=8 --learn restarts=20 --csv out.csv

Prints one line per (task, seed) and a summary per task: ``hits`` (seeds with the true k),
``ari`` (mean ARI over the hits), ``ari_all`` (mean over all seeds), the k found per seed,
the smallest per-transition gain at the true k and the largest at the true k + 1 over the
seeds (when learn() records its scores: a threshold between the two separates them), and the
wall time. ``--csv`` writes the per-run rows (atomically).
"""

from __future__ import annotations

import argparse
import ast
import io
import time
from collections.abc import Sequence
from typing import Any

import torch

from torchhrc._atomic import atomic_write_bytes
from torchhrc.metrics import adjusted_rand_index
from torchhrc.tasks import learn, make_task, suite_tasks


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        if "-" in part:
            lo, hi = part.split("-")
            out.extend(range(int(lo), int(hi) + 1))
        elif part:
            out.append(int(part))
    return out


def _learn_kwargs(items: Sequence[str]) -> dict[str, Any]:
    kw: dict[str, Any] = {}
    for item in items:
        key, _, value = item.partition("=")
        try:
            kw[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            kw[key] = value
    return kw


def _gain(info: dict[str, Any], k: int) -> float:
    """The per-transition gain of going to ``k`` types that learn() recorded, if it did
    (``info["scores"][str(k)]["gain"]``), else NaN."""
    try:
        return float(info["scores"][str(k)]["gain"])
    except (KeyError, TypeError, ValueError):
        return float("nan")


def run(
    tasks: Sequence[str],
    seeds: Sequence[int],
    *,
    subjects: int = 30,
    per_subject: int = 4,
    noise: float = 0.05,
    learn_kwargs: dict[str, Any] | None = None,
    verbose: bool = True,
) -> list[dict[str, Any]]:
    """One row per (task, seed): ``task, seed, true_k, k, hit, ari, seconds``."""
    rows = []
    for name in tasks:
        twp = make_task(name)
        for seed in seeds:
            demos, types = twp.demonstrations(
                subjects=subjects, per_subject=per_subject, noise=noise, seed=seed
            )
            start = time.perf_counter()
            model = learn(twp.task, demos, seed=seed, solve=False, **(learn_kwargs or {}))
            seconds = time.perf_counter() - start
            k = int(model.num_types)
            ari = adjusted_rand_index(types.tolist(), model.assignments.tolist())
            row = dict(task=name, states=twp.task.num_states, seed=seed, true_k=twp.num_types,
                       k=k, hit=k == twp.num_types, ari=ari, seconds=seconds,
                       gain_true=_gain(model.info, twp.num_types),
                       gain_next=_gain(model.info, twp.num_types + 1))  # fmt: skip
            rows.append(row)
            if verbose:
                print(f"{name:20s} seed {seed:3d}  k {k} (true {twp.num_types})  "
                      f"ARI {ari:6.3f}  gain at true k {row['gain_true']:.4f}, at true k + 1 "
                      f"{row['gain_next']:.4f}  {seconds:6.1f} s", flush=True)  # fmt: skip
    return rows


def summary(rows: Sequence[dict[str, Any]]) -> str:
    """A Markdown table per task: hits, mean ARI over the hits and over all seeds, k found."""
    lines = ["| task | X | true k | hits | ARI (hits) | ARI (all) | k per seed "
             "| min gain at true k | max gain at true k + 1 | s/run |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for name in dict.fromkeys(r["task"] for r in rows):
        rs = [r for r in rows if r["task"] == name]
        hits = [r for r in rs if r["hit"]]
        ari_hits = sum(r["ari"] for r in hits) / len(hits) if hits else float("nan")
        ari_all = sum(r["ari"] for r in rs) / len(rs)
        ks = " ".join(str(r["k"]) for r in rs)
        sec = sum(r["seconds"] for r in rs) / len(rs)
        g_true = min(r["gain_true"] for r in rs)
        g_next = max(r["gain_next"] for r in rs)
        lines.append(f"| {name} | {rs[0]['states']} | {rs[0]['true_k']} | {len(hits)}/{len(rs)} "
                     f"| {ari_hits:.3f} | {ari_all:.3f} | {ks} | {g_true:.4f} | {g_next:.4f} "
                     f"| {sec:.1f} |")  # fmt: skip
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", default="all", help="comma-separated names, or 'all'")
    parser.add_argument("--seeds", default="0-9", help="e.g. 0-9 or 0,3,5")
    parser.add_argument("--subjects", type=int, default=30)
    parser.add_argument("--per-subject", type=int, default=4)
    parser.add_argument("--noise", type=float, default=0.05)
    parser.add_argument("--learn", action="append", default=[], metavar="KEY=VALUE",
                        help="a learn() setting (repeatable), e.g. k_max=8")  # fmt: skip
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--csv", default=None, help="write the per-run rows here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    tasks = suite_tasks() if args.tasks == "all" else tuple(args.tasks.split(","))
    rows = run(tasks, _seeds(args.seeds), subjects=args.subjects, per_subject=args.per_subject,
               noise=args.noise, learn_kwargs=_learn_kwargs(args.learn))  # fmt: skip
    print()
    print(f"{args.subjects} subjects x {args.per_subject} demonstrations, noise {args.noise}, "
          f"learn settings {_learn_kwargs(args.learn) or 'defaults'}")  # fmt: skip
    print(summary(rows))
    if args.csv:
        buf = io.StringIO()
        keys = list(rows[0]) if rows else []
        buf.write(",".join(keys) + "\n")
        for r in rows:
            buf.write(",".join(str(r[k]) for k in keys) + "\n")
        atomic_write_bytes(args.csv, buf.getvalue().encode())
    return rows


if __name__ == "__main__":
    main()
