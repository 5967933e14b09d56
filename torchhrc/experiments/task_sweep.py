"""One sweep job of a task with simulated people: demonstrations -> learn -> evaluate -> metrics.

:func:`torchhrc.sweep` sweeps a :class:`~torchhrc.tasks.people.TaskWithPeople` (a suite task
by name, or a user's task through its factory) with :func:`task_metrics` as the job: for one
cell of the grid and one seed it

1. draws ``world.demonstrations(subjects=, per_subject=, noise=, seed=seed)``;
2. learns the type-aware model, ``torchhrc.learn(world.task, demos, seed=seed, ...)`` with
   the cell's clustering, human-model, IRL and solver settings, and the type-agnostic one
   (``k = 1``, the same human-model, IRL and solver settings);
3. runs both robots against the simulated people under their true rewards,
   ``torchhrc.evaluate_task(world, model, demonstrations=demos, agnostic=..., seed=seed)``;
4. returns the numbers: the ``k`` found and the true one, the ARI of the learned types
   against the true types, the human model used, each robot's mean return and 95% CI
   (overall and per true type), the type-aware robot's gain over the type-agnostic one, the
   online belief's accuracy after ``n`` steps, and the solver's gaps.

:data:`TASK_PARAMETERS` lists the names a task sweep takes; every other setting keeps
``learn()``'s and ``evaluate_task()``'s default, except that ``quick`` uses 3 clustering
restarts, a 1 s solver limit and 50 evaluation episodes per type (:data:`QUICK`) where the
cell does not set them.

Example:
    >>> from torchhrc.tasks.suite import make_task
    >>> m = task_metrics(make_task("tool_handover"), seed=0, quick=True, subjects=4,
    ...                  per_subject=2, episodes=4)
    >>> m["true_k"], 0.0 <= m["ari"] <= 1.0, sorted(m["return"])
    (2, True, ['type-agnostic', 'type-aware'])
"""

from __future__ import annotations

import warnings
from collections import Counter
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from torchhrc.experiments.sweep_grid import SweepParameter

if TYPE_CHECKING:
    from torchhrc.tasks.people import TaskWithPeople

__all__ = ["QUICK", "TASK_PARAMETERS", "check_cell", "task_metrics"]

_CRITERIA = ("icl_or_gain", "heldout", "bic", "icl", "exact_icl", "bic_or_exact_icl")

#: The parameters a task sweep takes (``--param NAME=...``), the same for every task.
TASK_PARAMETERS: dict[str, SweepParameter] = {
    # the demonstrations (world.demonstrations)
    "subjects": SweepParameter(int, 1, None, "demonstrating subjects (types in turn)"),
    "per_subject": SweepParameter(int, 1, None, "demonstrations per subject"),
    "noise": SweepParameter(
        float, 0.0, 1.0, "the simulated people's noise, in the demonstrations and the evaluation"
    ),
    # learn()
    "k": SweepParameter(int, 1, None, "learn(k=): force the number of types"),
    "k_min": SweepParameter(int, 1, None, "learn(k_min=)"),
    "k_max": SweepParameter(int, 1, None, "learn(k_max=)"),
    "restarts": SweepParameter(int, 1, None, "learn(restarts=): clustering restarts"),
    "criterion": SweepParameter(
        str, None, None, "learn(criterion=): the rule choosing k", choices=_CRITERIA
    ),
    "objects": SweepParameter(
        str, None, None, "learn(objects=)", choices=("auto", "raw", "exchangeable")
    ),
    "order": SweepParameter(
        str,
        None,
        None,
        "learn(order=): chains of order 1, 2 or 3, or the three compared ('auto')",
        choices=("1", "2", "3", "auto"),
    ),
    "mixture_method": SweepParameter(
        str, None, None, "learn(mixture_method=)", choices=("soft", "paper")
    ),
    "min_gain": SweepParameter(float, 0.0, None, "learn(min_gain=)"),
    "split_divided": SweepParameter(
        bool, None, None, "learn(split_divided=): split a type whose partners moved differently"
    ),
    "human_model": SweepParameter(
        str, None, None, "learn(human_model=)", choices=("auto", "chain", "state")
    ),
    "prior": SweepParameter(
        str,
        None,
        None,
        "learn(prior=): the robot's first belief over the types",
        choices=("shares", "uniform"),
    ),
    "irl_iterations": SweepParameter(int, 1, None, "learn(irl_iterations=)"),
    "irl_epsilon": SweepParameter(float, 0.0, None, "learn(irl_epsilon=)"),
    "irl_l2": SweepParameter(float, 0.0, None, "learn(irl_l2=): the MaxEnt ridge"),
    "irl_pooling": SweepParameter(
        float, 0.0, 0.999, "learn(irl_pooling=): the types' rewards' prior correlation"
    ),
    "irl_wrong_moves": SweepParameter(
        str,
        None,
        None,
        "learn(irl_wrong_moves=): the price of a move no partner of the type made",
        choices=("symmetric", "learned"),
    ),
    "solver_time": SweepParameter(float, 0.01, None, "learn(solver_time=): SARSOP limit (s)"),
    "solver_iterations": SweepParameter(
        int, 1, None, "learn(solver_iterations=): SARSOP iteration cap (a deterministic stop)"
    ),
    # evaluate_task()
    "episodes": SweepParameter(int, 2, None, "evaluate_task(episodes=): episodes per true type"),
}

