"""What a sweep runs: the task (a reproduction, a task with simulated people, or a user's
function, resolved by name so that workers import it), its parameters, the sweep's
specification (:class:`SweepSpec`) and one job (:func:`run_job`). Above
:mod:`.sweep_grid` and :mod:`.task_sweep`; :mod:`torchhrc.experiments.sweep` re-exports every
public name.

Example:
    >>> task_kind("place-and-drill")
    'study'
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from torchhrc.errors import ModelError
from torchhrc.experiments.sweep_grid import (
    PARAMETERS,
    Job,
    SweepParameter,
    Value,
    _infer,
    flatten_scalars,
    parse_seeds,
)


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


def _place_and_drill_metrics(params: Mapping[str, Any], seed: int, quick: bool) -> dict[str, Any]:
    from torchhrc.experiments.place_and_drill import StudySettings, metrics_from_study, run_study

    settings = StudySettings.quick(seed=seed) if quick else StudySettings(seed=seed)
    # the SAPIEN replay is a physical check of a few executions, not a swept statistic
    settings = dataclasses.replace(settings, separation=False, **dict(params))
    return metrics_from_study(run_study(settings))


def _hand_finishing_metrics(params: Mapping[str, Any], seed: int, quick: bool) -> dict[str, Any]:
    from torchhrc.experiments.hand_finishing import run_study
    from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings

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
    local = Path(where.replace(".", "/") + ".py")
    if local.is_file() and not _importable(where):
        # a module next to the caller that the console script cannot import (its folder is
        # not on sys.path): the file itself, as python would find it from this folder
        return f"{local.resolve()}:{name}"
    return task


def _importable(module: str) -> bool:
    """Whether ``import module`` would find it (without importing it)."""
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


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
        raise ModelError(
            f"cannot import the sweep task {task!r}: {error} (name the file, "
            f"'path/to/{where.replace('.', '/')}.py:{name}', or put its folder on PYTHONPATH)"
        ) from None
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
    from torchhrc._threads import torch_threads  # (torch loads with it: here, not at import)

    start = time.perf_counter()
    with torch_threads(1):
        kind = task_kind(task)
        if kind == "study":
            runner = _RUNNERS[task]
        elif kind == "task":
            runner = _world_metrics(task)
        else:
            runner = _function_metrics(task)
        metrics = runner(dict(params), seed, quick)
    scalars = flatten_scalars(metrics)
    row: dict[str, Any] = {name: value for name, value in params}
    row["seed"] = seed
    for key, value in scalars.items():
        if key not in row:
            row[key] = value
    row["wall_s"] = round(time.perf_counter() - start, 3)
    return row
