"""Benchmark the batched place-and-drill VectorEnv against gymnasium's SyncVectorEnv.

Both step ``N`` episodes of torchhrc/PlaceAndDrill-v0 (same dynamics, same autoreset mode,
``AutoresetMode.NEXT_STEP``) with uniformly random actions drawn beforehand:

* ``PlaceAndDrillVectorEnv(N)``: one batched tensor program per step for all ``N`` episodes;
* ``gymnasium.vector.SyncVectorEnv([PlaceAndDrillEnv] * N)``: ``N`` Python calls per step.

Prints environment steps per second of each (``N`` x steps / median wall time) and their
ratio, for each ``N``; the issue's target is >= 100,000 steps/s for the batched env on
2 CPU cores. The ratio is the figure to quote from a shared or loaded machine.

    python benchmarks/bench_envs.py [--envs 64 1024 4096] [--steps 200] [--repeats 3]
        [--threads 1]
"""

from __future__ import annotations

import argparse

import gymnasium
import numpy as np
import torch
from _timing import median_time

from torchhrc.tasks.place_and_drill.env import PlaceAndDrillEnv
from torchhrc.tasks.place_and_drill.vector_env import PlaceAndDrillVectorEnv


def _runner(envs, actions: np.ndarray):
    def run() -> None:
        envs.reset(seed=0)
        for a in actions:
            envs.step(a)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[64, 1024, 4096])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--sync-steps", type=int, default=20,
                        help="steps of the (slow) SyncVectorEnv run")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    print(f"torch threads: {args.threads}; random actions; autoreset NEXT_STEP in both")
    print("| N envs | batched steps/s | SyncVectorEnv steps/s | ratio |")
    print("|---:|---:|---:|---:|")
    for n in args.envs:
        batched = PlaceAndDrillVectorEnv(n)
        actions = rng.integers(batched.task.num_actions, size=(args.steps, n))
        t_batched = median_time(_runner(batched, actions), args.repeats)
        sync = gymnasium.vector.SyncVectorEnv([PlaceAndDrillEnv for _ in range(n)])
        sync_actions = actions[: args.sync_steps]
        t_sync = median_time(_runner(sync, sync_actions), args.repeats)
        rate_batched = n * args.steps / t_batched
        rate_sync = n * len(sync_actions) / t_sync
        print(f"| {n} | {rate_batched:,.0f} | {rate_sync:,.0f} | {rate_batched / rate_sync:.0f}x |")


if __name__ == "__main__":
    main()
