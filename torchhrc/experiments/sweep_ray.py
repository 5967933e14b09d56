"""Run sweep jobs as Ray tasks: a local Ray cluster or an existing one (the ``[ray]`` extra).

Each (cell, seed) of a :class:`~torchhrc.experiments.sweep_tasks.SweepSpec` is one Ray task
(:func:`~torchhrc.experiments.sweep_tasks.run_job`, one CPU); the driver collects results with
``ray.wait`` as they finish, so rows stream into the sweep's files in completion order. A
task whose worker dies or that raises is retried by Ray (``max_retries``,
``retry_exceptions``); one that still fails is reported, not fatal, and ``--resume`` runs it
again.

Example:
    >>> executor = RayExecutor(address="local", num_cpus=2)
    >>> executor.address, executor.max_retries
    ('local', 2)
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from torchhrc._ray import import_ray, init_ray, task_error
from torchhrc.errors import ModelError
from torchhrc.experiments.sweep_grid import Job
from torchhrc.experiments.sweep_tasks import SweepSpec, run_job

__all__ = ["RayExecutor"]


@dataclass(frozen=True)
class RayExecutor:
    """Runs sweep jobs as Ray tasks (see the module docstring).

    Attributes:
        address: ``"local"`` (a local cluster with ``num_cpus``) or ``HOST:PORT`` of a running
            cluster (``ray start --head`` prints it).
        num_cpus: CPUs of a local cluster (default: all cores).
        max_retries: Ray's retries of a task that raised or whose worker died.
        function: what a Ray task runs per job, ``function(task, params, seed, quick)``
            (:func:`~torchhrc.experiments.sweep_tasks.run_job` by default; module-level, so that
            Ray workers import it by name).
    """

    address: str = "local"
    num_cpus: int | None = None
    max_retries: int = 2
    function: Callable[[str, tuple[tuple[str, Any], ...], int, bool], dict] = run_job

    def __post_init__(self) -> None:
        if self.num_cpus is not None and self.address != "local":
            raise ModelError(
                f"num_cpus (--workers) sets the CPUs of a local Ray cluster; the cluster at "
                f"{self.address} has its own: leave it out"
            )

    def run(self, spec: SweepSpec, jobs: Sequence[Job]) -> Iterator[tuple[Job, Any]]:
        ray = import_ray()
        started = init_ray(self.address, num_cpus=self.num_cpus)
        try:
            remote = ray.remote(num_cpus=1, max_retries=self.max_retries,
                                retry_exceptions=True)(self.function)  # fmt: skip
            pending = {
                remote.remote(spec.task, job.params, job.seed, spec.quick): job for job in jobs
            }
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    job = pending.pop(ref)
                    try:
                        result: Any = ray.get(ref)
                    except Exception as error:  # failed after Ray's retries
                        result = task_error(error)
                    yield job, result
        finally:
            if started:
                ray.shutdown()
