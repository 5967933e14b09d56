"""Hand-finishing: SARSOP on the factored MOMDP against SARSOP on the flat POMDP.

Both solves use the same code and the same default initialisers (blind lower bound, FIB upper
bound); the factored one runs to ``--precision`` (or ``--time-limit``), the flat one
(``MOMDP.to_pomdp()``, ``S = X * Y`` states, ``X * O`` observations) to the gap the factored
one reached (or ``--flat-time``). Times are read from the solvers' histories (initialisation
included). Prints the ratio; a flat solve that does not reach the gap makes the ratio a lower
bound (printed with ">=").

The instance: the task's box grid restricted to the horizontal positions ``--horizontal``
(indices into the default 5), all 4 heights and 5 tilts, kept by the kinematic checks, with
``--work-units`` per side; the paper-size instance (1950 states) has a flat ``Z`` of ~640
million entries and does not fit in memory, which is the point of the factoring.

Run: ``python benchmarks/bench_hand_finishing.py [--horizontal 1 2 3] [--work-units 3]``
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from torchhrc.experiments.hand_finishing import factored_vs_flat
from torchhrc.tasks.hand_finishing import HandFinishingTask
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry, feasible_box_configurations
from torchhrc.tasks.hand_finishing.sensing import TRUE_HAND_LOC, observation_grid


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizontal", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--work-units", type=int, default=3)
    parser.add_argument("--noise", type=float, default=0.2)
    parser.add_argument("--precision", type=float, default=0.5)
    parser.add_argument("--time-limit", type=float, default=60.0)
    parser.add_argument("--flat-time", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=1, help="measure the ratio this often")
    args = parser.parse_args()
    torch.set_num_threads(1)  # the tree search is sequential
    base = BoxGeometry()
    geometry = BoxGeometry(horizontal=[base.horizontal[i] for i in args.horizontal])
    start = time.perf_counter()
    feasibility = feasible_box_configurations(geometry, seed=args.seed)
    print(f"kinematic checks: {time.perf_counter() - start:.1f} s")
    task = HandFinishingTask.build(
        feasible=feasibility.comfortable,
        reachable=feasibility.reachable,
        geometry=geometry,
        work_units=args.work_units,
    )
    hand = task.observation_model(
        observation_grid(),
        loc=torch.tensor(TRUE_HAND_LOC),
        scale=torch.tensor([args.noise, args.noise]),
    )
    model = task.momdp(hand)
    ratios = []
    for _ in range(args.repeats):
        result = factored_vs_flat(
            model,
            precision=args.precision,
            time_limit=args.time_limit,
            flat_time=args.flat_time,
            seed=args.seed,
        )
        print(json.dumps(result, indent=2))
        sign = "" if result["flat_reached_gap"] else ">="
        print(
            f"states {result['n_states']}, gap {result['target_gap']:.3g}: factored "
            f"{result['factored_time_s']:.2f} s, flat {result['flat_time_s']:.1f} s, "
            f"ratio {sign}{result['speedup']:.1f}x",
            flush=True,
        )
        ratios.append(result["speedup"])
    if len(ratios) > 1:
        print(f"ratios: {', '.join(f'{r:.1f}x' for r in ratios)}; min {min(ratios):.1f}x")


if __name__ == "__main__":
    main()