#: What ``quick`` changes where the cell does not set it.
QUICK: dict[str, Any] = {"restarts": 3, "solver_time": 1.0, "episodes": 50}

_DEFAULT_K_MAX = 6  # learn()'s
_DEMONSTRATIONS = ("subjects", "per_subject", "noise")
_CLUSTERING = ("k", "k_min", "k_max", "restarts", "criterion", "objects", "order",
               "mixture_method", "min_gain", "split_divided")  # fmt: skip
_MODEL = ("human_model", "prior", "irl_iterations", "irl_epsilon", "irl_l2", "irl_pooling",
          "irl_wrong_moves", "solver_time", "solver_iterations")  # fmt: skip


def task_metrics(
    world: TaskWithPeople, *, seed: int, quick: bool = False, **settings: Any
) -> dict[str, Any]:
    """The metrics of one sweep job of ``world``: learn from its simulated people, evaluate.

    Args:
        world: the task with simulated people
            (:class:`~torchhrc.tasks.people.TaskWithPeople`).
        seed: the seed of the demonstrations, of learning and of the evaluation.
        quick: :data:`QUICK`'s settings where ``settings`` does not give them.
        settings: values of :data:`TASK_PARAMETERS` (checked as a sweep checks them).

    Returns:
        A nested mapping of numbers (a sweep flattens it into ``a.b`` columns): ``k`` (found),
        ``true_k``, ``k_correct`` (1 or 0), ``ari`` (learned types against the true types of
        the demonstrations), ``human_model.<name>`` (1 for the model ``learn`` used: ``chain``
        or ``state``; both 0 when the task's behaviour is the same under both;
        ``human_model.habit_weight`` and ``.prior_strength``: the state model's smoothing),
        ``return.<robot>.mean`` / ``.ci95`` (over every episode) and ``.by_type.<type>`` /
        ``.by_type_ci95.<type>`` for ``type-aware`` and ``type-agnostic``, ``gain.mean`` (type-
        aware minus type-agnostic overall), ``gain.ci95`` (its paired 95% half-width),
        ``gain.by_type.<type>``, ``gain.beyond_ci`` (+1,
        0 or -1: ahead, level or behind beyond the 95% interval of the paired difference,
        :meth:`~torchhrc.tasks.evaluation.TaskEvaluation.compare`),
        ``belief.accuracy.after_<n>`` (``n`` = 1, 3, 5 up to the horizon; mean over the true
        types), ``belief.max_posterior`` (the mean largest posterior after the last ``n``),
        ``belief.by_type.<type>`` (the accuracy after the last ``n``), the shares of true
        types ``belief.identified`` / ``split`` / ``merged``, and ``solver.gap`` /
        ``solver.gap_agnostic`` (SARSOP's final upper minus lower bound), and
        ``warnings.<category>``: how many warnings of each category the job raised (they are
        counted, not printed: a sweep runs many jobs). The per-type breakdowns (``by_type``)
        and CIs go to ``results.csv``, not to the summary's plots.

    Raises:
        ModelError: an unknown setting or a bad value (named), or ``k_min > k_max``
            (:func:`check_cell`).

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> m = task_metrics(make_task("pace"), seed=1, quick=True, subjects=3,
        ...                  per_subject=2, k=1, episodes=4)
        >>> m["k"], m["true_k"], m["k_correct"]
        (1, 3, 0)
    """
    from torchhrc.errors import ModelError
    from torchhrc.metrics import adjusted_rand_index
    from torchhrc.tasks.evaluation import evaluate_task
    from torchhrc.tasks.pipeline import learn

    for name, value in settings.items():
        if name not in TASK_PARAMETERS:
            raise ModelError(
                f"a task sweep has no parameter {name!r} (parameters: "
                f"{', '.join(sorted(TASK_PARAMETERS))})"
            )
        TASK_PARAMETERS[name].parse(name, value)
    check_cell(settings)
    options: dict[str, Any] = {**(QUICK if quick else {}), **settings}
    demo_options = {n: options[n] for n in _DEMONSTRATIONS if n in options}
    model_options = {n: options[n] for n in _MODEL if n in options}
    cluster_options = {n: options[n] for n in _CLUSTERING if n in options}
    if cluster_options.get("order") in ("1", "2"):  # a sweep's value is a string
        cluster_options["order"] = int(cluster_options["order"])
    steps = tuple(n for n in (1, 3, 5) if n <= world.horizon)
    # a sweep runs many jobs: their warnings become counts in the row, not lines on stderr
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        demos, truth = world.demonstrations(seed=seed, **demo_options)
        model = learn(world.task, demos, seed=seed, **cluster_options, **model_options)
        agnostic = learn(world.task, demos, k=1, seed=seed, **model_options)
        evaluation = evaluate_task(
            world, model, demonstrations=demos, agnostic=agnostic,
            episodes=options.get("episodes", 200), noise=options.get("noise", 0.05),
            belief_steps=steps, seed=seed,
        )  # fmt: skip
    warned = Counter(w.category.__name__ for w in caught)

    names = world.type_names
    k, true_k = int(model.num_types), int(world.num_types)
    human_model = dict(model.info.get("human_model", {}))
    used = human_model.get("used")
    smoothing = dict(human_model.get("state_smoothing") or {})
    returns: dict[str, Any] = {}
    for r, robot in enumerate(evaluation.robots):
        returns[robot] = {
            "mean": float(evaluation.overall_mean[r]),
            "ci95": float(evaluation.overall_ci[r]),
            "by_type": {n: float(evaluation.mean[r, y]) for y, n in enumerate(names)},
            "by_type_ci95": {n: float(evaluation.ci[r, y]) for y, n in enumerate(names)},
        }
    aware, other = evaluation.index("type-aware"), evaluation.index("type-agnostic")
    checks = evaluation.belief_steps
    status = evaluation.belief_status
    return {
        "k": k,
        "true_k": true_k,
        "k_correct": int(k == true_k),
        "ari": adjusted_rand_index(truth.tolist(), model.assignments.tolist()),
        "human_model": {
            **{name: int(used == name) for name in ("chain", "state")},
            **{key: float(smoothing[key]) for key in ("habit_weight", "prior_strength")
               if key in smoothing},
        },
        "return": returns,
        "gain": {
            "mean": float(evaluation.overall_mean[aware] - evaluation.overall_mean[other]),
            "by_type": {
                n: float(evaluation.mean[aware, y] - evaluation.mean[other, y])
                for y, n in enumerate(names)
            },
            "ci95": float(evaluation.difference("type-aware", "type-agnostic", overall=True)[1]),
            "beyond_ci": int(evaluation.compare("type-aware", "type-agnostic", overall=True)),
        },
        "belief": {
            "accuracy": {
                f"after_{n}": float(evaluation.belief_accuracy[:, s].mean())
                for s, n in enumerate(checks)
            },
            "max_posterior": float(evaluation.belief_max[:, -1].mean()) if checks else None,
            "by_type": {
                n: float(evaluation.belief_accuracy[y, -1]) for y, n in enumerate(names)
            } if checks else {},
            **{label: status.count(label) / len(status) if status else 0.0
               for label in ("identified", "split", "merged")},
        },
        "solver": {"gap": _gap(model), "gap_agnostic": _gap(agnostic)},
        "warnings": dict(sorted(warned.items())),
    }  # fmt: skip


def check_cell(cell: Mapping[str, Any]) -> None:
    """Check a cell's settings together (each value alone is checked by
    :data:`TASK_PARAMETERS`): ``k_min <= k_max``, with ``learn()``'s defaults (1 and 6) for the
    one not given, unless ``k`` forces the number of types.

    Raises:
        ModelError: naming the parameters.

    Example:
        >>> check_cell({"k_min": 2, "k_max": 4})
        >>> try:
        ...     check_cell({"k_min": 7})
        ... except ValueError as error:
        ...     print(str(error)[-44:])
        got k_min = 7, k_max = 6 (learn()'s default)
    """
    from torchhrc.errors import ModelError

    if "k" in cell:
        return
    low, high = cell.get("k_min", 1), cell.get("k_max", _DEFAULT_K_MAX)
    if low > high:
        source = "" if "k_max" in cell else " (learn()'s default)"
        raise ModelError(
            f"expected --param k_min <= k_max in every cell, got k_min = {low}, "
            f"k_max = {high}{source}"
        )


def _gap(model: Any) -> float:
    upper, lower = getattr(model, "upper", None), getattr(model, "lower", None)
    return float("nan") if upper is None or lower is None else float(upper - lower)
