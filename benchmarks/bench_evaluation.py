"""The type-aware robot against the type-agnostic one on every suite task (issue 31 goal 3).

For each task of :data:`torchhrc.tasks.suite.SUITE`: demonstrations (``--subjects`` x
``--per-subject``, noise 0.05), ``torchhrc.learn`` with its defaults (type-aware) and with
``k=1`` (type-agnostic), then :func:`torchhrc.evaluate_task` against the task's simulated
people (``--episodes`` per true type, people's noise 0.05) under their true rewards. Prints a
Markdown table: per task the population's mean return ± 95% CI of both robots, of a robot
planning on the world's true model and finding the type online (``true_model=True``), and of
the type-aware robot told the person's type (``told_type=True``; the JSON records also
have the learned model with its true behaviour and with its true rewards, ``true_parts=True``,
and the summary's verdict on which part learning lost), the per-type
comparison (+ better beyond the CIs, = within, - worse), whether the types' best responses
differ (the demonstrating partner's best action differs between types in a state the
people reach), and the belief's status per type after ``--belief-steps`` steps.

Run: ``python benchmarks/bench_evaluation.py [--tasks a,b] [--episodes 200] [--json out.json]``
(about a minute per task on one core).

``--seeds 0-9``: every task on every seed (its own demonstrations and people), printed as
one row per task with three signs per seed: *told the type* against *type-agnostic* (does
knowing the type pay?), *true model* against *type-agnostic* (can finding it online pay?),
then *type-aware* against *type-agnostic*, over the population and beyond the CIs
(:func:`seeds_table`; the tables of docs/evaluation_history.md, "Over
ten seeds", at ``--solver-time 5 --episodes 100``; ``benchmarks/bench_heldout.py --goal 3
--seeds`` runs it on the held-out tasks). SARSOP stops on a wall-clock limit: on a loaded
machine a large task's policies can differ between runs; ``--json`` records the bounds' gaps.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import torch

import torchhrc
from torchhrc.tasks.suite import SUITE, make_task


def best_responses_differ(world) -> bool:
    """The partner's best action (first by index on ties) differs between two true types in
    a state that the people of some type reach (noise-free rollouts of the partner)."""
    Y = world.num_types
    g = torch.Generator().manual_seed(0)
    types = torch.arange(Y).repeat_interleave(4)
    states, _, _ = world.rollout(types, noise=0.0, generator=g)
    seen = states[states >= 0].unique()
    best = world.robot_demo_policy().argmax(-1)[:, seen]  # (Y, visited)
    return bool((best != best[:1]).any())


#: The Markdown header of :func:`evaluate_world`'s rows (``.format(steps=belief_steps)``).
TABLE_HEADER = (
    "| task | true k | k found | human model | type-aware (all) | type-agnostic (all) | "
    "true model (all) | told the type (all) | overall | per type | best responses differ | "
    "belief after {steps} steps |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
)


#: A comparison's sign (:meth:`torchhrc.tasks.evaluation.TaskEvaluation.compare`) as printed.
_SIGN = {1: "+", 0: "=", -1: "-"}


def evaluate_world(name: str, world, demos, *, episodes: int = 200, belief_steps: int = 5,
                   solver_time: float = 10.0, seed: int = 0,
                   human_model: str | None = None) -> tuple[str, dict]:  # fmt: skip
    """One task: learn() type-aware and with k=1 from ``demos``, evaluate_task against the
    world's people (over the population of the world's ``shares``); returns the Markdown row
    and the JSON record."""
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        aware = torchhrc.learn(world.task, demos, solver_time=solver_time,
                               human_model=human_model, seed=seed)  # fmt: skip
        agnostic = torchhrc.learn(world.task, demos, k=1, solver_time=solver_time,
                                  seed=seed)  # fmt: skip
    result = torchhrc.evaluate_task(world, aware, demonstrations=demos, agnostic=agnostic,
                                    episodes=episodes, noise=0.05,
                                    belief_steps=belief_steps, told_type=True,
                                    true_model=True, true_parts=True, seed=seed)  # fmt: skip
    per_type = result.compare("type-aware", "type-agnostic")
    overall = int(result.compare("type-aware", "type-agnostic", overall=True))
    differ = best_responses_differ(world)
    signs = "".join(_SIGN[int(c)] for c in per_type)
    status = ", ".join(f"{n}: {s}" for n, s in zip(result.type_names, result.belief_status))
    m, c = result.overall_mean, result.overall_ci
    used = aware.info.get("human_model", {})
    used = used.get("used", "?") if isinstance(used, dict) else str(used)
    row = (
        f"| {name} | {world.num_types} | {aware.num_types} | {used} | "
        f"{m[0]:.2f} ± {c[0]:.2f} | "
        f"{m[1]:.2f} ± {c[1]:.2f} | {m[2]:.2f} ± {c[2]:.2f} | {m[3]:.2f} ± {c[3]:.2f} | "
        f"{_SIGN[overall]} | "
        f"{signs} | "
        f"{'yes' if differ else 'no'} | {status} |"
    )
    pays = int(result.compare("told the type", "type-agnostic", overall=True))
    online = int(result.compare("true model", "type-agnostic", overall=True))
    record = {**result.to_dict(), "best_responses_differ": differ,
              "signs": _SIGN[pays] + _SIGN[online] + _SIGN[overall], "summary": result.summary(),
              "paired": {name: [float(v) for v in result.difference(name, "type-agnostic",
                                                                    overall=True)]
                         for name in ("type-aware", "told the type", "true model")},
              "k_found": aware.num_types, "human_model": used,
              "gap": [aware.upper - aware.lower, agnostic.upper - agnostic.lower],
              "seconds": time.perf_counter() - start}  # fmt: skip
    return row, record


def seeds_table(names: list[str], seeds: list[int], make_world, *, subjects: int = 30,
                per_subject: int = 4, noise: float = 0.05,
                **options) -> dict[str, dict[int, dict]]:  # fmt: skip
    """Every task of ``names`` (``make_world(name)``) on every seed: :func:`evaluate_world`
    on the seed's demonstrations (``subjects`` x ``per_subject``, ``noise``), one line per
    run as it ends, then a Markdown row per task of three signs per seed (told the type /
    true model / type-aware, each against the type-agnostic robot over the population) and
    the counts where finding the type online pays (the true model ahead), where only being
    told it pays, and where neither does. ``options`` go to
    :func:`evaluate_world`. Returns the records by task and seed."""
    records: dict[str, dict[int, dict]] = {}
    steps = options.get("belief_steps", 5)
    print(
        "each run: seed N: three signs (told the type / true model / type-aware, against "
        "the type-agnostic robot over the population), then the row of"
    )
    print(TABLE_HEADER.format(steps=steps), flush=True)
    for name in names:
        world = make_world(name)
        for seed in seeds:
            demos, _ = world.demonstrations(subjects=subjects, per_subject=per_subject,
                                            noise=noise, seed=seed)  # fmt: skip
            row, record = evaluate_world(name, world, demos, seed=seed, **options)
            records.setdefault(name, {})[seed] = record
            print(f"seed {seed}: {record['signs']} {row}", flush=True)
    print(f"\n| task | seeds {' '.join(map(str, seeds))} |\n|---|---|")
    cases = ("finding it online pays", "only being told it pays", "knowing it does not pay")
    counts = {case: {"+": 0, "=": 0, "-": 0} for case in cases}
    for name, by_seed in records.items():
        signs = [by_seed[s]["signs"] for s in seeds]
        print(f"| {name} | {' '.join(signs)} |")
        for told, online, aware in signs:
            case = cases[0] if online == "+" else cases[1] if told == "+" else cases[2]
            counts[case][aware] += 1
    for case, c in counts.items():
        print(f"{case}: {sum(c.values())} runs, type-aware ahead on {c['+']}, "
              f"level on {c['=']}, behind on {c['-']}")  # fmt: skip
    return records


def _seeds(text: str) -> list[int]:
    """``"0-9"`` or ``"0,3,5"`` (or a mix) -> the seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default=",".join(SUITE))
    parser.add_argument("--subjects", type=int, default=30)
    parser.add_argument("--per-subject", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--belief-steps", type=int, default=5)
    parser.add_argument("--solver-time", type=float, default=10.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seeds", default=None, help="e.g. 0-9: every seed (seeds_table)")
    parser.add_argument("--human-model", default=None, help="learn()'s human_model (default)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.seeds is not None:
        out = seeds_table(args.tasks.split(","), _seeds(args.seeds), make_task,
                          subjects=args.subjects, per_subject=args.per_subject,
                          episodes=args.episodes, belief_steps=args.belief_steps,
                          solver_time=args.solver_time, human_model=args.human_model)  # fmt: skip
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
        return
    rows, records = [], {}
    for name in args.tasks.split(","):
        world = make_task(name)
        demos, _ = world.demonstrations(subjects=args.subjects, per_subject=args.per_subject,
                                        noise=0.05, seed=args.seed)  # fmt: skip
        row, records[name] = evaluate_world(name, world, demos, episodes=args.episodes,
                                            belief_steps=args.belief_steps,
                                            solver_time=args.solver_time, seed=args.seed,
                                            human_model=args.human_model)  # fmt: skip
        rows.append(row)
        print(row, flush=True)
    print()
    print(TABLE_HEADER.format(steps=args.belief_steps))
    print("\n".join(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=1)


if __name__ == "__main__":
    main()
