"""Model selection study (issue 31 goal 2): which k each criterion finds, task by task.

For every task and seed, demonstrations are simulated at ``--subjects`` x ``--per-subject``
(noise ``--noise``) and clustered with ``fit_mixture``'s selection as ``learn()`` runs it
(soft EM, k = 1..6, 10 restarts, ``initial=True``, the default criterion ``icl_or_gain``):
its k and ARI are the "fit" columns. The record of every k (``per_k``: BIC, exact ICL,
in-sample gain; with ``--heldout`` also the held-out log-likelihood by subject and its
standard error, from a second fit with ``criterion="heldout"``) gives the k that other rules
would choose from the same fits:

* ``exact_icl``: the exact ICL's k, then the ``min_gain`` cut;
* ``bic|icl`` (the soft default before issue 31): the larger of BIC's and the exact ICL's k,
  then the ``min_gain`` cut;
* ``held1se``: the smallest k whose held-out log-likelihood is within one standard error of
  the best k's, then the ``min_gain`` cut;
* ``bic``: the paper's BIC alone.

Tasks: the generated suite (``torchhrc.tasks.suite.SUITE``), synthetic mixtures of Markov
chains with subjects (``synth-*``: ``Y`` types over ``A`` symbols whose chains differ in a
fraction of their rows; the first symbol is uniform, carrying no type), the kitchen of
``examples/your_own_task.py`` and the place-and-drill study (soft EM, 2 types).

Usage::

    python benchmarks/bench_selection.py --tasks suite place_and_drill kitchen --seeds 10
    python benchmarks/bench_selection.py --tasks suite --seeds 10 --subjects 300  # 10x data
    python benchmarks/bench_selection.py --tasks suite --heldout --initial 1 0 --json out.json

Prints one line per task and ``initial``: the true k, the seeds on which the fit found it with
ARI >= 0.9, each rule's seeds with the true k, the fit's smallest ARI at the true k and its
k on every seed. Docs: ``docs/clustering.md`` ("Choosing k on tasks nobody tuned for").
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from pathlib import Path
from typing import Any

import torch

from torchhrc import Demonstrations
from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import fit_mixture

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------------------- task generators
def synthetic(
    types: int, symbols: int, differ: float, *, subjects: int, per_subject: int, noise: float,
    seed: int, length: int = 16, task_seed: int = 0,
) -> tuple[Demonstrations, list[int]]:  # fmt: skip
    """``types`` Markov chains over ``symbols`` symbols: a shared chain (2 successors a row)
    and, for a fraction ``differ`` of the rows, a successor set of each type's own; each
    subject has one type; every step is replaced with probability ``noise`` by a uniformly
    random symbol."""
    g = torch.Generator().manual_seed(1000 + task_seed)
    base = torch.zeros(symbols, symbols)
    for a in range(symbols):
        succ = torch.randperm(symbols, generator=g)[:2]
        u = float(torch.rand((), generator=g))  # Dirichlet(1, 1), from this generator
        base[a, succ] = torch.tensor([u, 1.0 - u])
    chains = base.expand(types, symbols, symbols).clone()
    rows = torch.randperm(symbols, generator=g)[: max(1, round(differ * symbols))]
    for y in range(1, types):
        for a in rows.tolist():
            succ = torch.randperm(symbols, generator=g)[:2]
            chains[y, a] = 0.0
            chains[y, a, succ] = torch.tensor([0.7, 0.3])
    rng = random.Random(seed)
    seqs, who, labels = [], [], []
    for s in range(subjects):
        y = s % types
        for _ in range(per_subject):
            x = rng.randrange(symbols)
            seq = [x]
            for _ in range(length - 1):
                if rng.random() < noise:
                    x = rng.randrange(symbols)
                else:
                    x = rng.choices(range(symbols), weights=chains[y, x].tolist())[0]
                seq.append(x)
            seqs.append([("human", f"s{v}") for v in seq])
            who.append(f"p{s}")
            labels.append(y)
    return Demonstrations.from_lists(seqs, subjects=who), labels


def kitchen(*, subjects: int, per_subject: int, noise: float, seed: int):
    """The kitchen of examples/your_own_task.py (3 types); ``noise`` is not used (the
    example's own slips)."""
    sys.path.insert(0, str(ROOT / "examples"))
    import your_own_task as ex

    demos = ex.demonstrations(ex.Kitchen(), subjects, per_subject, seed)
    names = list(demos.types)
    return demos, [ex.TYPES.index(t) for t in names]


def place_and_drill(*, subjects: int, per_subject: int, noise: float, seed: int):
    """The place-and-drill study (safe and efficient; the study's own noise range)."""
    from torchhrc.tasks.place_and_drill.demos import simulate_study

    demos = simulate_study(n_subjects=subjects, n_demos=per_subject, seed=seed)
    index: dict[str, int] = {}
    return demos, [index.setdefault(t, len(index)) for t in demos.types]


def tasks(names: list[str]) -> dict[str, tuple[int, Any]]:
    """``name -> (true k, generator(subjects=, per_subject=, noise=, seed=))``."""
    out: dict[str, tuple[int, Any]] = {}
    for name in names:
        if name == "synth":
            shapes = ((2, 10, 0.3), (3, 12, 0.25), (4, 14, 0.3), (5, 16, 0.3), (3, 20, 0.1),
                      (4, 24, 0.1))  # fmt: skip
            for y, a, d in shapes:
                make = lambda y=y, a=a, d=d, **kw: synthetic(y, a, d, **kw)  # noqa: E731
                out[f"synth-{y}x{a}-{d}"] = (y, make)
        elif name == "kitchen":
            out["kitchen"] = (3, kitchen)
        elif name == "place_and_drill":
            out["place_and_drill"] = (2, place_and_drill)
        elif name == "suite":
            from torchhrc.tasks.suite import SUITE

            for key, make in SUITE.items():
                twp = make()

                def gen(twp=twp, **kw):
                    demos, y = twp.demonstrations(**kw)
                    return demos, y.tolist()

                out[key] = (twp.num_types, gen)
        else:
            raise SystemExit(f"unknown task set {name!r}")
    return out


# ---------------------------------------------------------------------------- the rules
def rule_k(per_k: dict[int, dict[str, float]], rule: str, *, se: float = 1.0,
           min_gain: float = 0.015, strong: float = 0.04) -> int:  # fmt: skip
    """The k a rule chooses from one fit's record of every k."""
    ks = sorted(per_k)
    if rule == "bic":
        return max(ks, key=lambda k: per_k[k]["bic"])
    if rule == "exact_icl":
        top = max(ks, key=lambda k: per_k[k]["exact_icl"])
    elif rule == "icl_or_gain":  # the default: the exact ICL's k, or more where gains are strong
        top = max(ks, key=lambda k: per_k[k]["exact_icl"])
        for k in ks[1:]:
            if not per_k[k]["gain"] >= strong:
                break
            top = max(top, k)
    elif rule == "bic_or_exact_icl":
        top = max(max(ks, key=lambda k: per_k[k]["bic"]),
                  max(ks, key=lambda k: per_k[k]["exact_icl"]))  # fmt: skip
    elif rule == "heldout":
        best = max(ks, key=lambda k: per_k[k]["heldout"])
        top = next(k for k in ks if per_k[k]["heldout"] - per_k[best]["heldout"]
                   >= -se * per_k[k]["heldout_se"])  # fmt: skip
    else:
        raise ValueError(rule)
    for k in ks:
        if k >= top:
            return top
        if not per_k[k + 1].get("gain", math.nan) >= min_gain:
            return k
    return top


#: the rules compared: (label, rule, options)
VARIANTS = [
    ("exact_icl", "exact_icl", {}),
    ("bic|icl", "bic_or_exact_icl", {}),
    ("held1se", "heldout", dict(se=1.0)),
    ("bic", "bic", {}),
]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", nargs="+", default=["synth", "kitchen", "place_and_drill"])
    p.add_argument("--only", nargs="*", default=None, help="task names to keep")
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--subjects", type=int, default=30)
    p.add_argument("--per-subject", type=int, default=4)
    p.add_argument("--noise", type=float, default=0.05)
    p.add_argument("--k-max", type=int, default=6)
    p.add_argument("--restarts", type=int, default=10)
    p.add_argument("--initial", nargs="+", default=["1"],
                   help="model the first symbol: 1 (the default), 0 or both")  # fmt: skip
    p.add_argument("--criterion", default=None,
                   help="the fit's criterion (its k and ARI are reported; default: "
                   "fit_mixture's)")  # fmt: skip
    p.add_argument(
        "--heldout",
        action="store_true",
        help="also fit with criterion='heldout' (5-fold CV) for its columns",
    )
    p.add_argument("--json", type=str, default=None, help="write every fit's record here")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    records = []
    header = ["task", "k", "initial", "fit: true k, ARI >= 0.9"] + [v[0] for v in VARIANTS]
    header += ["fit: min ARI at true k", "ks"]
    print(" | ".join(header), flush=True)
    for name, (true_k, make) in tasks(args.tasks).items():
        if args.only and name not in args.only:
            continue
        for initial in (bool(int(i)) for i in args.initial):
            found = [0] * len(VARIANTS)
            good = 0
            aris, ks_fit, t0 = [], [], time.perf_counter()
            for seed in range(args.seeds):
                demos, labels = make(subjects=args.subjects, per_subject=args.per_subject,
                                     noise=args.noise, seed=seed)  # fmt: skip
                fit = fit_mixture(demos, k_min=1, k_max=args.k_max, restarts=args.restarts,
                                  seed=seed, initial=initial, criterion=args.criterion)  # fmt: skip
                ari = adjusted_rand_index(labels, fit.assignments.tolist())
                per_k = fit.per_k
                if args.heldout:
                    per_k = fit_mixture(demos, k_min=1, k_max=args.k_max, seed=seed,
                                        restarts=args.restarts, initial=initial,
                                        criterion="heldout").per_k  # fmt: skip
                ks_fit.append(fit.k)
                if fit.k == true_k:
                    aris.append(ari)
                    good += ari >= 0.9
                for i, (_, rule, opts) in enumerate(VARIANTS):
                    if rule == "heldout" and not args.heldout:
                        found[i] = -1
                        continue
                    found[i] += rule_k(per_k, rule, **opts) == true_k
                records.append(dict(task=name, seed=seed, true_k=true_k, initial=initial,
                                    k=fit.k, ari=ari, objects=fit.objects,
                                    per_k=per_k))  # fmt: skip
            ari = f"{min(aris):.3f}" if aris else "-"
            cells = [f"{f}/{args.seeds}" if f >= 0 else "-" for f in found]
            print(f"{name} | {true_k} | {int(initial)} | {good}/{args.seeds} | "
                  + " | ".join(cells) + f" | {ari} | "
                  f"{''.join(map(str, ks_fit))} | {time.perf_counter() - t0:.0f}s",
                  flush=True)  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
