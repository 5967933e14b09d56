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
import dataclasses
import io
import itertools
import json
import math
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from torchhrc.errors import ModelError

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
    "flatten_scalars",
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


@dataclass(frozen=True)
class SweepParameter:
    """A parameter a sweep may vary.

    Attributes:
        kind: ``int`` or ``float``: the type its values are parsed as.
        low, high: inclusive range of valid values (``None``: unbounded).
        help: what it sets in the study.
        choices: the values a ``str`` parameter may take (``None``: any).
    """

    kind: type
    low: float | None
    high: float | None
    help: str
    choices: tuple[str, ...] | None = None

    def parse(self, name: str, text: Any) -> Value:
        """Parse one value (a string, or a Python value given to :func:`sweep`); raise
        :class:`ModelError` naming ``name`` when it is invalid."""
        value: Value
        try:
            if self.kind is bool:
                value = _parse_bool(text)
            elif self.kind is int and not isinstance(text, str):
                if isinstance(text, bool) or float(text) != int(text):
                    raise ValueError
                value = int(text)
            elif self.kind is str:
                if not isinstance(text, str):
                    raise ValueError
                value = text
            else:
                if isinstance(text, bool):
                    raise ValueError
                value = self.kind(text)
        except (TypeError, ValueError):
            raise ModelError(
                f"expected --param {name} values of type {self.kind.__name__}, got {text!r}"
            ) from None
        if self.choices is not None and value not in self.choices:
            raise ModelError(
                f"expected --param {name} values in {{{', '.join(self.choices)}}}, got {value!r}"
            )
        if isinstance(value, float) and not math.isfinite(value):
            raise ModelError(f"expected a finite --param {name} value, got {text!r}")
        if (self.low is not None and value < self.low) or (
            self.high is not None and value > self.high
        ):
            raise ModelError(
                f"expected --param {name} values in [{self.low}, {self.high}], got {value}"
            )
        return value


#: A swept value: parsed by the parameter's kind.
Value = int | float | str | bool


def _parse_bool(text: Any) -> bool:
    if isinstance(text, bool):
        return text
    word = str(text).strip().lower()
    if word in ("true", "1", "yes"):
        return True
    if word in ("false", "0", "no"):
        return False
    raise ValueError(text)


def _infer(text: Any) -> Value:
    """A value of a parameter without a declared type: int, then float, else the string."""
    if not isinstance(text, str):
        return text
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


#: Task -> parameter name -> :class:`SweepParameter`: the names ``--param`` accepts.
PARAMETERS: dict[str, dict[str, SweepParameter]] = {
    "place-and-drill": {
        "subjects": SweepParameter(int, 2, None, "simulated subjects (half per type)"),
        "noise": SweepParameter(
            float, 0.0, 1.0, "demonstration noise: per-step deviation rate of every subject"
        ),
        "runs": SweepParameter(int, 1, None, "simulated executions per subject and epsilon"),
        "demos": SweepParameter(int, 1, None, "demonstrations per subject"),
    },
    "hand-finishing": {
        "noise": SweepParameter(float, 0.001, 2.0, "hand-position noise (m, per axis)"),
        "subjects": SweepParameter(int, 2, None, "demonstrating subjects (half per side)"),
        "episodes": SweepParameter(int, 2, None, "closed-loop episodes (half per type)"),
    },
}

#: Columns that measure time: they differ between runs of the same job.
TIMING_COLUMNS: tuple[str, ...] = ("wall_s",)
_TIMING_MARKERS = ("time", "speedup", "seconds", "wall")


def is_timing_column(name: str) -> bool:
    """True for a column that measures time (excluded when comparing results)."""
    return name in TIMING_COLUMNS or any(m in name for m in _TIMING_MARKERS)


