"""Where a sweep's jobs run: in this process (:class:`SerialExecutor`) or in local worker
processes (:class:`LocalExecutor`), with retries; Ray tasks are in :mod:`.sweep_ray`. Both
follow the :class:`Executor` protocol: ``run(spec, jobs, on_result)``.

Example:
    >>> SerialExecutor().retries
    0
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from torchhrc.experiments.sweep_grid import Job
from torchhrc.experiments.sweep_tasks import SweepSpec, run_job


class Executor(Protocol):
    """Runs jobs and yields ``(job, row or exception)`` as each finishes (any order)."""

    def run(self, spec: SweepSpec, jobs: Sequence[Job]) -> Iterator[tuple[Job, Any]]: ...


@dataclass(frozen=True)
class SerialExecutor:
    """Runs the jobs one after the other in this process (tests, debugging).

    Attributes:
        retries: extra tries of a job that raised.
    """

    retries: int = 0

    def run(self, spec: SweepSpec, jobs: Sequence[Job]) -> Iterator[tuple[Job, Any]]:
        for job in jobs:
            result: Any = None
            for _ in range(self.retries + 1):
                try:
                    result = run_job(spec.task, job.params, job.seed, spec.quick)
                    break
                except Exception as error:  # a job's failure is reported, not fatal
                    result = error
            yield job, result


def _stop_workers(pool: Any) -> None:
    """End a process pool's workers now, jobs in flight included (they are not recorded, so
    ``resume`` runs them again). Waiting for them instead made an interrupted sweep run on
    for as long as its longest job, and a second Ctrl-C during that wait left the driver
    joining an idle worker forever."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()


@dataclass(frozen=True)
class LocalExecutor:
    """Runs the jobs in local worker processes (``spawn``), one per core by default.

    At most ``workers`` jobs are in flight. A job that raises is retried up to ``retries``
    times. When a worker process dies the pool is restarted and the jobs that were in flight
    run again one at a time, so that a death is charged to the job that caused it (a try of
    its own) and never to a job that happened to run beside it; jobs that had finished are
    never run again. An interrupt (``KeyboardInterrupt``) ends the workers at once; the jobs
    that were in flight are not recorded.

    Attributes:
        workers: worker processes (``None``: ``os.cpu_count()``).
        retries: extra tries of a job that raised or whose worker died.
        function: what a worker runs per job, called as ``function(task, params, seed,
            quick)``; :func:`run_job` by default. It must be importable by name (a module-level
            function), since ``spawn`` workers import it.

    Example:
        >>> spec = SweepSpec.create("place-and-drill", ["subjects=2", "runs=2"], quick=True)
        >>> rows = dict(LocalExecutor(workers=1).run(spec, spec.jobs()))  # doctest: +SKIP
    """

    workers: int | None = None
    retries: int = 2
    function: Callable[[str, tuple[tuple[str, Any], ...], int, bool], dict] = run_job

    def run(self, spec: SweepSpec, jobs: Sequence[Job]) -> Iterator[tuple[Job, Any]]:
        import multiprocessing
        from collections import deque
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
        from concurrent.futures.process import BrokenProcessPool

        workers = self.workers or os.cpu_count() or 1
        context = multiprocessing.get_context("spawn")
        tries = dict.fromkeys(jobs, 0)
        todo = deque(jobs)
        suspects: deque[Job] = deque()  # in flight when a worker died: rerun one at a time
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
        running: dict[Any, Job] = {}

        def submit(job: Job) -> None:
            future = pool.submit(self.function, spec.task, job.params, job.seed, spec.quick)
            running[future] = job

        try:
            while todo or suspects or running:
                if suspects:  # a suspect runs alone, so a death is its own
                    if not running:
                        submit(suspects.popleft())
                else:
                    while todo and len(running) < workers:
                        submit(todo.popleft())
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                alone = len(running) == 1
                if any(isinstance(f.exception(), BrokenProcessPool) for f in done):
                    for future, job in list(running.items()):  # keep what finished first
                        if future.done() and future.exception() is None:
                            yield job, future.result()
                        elif alone:
                            tries[job] += 1
                            if tries[job] > self.retries:
                                yield job, future.exception()
                            else:
                                suspects.append(job)
                        else:
                            suspects.append(job)
                    running.clear()
                    pool.shutdown(wait=False, cancel_futures=True)
                    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
                    continue
                for future in done:
                    job = running.pop(future)
                    error = future.exception()
                    if error is None:
                        yield job, future.result()
                        continue
                    tries[job] += 1
                    if tries[job] > self.retries:
                        yield job, error
                    else:
                        todo.appendleft(job)
        except BaseException:  # an interrupt (Ctrl-C) or an abandoned sweep: stop at once
            _stop_workers(pool)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
