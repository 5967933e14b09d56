"""Speed of Select-Best-Model: torchhrc's batched EM against straightforward implementations.

Workload (issue 3): 100,000 sequences of length 12 over 8 symbols, k = 2..10, 20 restarts
per k (180 EM runs). Data: a mixture of 3 Markov chains whose transition rows are
Dirichlet(concentration) draws: ``--concentration 0.1`` gives peaked, demonstration-like
chains (many repeated sequences), ``1.0`` dense chains (almost every sequence distinct).

Compared in the same process, on the same data:

* ``torchhrc paper``: ``fit_mixture(method="paper")``, the paper's hard EM, all 180 runs as
  one batch (float32).
* ``torchhrc soft``: ``fit_mixture()`` (k-means++, em-EM, soft EM, float32).
* ``numpy per-run``: the paper's algorithm vectorised over sequences with numpy, one run at
  a time (a loop over k and restarts); measured on ``--numpy-restarts`` restarts per k and
  scaled to 20.
* ``numpy per-sequence``: the straightforward implementation the issue names, a Python
  loop over the sequences in both steps with numpy inside; measured on ``--loop-subset``
  sequences with 1 restart per k and scaled linearly to all sequences and 20 restarts (an
  extrapolation: iteration counts on the subset may differ).

pomegranate 1.x is not a peer here: its ``GeneralMixtureModel`` accepts only 2-D inputs and
its ``MarkovChain`` only 3-D ones, so it cannot fit a mixture of Markov chains.

Peak memory is the process's maximum resident set size (``ru_maxrss``), read right after
the torchhrc runs (the baselines run afterwards). Wall and process CPU times are printed:
on a shared, loaded machine the CPU time is what a free core would need.

Usage::

    python benchmarks/bench_mixture.py [--n 100000] [--concentration 0.1] [--threads 2]
    python benchmarks/bench_mixture.py --shards 16 --total 10000000 --n 1000000  # Ray, Parquet

Study mode (issue 12.1), ``--study 2`` or ``--study 3``: the place-and-drill corpus of
``docs/clustering.md`` (``--study 2``: "safe" and "efficient" at 3 positions; ``--study 3``:
plus "lagging", at 4 positions; 3 demonstrations per subject, a fresh random placement
order in every demonstration, every step replaced with probability 0.1 by a uniformly random
action of its actor) with ``--n`` sequences, clustered with ``fit_mixture``'s defaults
(float64, all 20 restarts of k = 2..10, objects detected: ``--objects raw`` for the recorded
symbols); prints the simulation and fit times (wall and CPU), k, the ARI against the true
types and which form of the objects was kept (with the two forms' scores)::

    python benchmarks/bench_mixture.py --study 2 --n 1000000 --threads 2

To compare two versions of the library on a shared machine, run this script alternately with
``PYTHONPATH`` set to each checkout (old, new, old, new, within minutes of each other) and
compare the process CPU times: ``docs/clustering.md`` ("Speed") lists the 1,000,000-sequence
figures measured that way (3 types: CPU ratio new/old 0.73 over five pairs, the same k and
ARI).
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from torchhrc.mixture import fit_mixture


def make_data(
    n: int, length: int, symbols: int, clusters: int, concentration: float, seed: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(n, length)`` int64 sequences from a random mixture of Markov chains, and lengths."""
    rng = np.random.default_rng(seed)
    theta = rng.dirichlet(np.full(symbols, concentration), size=(clusters, symbols))  # (C, A, A)
    z = rng.integers(0, clusters, n)
    seqs = np.empty((n, length), dtype=np.int64)
    seqs[:, 0] = rng.integers(0, symbols, n)
    cdf = np.cumsum(theta, -1)
    for j in range(1, length):
        u = rng.random(n)[:, None]
        rows = cdf[z, seqs[:, j - 1]]  # (n, A)
        seqs[:, j] = np.minimum((u > rows).sum(-1), symbols - 1)
    return torch.from_numpy(seqs), torch.full((n,), length, dtype=torch.long)