def parse_seeds(text: str) -> tuple[int, ...]:
    """Parse ``"0-4"``, ``"3"`` or ``"0,2,5"`` (ranges and lists mixed) into sorted seeds.

    Example:
        >>> parse_seeds("0-2,5")
        (0, 1, 2, 5)
    """
    seeds: set[int] = set()
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part[1:]:
                lo, hi = part.split("-", 1) if not part.startswith("-") else (part, "")
                a, b = int(lo), int(hi)
                if b < a:
                    raise ValueError
                seeds.update(range(a, b + 1))
            else:
                seeds.add(int(part))
        except ValueError:
            raise ModelError(
                f"expected --seeds as 'A-B' or 'A,B,...' of non-negative integers, got {text!r}"
            ) from None
    if not seeds or min(seeds) < 0:
        raise ModelError(f"expected non-negative --seeds, got {text!r}")
    return tuple(sorted(seeds))


@dataclass(frozen=True)
class Job:
    """One grid cell and one seed.

    Attributes:
        params: ``((name, value), ...)`` in the sweep's parameter order.
        seed: the seed of the job's study.
    """

    params: tuple[tuple[str, Value], ...]
    seed: int

    @property
    def key(self) -> str:
        """A stable identifier, e.g. ``"noise=0.1,subjects=6|seed=2"``."""
        cell = ",".join(f"{k}={v!r}" for k, v in self.params)
        return f"{cell}|seed={self.seed}"


@dataclass(frozen=True)
class SweepSpec:
    """What a sweep runs: task, grid and seeds (see :meth:`create`).

    Attributes:
        task: ``"place-and-drill"``, ``"hand-finishing"``, or a user's function as
            ``"module:function"`` or ``"/absolute/path/file.py:function"``.
        grid: ``((name, (v1, v2, ...)), ...)``, each name once.
        seeds: the seeds of every cell.
        quick: run each job's ``--quick`` version of the study (a function gets
            ``quick=True`` when it takes a ``quick`` argument).
    """

    task: str
    grid: tuple[tuple[str, tuple[Value, ...]], ...]
    seeds: tuple[int, ...]
    quick: bool = False

    @classmethod
    def create(
        cls,
        task: str,
        params: Sequence[str] | Mapping[str, Sequence[Any]],
        *,
        seeds: str | Sequence[int] = "0",
        quick: bool = False,
    ) -> SweepSpec:
        """Parse ``--param NAME=V1,V2`` strings; raise :class:`ModelError` on bad input.

        Args:
            task: a key of :data:`PARAMETERS`, or ``"module:function"`` /
                ``"path/file.py:function"`` (a relative path is made absolute).
            params: ``"NAME=V1,V2,..."`` strings, or a mapping ``name -> values`` (no
                parameter: one cell, the defaults). A function's parameters are its keyword
                arguments (typed by annotation or default; any name if it takes
                ``**kwargs``).
            seeds: ``"0-4"``-style text or a sequence of seeds.
            quick: run the quick version of each study.
        """
        task = canonical_task(task)
        known = task_parameters(task)
        items: list[tuple[str, list[Any], str]] = []
        if isinstance(params, Mapping):
            for name, values in params.items():
                values = [values] if isinstance(values, (str, int, float)) else list(values)
                items.append((str(name), values, repr(values)))
        else:
            for text in params:
                name, sep, values = str(text).partition("=")
                if not sep or not values.strip():
                    raise ModelError(f"expected --param NAME=V1,V2,..., got {text!r}")
                items.append((name.strip(), [v.strip() for v in values.split(",")], values))
        grid: list[tuple[str, tuple[Value, ...]]] = []
        for name, values, text in items:
            if name not in known and _ANY not in known:
                raise ModelError(
                    f"task {task} has no sweep parameter {name!r} "
                    f"(parameters: {', '.join(sorted(known)) or 'none'})"
                )
            if any(name == g for g, _ in grid):
                raise ModelError(f"--param {name} given twice")
            if not values:
                raise ModelError(f"expected --param {name} to have at least one value")
            parameter = known.get(name)
            parsed = tuple(
                _infer(v) if parameter is None else parameter.parse(name, v) for v in values
            )
            if len(set(parsed)) != len(parsed):
                raise ModelError(f"--param {name} repeats a value: {text!r}")
            grid.append((name, parsed))
        if task_kind(task) == "task":  # a task's settings are also checked together
            from torchhrc.experiments.task_sweep import check_cell

            names = [name for name, _ in grid]
            for cell in itertools.product(*(values for _, values in grid)):
                check_cell(dict(zip(names, cell, strict=True)))
        seed_tuple = (
            parse_seeds(seeds) if isinstance(seeds, str) else tuple(sorted({int(s) for s in seeds}))
        )
        if not seed_tuple or min(seed_tuple) < 0:
            raise ModelError(f"expected non-negative seeds, got {seeds!r}")
        return cls(task=task, grid=tuple(grid), seeds=seed_tuple, quick=bool(quick))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.grid)

    def jobs(self) -> list[Job]:
        """Every (cell, seed), cells in grid order, seeds innermost."""
        names = self.parameter_names
        values = [v for _, v in self.grid]
        return [
            Job(tuple(zip(names, cell, strict=True)), seed)
            for cell in itertools.product(*values)
            for seed in self.seeds
        ]

    def to_json(self) -> dict[str, Any]:
        return {
            "task": self.task,
            "grid": {name: list(values) for name, values in self.grid},
            "seeds": list(self.seeds),
            "quick": self.quick,
        }


