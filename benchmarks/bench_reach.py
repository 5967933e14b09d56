"""Benchmark: reach check of 10,000 box poses, batched, against one pose at a time.

The 10,000 poses are the grip poses of a 25 x 20 x 20 grid of box configurations
(horizontal -1..1 m, vertical -0.3..1.1 m above the robot base, tilt -90..90 deg), wider
than the task's grid so that part of it is out of reach. The batched call is
``torchhrc.kinematics.reach_check`` on all of them; the one-pose-at-a-time loop calls the same
function with one pose per call on a seeded random subset and is extrapolated to 10,000
(printed as such). Also printed: forward kinematics plus Jacobian of 10,000 joint vectors with
the compiled chain against pytorch-kinematics' own ``chain.jacobian`` in the same run.

Run: ``python benchmarks/bench_reach.py [--subset 200] [--repeats 3] [--threads 2]``.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import torch

from torchhrc.kinematics import SerialArm, reach_check
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry


def _best_of(fn, repeats: int) -> tuple[float, float]:
    """Best wall time and best CPU time of this process (s) over ``repeats`` calls."""
    best, best_cpu = math.inf, math.inf
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        fn()
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - cpu)
    return best, best_cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subset", type=int, default=200, help="poses timed one at a time")
    parser.add_argument("--repeats", type=int, default=3, help="best-of repeats")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dtypes", default="float64,float32", help="comma-separated dtypes")
    parser.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: keep)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    geometry = BoxGeometry(
        horizontal=tuple(torch.linspace(-1.0, 1.0, 25).tolist()),
        vertical=tuple(torch.linspace(-0.3, 1.1, 20).tolist()),
        tilt=tuple(torch.linspace(-math.pi / 2, math.pi / 2, 20).tolist()),
    )
    load_before = os.getloadavg()
    print(
        f"torch {torch.__version__}, threads {torch.get_num_threads()}, "
        f"cpus {os.cpu_count()}, load average {load_before[0]:.2f}"
    )

    results = {}
    for dtype in [getattr(torch, name) for name in args.dtypes.split(",")]:
        arm = SerialArm.panda(dtype=dtype)
        poses = geometry.grip_poses(dtype=dtype).reshape(-1, 4, 4)
        res = reach_check(poses, arm=arm, seed=args.seed)  # warm-up, and the verdicts
        t_batch, cpu_batch = _best_of(
            lambda arm=arm, poses=poses: reach_check(poses, arm=arm, seed=args.seed), args.repeats
        )
        gen = torch.Generator().manual_seed(args.seed)
        subset = torch.randperm(poses.shape[0], generator=gen)[: args.subset]

        def loop(arm=arm, poses=poses, subset=subset):
            for i in subset.tolist():
                reach_check(poses[i : i + 1], arm=arm, seed=args.seed)

        t_loop, cpu_loop = (t * poses.shape[0] / subset.numel() for t in _best_of(loop, 1))
        results[dtype] = (t_batch, t_loop, float(res.reachable.double().mean()))
        name = str(dtype).replace("torch.", "")
        print(
            f"[{name}] reach check of {poses.shape[0]} poses, batched: {t_batch:.3f} s wall, "
            f"{cpu_batch:.3f} s CPU (reachable fraction {results[dtype][2]:.3f})"
        )
        print(
            f"[{name}] one at a time (timed on {subset.numel()}, extrapolated): "
            f"{t_loop:.1f} s wall, {cpu_loop:.1f} s CPU; ratio {t_loop / t_batch:.0f}x wall, "
            f"{cpu_loop / cpu_batch:.0f}x CPU"
        )

    arm = SerialArm.panda()
    gen = torch.Generator().manual_seed(args.seed)
    q = arm.lower + (arm.upper - arm.lower) * torch.rand(
        10_000, arm.dof, generator=gen, dtype=torch.float64
    )
    t_ours = _best_of(lambda: arm.forward_and_jacobian(q), args.repeats)[0]
    t_pk = _best_of(lambda: (arm.chain.forward_kinematics(q), arm.chain.jacobian(q)), args.repeats)[
        0
    ]
    print(
        f"FK + Jacobian of 10000 joint vectors: compiled chain {t_ours * 1e3:.1f} ms, "
        f"pytorch-kinematics {t_pk * 1e3:.1f} ms; ratio {t_pk / t_ours:.1f}x"
    )
    load_after = os.getloadavg()
    print(f"load average after: {load_after[0]:.2f}")


if __name__ == "__main__":
    main()
