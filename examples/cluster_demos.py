"""Cluster a simulated place-and-drill study into human types (the paper's first stage).

Simulates the paper's study (18 subjects x 3 demonstrations, 3 screw positions, half
"safe", half "efficient", noise 0 to 0.15 per subject), selects the number of types by
BIC, shows how each learned type's robot responds to a placement, and evaluates the
leave-one-subject-out type accuracy with the paper's likelihood-weighted vote (paper:
96.5%). Then a harder study (three strategies, 4 positions, 150 subjects) clustered with the
positions read as recorded and as the default reads them (exchangeable objects detected,
docs/clustering.md). Runs in a minute or two on a CPU:

    python examples/cluster_demos.py

``TORCHHRC_EXAMPLES_QUICK=1`` (set by ``tests/test_examples.py``) runs every step at a
smaller size (fewer k and restarts, 60 subjects in the harder study): the same calls, in
seconds; the numbers printed are then not the ones above.
"""

from __future__ import annotations

import os

import torch

from torchhrc.experiments.loo import leave_one_subject_out
from torchhrc.metrics import adjusted_rand_index, match_clusters
from torchhrc.mixture import fit_mixture
from torchhrc.tasks.place_and_drill import simulate_study

SEED = 0
#: smaller sizes for the smoke test (tests/test_examples.py): the same steps
QUICK = os.environ.get("TORCHHRC_EXAMPLES_QUICK") == "1"


def main() -> None:
    demos = simulate_study(seed=SEED)
    print(f"study: {demos}")
    for steps in demos.select_subjects(["S01"]).to_lists()[:1]:
        print("a demonstration of S01:", " ".join(f"{a[0]}:{b}" for a, b in steps))

    fit = fit_mixture(
        demos, k_min=2, k_max=4 if QUICK else 10, restarts=5 if QUICK else 20, seed=SEED
    )
    print("\n  k        BIC   log-likelihood")
    for k, scores in fit.per_k.items():
        mark = "  <- selected" if k == fit.k else ""
        print(f"{k:>3} {scores['bic']:>10.2f} {scores['log_likelihood']:>16.2f}{mark}")
    ari = adjusted_rand_index(demos.types, fit.assignments)
    names = match_clusters(demos.types, fit.assignments)
    print(f"\nselected k = {fit.k}; adjusted Rand index vs the true types = {ari:.3f}")

    # Each type's transition matrix, read where it differs between types: what the robot
    # does right after the human places a screw (drill it at once, or wait).
    symbols = demos.symbol_names
    places = [i for i, s in enumerate(symbols) if s.startswith("human:place_")]
    drills = [i for i, s in enumerate(symbols) if s.startswith("robot:drill_")]
    wait = symbols.index("robot:wait")
    transition = fit.transition_over(demos).detach().to(torch.float64)  # (k, A, A)
    print("\nP(robot's next action | human placed screw p), per learned type:")
    for c in range(fit.k):
        drill = torch.stack([transition[c, p, d] for p, d in zip(places, drills)])
        waits = transition[c, places, wait]
        size = int((fit.assignments == c).sum())
        print(
            f"  cluster {c} ({names.get(c, '?')}, {size} sequences): "
            f"drill p at once {drill.mean():.2f}, wait {waits.mean():.2f}"
        )

    # 18 folds, each a full Select-Best-Model on 17 subjects (k up to 6 here, for speed).
    result = leave_one_subject_out(
        demos, k_max=3 if QUICK else 6, restarts=3 if QUICK else 10, seed=SEED, inference="vote"
    )
    wrong = [f.subject for f in result.folds if not f.correct]
    print(
        f"\nleave-one-subject-out accuracy (likelihood-weighted vote): {result.accuracy:.3f} "
        f"(paper: 0.965); k per fold {result.k_counts}"
        + (f"; misclassified {wrong}" if wrong else "")
    )

    # Harder: every subject keeps its own placement order, so over place_A..place_D the
    # best-scoring clusters are placement orders; renaming the positions by first use in
    # each sequence (place_1, place_2, ...) leaves the strategies. The default detects that
    # (objects="auto": both forms fitted and scored on the recorded data); objects="raw"
    # forces the recorded position symbols.
    harder = simulate_study(
        n_subjects=60 if QUICK else 150,
        n_positions=4,
        strategies=("safe", "efficient", "pairs"),
        noise=0.1,
        seed=SEED,
    )
    for name, objects in (("position symbols", "raw"), ("default", "auto")):
        fit = fit_mixture(harder, seed=SEED, objects=objects)
        ari = adjusted_rand_index(harder.types, fit.assignments)
        print(
            f"harder study, {name:<16}: k = {fit.k}, ARI vs the 3 strategies = {ari:.3f} "
            f"(objects: {fit.objects})"
        )


if __name__ == "__main__":
    main()