def flatten_scalars(data: Mapping[str, Any], prefix: str = "") -> dict[str, float | int | bool]:
    """Every number of a nested ``metrics.json``-like mapping, keyed ``a.b`` / ``a.b.0``.

    Dicts are walked, lists of numbers are indexed and averaged (``.mean``); strings, ``None``
    and lists of records (e.g. per-fold tables) are left out: a sweep aggregates numbers.

    Example:
        >>> flatten_scalars({"k": 2, "reward": {"learned": [1.0, 2.5]}, "name": "x"})
        {'k': 2, 'reward.learned.0': 1.0, 'reward.learned.1': 2.5, 'reward.learned.mean': 1.75}
    """
    out: dict[str, float | int | bool] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten_scalars(value, prefix=f"{name}."))
        elif isinstance(value, (list, tuple)):
            if value and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
            ):
                out.update({f"{name}.{i}": v for i, v in enumerate(value)})
                out[f"{name}.mean"] = sum(value) / len(value)
        elif isinstance(value, (int, float)) and value is not None:
            if isinstance(value, float) and not math.isfinite(value):
                continue
            out[name] = value
    return out


def _place_and_drill_metrics(params: Mapping[str, Any], seed: int, quick: bool) -> dict[str, Any]:
    from torchhrc.experiments.place_and_drill import StudySettings, metrics_from_study, run_study

    settings = StudySettings.quick(seed=seed) if quick else StudySettings(seed=seed)
    # the SAPIEN replay is a physical check of a few executions, not a swept statistic
    settings = dataclasses.replace(settings, separation=False, **dict(params))
    return metrics_from_study(run_study(settings))


def _hand_finishing_metrics(params: Mapping[str, Any], seed: int, quick: bool) -> dict[str, Any]:
    from torchhrc.experiments.hand_finishing import HandFinishingSettings, run_study

    settings = HandFinishingSettings.create(quick=quick, seed=seed)
    changes: dict[str, Any] = {"sim": False, "speedup": False}
    if "noise" in params:
        changes["paper_noise"] = float(params["noise"])
        changes["noise_levels"] = (float(params["noise"]),)
    if "subjects" in params:
        changes["subjects"] = int(params["subjects"])
    if "episodes" in params:
        changes["episodes"] = int(params["episodes"])
    settings = dataclasses.replace(settings, **changes)
    return run_study(settings)["metrics"]


