"""``torchhrc cluster``: cluster demonstrations into human types (mixture of Markov chains).

Reads a demonstrations file (CSV of shared/DESIGN.md, or the JSON form for ``.json``),
runs Select-Best-Model (:func:`torchhrc.mixture.fit_mixture`) and prints the selected ``k``,
its BIC and log-likelihood, the best BIC and log-likelihood of every ``k`` and the cluster
of every sequence: one JSON object with ``--json``, a readable report otherwise. When the
file has a ``type`` column, the adjusted Rand index against it is reported too, and
``--loo`` adds the leave-one-subject-out type accuracy (the paper's evaluation).

JSON keys: ``k``, ``bic``, ``icl``, ``log_likelihood``, ``method``, ``criterion``,
``num_sequences``, ``num_subjects``, ``num_symbols``, ``symbols``, ``per_k`` (``"k"`` ->
``{"bic", "icl", "log_likelihood"}``), ``cluster_sizes``, ``assignments``
(``"subject/sequence"`` -> cluster), and with types ``adjusted_rand_index`` and
``matched_accuracy``; with ``--loo`` also ``loo`` (accuracy, k per fold, predictions).
``objects``: the form the model is over (``"raw"`` or ``"exchangeable"``, ``--objects``), and
``object_comparison`` when ``--objects auto`` compared the two (k, BIC, exact ICL per form).
``order``: chains of order 1, 2 or 3 (``--order``), and ``order_comparison`` when
``--order auto`` compared them (k, exact ICL, log-likelihood per order). ``next_step``
(``--criterion icl_or_gain``, below ``--k-max``): the thresholds the step to one more
cluster falls short of (:attr:`torchhrc.mixture.MixtureFit.next_step`).
Non-finite numbers are written as ``null``.

Example:
    >>> import argparse
    >>> from torchhrc.commands import cluster
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> cluster.register(sub)
    >>> sub.choices["cluster"].parse_args(["d.csv", "--k-max", "4"]).k_max
    4
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError

__all__ = ["cluster_report", "read_demonstrations", "register", "run", "sharded_cluster_report"]


def read_demonstrations(path: str) -> Demonstrations:
    """Read ``path`` as JSON (``.json``) or CSV (anything else).

    Example:
        >>> read_demonstrations("missing.csv")
        Traceback (most recent call last):
        ...
        FileNotFoundError: [Errno 2] No such file or directory: 'missing.csv'
    """
    if path.lower().endswith(".json"):
        return Demonstrations.read_json(path)
    return Demonstrations.read_csv(path)


def _next_step(step: dict[str, Any]) -> dict[str, Any]:
    """``MixtureFit.next_step`` with non-finite numbers as None (JSON)."""
    return {**step, **{part: {name: _finite(v) for name, v in step[part].items()}
                       for part in ("values", "thresholds")}}  # fmt: skip


def _finite(value: float) -> float | None:
    value = float(value)
    return value if math.isfinite(value) else None


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``cluster`` sub-command."""
    parser = subparsers.add_parser(
        "cluster",
        help="cluster demonstrations into human types; BIC selects k",
        description=(
            "Cluster joint-action demonstrations into human types with a mixture of Markov "
            "chains; Select-Best-Model picks k in [k-min, k-max] by BIC over restarts."
        ),
    )
    parser.add_argument(
        "demos",
        metavar="DEMOS",
        nargs="+",
        help="demonstrations file (.csv or .json), or a corpus in shards: several files, a "
        "directory or a glob of .csv/.parquet files with the same columns",
    )
    parser.add_argument("--k-min", type=int, default=2, help="smallest k (2)")
    parser.add_argument("--k-max", type=int, default=10, help="largest k (10)")
    parser.add_argument("--restarts", type=int, default=20, help="EM runs per k (20)")
    parser.add_argument(
        "--method",
        choices=("soft", "paper"),
        default="soft",
        help="soft: k-means++ init + smoothed soft EM (default); paper: random init + hard EM",
    )
    parser.add_argument(
        "--criterion",
        choices=("icl_or_gain", "heldout", "bic", "icl", "exact_icl", "bic_or_exact_icl"),
        default=None,
        help="model selection (soft: icl_or_gain, paper: bic; see docs/clustering.md)",
    )
    parser.add_argument(
        "--min-gain",
        type=float,
        default=None,
        help="least gain (nats per transition) an extra cluster must add (soft: 0.015; "
        "0 = BIC alone; see docs/clustering.md)",
    )
    parser.add_argument(
        "--min-consistency",
        type=float,
        default=None,
        help="least subject consistency (ICC, 0-1) of every cluster: a type belongs to a "
        "person (soft: 0.5; 0 = off; see docs/clustering.md)",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (0)")
    parser.add_argument(
        "--loo",
        action="store_true",
        help="also report leave-one-subject-out type accuracy (needs a type column)",
    )
    parser.add_argument(
        "--inference",
        choices=("vote", "posterior"),
        default="vote",
        help="type of a held-out subject for --loo: the paper's vote or the posterior",
    )
    parser.add_argument(
        "--relabel-objects",
        action="store_true",
        help="treat the objects of verb_object actions as exchangeable: rename them 1, 2, ... "
        "by first use in each sequence (types become strategies, not placement orders)",
    )
    parser.add_argument(
        "--objects",
        choices=("auto", "raw", "exchangeable"),
        default=None,
        help="how objects of verb_object actions are read: auto (soft default) fits the raw "
        "symbols and exchangeable objects (renamed by first use) and keeps the better by the "
        "exact ICL, for a sharded corpus as in memory; raw (paper default) or exchangeable "
        "force one (see docs/clustering.md)",
    )
    parser.add_argument(
        "--order",
        choices=("1", "2", "3", "auto"),
        default="1",
        help="1 (default): first-order chains, the paper's; 2: second-order chains, which "
        "see a type's order across a step every type shares (a robot waiting between the "
        "person's actions); 3: third-order chains, which see the person's last two actions "
        "across the robot's moves; auto: select k in all three and keep the fit with the "
        "most types (docs/clustering.md, 'Second-order chains', 'Third-order chains'); one "
        "file in memory only",
    )
    parser.add_argument(
        "--ray",
        metavar="local|HOST:PORT",
        default=None,
        help="reduce each shard in a Ray task and run the E-steps on Ray actors (a local "
        "cluster or a running one)",
    )
    parser.add_argument("--save-model", metavar="PATH", help="save the fitted mixture (.json)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def _fit_scores(fit: Any) -> dict[str, Any]:
    """The selected model's ``k``, scores, method and criterion (the report's first keys)."""
    return {
        "k": fit.k,
        "bic": _finite(fit.bic),
        "icl": _finite(fit.icl),
        "log_likelihood": _finite(fit.log_likelihood),
        "method": fit.method,
        "criterion": fit.criterion,
    }


def _per_k(fit: Any) -> dict[str, dict[str, float | None]]:
    """``{"k": {score: value}}`` of the best run of every k searched."""
    return {
        str(k): {name: _finite(v) for name, v in sorted(scores.items())}
        for k, scores in sorted(fit.per_k.items())
    }


def _check_search(k_min: int, k_max: int, restarts: int) -> None:
    for name, value in (("k_min", k_min), ("k_max", k_max), ("restarts", restarts)):
        if value < 1:
            raise ModelError(f"expected {name} >= 1, got {value}")
    if k_max < k_min:
        raise ModelError(f"expected k_min <= k_max, got k_min = {k_min} > k_max = {k_max}")


def _against_types(types: Any, assignments: torch.Tensor, k: int) -> dict[str, Any]:
    """Adjusted Rand index, matched accuracy and the type-by-cluster table."""
    from torchhrc.metrics import adjusted_rand_index, matched_accuracy

    table: dict[str, list[int]] = {}
    for label, c in zip(types, assignments.tolist(), strict=True):
        table.setdefault(label, [0] * k)[c] += 1
    return {
        "adjusted_rand_index": adjusted_rand_index(types, assignments),
        "matched_accuracy": matched_accuracy(types, assignments),
        "type_by_cluster": dict(sorted(table.items())),
    }


def cluster_report(
    demos: Demonstrations,
    *,
    k_min: int = 2,
    k_max: int = 10,
    restarts: int = 20,
    method: str = "soft",
    criterion: str | None = None,
    seed: int = 0,
    loo: bool = False,
    inference: str = "vote",
    save_model: str | None = None,
    relabel_objects: bool = False,
    min_gain: float | None = None,
    objects: str | None = None,
    min_consistency: float | None = None,
    order: int | str = 1,
) -> dict[str, Any]:
    """Fit, score and summarise: the dict that ``--json`` prints.

    ``min_gain`` and ``min_consistency`` are passed to ``fit_mixture`` (``None``: its
    default).
    With ``relabel_objects`` the demonstrations are first passed through
    :meth:`~torchhrc.data.Demonstrations.relabel_objects` (symbols, counts and the model are
    then over the relabelled vocabulary, and fitted as they are: ``objects="raw"``).
    ``objects`` is passed to ``fit_mixture`` (``None``: its default, ``"auto"`` for the soft
    method: the report's ``objects`` says which form was kept), and so is ``order`` (1, 2,
    3 or ``"auto"``: the report's ``order`` says which was kept).

    Raises:
        ModelError: ``loo`` without types, or a ``k`` range or ``restarts`` out of range.

    Example:
        >>> from torchhrc.tasks.place_and_drill import simulate_study
        >>> r = cluster_report(simulate_study(n_subjects=4, noise=0.0), k_max=3, restarts=2)
        >>> r["k"], r["adjusted_rand_index"], len(r["assignments"])
        (2, 1.0, 12)
    """
    from torchhrc.mixture import fit_mixture

    _check_search(k_min, k_max, restarts)
    if k_min > demos.num_sequences:
        raise ModelError(
            f"expected k_min <= the number of sequences ({demos.num_sequences}), got {k_min}"
        )
    if loo and demos.types is None:
        raise ModelError("leave-one-out needs ground-truth types (a 'type' column in the file)")
    if loo and order != 1:
        raise ModelError(
            f"leave-one-out scores each held-out subject under a model fitted without them; "
            f"with --order {order} a step after a step no other subject made has no "
            "probability: use --order 1 with --loo"
        )
    if relabel_objects:
        if objects not in (None, "raw"):
            raise ModelError(
                f"--relabel-objects relabels the file itself and fits it raw; with --objects "
                f"{objects} leave it out"
            )
        demos = demos.relabel_objects()
        objects = "raw"
    fit = fit_mixture(
        demos,
        k_min=k_min,
        k_max=k_max,
        restarts=restarts,
        method=method,  # type: ignore[arg-type]
        criterion=criterion,  # type: ignore[arg-type]
        seed=seed,
        min_gain=min_gain,
        min_consistency=min_consistency,
        objects=objects,  # type: ignore[arg-type]
        order=order,  # type: ignore[arg-type]
    )
    if save_model is not None:
        fit.model.save(save_model)
    assignments = fit.assignments.cpu()
    sizes = torch.bincount(assignments, minlength=fit.k).tolist()
    report: dict[str, Any] = {
        **_fit_scores(fit),
        "num_sequences": demos.num_sequences,
        "num_subjects": len(demos.unique_subjects),
        "num_symbols": demos.num_symbols,
        "symbols": list(demos.symbol_names),
        "per_k": _per_k(fit),
        "objects": fit.objects,
        **({"object_comparison": fit.object_comparison} if fit.object_comparison else {}),
        "order": fit.order,
        **({"order_comparison": fit.order_comparison} if fit.order_comparison else {}),
        **({"next_step": _next_step(fit.next_step)} if fit.next_step else {}),
        "cluster_sizes": sizes,
        "assignments": dict(zip(demos.keys, assignments.tolist())),
    }
    # Per-cluster transition counts, for the readable report's summary.
    counts = demos.transition_counts(per_sequence=True).cpu()  # (N, A, A)
    by_cluster = torch.zeros(fit.k, *counts.shape[1:], dtype=counts.dtype)
    by_cluster.index_add_(0, assignments, counts)  # (k, A, A)
    report["_cluster_counts"] = by_cluster
    if demos.types is not None:
        report.update(_against_types(demos.types, assignments, fit.k))
    if loo:
        from torchhrc.experiments.loo import leave_one_subject_out

        result = leave_one_subject_out(
            demos,
            k_min=k_min,
            k_max=k_max,
            restarts=restarts,
            method=method,
            inference=inference,  # type: ignore[arg-type]
            seed=seed,
            **({} if min_gain is None else {"min_gain": min_gain}),
            **({} if min_consistency is None else {"min_consistency": min_consistency}),
            **({} if objects is None else {"objects": objects}),
        )
        report["loo"] = {
            "accuracy": result.accuracy,
            "inference": inference,
            "k_counts": {str(k): v for k, v in result.k_counts.items()},
            "predictions": result.predictions,
            "misclassified": [f.subject for f in result.folds if not f.correct],
        }
    return report


def sharded_cluster_report(
    corpus: Any,
    *,
    k_min: int = 2,
    k_max: int = 10,
    restarts: int = 20,
    method: str = "soft",
    criterion: str | None = None,
    seed: int = 0,
    save_model: str | None = None,
    ray: str | None = None,
    min_gain: float | None = None,
    objects: str | None = None,
    min_consistency: float | None = None,
) -> dict[str, Any]:
    """:func:`cluster_report` for a :class:`~torchhrc.mixture.sharded.ShardedCorpus` (same keys).

    ``fit_mixture`` reads the corpus shard by shard (each shard a Ray task with ``ray``, and
    the soft method's E-steps on Ray actors), with the same defaults as the same rows in
    memory, ``objects="auto"`` included: the report equals :func:`cluster_report`'s on the
    rows in shard order. ``--loo`` and ``--relabel-objects`` need the corpus in memory and
    are not offered here.
    """
    from torchhrc.mixture import fit_mixture

    _check_search(k_min, k_max, restarts)
    started = False
    if ray is not None:  # one cluster for every pass and E-step of the report
        from torchhrc._ray import import_ray, init_ray

        started = init_ray("local" if ray is True else str(ray))
    try:
        return _sharded_report(corpus, fit_mixture, k_min=k_min, k_max=k_max,
                               restarts=restarts, method=method, criterion=criterion,
                               seed=seed, save_model=save_model, ray=ray,
                               min_gain=min_gain, objects=objects,
                               min_consistency=min_consistency)  # fmt: skip
    finally:
        if started:
            import_ray().shutdown()


def _sharded_report(
    corpus: Any,
    fit_mixture: Any,
    *,
    k_min: int,
    k_max: int,
    restarts: int,
    method: str,
    criterion: str | None,
    seed: int,
    save_model: str | None,
    ray: str | None,
    min_gain: float | None,
    objects: str | None,
    min_consistency: float | None,
) -> dict[str, Any]:
    fit = fit_mixture(
        corpus,
        k_min=k_min,
        k_max=k_max,
        restarts=restarts,
        method=method,  # type: ignore[arg-type]
        criterion=criterion,  # type: ignore[arg-type]
        seed=seed,
        min_gain=min_gain,
        min_consistency=min_consistency,
        objects=objects,  # type: ignore[arg-type]
        ray=ray,
    )
    if save_model is not None:
        fit.model.save(save_model)
    # the recorded symbols' counts per cluster, for the readable report (one more pass)
    unit = "subject" if method == "soft" else "sequence"
    raw = corpus.statistics(unit=unit, ray=ray)
    stats = raw.stats
    assignments = fit.assignments.cpu()
    A = stats.num_symbols
    row_cluster = torch.zeros(stats.num_distinct, dtype=torch.long)
    row_cluster.scatter_(0, stats.inverse, assignments)
    weighted = stats.counts * stats.multiplicity[:, None]
    by_cluster = torch.zeros(fit.k, A * A, dtype=weighted.dtype)
    by_cluster.index_add_(0, row_cluster, weighted)
    keys = corpus.keys
    report: dict[str, Any] = {
        **_fit_scores(fit),
        "num_sequences": stats.num_sequences,
        "num_subjects": len(corpus.unique_subjects),
        "num_symbols": A,
        "symbols": [f"{a}:{b}" for a, b in raw.vocabulary],
        "num_shards": len(corpus.paths),
        "per_k": _per_k(fit),
        "objects": fit.objects,
        **({"object_comparison": fit.object_comparison} if fit.object_comparison else {}),
        "cluster_sizes": torch.bincount(assignments, minlength=fit.k).tolist(),
        "assignments": dict(zip(keys, assignments.tolist())),
        "_cluster_counts": by_cluster.view(fit.k, A, A),
    }
    types = corpus.types
    if types is not None:
        report.update(_against_types(types, assignments, fit.k))
    return report


def _is_sharded(paths: list[str]) -> bool:
    import glob
    import os

    return (
        len(paths) > 1
        or os.path.isdir(paths[0])
        or glob.has_magic(paths[0])
        or paths[0].lower().endswith((".parquet", ".pq"))
    )


def _print_table(report: dict[str, Any], path: str, out: Any) -> None:
    w = out.write
    w(
        f"{path}: {report['num_sequences']} sequences, {report['num_subjects']} subjects, "
        f"{report['num_symbols']} symbols; method {report['method']}, "
        f"criterion {report['criterion']}\n\n"
    )
    w(f"{'k':>4} {'BIC':>12} {'ICL':>12} {'log-likelihood':>15}\n")

    def fmt(v: float | None) -> str:
        return "-inf" if v is None else f"{v:.2f}"

    for k, scores in report["per_k"].items():
        mark = "  <- selected" if int(k) == report["k"] else ""
        w(
            f"{k:>4} {fmt(scores.get('bic')):>12} {fmt(scores.get('icl')):>12} "
            f"{fmt(scores.get('log_likelihood')):>15}{mark}\n"
        )
    w(f"\nselected k = {report['k']}, BIC {fmt(report['bic'])}\n")
    compared = report.get("object_comparison")
    if report.get("objects") == "exchangeable" or compared:
        w(f"objects: {report['objects']}")
        if compared:
            w(
                " (exact ICL on the recorded demonstrations, the larger kept: "
                + ", ".join(
                    f"{form} k = {int(c['k'])} {fmt(c['exact_icl'])}"
                    for form, c in compared.items()
                )
                + f"; compared on {int(compared['raw']['units'])} units)"
            )
        w("\n")
    w("\n")
    symbols = report["symbols"]
    counts = report["_cluster_counts"]
    for c, size in enumerate(report["cluster_sizes"]):
        total = counts[c].sum(-1, keepdim=True).clamp_min(1)
        prob = counts[c] / total
        flat = counts[c].flatten()
        top = torch.argsort(flat, descending=True, stable=True)[:4].tolist()
        a = len(symbols)
        parts = [
            f"{symbols[i // a]} -> {symbols[i % a]} ({prob[i // a, i % a]:.2f})"
            for i in top
            if flat[i] > 0
        ]
        w(f"cluster {c}: {size} sequences; most frequent transitions: {', '.join(parts)}\n")
    if "adjusted_rand_index" in report:
        w(
            f"\nagainst the type column: adjusted Rand index {report['adjusted_rand_index']:.3f},"
            f" matched accuracy {report['matched_accuracy']:.3f}\n"
        )
        k = report["k"]
        width = max(len(t) for t in report["type_by_cluster"])
        w(f"{'type':<{width}} " + " ".join(f"{c:>5}" for c in range(k)) + "\n")
        for label, row in report["type_by_cluster"].items():
            w(f"{label:<{width}} " + " ".join(f"{v:>5}" for v in row) + "\n")
    if "loo" in report:
        loo = report["loo"]
        wrong = loo["misclassified"]
        w(
            f"\nleave-one-subject-out accuracy ({loo['inference']}): {loo['accuracy']:.3f}"
            f"; k per fold {loo['k_counts']}"
            + (f"; misclassified {', '.join(wrong)}" if wrong else "")
            + "\n"
        )
    w("\nassignments (subject: cluster of each sequence)\n")
    per_subject: dict[str, list[str]] = {}
    for key, c in report["assignments"].items():
        per_subject.setdefault(key.rsplit("/", 1)[0], []).append(str(c))
    for subject, cs in per_subject.items():
        w(f"  {subject}: {' '.join(cs)}\n")


def run(args: argparse.Namespace) -> int:
    """Cluster ``args.demos`` and print the report; return the exit status."""
    paths = list(args.demos)
    if _is_sharded(paths) or args.ray is not None:
        from torchhrc.mixture.sharded import ShardedCorpus

        for flag, value in (
            ("--loo", args.loo),
            ("--relabel-objects", args.relabel_objects),
            (f"--order {args.order}", args.order != "1"),
        ):
            if value:
                raise ModelError(f"{flag} needs one demonstrations file, not a sharded corpus")
        if args.ray is not None:
            from torchhrc._ray import check_reachable, import_ray

            import_ray()
            if args.ray != "local":
                check_reachable(args.ray)
        corpus = ShardedCorpus.open(paths)
        report = sharded_cluster_report(
            corpus, k_min=args.k_min, k_max=args.k_max, restarts=args.restarts,
            method=args.method, criterion=args.criterion, seed=args.seed,
            save_model=args.save_model, ray=args.ray, min_gain=args.min_gain,
            objects=args.objects, min_consistency=args.min_consistency,
        )  # fmt: skip
        _emit(report, " ".join(paths), args.json)
        return 0
    demos = read_demonstrations(paths[0])
    report = cluster_report(
        demos,
        k_min=args.k_min,
        k_max=args.k_max,
        restarts=args.restarts,
        method=args.method,
        criterion=args.criterion,
        seed=args.seed,
        loo=args.loo,
        inference=args.inference,
        save_model=args.save_model,
        relabel_objects=args.relabel_objects,
        min_gain=args.min_gain,
        objects=args.objects,
        min_consistency=args.min_consistency,
        order=args.order if args.order == "auto" else int(args.order),
    )
    _emit(report, paths[0], args.json)
    return 0


def _emit(report: dict[str, Any], source: str, as_json: bool) -> None:
    if as_json:
        public = {k: v for k, v in report.items() if not k.startswith("_")}
        json.dump(public, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        _print_table(report, source, sys.stdout)
