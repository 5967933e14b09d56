"""Can a mixture of Markov chains find a task's true types at all? The true partition, scored.

The clustering (``benchmarks/bench_heldout.py --goal 2``) can miss a task's types for two
reasons: its search or its rule for k falls short, or the model family itself prefers
another partition. This script separates the two on a task with known types (a held-out
task of :mod:`heldout_tasks` or a suite task), for every chain order 1 to 3:

* ``oracle ARI``: each subject classified by the *true* types' chains (fitted on the true
  labels, in sample: an optimistic bound) and the types' shares; the ARI of that
  classification against the truth. Below 0.9, no clustering with chains of that order can
  meet issue 31's goal 2 on the seed, whatever its rule for k.
* for each pair of true types ``(i, j)``, the true partition against the same with ``j``
  merged into ``i``: ``dICL``, the exact ICL's difference
  (:func:`torchhrc.mixture.criteria.partition_icl`, subjects as units, ``log p(D, z)``);
  ``dLL``, the complete-data log-likelihood's difference at the maximum-likelihood chains;
  and ``labels``, the weights' share of ``dICL`` (``log p(z)`` under the Dirichlet(1) prior
  on the weights, the price of telling the two types' subjects apart); ``gain``,
  ``(dLL + labels)`` per transition, the effect size that ``fit_mixture``'s ``min_gain`` and
  ``strong_gain`` ask of a step (``learn()``: 0.01; its fits' own steps are soft and
  smoothed, so they gain a little less). ``dICL < 0``: the
  marginal likelihood itself prefers the merge, so a likelihood rule for k that is right
  about the model picks one type fewer. ``dLL + labels - dICL`` is what the chains'
  parameters of the extra type cost under the ICL's per-row Dirichlet prior.

Usage::

    python benchmarks/bench_true_partition.py --tasks leaky_tubes --seeds 0-4 --subjects 300
    python benchmarks/bench_true_partition.py --tasks slow_sanding,press_block --seeds 0-2

Per task, seed and order it prints the pair of types whose merge the exact ICL minds least
(``--all-pairs``: every pair).
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_evaluation import _seeds
from bench_heldout import _world

from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture.criteria import partition_icl
from torchhrc.mixture.history import context_symbols
from torchhrc.mixture.selection import partition_chains

#: The chain orders scored (those ``learn()``'s ``order="auto"`` compares).
ORDERS = (1, 2, 3)


def _complete_log_likelihood(data, counts: torch.Tensor, z: torch.Tensor) -> float:
    """``sum_n sum_(a, b) counts[n, a, b] log theta_(z_n)(b | a)`` at the maximum-likelihood
    chains of partition ``z`` (``counts (N, P, P)`` of ``data``'s sequences, ``z (N,)``;
    :func:`~torchhrc.mixture.selection.partition_chains` without pseudo-counts)."""
    labels, z = torch.unique(z, return_inverse=True)
    one_hot = torch.nn.functional.one_hot(z, labels.numel()).to(torch.float64)
    chains = partition_chains(data, one_hot, pseudo_count=0.0)  # (k, P, P)
    return float((counts * chains[z].clamp_min(1e-300).log()).sum())


def _label_log_prior(z: torch.Tensor) -> float:
    """``log p(z)`` of unit labels ``z`` under a Dirichlet(1) on the weights:
    ``log Gamma(K) + sum_k log Gamma(m_k + 1) - log Gamma(n + K)``, the weight term of
    :func:`~torchhrc.mixture.criteria.exact_icl` (``weight_prior = 1``), which that function
    does not give apart."""
    m = torch.bincount(z)
    m = m[m > 0].to(torch.float64)
    K, n = float(m.numel()), float(m.sum())
    return math.lgamma(K) + float(torch.lgamma(m + 1.0).sum()) - math.lgamma(n + K)


def true_partition_rows(name: str, seed: int, *, subjects: int, per_subject: int,
                        noise: float) -> list[dict[str, float | int | str]]:  # fmt: skip
    """The rows of one task and seed: per order, the oracle ARI and every pair's scores
    (see the module docstring); one dict per (order, pair)."""
    world = _world(name)
    demos, types = world.demonstrations(subjects=subjects, per_subject=per_subject,
                                        noise=noise, seed=seed)  # fmt: skip
    g = demos.subject_index
    G = int(g.max()) + 1
    truth = torch.zeros(G, dtype=torch.long).index_put_((g,), types)  # (G,) per subject
    K = int(types.max()) + 1
    shares = torch.bincount(truth, minlength=K).to(torch.float64) / G
    rows: list[dict[str, float | int | str]] = []
    for order in ORDERS:
        data = demos if order == 1 else context_symbols(demos, order).data
        counts = data.transition_counts(per_sequence=True).to(torch.float64)  # (N, P, P)
        chains = partition_chains(data, torch.nn.functional.one_hot(types, K).to(torch.float64))
        per_subject_counts = counts.new_zeros(G, *counts.shape[1:]).index_add_(0, g, counts)
        score = torch.einsum("gab,kab->gk", per_subject_counts, chains.clamp_min(1e-300).log())
        oracle = (score + shares.clamp_min(1e-300).log()).argmax(-1)
        ari = adjusted_rand_index(truth.tolist(), oracle.tolist())
        true_ll = _complete_log_likelihood(data, counts, types)  # the same for every pair
        true_labels = _label_log_prior(truth)
        for i, j in itertools.combinations(range(K), 2):
            merged = torch.where(types == j, i, types)
            merged_units = torch.where(truth == j, i, truth)
            icl_true, icl_merged = partition_icl(demos, [types, merged], order, groups=g)
            d_ll = true_ll - _complete_log_likelihood(data, counts, merged)
            labels = true_labels - _label_log_prior(merged_units)
            rows.append(
                {
                    "task": name,
                    "seed": seed,
                    "order": order,
                    "oracle_ari": ari,
                    "pair": f"{i}+{j}",
                    "d_icl": icl_true - icl_merged,
                    "d_ll": d_ll,
                    "labels": labels,
                    "gain": (d_ll + labels) / float(counts.sum()),
                }
            )
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", required=True, help="comma-separated task names")
    parser.add_argument("--seeds", default="0-4", help="e.g. 0-4 or 0,3,7")
    parser.add_argument("--subjects", type=int, default=30)
    parser.add_argument("--per-subject", type=int, default=4)
    parser.add_argument("--noise", type=float, default=0.05)
    parser.add_argument(
        "--all-pairs",
        action="store_true",
        help="every pair of types (default: the pair of least dICL per order)",
    )
    args = parser.parse_args(argv)
    print("| task | seed | order | oracle ARI | pair merged | dICL | dLL | labels | gain |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.tasks.split(","):
        for seed in _seeds(args.seeds):
            rows = true_partition_rows(
                name, seed, subjects=args.subjects, per_subject=args.per_subject, noise=args.noise
            )
            if not args.all_pairs:  # the closest pair of each order
                rows = [min((r for r in rows if r["order"] == o), key=lambda r: r["d_icl"])
                        for o in ORDERS]  # fmt: skip
            for r in rows:
                print(f"| {r['task']} | {r['seed']} | {r['order']} | {r['oracle_ari']:.3f} | "
                      f"{r['pair']} | {r['d_icl']:.1f} | {r['d_ll']:.1f} | {r['labels']:.1f} | "
                      f"{r['gain']:.4f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