_RUNNERS: dict[str, Callable[[Mapping[str, Any], int, bool], dict[str, Any]]] = {
    "place-and-drill": _place_and_drill_metrics,
    "hand-finishing": _hand_finishing_metrics,
}

#: In :func:`task_parameters`: the function takes ``**kwargs`` (any parameter name).
_ANY = "**"
_LOADED: dict[str, Callable[..., Any]] = {}
_WORLDS: dict[str, Any] = {}  # task -> its TaskWithPeople, built once per process
_BY_PATH = "_torchhrc_sweep_"  # the name prefix of a module imported from its file


def _suite() -> Mapping[str, Callable[..., Any]]:
    from torchhrc.tasks.suite import SUITE

    return SUITE


def canonical_task(task: Any) -> str:
    """The task's name as a sweep records it: a study name, a suite task's name,
    ``"module:function"``, or ``"/absolute/path.py:function"``; a module-level function given
    itself becomes its ``"module:function"`` (the file's path when it lives in the
    ``__main__`` script; a suite task's factory, its name).

    Raises:
        ModelError: not a study, not a suite task, not a ``MODULE:FUNCTION`` string, or a
            function that workers cannot import by name (a lambda, a nested function).
        TypeError: a :class:`~torchhrc.tasks.people.TaskWithPeople` object: workers rebuild
            the task by name, so pass its factory (or the suite task's name).
    """
    from torchhrc.tasks.people import TaskWithPeople

    if isinstance(task, TaskWithPeople):
        raise TypeError(
            "a sweep cannot send a TaskWithPeople object to its workers: pass the module-level "
            "function that builds it (no arguments, returns the TaskWithPeople; as itself or "
            "'module:function' / 'file.py:function'), or a suite task's name"
        )
    if callable(task) and not isinstance(task, str):
        suite_name = next((n for n, f in _suite().items() if f is task), None)
        if suite_name is not None:
            return suite_name
        module = getattr(task, "__module__", None)
        name = getattr(task, "__qualname__", "")
        if not module or "<" in name or "." in name:
            raise ModelError(
                f"expected a module-level function (workers import it by name), got {task!r}"
            )
        if module == "__main__" or module.startswith(_BY_PATH):  # a script, a file by path
            import sys

            main_file = getattr(sys.modules.get(module), "__file__", None)
            if not main_file:
                raise ModelError(
                    f"{name} is defined in an interactive session: put it in a file and pass "
                    "'file.py:function'"
                )
            return f"{Path(main_file).resolve()}:{name}"
        return f"{module}:{name}"
    if not isinstance(task, str):
        raise ModelError(f"expected a task name or a function, got {task!r}")
    if task in _RUNNERS or task in _suite():
        return task
    where, sep, name = task.rpartition(":")
    if not sep or not where or not name.isidentifier():
        raise ModelError(
            f"expected a task: a study ({', '.join(sorted(PARAMETERS))}), a suite task "
            f"({', '.join(_suite())}) or MODULE:FUNCTION or FILE.py:FUNCTION, got {task!r}"
        )
    if where.endswith(".py"):
        return f"{Path(where).resolve()}:{name}"
    return task