def numpy_paper_run(
    counts: np.ndarray, k: int, rng: np.random.Generator, floor: float = 1e-10
) -> tuple[float, int]:
    """One run of Cluster-Transition-Matrices, numpy-vectorised over sequences.

    ``counts``: ``(N, A, A)`` transition counts. Returns the classification log-likelihood
    and the number of iterations.
    """
    N, A, _ = counts.shape
    flat = counts.reshape(N, A * A)
    theta = rng.dirichlet(np.ones(A), size=(k, A))
    z = rng.integers(0, k, N)
    it = 0
    while it < 100:
        it += 1
        logt = np.log(np.maximum(theta, floor)).reshape(k, A * A)
        new = (flat @ logt.T).argmax(-1)
        n = (np.eye(k)[new].T @ flat).reshape(k, A, A)
        rows = n.sum(-1, keepdims=True)
        theta = np.where(rows > 0, n / np.maximum(rows, 1), theta)
        stable = np.array_equal(new, z)
        z = new
        if stable:
            break
    with np.errstate(divide="ignore"):
        logt = np.log(theta).reshape(k, A * A)
        ll = np.where(flat > 0, flat * np.where(np.isfinite(logt[z]), logt[z], 0.0), 0.0).sum()
    sizes = np.bincount(z, minlength=k)
    return float(ll + (sizes[sizes > 0] * np.log(sizes[sizes > 0] / N)).sum()), it


def per_sequence_paper_run(
    seqs: list[np.ndarray], A: int, k: int, rng: np.random.Generator, floor: float = 1e-10
) -> int:
    """The straightforward implementation of the paper's algorithm: a Python loop over the
    sequences in both steps, numpy inside (one sequence's score under all k chains; one
    sequence's transitions added to its cluster's counts)."""
    theta = rng.dirichlet(np.ones(A), size=(k, A))
    z = [int(v) for v in rng.integers(0, k, len(seqs))]
    it = 0
    while it < 100:
        it += 1
        logt = np.log(np.maximum(theta, floor))
        new = []
        for s in seqs:
            prev, nxt = s[:-1], s[1:]
            new.append(int(np.argmax(logt[:, prev, nxt].sum(-1))))
        n = np.zeros((k, A, A))
        for c, s in zip(new, seqs):
            np.add.at(n[c], (s[:-1], s[1:]), 1)
        rows = n.sum(-1, keepdims=True)
        theta = np.where(rows > 0, n / np.maximum(rows, 1), theta)
        if new == z:
            break
        z = new
    return it


def study_corpus(n_sequences: int, types: int, seed: int):
    """The issue-12 place-and-drill corpus with about ``n_sequences`` sequences (3 per subject)."""
    from torchhrc.tasks.place_and_drill import scaling_study

    return scaling_study(max(3, n_sequences), types, seed=seed)


