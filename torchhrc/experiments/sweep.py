"""Parameter sweeps of the reproductions, of a task with simulated people, or of a user's own
function: every grid cell x every seed, locally or on Ray.

A sweep runs one task for every cell of a grid (the product of the swept parameters' values)
and every seed. The task is a reproduction (``place-and-drill`` or ``hand-finishing``); a
task with simulated people (a :class:`~torchhrc.tasks.people.TaskWithPeople`: a suite task by
name, e.g. ``"fetch_order"``, or a user's factory, a function of no argument that builds it,
named ``"module:factory"`` or ``"path/to/file.py:factory"``), whose every job draws
demonstrations, learns and evaluates (:mod:`torchhrc.experiments.task_sweep`); or a user's
function, named the same way (or passed itself to :func:`sweep`):
``function(seed=..., **params)`` returns a mapping of metrics. A named callable that takes a
``seed`` is a function, one that takes no argument a task factory (:func:`task_kind`). All
kinds run through the same jobs, executors, files, resume and retries. Each (cell, seed) is
one independent job: it runs the study (or the function) in memory and returns one row (the
parameters, the seed, every scalar of the metrics flattened to ``a.b.0`` keys, and the job's
wall time). Jobs run on an :class:`Executor`: in this process
(``workers=1``), in local worker processes (one per core), or as Ray tasks
(:mod:`torchhrc.experiments.sweep_ray`).

Files in the output directory (nothing is lost when the driver dies)::

    sweep.json       the sweep's specification (task, grid, seeds, quick); --resume checks it
    results.jsonl    one JSON row per finished job, appended and fsynced as each finishes
    results.csv      the same rows as CSV, rewritten atomically after each job
    summary.md       mean and 95% CI over seeds of each metric per cell, at the end
    <metric>.png     a plot per metric: metric against each swept parameter

A job's result depends only on the task, the cell, the seed and ``quick``: each job runs with
one intra-op thread and a fresh generator from its seed, so results are the same whatever the
executor and the number of workers (the timing columns aside, see :data:`TIMING_COLUMNS`).

Example:
    >>> spec = SweepSpec.create("place-and-drill", ["noise=0,0.1"], seeds="0-1", quick=True)
    >>> [(dict(c.params)["noise"], c.seed) for c in spec.jobs()]
    [(0.0, 0), (0.0, 1), (0.1, 0), (0.1, 1)]
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from torchhrc.errors import ModelError
from torchhrc.experiments.sweep_executors import Executor, LocalExecutor, SerialExecutor
from torchhrc.experiments.sweep_grid import (
    PARAMETERS,
    TIMING_COLUMNS,
    Job,
    SweepParameter,
    _columns,
    flatten_scalars,
    is_timing_column,
    parse_seeds,
)
from torchhrc.experiments.sweep_summary import cell_statistics, write_summary
from torchhrc.experiments.sweep_tasks import (
    _RUNNERS,  # noqa: F401  (tests patch a runner here)
    SweepSpec,
    canonical_task,
    load_callable,
    load_world,
    run_job,
    task_kind,
    task_parameters,
)

__all__ = [
    "PARAMETERS",
    "TIMING_COLUMNS",
    "Executor",
    "Job",
    "LocalExecutor",
    "SerialExecutor",
    "SweepParameter",
    "SweepResult",
    "SweepSpec",
    "canonical_task",
    "cell_statistics",
    "flatten_scalars",
    "is_timing_column",
    "load_callable",
    "load_world",
    "parse_seeds",
    "run_job",
    "run_sweep",
    "sweep",
    "task_kind",
    "task_parameters",
    "write_summary",
]


# --- executors -----------------------------------------------------------------------------


# --- results files --------------------------------------------------------------------------


def _csv_text(rows: Sequence[Mapping[str, Any]], first: Sequence[str]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=_columns(rows, first), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(row)
    return buffer.getvalue()


def read_results(out_dir: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The finished rows of a sweep directory (a torn last line, from a crash, is skipped)."""
    path = Path(out_dir) / "results.jsonl"
    if not path.exists():
        return []
    rows = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line torn by a crash mid-write: its job runs again
        if isinstance(row, dict) and "_key" in row:
            rows.append(row)
    return rows


@dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` did.

    Attributes:
        out_dir: the sweep directory.
        rows: every finished row (earlier runs' included when resuming), in job order.
        skipped: jobs already finished by an earlier run (``resume``).
        failed: ``{job key: error message}`` of jobs that failed after their retries.
    """

    out_dir: Path
    rows: list[dict[str, Any]]
    skipped: int
    failed: dict[str, str]


def _prepare(out_dir: Path, spec: SweepSpec, resume: bool) -> None:
    spec_path = out_dir / "sweep.json"
    if out_dir.exists() and not out_dir.is_dir():
        raise ModelError(f"--out {out_dir} exists and is not a directory")
    if resume:
        if not spec_path.exists():
            raise ModelError(f"--resume: {out_dir} holds no sweep (no sweep.json)")
        earlier = json.loads(spec_path.read_text(encoding="utf-8"))
        if earlier != spec.to_json():
            raise ModelError(
                f"--resume: {spec_path} describes another sweep ({json.dumps(earlier)}); "
                "resume with the same task, --param, --seeds and --quick"
            )
        return
    if out_dir.exists() and any(out_dir.iterdir()):
        raise ModelError(f"--out {out_dir} is not empty (use --resume to continue a sweep)")
    from torchhrc.experiments.report import write_json_atomic

    out_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(spec_path, spec.to_json())


def run_sweep(
    spec: SweepSpec,
    out_dir: str | os.PathLike[str],
    *,
    executor: Executor | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
    summary: bool = True,
) -> SweepResult:
    """Run every job of ``spec`` not yet finished in ``out_dir``; stream rows to its files.

    Args:
        spec: the sweep.
        out_dir: the sweep directory; must be empty or absent unless ``resume``.
        executor: where jobs run (default: :class:`LocalExecutor`, one process per core).
        resume: skip the jobs that ``results.jsonl`` already holds; ``sweep.json`` must
            describe the same sweep.
        progress: ``progress(done, total)`` after each finished job.
        summary: write ``summary.md`` and the plots at the end.

    Returns:
        A :class:`SweepResult`.

    Raises:
        ModelError: a non-empty ``out_dir`` without ``resume``, or a resume of another sweep.

    Example:
        >>> import tempfile
        >>> spec = SweepSpec.create("place-and-drill", ["subjects=2"], seeds="0", quick=True)
        >>> out = tempfile.mkdtemp()
        >>> result = run_sweep(spec, out, executor=SerialExecutor(), summary=False)
        >>> len(result.rows), result.failed
        (1, {})
    """
    from torchhrc.experiments.report import write_text_atomic

    path = Path(out_dir)
    _prepare(path, spec, resume)
    jobs = spec.jobs()
    earlier: dict[str, dict[str, Any]] = {}
    if resume:
        earlier = {row["_key"]: row for row in read_results(path)}
        # drop a line torn by a crash before appending after it
        text = "".join(json.dumps(row) + "\n" for row in earlier.values())
        write_text_atomic(path / "results.jsonl", text)
    todo = [job for job in jobs if job.key not in earlier]
    rows_by_key = dict(earlier)
    first = [*spec.parameter_names, "seed"]
    failed: dict[str, str] = {}
    done = len(jobs) - len(todo)
    if progress is not None:
        progress(done, len(jobs))
    executor = executor or LocalExecutor()
    order = {job.key: i for i, job in enumerate(jobs)}

    def ordered() -> list[dict[str, Any]]:
        rows = sorted(rows_by_key.values(), key=lambda r: order.get(r["_key"], len(order)))
        return [{k: v for k, v in r.items() if k != "_key"} for r in rows]

    with open(path / "results.jsonl", "a", encoding="utf-8") as log:
        for job, result in executor.run(spec, todo):
            done += 1
            if isinstance(result, BaseException):
                failed[job.key] = f"{type(result).__name__}: {result}"
            else:
                row = {"_key": job.key, **result}
                log.write(json.dumps(row) + "\n")
                log.flush()
                os.fsync(log.fileno())
                rows_by_key[job.key] = row
                write_text_atomic(path / "results.csv", _csv_text(ordered(), first))
            if progress is not None:
                progress(done, len(jobs))
    rows = ordered()
    if rows:
        write_text_atomic(path / "results.csv", _csv_text(rows, first))
    if summary and rows and (todo or not (path / "summary.md").exists()):
        # (a resume with nothing left to run keeps the summary and plots it already has)
        write_summary(path, spec, rows, failed=failed)
    return SweepResult(out_dir=path, rows=rows, skipped=len(earlier), failed=failed)


def sweep(
    task: str | Callable[..., Any],
    params: Mapping[str, Sequence[Any]] | Sequence[str] | None = None,
    *,
    out: str | os.PathLike[str],
    seeds: str | Sequence[int] = "0",
    quick: bool = False,
    workers: int | None = None,
    ray: str | None = None,
    retries: int = 2,
    resume: bool = False,
    summary: bool = True,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SweepResult:
    """Sweep a task over a grid of parameters and seeds: a paper study, a task with simulated
    people, or a user's function.

    A task with simulated people is a suite task's name (``"fetch_order"``, see
    :mod:`torchhrc.tasks.suite`) or a factory: a module-level function of no argument that
    returns a :class:`~torchhrc.tasks.people.TaskWithPeople` (your own task, e.g. built by
    :func:`torchhrc.tasks.suite.builder.build`). Each job draws its demonstrations, learns the
    type-aware and the type-agnostic (``k = 1``) models and evaluates both against the
    people under their true rewards; its row holds the ``k`` found and the true one, the ARI
    against the true types, the human model used, each robot's mean return and 95% CI
    (overall and per type), the gain of the type-aware robot and the belief's accuracy after
    ``n`` steps (:func:`~torchhrc.experiments.task_sweep.task_metrics`). Its parameters are
    :data:`~torchhrc.experiments.task_sweep.TASK_PARAMETERS`: ``subjects``, ``per_subject``,
    ``noise``; ``learn()``'s ``k``, ``k_min``, ``k_max``, ``restarts``, ``criterion``,
    ``objects``, ``order``, ``mixture_method``, ``min_gain``, ``split_divided``,
    ``human_model``, ``prior``,
    ``irl_iterations``, ``irl_epsilon``, ``irl_l2``, ``irl_pooling``, ``irl_wrong_moves``,
    ``solver_time``, ``solver_iterations``; and ``episodes``.

    A function (one that takes a ``seed`` keyword argument) is called as
    ``task(seed=seed, **cell)`` and returns a mapping of metrics (numbers, nested mappings or
    lists of numbers: :func:`flatten_scalars`). A factory or a function must be module-level,
    given itself or as ``"module:function"`` / ``"path/file.py:function"``, since workers
    import it by name (a ``TaskWithPeople`` object cannot travel: pass its factory). Every
    job runs in a worker process (or a Ray task). The output directory gets the paper
    studies' files: ``results.csv`` streamed as jobs finish, ``summary.md`` with means and
    95% CIs over seeds, a plot per metric, and ``results.jsonl`` for ``resume``.

    Args:
        task: ``"place-and-drill"``, ``"hand-finishing"``, a suite task's name, a task
            factory, a function, or a factory's or function's name.
        params: ``name -> values`` (or ``"name=v1,v2"`` strings); the grid is the product.
            A task's values are checked against ``TASK_PARAMETERS``, a function's against
            its keyword arguments' types.
        out: the sweep directory (empty or absent unless ``resume``).
        seeds: ``"0-4"``-style text or a sequence of seeds.
        quick: the studies' quick versions (a task: 3 restarts, a 1 s solver limit, 50
            episodes per type where the cell does not set them; a function gets
            ``quick=True``).
        workers: worker processes, or Ray CPUs of a local cluster (default: the cores).
        ray: ``"local"`` or ``"HOST:PORT"``: run every job as a Ray task.
        retries: extra tries of a job that raised or whose worker died.
        resume: run only the jobs ``out`` does not hold yet.
        summary: write ``summary.md`` and the plots at the end.
        executor: where jobs run (overrides ``workers``, ``ray`` and ``retries``).
        progress: ``progress(done, total)`` after each finished job.

    Returns:
        :class:`SweepResult` (its ``failed`` names the jobs that failed after their retries).

    Raises:
        ModelError: an unknown task or parameter, a bad value, a non-empty ``out`` without
            ``resume``.
        TypeError: a ``TaskWithPeople`` object (pass its factory).

    Example:
        >>> import tempfile
        >>> result = sweep("tool_handover", {"noise": [0.0, 0.1], "subjects": [4]},
        ...                seeds=[0], quick=True, out=tempfile.mkdtemp(),
        ...                executor=SerialExecutor(), summary=False)
        >>> [(r["noise"], r["true_k"]) for r in result.rows], result.failed
        ([(0.0, 2), (0.1, 2)], {})
        >>> result = sweep("mypackage.study:run", {"noise": [0.0, 0.1]}, seeds="0-4",
        ...                out="runs/noise")  # doctest: +SKIP
    """
    _refuse_while_a_worker_imports_main()
    spec = SweepSpec.create(canonical_task(task), params or [], seeds=seeds, quick=quick)
    if executor is not None and (ray is not None or workers is not None):
        raise ModelError("pass either executor or ray/workers, not both (the executor decides)")
    if executor is None:
        if ray is not None:
            from torchhrc.experiments.sweep_ray import RayExecutor

            executor = RayExecutor(address=ray, num_cpus=workers, max_retries=retries)
        else:
            executor = LocalExecutor(workers=workers, retries=retries)
    return run_sweep(spec, out, executor=executor, resume=resume, progress=progress,
                     summary=summary)  # fmt: skip


def _refuse_while_a_worker_imports_main() -> None:
    """A ``spawn`` worker imports the script that started the sweep (as ``__mp_main__``): a
    ``sweep()`` at the script's top level would start again in every worker, each failing
    on the now non-empty ``out`` (the parent then sees only dead workers). The same test as
    multiprocessing's own ``_check_not_importing_main``."""
    import multiprocessing

    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise RuntimeError(
            "torchhrc.sweep() was called while a sweep worker process imported your script: "
            "put the call under 'if __name__ == \"__main__\":' (workers import the script "
            "to find your task or function; they must not start the sweep again)"
        )


# --- summary --------------------------------------------------------------------------------
