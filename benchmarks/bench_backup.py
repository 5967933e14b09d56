"""Benchmark the point-based backup kernel (torchhrc.solvers.backup).

Two ratios, each measured in the same run:

1. batched vs one belief at a time: ``point_backup`` of ``M`` beliefs in one call against a
   Python loop of ``M`` single-belief calls (same kernel, same results), on Tiger, a random
   POMDP and RockSample(4, 4) flat.
2. MOMDP-factored vs flat: the backup of the same beliefs ``(x, b_y)`` with
   ``momdp_point_backup`` against ``point_backup`` on ``to_pomdp()`` (the flat model has
   ``X * Y`` states and ``X * O`` observations) on the belief set of a PBVI run, and whole
   PBVI solves (``factored=True`` vs ``False``) with the same settings, on RockSample(4, 4)
   (robot position observed, rock qualities hidden).

    python benchmarks/bench_backup.py [--repeats 3] [--threads 1] [--beliefs 256]

Prints a Markdown table (times are medians over the repeats).
"""

from __future__ import annotations

import argparse
import time

import torch
from _timing import median_time

from torchhrc.solvers import PBVIConfig, pbvi
from torchhrc.solvers.backup import momdp_point_backup, point_backup
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.tasks.classic import rock_sample, tiger
from torchhrc.testing import random_pomdp


def batched_vs_loop(repeats: int, M: int) -> list[tuple[str, int, int, float, float]]:
    rows = []
    problems = {
        "Tiger": tiger(),
        "random S=30 A=4 O=5": random_pomdp(30, 4, 5, seed=0),
        "RockSample(4,4) flat": rock_sample(4, 4, form="momdp").to_pomdp(),
    }
    for name, model in problems.items():
        generator = torch.Generator().manual_seed(0)
        S = model.num_states
        beliefs = torch.distributions.Dirichlet(torch.full((S,), 0.3, dtype=torch.float64))
        torch.manual_seed(0)
        beliefs = beliefs.sample((M,))
        alphas = torch.randn(32, S, dtype=torch.float64, generator=generator)
        policy = AlphaVectorPolicy(alphas, torch.zeros(32, dtype=torch.long))

        def one_call(m=model, b=beliefs, p=policy):
            return point_backup(m, p, b)

        def loop_calls(m=model, b=beliefs, p=policy):
            return [point_backup(m, p, b[i : i + 1]) for i in range(M)]

        batched = median_time(one_call, repeats)
        loop = median_time(loop_calls, repeats)
        rows.append((name, S, M, batched, loop))
    return rows


def factored_vs_flat(repeats: int, expansions: int) -> list[tuple[str, str, str]]:
    momdp = rock_sample(4, 4, form="momdp")
    flat_model = momdp.to_pomdp()
    X, Y = momdp.num_observed, momdp.num_hidden
    # the belief set and vectors of a factored PBVI run: the same inputs for both kernels
    solution = pbvi(momdp, PBVIConfig(time_limit=600, expansions=expansions, seed=0))
    policy, x, b_y = solution.policy, solution.info["belief_x"], solution.info["beliefs"]
    M = b_y.shape[0]
    flat_beliefs = torch.zeros(M, X, Y, dtype=torch.float64)
    flat_beliefs[torch.arange(M), x] = b_y
    flat_beliefs = flat_beliefs.reshape(M, X * Y)
    # each vector of x, embedded in the flat state space (very low outside x's block)
    embedded = torch.full((policy.num_vectors, X, Y), -1e4, dtype=torch.float64)
    embedded[torch.arange(policy.num_vectors), policy.observed] = policy.alphas
    flat_policy = AlphaVectorPolicy(embedded.reshape(-1, X * Y), policy.actions)
    factored = median_time(lambda: momdp_point_backup(momdp, policy, x, b_y), repeats)
    flat = median_time(lambda: point_backup(flat_model, flat_policy, flat_beliefs), repeats)
    rows = [
        (
            f"one backup sweep: {M} beliefs, {policy.num_vectors} vectors",
            f"{factored:.4f}",
            f"{flat:.4f}",
            f"{flat / factored:.1f}x",
        )
    ]
    config = {"time_limit": 600, "expansions": expansions, "seed": 0}
    start = time.perf_counter()
    fact = pbvi(momdp, PBVIConfig(**config))
    t_factored = time.perf_counter() - start
    start = time.perf_counter()
    flat_solution = pbvi(momdp, PBVIConfig(factored=False, **config))
    t_flat = time.perf_counter() - start
    rows.append(
        (
            f"PBVI solve, {expansions} expansions (lower bound at b0)",
            f"{t_factored:.2f} ({fact.lower:.3f})",
            f"{t_flat:.2f} ({flat_solution.lower:.3f})",
            f"{t_flat / t_factored:.1f}x",
        )
    )
    start = time.perf_counter()
    more = pbvi(momdp, PBVIConfig(**{**config, "expansions": expansions + 3}))
    t_more = time.perf_counter() - start
    rows.append(
        (
            f"PBVI solve, factored {expansions + 3} expansions vs flat {expansions}",
            f"{t_more:.2f} ({more.lower:.3f})",
            f"{t_flat:.2f} ({flat_solution.lower:.3f})",
            f"{t_flat / t_more:.1f}x",
        )
    )
    per_f = t_factored / max(1, fact.info["iterations"])
    per_flat = t_flat / max(1, flat_solution.info["iterations"])
    rows.append(
        (
            "PBVI time per backup sweep (solve time / sweeps)",
            f"{per_f:.4f}",
            f"{per_flat:.4f}",
            f"{per_flat / per_f:.1f}x",
        )
    )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--beliefs", type=int, default=256, help="beliefs per backup")
    parser.add_argument("--expansions", type=int, default=7, help="PBVI expansions (7)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s)\n")
    print("| problem | S | beliefs | batched (s) | one at a time (s) | speed-up |")
    print("|---|---|---|---|---|---|")
    for name, S, M, batched, loop in batched_vs_loop(args.repeats, args.beliefs):
        print(f"| {name} | {S} | {M} | {batched:.4f} | {loop:.4f} | {loop / batched:.1f}x |")
    print()
    print("| RockSample(4,4): X=17 observed, Y=16 hidden | factored (s) | flat (s) | speed-up |")
    print("|---|---|---|---|")
    for name, factored, flat, ratio in factored_vs_flat(args.repeats, args.expansions):
        print(f"| {name} | {factored} | {flat} | {ratio} |")


if __name__ == "__main__":
    main()