def run_study(args: argparse.Namespace) -> None:
    """Time the default ``fit_mixture`` on the issue-12 corpus (see the module docstring)."""
    from torchhrc.metrics import adjusted_rand_index

    t0, c0 = time.perf_counter(), time.process_time()
    demos = study_corpus(args.n, args.study, args.seed)
    sim_wall, sim_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(
        f"study: {demos.num_sequences} sequences, {len(demos.unique_subjects)} subjects, "
        f"{args.study} types, {demos.num_symbols} symbols; simulated in {sim_wall:.2f} s wall, "
        f"{sim_cpu:.2f} s CPU; torch threads = {torch.get_num_threads()}"
    )
    soft = {} if args.objects is None else {"objects": args.objects}
    for name, kwargs in (("soft", soft), ("paper", {"method": "paper"})):
        if name == "paper" and args.skip_baselines:
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        fit = fit_mixture(demos, seed=args.seed, **kwargs)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        ari = adjusted_rand_index(list(demos.types), fit.assignments.tolist())
        print(
            f"torchhrc {name:5s}: {wall:7.2f} s wall, {cpu:7.2f} s CPU  (k = {fit.k}, "
            f"ARI = {ari:.3f}, {fit.num_distinct} distinct units, objects {fit.objects})"
        )
        for form, c in (fit.object_comparison or {}).items():
            print(
                f"  {form:12s}: k = {int(c['k'])}, exact ICL {c['exact_icl']:.1f}, BIC "
                f"{c['bic']:.1f} (compared on {int(c['units'])} units)"
            )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory: {peak_mb:.0f} MiB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--length", type=int, default=12)
    parser.add_argument("--symbols", type=int, default=8)
    parser.add_argument("--concentration", type=float, default=0.1)
    parser.add_argument("--restarts", type=int, default=20)
    parser.add_argument("--numpy-restarts", type=int, default=2)
    parser.add_argument("--loop-subset", type=int, default=500)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-baselines", action="store_true", help="time torchhrc only")
    parser.add_argument("--shards", type=int, default=0,
                        help="corpus-scale run: --total sequences in this many Parquet shards "
                        "on a local Ray cluster, against the in-memory fit of --n")  # fmt: skip
    parser.add_argument("--total", type=int, default=10_000_000)
    parser.add_argument(
        "--objects",
        choices=("auto", "raw", "exchangeable"),
        default=None,
        help="study mode: fit_mixture's objects (default: its default, auto)",
    )
    parser.add_argument("--ray-cpus", type=int, default=2)
    parser.add_argument("--shard-dir", default=None, help="keep/reuse the shards here")
    parser.add_argument(
        "--data",
        choices=("study", "chains"),
        default="study",
        help="--shards data: place-and-drill demonstrations or random chains",
    )
    parser.add_argument(
        "--study",
        type=int,
        choices=(2, 3),
        default=None,
        help="time the default clustering on the issue-12 place-and-drill corpus with 2 or 3 "
        "types instead (--skip-baselines: without the paper's method)",
    )
    args = parser.parse_args()
    if args.shards:
        import _sharded

        _sharded.run(args, make_data, study_corpus)
        return
    if args.threads:  # the same number of threads for torch and numpy's BLAS
        torch.set_num_threads(args.threads)
        threadpool_limits(args.threads)
    if args.study is not None:
        run_study(args)
        return
    seqs, lengths = make_data(args.n, args.length, args.symbols, 3, args.concentration, args.seed)
    A, ks = args.symbols, range(2, 11)
    runs = len(ks) * args.restarts
    print(
        f"data: {args.n} sequences x {args.length} steps, {A} symbols, Dirichlet "
        f"{args.concentration} chains; k = 2..10, {args.restarts} restarts ({runs} runs); "
        f"torch threads = {torch.get_num_threads()}"
    )

    timings, cpu = {}, {}
    for name, kwargs in (("paper", {"method": "paper"}), ("soft", {})):
        t0, c0 = time.perf_counter(), time.process_time()
        fit = fit_mixture(
            (seqs, lengths, A),
            k_min=2,
            k_max=10,
            restarts=args.restarts,
            dtype=torch.float32,
            seed=args.seed,
            unit="sequence",
            **kwargs,
        )
        timings[name] = time.perf_counter() - t0
        cpu[name] = time.process_time() - c0
        print(
            f"torchhrc {name:5s}: {timings[name]:7.2f} s wall, {cpu[name]:7.2f} s CPU  "
            f"(k = {fit.k}, "
            f"{fit.num_distinct} distinct sequences, {fit.iterations} iterations)"
        )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory after the torchhrc runs: {peak_mb:.0f} MiB")
    if args.skip_baselines:
        return

    counts = np.zeros((args.n, A, A))
    s = seqs.numpy()
    np.add.at(counts, (np.arange(args.n)[:, None], s[:, :-1], s[:, 1:]), 1)
    rng = np.random.default_rng(args.seed)
    t0, c0 = time.perf_counter(), time.process_time()
    for k in ks:
        for _ in range(args.numpy_restarts):
            numpy_paper_run(counts, k, rng)
    measured = time.perf_counter() - t0
    scale = args.restarts / args.numpy_restarts
    numpy_total, numpy_cpu = measured * scale, (time.process_time() - c0) * scale
    print(
        f"numpy per-run : {numpy_total:7.2f} s wall, {numpy_cpu:7.2f} s CPU  "
        f"(measured {measured:.2f} s on "
        f"{args.numpy_restarts} restarts per k, scaled to {args.restarts})"
    )

    subset = list(s[: args.loop_subset])  # one numpy array per sequence
    t0, c0 = time.perf_counter(), time.process_time()
    for k in ks:
        per_sequence_paper_run(subset, A, k, rng)
    measured = time.perf_counter() - t0
    scale = (args.n / args.loop_subset) * args.restarts
    loop_total, loop_cpu = measured * scale, (time.process_time() - c0) * scale
    print(
        f"numpy per-seq : {loop_total:7.0f} s wall, {loop_cpu:7.0f} s CPU  "
        f"(measured {measured:.2f} s on "
        f"{args.loop_subset} sequences x 1 restart per k, extrapolated)"
    )
    for name, t in timings.items():
        print(
            f"speed-up of torchhrc {name} (wall | CPU): {numpy_total / t:6.1f}x | "
            f"{numpy_cpu / cpu[name]:6.1f}x vs numpy per-run, {loop_total / t:7.0f}x | "
            f"{loop_cpu / cpu[name]:7.0f}x vs numpy per-sequence"
        )


if __name__ == "__main__":
    main()
