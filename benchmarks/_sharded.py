"""``bench_mixture.py --shards S``: corpus-scale clustering on Parquet shards and Ray.

Writes ``--total`` sequences (``--data study``: place-and-drill demonstrations as in issue 12,
2 types, noise 0.1, random placement orders; ``--data chains``: the random mixture of Markov
chains of the in-memory benchmark, almost every sequence distinct), generated shard by shard,
never all in memory, into ``S`` Parquet shards, then
times ``fit_mixture(ShardedCorpus.open(dir), ray=True)`` on a local Ray cluster against the
in-memory fit of ``--n`` sequences. Reports wall time, the driver's peak resident memory, a
worker's peak resident memory (a Ray task that reduces one shard, as the fit's tasks do),
the number of distinct rows the driver holds, and the extrapolation to more nodes.
"""

from __future__ import annotations

import os
import resource
import tempfile
import time
from pathlib import Path
from typing import Any

import torch


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _shard_worker_peak(path: str) -> tuple[float, float]:
    """Reduce one shard in this (worker) process: ``(seconds, peak RSS MiB)``."""
    from torchhrc.mixture.sharded import shard_statistics

    t0 = time.perf_counter()
    shard_statistics(path, by_subject=True, initial=False)
    return time.perf_counter() - t0, _peak_mib()


def write_shards(args: Any, make_data: Any, study_corpus: Any, folder: Path) -> float:
    """Write the shards; return the seconds it took."""
    from torchhrc.data import Demonstrations
    from torchhrc.io.parquet import write_parquet

    per = args.total // args.shards
    t0 = time.perf_counter()
    vocab = tuple(("human" if a % 2 == 0 else "robot", f"a{a}") for a in range(args.symbols))
    vocab_sorted = tuple(sorted(vocab))
    remap = torch.tensor([vocab_sorted.index(v) for v in vocab])
    for i in range(args.shards):
        if args.data == "study":
            demos = study_data(study_corpus, per, args.seed + 1000 + i, prefix=f"p{i}_")
        else:
            seqs, lengths = make_data(per, args.length, args.symbols, 3, args.concentration,
                                      args.seed + 1000 + i)  # fmt: skip
            ids = [f"s{i}_{j}" for j in range(per)]
            demos = Demonstrations(vocabulary=vocab_sorted, sequences=remap[seqs],
                                   lengths=lengths, subjects=ids,
                                   sequence_ids=("0",) * per)  # fmt: skip
        write_parquet(demos, folder / f"part{i:03d}.parquet")
        del demos
    return time.perf_counter() - t0


def study_data(study_corpus: Any, n: int, seed: int, prefix: str = "") -> Any:
    """``n`` demonstrations of the issue-12 corpus (``bench_mixture.study_corpus``: 2 types,
    3 positions, noise 0.1, a fresh random placement order in every demonstration); subject
    ids start with ``prefix`` (distinct across shards: a subject is one clustering unit)."""
    import dataclasses

    demos = study_corpus(n + 2, 2, seed).subset(torch.arange(n))
    if prefix:
        demos = dataclasses.replace(demos, subjects=tuple(prefix + s for s in demos.subjects))
    return demos


def run(args: Any, make_data: Any, study_corpus: Any) -> None:
    """The sharded benchmark; ``make_data`` and ``study_corpus`` are bench_mixture's
    generators (passed in, so that this module imports no benchmark)."""
    import ray

    from torchhrc.mixture import fit_mixture
    from torchhrc.mixture.sharded import ShardedCorpus

    folder = Path(args.shard_dir or tempfile.mkdtemp(prefix="torchhrc_shards_"))
    folder.mkdir(parents=True, exist_ok=True)
    if not any(folder.glob("*.parquet")):
        seconds = write_shards(args, make_data, study_corpus, folder)
        size = sum(p.stat().st_size for p in folder.glob("*.parquet")) / 2**20
        print(f"wrote {args.total} sequences in {args.shards} Parquet shards ({size:.0f} MiB) "
              f"in {seconds:.1f} s: {folder}")  # fmt: skip
    corpus = ShardedCorpus.open(folder)
    # fit_mixture's defaults (one type per subject, min_gain), in float32
    unit = "subject" if args.data == "study" else "sequence"
    options = dict(k_min=2, k_max=10, restarts=args.restarts, dtype=torch.float32,
                   seed=args.seed, unit=unit)  # fmt: skip
    ray.init(num_cpus=args.ray_cpus, include_dashboard=False, log_to_driver=False)
    try:
        worker = ray.remote(num_cpus=1)(_shard_worker_peak)
        w_seconds, w_peak = ray.get(worker.remote(corpus.paths[0]))
        t0 = time.perf_counter()
        merged = corpus.statistics(unit=unit, ray=True, dtype=torch.float32)
        t_stats = time.perf_counter() - t0
        # the corpus itself, not the merged statistics: objects="auto" relabels its shards
        t0, c0 = time.perf_counter(), time.process_time()
        fit = fit_mixture(corpus, ray=True, **options)
        t_total, c_total = time.perf_counter() - t0, time.process_time() - c0
    finally:
        ray.shutdown()
    driver_peak = _peak_mib()
    print(
        f"sharded on Ray ({args.ray_cpus} CPUs): one pass of shard tasks + merge "
        f"{t_stats:.1f} s; the fit {t_total:.1f} s wall (its passes over the shards, E-steps on "
        f"Ray actors, M-steps on the driver), driver CPU {c_total:.1f} s; k = {fit.k}; "
        f"{merged.stats.num_distinct} distinct rows on the driver"
    )
    print(f"peak RSS: driver {driver_peak:.0f} MiB, a worker reducing one shard "
          f"{w_peak:.0f} MiB ({w_seconds:.1f} s per shard)")  # fmt: skip
    if args.data == "study":
        data: Any = study_data(study_corpus, args.n, args.seed)
    else:
        data = (*make_data(args.n, args.length, args.symbols, 3, args.concentration, args.seed),
                args.symbols)  # fmt: skip
    t0 = time.perf_counter()
    mem = fit_mixture(data, **options)
    t_mem = time.perf_counter() - t0
    print(f"in memory, {args.n} sequences: {t_mem:.1f} s wall; k = {mem.k}, "
          f"{mem.num_distinct} distinct rows")  # fmt: skip
    per_shard = w_seconds
    print(
        f"scaling: shard reduction is {per_shard:.1f} s per shard per CPU; with C CPUs across "
        f"nodes the reduction takes about ceil({args.shards}/C) x {per_shard:.1f} s; the EM "
        f"grows with distinct rows, not sequences"
    )
    if not args.shard_dir:
        for p in folder.glob("*.parquet"):
            os.unlink(p)
        folder.rmdir()
