"""The soft-EM E-step on a Ray cluster: the distinct rows split among actors (the ``[ray]``
extra).

:func:`~torchhrc.mixture.fit_mixture` with ``ray=`` builds a :class:`RayEStep` over the
merged statistics (of data in memory or of a :class:`~torchhrc.mixture.sharded.ShardedCorpus`)
and passes it to :func:`~torchhrc.mixture.soft_em.soft_em` as its ``e_step``: every E-step
runs on the actors, every M-step on the driver.
"""

from __future__ import annotations

import itertools
import os
from typing import Any

import torch

from torchhrc.mixture.counts import SufficientStatistics
from torchhrc.mixture.soft_em import _Data, _pass, sum_statistics

__all__ = ["RayEStep"]


class _ChunkPass:
    """A Ray actor's state: one chunk of the distinct rows, laid out for the E-step."""

    def __init__(self, stats: Any, dtype: torch.dtype) -> None:
        self.data = _Data(stats, dtype)
        self.passes = 0

    def run(self, lt: torch.Tensor, lw: torch.Tensor, li: torch.Tensor | None,
            mask: torch.Tensor, details: bool) -> Any:  # fmt: skip
        self.passes += 1
        return _pass(self.data, lt, lw, li, mask, details)

    def worker(self) -> tuple[int, int]:
        """``(process id, passes run)`` of this actor."""
        return os.getpid(), self.passes


class RayEStep:
    """Every soft-EM pass over the data computed on a Ray cluster, chunk by chunk.

    The distinct rows are split into ``chunks`` contiguous blocks, each held by one Ray actor
    (one CPU; the blocks are sent once). A pass sends the current parameters of every run to
    every actor, each computes the expected counts, sizes and log-likelihood of its block for
    all runs and all k at once (:func:`~torchhrc.mixture.soft_em.soft_pass`), and the driver
    adds them up (:func:`~torchhrc.mixture.soft_em.sum_statistics`): the E-step of every EM
    iteration runs on the cluster, the M-step on the driver. Sums over blocks equal the
    one-pass sums up to floating-point rounding.

    Args:
        stats: the merged :class:`~torchhrc.mixture.SufficientStatistics`.
        dtype: float dtype of the passes.
        ray: ``True``/``"local"`` or ``"HOST:PORT"`` (see :func:`torchhrc._ray.init_ray`).
        chunks: number of blocks (default: the cluster's CPUs).

    Example:
        >>> from torchhrc.mixture import ShardedCorpus, fit_mixture  # doctest: +SKIP
        >>> fit = fit_mixture(ShardedCorpus.open("shards/"), ray=True)  # doctest: +SKIP
        >>> fit.k  # E-steps ran on the Ray actors  # doctest: +SKIP
        2
    """

    def __init__(self, stats: Any, *, dtype: torch.dtype, ray: bool | str = True,
                 chunks: int | None = None) -> None:  # fmt: skip
        from torchhrc._ray import import_ray, init_ray

        self._ray = import_ray()
        self._started = init_ray("local" if ray is True else str(ray))
        cpus = int(self._ray.cluster_resources().get("CPU", 1))
        U = stats.num_distinct
        n = max(1, min(U, chunks or cpus))
        edges = [round(i * U / n) for i in range(n + 1)]
        actor = self._ray.remote(num_cpus=1)(_ChunkPass)
        self._actors = []
        for a, b in itertools.pairwise(edges):
            block = SufficientStatistics(
                counts=stats.counts[a:b],
                first_counts=None if stats.first_counts is None else stats.first_counts[a:b],
                multiplicity=stats.multiplicity[a:b],
                inverse=torch.empty(0, dtype=torch.long),  # rows only: no sequence map
                num_units=int(stats.multiplicity[a:b].sum().round()),
                num_symbols=stats.num_symbols,
            )
            self._actors.append(actor.remote(block, dtype))

    def __call__(self, lt: torch.Tensor, lw: torch.Tensor, li: torch.Tensor | None,
                 mask: torch.Tensor, details: bool) -> Any:  # fmt: skip
        """One pass over all rows, as SoftStatistics (the blocks' passes added up)."""
        refs = [a.run.remote(lt, lw, li, mask, details) for a in self._actors]
        return sum_statistics(self._ray.get(refs))

    def worker_passes(self) -> list[tuple[int, int]]:
        """``(process id, passes run)`` of every actor: where the E-steps ran."""
        return list(self._ray.get([a.worker.remote() for a in self._actors]))

    def close(self) -> None:
        """Release the actors (and the Ray connection when this object started it)."""
        for a in self._actors:
            self._ray.kill(a)
        self._actors = []
        if self._started:
            self._ray.shutdown()