def load_callable(task: str) -> Callable[..., Any]:
    """The function ``"module:function"`` or ``"path/file.py:function"`` names (imported
    once per process; a file is imported under a private module name, so its
    ``if __name__ == "__main__":`` block does not run).

    Raises:
        ModelError: the module, file or function is not found, or is not callable.
    """
    if task in _LOADED:
        return _LOADED[task]
    import hashlib
    import importlib
    import importlib.util
    import sys

    where, _, name = task.rpartition(":")
    try:
        if where.endswith(".py"):
            path = Path(where)
            if not path.is_file():
                raise ModelError(f"sweep task file {where} does not exist")
            digest = hashlib.sha1(str(path).encode()).hexdigest()[:12]  # same in every process
            module_name = f"{_BY_PATH}{path.stem}_{digest}"
            module = sys.modules.get(module_name)
            if module is None:
                spec = importlib.util.spec_from_file_location(module_name, path)
                assert spec is not None and spec.loader is not None
                module = importlib.util.module_from_spec(spec)
                sys.modules[module_name] = module
                try:
                    spec.loader.exec_module(module)
                except BaseException:
                    sys.modules.pop(module_name, None)
                    raise
        else:
            module = importlib.import_module(where)
    except ImportError as error:
        raise ModelError(f"cannot import the sweep task {task!r}: {error}") from None
    function = getattr(module, name, None)
    if not callable(function):
        raise ModelError(f"the sweep task {task!r}: {where} has no function {name!r}")
    _LOADED[task] = function
    return function


def _accepts(function: Callable[..., Any], name: str) -> bool:
    import inspect

    parameters = inspect.signature(function).parameters
    return name in parameters or any(p.kind is p.VAR_KEYWORD for p in parameters.values())


def task_kind(task: str) -> str:
    """What a (canonical) sweep task is: ``"study"`` (a reproduction), ``"task"`` (a task with
    simulated people: a suite task's name, or a factory) or ``"function"`` (a metrics
    function).

    A named callable that takes a ``seed`` keyword argument (or ``**kwargs``) is a metrics
    function, called ``function(seed=seed, **cell)`` per job. One that takes no ``seed`` and
    can be called without arguments is a task factory: ``factory()`` must return a
    :class:`~torchhrc.tasks.people.TaskWithPeople` (built once per process by
    :func:`load_world`; a factory annotated to return something else is refused without a
    call).

    Raises:
        ModelError: the callable cannot be loaded, is neither (it needs arguments other than
            ``seed``), or is a factory that does not return a ``TaskWithPeople``.
    """
    if task in _RUNNERS:
        return "study"
    if task in _suite():
        return "task"
    import inspect

    function = load_callable(task)
    if _accepts(function, "seed"):
        return "function"
    try:
        inspect.signature(function).bind()
    except TypeError:
        raise ModelError(
            f"the sweep task {task!r} must take a 'seed' keyword argument (a metrics function, "
            "called as function(seed=..., **params)) or no argument (a task factory returning "
            "a TaskWithPeople)"
        ) from None
    load_world(task)
    return "task"


def load_world(task: str) -> Any:
    """The :class:`~torchhrc.tasks.people.TaskWithPeople` a task sweep names: ``make_task(name)``
    of a suite task, or ``factory()`` of ``"module:factory"`` / ``"path/file.py:factory"``
    (built once per process).

    Raises:
        ModelError: the factory fails, or returns something other than a ``TaskWithPeople``.
    """
    if task in _WORLDS:
        return _WORLDS[task]
    import typing

    from torchhrc.tasks.people import TaskWithPeople

    if task in _suite():
        world = _suite()[task]()
    else:
        factory = load_callable(task)
        try:
            returns = typing.get_type_hints(factory).get("return")
        except Exception:  # unresolvable annotations: the call decides
            returns = None
        wrong = (
            f"the sweep task {task!r} takes no 'seed' keyword argument, so it is read as a "
            "task factory, but it {} not a TaskWithPeople (a metrics function must take a "
            "'seed' keyword argument)"
        )
        if isinstance(returns, type) and not issubclass(returns, TaskWithPeople):
            raise ModelError(wrong.format(f"is annotated to return {returns.__name__},"))
        try:
            world = factory()
        except Exception as error:
            raise ModelError(
                f"the sweep task factory {task!r} failed: {type(error).__name__}: {error}"
            ) from error
        if not isinstance(world, TaskWithPeople):
            raise ModelError(wrong.format(f"returned {type(world).__name__},"))
    _WORLDS[task] = world
    return world


