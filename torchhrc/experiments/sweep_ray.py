"""Run sweep jobs as Ray tasks: a local Ray cluster or an existing one (the ``[ray]`` extra).

Each (cell, seed) of a :class:`~torchhrc.experiments.sweep.SweepSpec` is one Ray task
(:func:`~torchhrc.experiments.sweep.run_job`, one CPU); the driver collects results with
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

import os
import socket
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from torchhrc.errors import ModelError
from torchhrc.experiments.sweep import Job, SweepSpec, run_job

__all__ = ["RayExecutor", "check_reachable", "import_ray", "init_ray"]


def import_ray() -> Any:
    """Import ray, or raise :class:`ModelError` naming the extra to install."""
    try:
        import ray
    except ImportError:
        raise ModelError(
            "Ray is not installed: pip install 'torchhrc[ray]' (or run without --ray)"
        ) from None
    return ray


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Raise :class:`ModelError` unless ``HOST:PORT`` (or ``ray://HOST:PORT``) accepts a TCP
    connection within ``timeout`` seconds: an unreachable cluster fails fast, in one line.

    Example:
        >>> check_reachable("no-port")
        Traceback (most recent call last):
        ...
        torchhrc.errors.ModelError: expected a Ray address HOST:PORT (or 'local'), got 'no-port'
    """
    target = address.split("://", 1)[-1]
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit():
        raise ModelError(f"expected a Ray address HOST:PORT (or 'local'), got {address!r}")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            pass
    except OSError as error:
        raise ModelError(f"cannot reach the Ray cluster at {address}: {error}") from None


def init_ray(address: str = "local", *, num_cpus: int | None = None) -> bool:
    """Connect to Ray: ``"local"`` starts a local cluster, ``HOST:PORT`` joins one.

    Returns ``True`` when this call started the connection (the caller shuts it down), and
    ``False`` when Ray was already initialised in this process.

    Raises:
        ModelError: Ray is missing, or the address is malformed or unreachable.
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    if address == "local":
        ray.init(
            num_cpus=num_cpus or os.cpu_count() or 1,
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
        )
    else:
        check_reachable(address)
        ray.init(address=address, log_to_driver=False, configure_logging=False)
    return True


@dataclass(frozen=True)
class RayExecutor:
    """Runs sweep jobs as Ray tasks (see the module docstring).

    Attributes:
        address: ``"local"`` (a local cluster with ``num_cpus``) or ``HOST:PORT`` of a running
            cluster (``ray start --head`` prints it).
        num_cpus: CPUs of a local cluster (default: all cores).
        max_retries: Ray's retries of a task that raised or whose worker died.
    """

    address: str = "local"
    num_cpus: int | None = None
    max_retries: int = 2

    def run(self, spec: SweepSpec, jobs: Sequence[Job]) -> Iterator[tuple[Job, Any]]:
        ray = import_ray()
        started = init_ray(self.address, num_cpus=self.num_cpus)
        try:
            remote = ray.remote(num_cpus=1, max_retries=self.max_retries,
                                retry_exceptions=True)(run_job)  # fmt: skip
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
                        cause = getattr(error, "cause", None)
                        result = cause if isinstance(cause, Exception) else error
                    yield job, result
        finally:
            if started:
                ray.shutdown()