def task_parameters(task: str) -> Mapping[str, SweepParameter | None]:
    """The parameters a task may sweep: :data:`PARAMETERS` of a study;
    :data:`~torchhrc.experiments.task_sweep.TASK_PARAMETERS` of a task with simulated people
    (a suite task or a factory, see :func:`task_kind`); a function's keyword arguments but
    ``seed`` and ``quick``, typed by annotation (``int``, ``float``, ``str``, ``bool``) or by
    the default's type. ``None``: untyped, values read as int, float or text (key ``"**"``
    when the function takes ``**kwargs``: any other name too).

    Raises:
        ModelError: the task is unknown, or a callable that is neither a metrics function nor
            a task factory (:func:`task_kind`).
    """
    if task in PARAMETERS:
        return PARAMETERS[task]
    if task_kind(task) == "task":
        from torchhrc.experiments.task_sweep import TASK_PARAMETERS

        return TASK_PARAMETERS
    import inspect
    import typing

    function = load_callable(task)
    try:
        hints = typing.get_type_hints(function)
    except Exception:  # unresolvable annotations: fall back to the defaults' types
        hints = {}
    known: dict[str, SweepParameter | None] = {}
    for name, parameter in inspect.signature(function).parameters.items():
        if parameter.kind is parameter.VAR_KEYWORD:
            known[_ANY] = None
            continue
        if name in ("seed", "quick") or parameter.kind in (
            parameter.POSITIONAL_ONLY, parameter.VAR_POSITIONAL
        ):  # fmt: skip
            continue
        kind = hints.get(name)
        if kind not in (int, float, str, bool):
            default = parameter.default
            kind = type(default) if type(default) in (int, float, str, bool) else None
        known[name] = None if kind is None else SweepParameter(kind, None, None, name)
    return known


def _function_metrics(task: str) -> Callable[[Mapping[str, Any], int, bool], Mapping[str, Any]]:
    function = load_callable(task)

    def run(params: Mapping[str, Any], seed: int, quick: bool) -> Mapping[str, Any]:
        options = dict(params)
        if quick:
            if not _accepts(function, "quick"):
                raise ModelError(f"--quick: the sweep task {task!r} takes no 'quick' argument")
            options["quick"] = True
        metrics = function(seed=seed, **options)
        if not isinstance(metrics, Mapping):
            raise ModelError(
                f"the sweep task {task!r} returned {type(metrics).__name__}; expected a mapping "
                "of metric names to numbers"
            )
        return metrics

    return run


def _world_metrics(task: str) -> Callable[[Mapping[str, Any], int, bool], Mapping[str, Any]]:
    from torchhrc.experiments.task_sweep import task_metrics

    world = load_world(task)

    def run(params: Mapping[str, Any], seed: int, quick: bool) -> Mapping[str, Any]:
        return task_metrics(world, seed=seed, quick=quick, **params)

    return run


def run_job(task: str, params: tuple[tuple[str, Any], ...], seed: int, quick: bool) -> dict:
    """Run one (cell, seed) of a sweep in this process; return its result row.

    The row holds the parameters, ``seed``, every scalar of the study's metrics
    (:func:`flatten_scalars`) and ``wall_s``. One intra-op thread, so that the result does not
    depend on the machine's core count.

    Example:
        >>> row = run_job("place-and-drill", (("subjects", 2), ("runs", 2)), 0, True)
        >>> row["subjects"], row["seed"], 0.0 <= row["loo_accuracy"] <= 1.0
        (2, 0, True)
    """
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    start = time.perf_counter()
    try:
        kind = task_kind(task)
        if kind == "study":
            runner = _RUNNERS[task]
        elif kind == "task":
            runner = _world_metrics(task)
        else:
            runner = _function_metrics(task)
        metrics = runner(dict(params), seed, quick)
    finally:
        torch.set_num_threads(threads)
    scalars = flatten_scalars(metrics)
    row: dict[str, Any] = {name: value for name, value in params}
    row["seed"] = seed
    for key, value in scalars.items():
        if key not in row:
            row[key] = value
    row["wall_s"] = round(time.perf_counter() - start, 3)
    return row


# --- executors -----------------------------------------------------------------------------


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


@dataclass(frozen=True)
class LocalExecutor:
    """Runs the jobs in local worker processes (``spawn``), one per core by default.

    At most ``workers`` jobs are in flight. A job that raises is retried up to ``retries``
    times. When a worker process dies the pool is restarted and the jobs that were in flight
    run again one at a time, so that a death is charged to the job that caused it (a try of
    its own) and never to a job that happened to run beside it; jobs that had finished are
    never run again.

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
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


# --- results files --------------------------------------------------------------------------


def _columns(rows: Iterable[Mapping[str, Any]], first: Sequence[str]) -> list[str]:
    columns = list(first)
    seen = set(columns)
    for row in rows:
        for key in row:
            if key not in seen:
                seen.add(key)
                columns.append(key)
    if "wall_s" in seen:  # the timing column last
        columns.remove("wall_s")
        columns.append("wall_s")
    return columns


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
    if summary and rows:
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
    ``objects``, ``mixture_method``, ``min_gain``, ``human_model``, ``irl_iterations``,
    ``irl_epsilon``, ``solver_time``, ``solver_iterations``; and ``episodes``.

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


# --- summary --------------------------------------------------------------------------------


def _is_summary_metric(name: str) -> bool:
    """Headline columns: not a list element (``a.3``, its ``a.mean`` is kept), not a CI, not
    a per-type breakdown (``a.by_type.<type>``)."""
    last = name.rsplit(".", 1)[-1]
    return not last.isdigit() and "ci95" not in name and ".by_type" not in name


def _metric_columns(rows: Sequence[Mapping[str, Any]], spec: SweepSpec) -> list[str]:
    skip = {*spec.parameter_names, "seed"}
    columns = [
        c for c in _columns(rows, [])
        if c not in skip and not is_timing_column(c) and _is_summary_metric(c)
    ]  # fmt: skip
    varying = []
    for c in columns:
        values = {row.get(c) for row in rows}
        if len(values) > 1 or len(spec.grid) == 0:
            varying.append(c)
    return varying


def _mean_ci(values: Sequence[float]) -> tuple[float, float]:
    import torch

    from torchhrc.experiments.robustness import mean_ci95

    mean, half = mean_ci95(torch.tensor(values, dtype=torch.float64), over="subjects")
    return float(mean), float(half)


def cell_statistics(
    rows: Sequence[Mapping[str, Any]], spec: SweepSpec, metric: str
) -> list[tuple[tuple[tuple[str, Any], ...], float, float, int]]:
    """``[(cell params, mean, 95% CI half-width, n seeds), ...]`` of ``metric`` per cell.

    The half-width uses Student's t with ``n - 1`` degrees of freedom (0 for one seed).
    """
    names = spec.parameter_names
    groups: dict[tuple[tuple[str, Any], ...], list[float]] = {}
    for row in rows:
        if row.get(metric) is None:
            continue
        cell = tuple((n, row[n]) for n in names)
        groups.setdefault(cell, []).append(float(row[metric]))
    return [(cell, *_mean_ci(v), len(v)) for cell, v in groups.items()]


def _safe_name(metric: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in metric)


def write_summary(
    out_dir: str | os.PathLike[str],
    spec: SweepSpec,
    rows: Sequence[Mapping[str, Any]],
    *,
    failed: Mapping[str, str] | None = None,
    plots: bool = True,
) -> Path:
    """Write ``summary.md`` (mean +/- 95% CI per cell) and a PNG per metric; return the md path.

    Each PNG has one panel per swept parameter: the metric's mean and 95% CI over seeds
    against that parameter, one line per combination of the other parameters. The headline
    metrics are summarised: scalars and the mean of each list (``reward.learned.mean``); list
    elements, CI columns and per-type breakdowns (``.by_type.``) stay in ``results.csv``.
    Metrics that do not vary over the sweep are listed once, not plotted.
    """
    from torchhrc.experiments.report import write_text_atomic

    path = Path(out_dir)
    metrics = _metric_columns(rows, spec)
    names = spec.parameter_names
    lines = [
        f"# Sweep: {spec.task}",
        "",
        f"Grid: {', '.join(f'{n} = {list(v)}' for n, v in spec.grid) or '(defaults)'}; "
        f"seeds {list(spec.seeds)}; quick = {spec.quick}; {len(rows)} finished jobs"
        + (f", {len(failed)} failed" if failed else "")
        + ".",
        "",
        "Each entry: mean +/- 95% CI half-width over seeds (Student t).",
        "",
    ]
    constant = [
        c for c in _columns(rows, []) if c not in {*names, "seed"} and c not in metrics
        and not is_timing_column(c) and _is_summary_metric(c)
    ]  # fmt: skip
    for metric in metrics:
        stats = cell_statistics(rows, spec, metric)
        lines += [f"## {metric}", "", "| " + " | ".join([*names, "mean", "ci95", "seeds"]) + " |"]
        lines.append("|" + "---|" * (len(names) + 3))
        for cell, mean, half, n in stats:
            values = [str(v) for _, v in cell]
            lines.append("| " + " | ".join([*values, f"{mean:.4g}", f"{half:.3g}", str(n)]) + " |")
        if plots and names:
            lines += ["", f"![{metric}]({_safe_name(metric)}.png)"]
        lines.append("")
    if constant:
        lines += ["## Constant over the sweep", ""]
        lines += [f"- {c} = {rows[0].get(c)}" for c in constant]
        lines.append("")
    if failed:
        lines += ["## Failed jobs", ""] + [f"- `{k}`: {v}" for k, v in failed.items()] + [""]
    if plots and names:
        for metric in metrics:
            _plot(path / f"{_safe_name(metric)}.png", spec, rows, metric)
    target = path / "summary.md"
    write_text_atomic(target, "\n".join(lines))
    return target


def _plot(target: Path, spec: SweepSpec, rows: Sequence[Mapping[str, Any]], metric: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from torchhrc.experiments.report import _atomic

    names = spec.parameter_names
    stats = cell_statistics(rows, spec, metric)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        grid = dict(spec.grid)[name]
        # numbers on a numeric axis; text (criterion=bic,icl) and bools at their grid positions
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in grid)
        lines: dict[tuple[tuple[str, Any], ...], list[tuple[float, float, float]]] = {}
        for cell, mean, half, _ in stats:
            values = dict(cell)
            others = tuple((n, values[n]) for n in names if n != name)
            x_value = float(values[name]) if numeric else float(grid.index(values[name]))
            lines.setdefault(others, []).append((x_value, mean, half))
        if not numeric:
            ax.set_xticks(range(len(grid)), [str(v) for v in grid])
        for others, points in lines.items():
            points.sort()
            x = [p[0] for p in points]
            label = ", ".join(f"{n}={v}" for n, v in others) or None
            ax.errorbar(x, [p[1] for p in points], yerr=[p[2] for p in points], marker="o",
                        capsize=3, label=label)  # fmt: skip
        ax.set_xlabel(name)
        ax.set_ylabel(metric)
        if any(others for others in lines):
            ax.legend(fontsize=7)
    fig.suptitle(f"{spec.task}: {metric} (mean, 95% CI over {len(spec.seeds)} seeds)", fontsize=9)
    fig.tight_layout()

    def write(tmp: str) -> None:
        fig.savefig(tmp, format="png", dpi=90)

    try:
        _atomic(target, write)
    finally:
        plt.close(fig)
