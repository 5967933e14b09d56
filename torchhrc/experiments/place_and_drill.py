"""The place-and-drill study end to end: ``torchhrc reproduce place-and-drill``.

Paper (section "Evaluation"): 18 subjects x 3 demonstrations; leave-one-subject-out: learn
the model from 17 subjects, infer the held-out subject's type from its 3 demonstrations
(96.5% accuracy), use that as the initial belief of the MOMDP solved by SARSOP, and run the
task with a simulated human who deviates with probability epsilon (Fig. 3), against the
hand-coded expert MOMDP and human-robot cross-training.

Pipeline (one call of :func:`reproduce_place_and_drill`):

1. simulate the study (:func:`~torchhrc.tasks.place_and_drill.demos.simulate_study`);
2. cross-training: one MDP per subject from its own demonstrations, solved in one batch;
3. hand-coded expert MOMDP: read ``models/place_and_drill_expert.json``, solved by SARSOP
   once per distinct initial belief (the expert's belief depends only on its label of the
   subject, so that is once per type);
4. per fold (held-out subject): fit the mixture on the other subjects (BIC picks k), the
   paper's vote for the accuracy (clusters matched one-to-one to the labels on the training
   data), the Bayesian posterior over the clusters from the subject's 3 demonstrations as the
   initial belief, IRL per cluster, build the MOMDP, solve it with SARSOP once, and run the
   three policies ``runs`` times for every epsilon in one batch;
5. a mixture fitted to all subjects for the plots of the cluster transition matrices;
6. write ``metrics.json``, ``report.md`` and the PNG plots (:mod:`.report`).

Nothing is cached on disk; the output directory must be empty (or ``force=True``).

Example:
    >>> import tempfile
    >>> out = tempfile.mkdtemp()
    >>> metrics = reproduce_place_and_drill(out, quick=True, force=True)  # doctest: +SKIP
    >>> sorted(metrics)[:3]  # doctest: +SKIP
    ['epsilon', 'k', 'k_per_fold']
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from torchhrc._threads import torch_threads
from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.experiments.robustness import (
    EPSILONS,
    POLICY_NAMES,
    MOMDPPolicy,
    RobustnessResult,
    simulate_subject,
)
from torchhrc.pomdp import MOMDP
from torchhrc.tasks.interface import chain_preferences
from torchhrc.tasks.pipeline import build_model, solve_model, solve_momdp
from torchhrc.tasks.place_and_drill.cross_training import fit_cross_training
from torchhrc.tasks.place_and_drill.hand_coded import (
    build_expert_momdp,
    expert_initial_belief,
    load_expert_model,
)
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
from torchhrc.tasks.place_and_drill.simulate import demonstrated_orders

__all__ = [
    "PAPER",
    "StudySettings",
    "metrics_from_study",
    "prepare_output_dir",
    "reproduce_place_and_drill",
    "run_study",
]

logger = logging.getLogger(__name__)

#: The paper's reported numbers (section "Evaluation").
PAPER: dict[str, Any] = {
    "subjects": 18,
    "demonstrations_per_subject": 3,
    "loo_accuracy": 0.965,
    "k": 2,
    "runs_per_subject": 100,
}

#: ``progress(stage, done, total)``: stage is a short label, e.g. ``"fold"``.
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True, kw_only=True)
class StudySettings:
    """Settings of the reproduction (keyword-only; defaults are the paper's protocol).

    Attributes:
        subjects: number of simulated subjects (even split safe / efficient).
        demos: demonstrations per subject.
        positions: screw positions.
        noise: demonstration noise: each subject's per-step deviation rate, one rate for
            all or a ``(low, high)`` range drawn per subject (the study simulator's ``noise``).
        runs: simulated executions per subject per epsilon.
        epsilons: deviation probabilities.
        k_min, k_max, restarts, mixture_method: Select-Best-Model settings.
        solver_time: SARSOP time limit per MOMDP (seconds): a safety net only. Solves stop on
            ``solver_precision`` (within 18 iterations on the default run, measured
            2026-12-01) or ``solver_max_iterations``, so the results do not depend on the
            machine's speed or load.
        solver_max_iterations: cap on the SARSOP iterations of each solve.
        solver_precision: SARSOP target gap, relative to the reward span of the model.
        irl_iterations: cap on the IRL policies per type.
        seed: the seed of everything (study, fits, IRL, solver, simulation).
        online: also run the online case (uniform initial belief, type inferred while
            acting; :mod:`.online`).
        separation: replay sampled executions of every policy in the SAPIEN workbench and
            measure human-robot separation (needs the ``sim`` extra; skipped without it).
        separation_runs, separation_subjects, separation_epsilon: executions per (subject,
            policy, case), subjects per type, and their deviation probability.
        separation_threshold: the separation (m) below which a step counts as close.
    """

    subjects: int = 18
    demos: int = 3
    positions: int = 3
    noise: float | tuple[float, float] = (0.0, 0.15)
    runs: int = 100
    epsilons: tuple[float, ...] = EPSILONS
    k_min: int = 2
    k_max: int = 10
    restarts: int = 20
    mixture_method: str = "soft"
    solver_time: float = 60.0
    solver_max_iterations: int = 200
    solver_precision: float = 1e-3
    irl_iterations: int = 10
    separation: bool = True
    separation_runs: int = 2
    separation_subjects: int = 2
    separation_epsilon: float = 0.0
    separation_threshold: float = 0.10
    seed: int = 0
    online: bool = True

    @classmethod
    def quick(cls, seed: int = 0) -> StudySettings:
        """A small version for tests: 6 subjects, 20 runs, k in 2..4, 4 restarts."""
        return cls(
            subjects=6,
            runs=20,
            k_max=4,
            restarts=4,
            irl_iterations=5,
            separation_runs=1,
            separation_subjects=1,
            seed=seed,
        )


def prepare_output_dir(out_dir: str | os.PathLike[str], *, force: bool = False) -> Path:
    """Create ``out_dir``; refuse a non-empty one unless ``force``.

    Raises:
        FileExistsError: ``out_dir`` is not empty (or is a file) and ``force`` is False.
    """
    path = Path(out_dir)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"output path {str(path)!r} exists and is not a directory")
    if path.is_dir() and any(path.iterdir()) and not force:
        raise FileExistsError(
            f"output directory {str(path)!r} is not empty; pass --force to write into it"
        )
    path.mkdir(parents=True, exist_ok=True)
    return path


def _solve(model: MOMDP, settings: StudySettings) -> Any:
    """A baseline's MOMDP solved with the settings of the learned one (:func:`solve_model`)."""
    s = settings
    return solve_momdp(model, time_limit=s.solver_time, precision=s.solver_precision,
                       max_iterations=s.solver_max_iterations, seed=s.seed)  # fmt: skip


def _subject_types(demos: Demonstrations) -> dict[str, str]:
    assert demos.types is not None
    out: dict[str, str] = {}
    for subject, label in zip(demos.subjects, demos.types):
        out.setdefault(subject, label)
    return out


def _online_setup(expert: Any, s: StudySettings) -> dict[str, Any]:
    """Solve the hand-coded online MOMDP once; the per-fold accumulators of the online case."""
    from torchhrc.experiments.online import expert_online_momdp

    t = time.perf_counter()
    model = expert_online_momdp(expert)
    solution = _solve(model, s)
    return {
        "hand_coded": MOMDPPolicy(model, solution.policy, model.b0),
        "generator": torch.Generator().manual_seed(s.seed),
        "rewards": {name: [] for name in POLICY_NAMES},
        "turn_taking": [],
        "time": time.perf_counter() - t,
    }


def _online_fold(
    state: dict[str, Any],
    task: Any,
    learned: Any,
    fit: Any,
    train: Demonstrations,
    orders: torch.Tensor,
    score: torch.Tensor,
    label: str,
    s: StudySettings,
    *,
    on_trace: Callable[..., None] | None = None,
) -> None:
    """The online case of one fold: learned turn taking, SARSOP from the uniform belief, runs."""
    from torchhrc.experiments.online import (
        human_chunk_size,
        learn_turn_taking,
        online_momdp,
        pooled_cross_training,
    )

    t = time.perf_counter()
    wait = learn_turn_taking(task, train, fit.assignments, fit.k)
    placement = chain_preferences(learned.chains, learned.vocabulary, task.robot_actions,
                                  task.human_actions)  # fmt: skip
    model = online_momdp(
        task,
        placement,
        learned.momdp.R,
        wait,
        discount=learned.momdp.discount,
        type_names=learned.type_names,
    )
    solution = _solve(model, s)
    result = simulate_subject(
        task,
        momdp_policies={
            "learned": MOMDPPolicy(model, solution.policy, model.b0),
            "hand_coded": state["hand_coded"],
        },
        cross_training=pooled_cross_training(task, train, discount=learned.momdp.discount),
        subject_index=0,
        orders=orders,
        score=score,
        epsilons=s.epsilons,
        runs=s.runs,
        generator=state["generator"],
        human_chunk=human_chunk_size(task, label),
        on_trace=on_trace,
    )
    for name in POLICY_NAMES:
        state["rewards"][name].append(result[name])
    state["turn_taking"].append([[round(float(q), 6) for q in row] for row in wait.tolist()])
    state["time"] += time.perf_counter() - t


def _online_metrics(online: RobustnessResult | None, rounded: Callable[..., Any]) -> dict[str, Any]:
    """``reward_online``, ``reward_online_ci95``, ``reward_online_ci95_subjects`` (or nothing)."""
    from torchhrc.experiments.robustness import mean_ci95

    if online is None:
        return {}
    return {
        "reward_online": {name: rounded(online.mean(name)) for name in POLICY_NAMES},
        "reward_online_ci95": {name: rounded(online.ci95(name)) for name in POLICY_NAMES},
        "reward_online_ci95_subjects": {
            name: rounded(mean_ci95(online.subject_means(name), over="subjects")[1])
            for name in POLICY_NAMES
        },
    }


def run_study(settings: StudySettings, *, progress: Progress | None = None) -> dict[str, Any]:
    """Run the whole study in memory; return everything the report needs.

    Returns:
        A dict with ``demonstrations``, ``robustness`` (:class:`RobustnessResult`),
        ``folds`` (per-subject records), ``full_fit`` (mixture on all subjects),
        ``expert``, ``timings`` and ``settings``.
    """
    from torchhrc.metrics import match_clusters
    from torchhrc.mixture import fit_mixture, infer_type
    from torchhrc.tasks.place_and_drill.demos import simulate_study

    timings: dict[str, float] = {}
    start = time.perf_counter()
    cpu_start = time.process_time()
    s = settings
    demos = simulate_study(
        n_subjects=s.subjects,
        n_demos=s.demos,
        n_positions=s.positions,
        noise=s.noise,
        seed=s.seed,
    )
    expert = load_expert_model()
    task = expert.task
    if task.n_positions != s.positions:
        raise ModelError(
            f"the expert model {expert.path} is written for {task.n_positions} positions, "
            f"the study has {s.positions}"
        )
    learner_task = PlaceAndDrillTask(task.n_positions, discount=expert.discount)
    labels = _subject_types(demos)
    subjects = demos.unique_subjects
    orders = demonstrated_orders(task, demos)
    score = expert.reward()  # (A, X, Y)
    expert_index = {name: i for i, name in enumerate(expert.type_names)}
    for subject, label in labels.items():
        if label not in expert_index:
            raise ModelError(
                f"subject {subject} has type {label!r}, which the expert model {expert.path} "
                f"does not define (types: {', '.join(expert.type_names)})"
            )

    t = time.perf_counter()
    cross = fit_cross_training(task, demos, discount=expert.discount)
    timings["cross_training"] = time.perf_counter() - t

    t = time.perf_counter()
    hand_b0 = expert_initial_belief(expert, [labels[x] for x in subjects])  # (S, Y)
    hand_solutions: dict[tuple[float, ...], Any] = {}
    for row in hand_b0:
        key = tuple(row.tolist())
        if key not in hand_solutions:
            hand_solutions[key] = _solve(build_expert_momdp(expert, row), s)
    timings["hand_coded_solve"] = time.perf_counter() - t
    online_state = _online_setup(expert, s) if s.online else None
    sampler = None
    if s.separation:
        from torchhrc.experiments.separation import TraceSampler

        sampler = TraceSampler(runs=s.separation_runs, epsilon=s.separation_epsilon,
                               subjects=s.separation_subjects)  # fmt: skip

    generator = torch.Generator().manual_seed(s.seed)
    rewards: dict[str, list[torch.Tensor]] = {name: [] for name in POLICY_NAMES}
    folds: list[dict[str, Any]] = []
    fit_time = irl_time = solve_time = sim_time = 0.0
    for f, subject in enumerate(subjects):
        held_out = torch.tensor([x == subject for x in demos.subjects])
        train, test = demos.subset(~held_out), demos.subset(held_out)
        t = time.perf_counter()
        fit = fit_mixture(
            train,
            k_min=s.k_min,
            k_max=s.k_max,
            restarts=s.restarts,
            method=s.mixture_method,
            seed=s.seed,  # type: ignore[arg-type]
        )
        assert train.types is not None
        mapping = match_clusters(train.types, fit.assignments.tolist())
        cluster_labels = tuple(mapping.get(c) for c in range(fit.k))
        scored = fit.model.prepare(test)  # the form the chains are over (fit.objects)
        vote = infer_type(fit.model, scored.sequences, scored.lengths, method="vote")
        posterior = infer_type(fit.model, scored.sequences, scored.lengths, method="posterior")
        vote, posterior = vote.detach().double(), posterior.detach().double()
        by_label: dict[str | None, float] = {}
        for name, p in zip(cluster_labels, vote.tolist()):
            by_label[name] = by_label.get(name, 0.0) + p
        predicted = max(by_label, key=lambda name: by_label[name])
        fit_time += time.perf_counter() - t

        t = time.perf_counter()
        # the task-independent pipeline (torchhrc.tasks.pipeline), as for any user's task
        learned = build_model(
            learner_task,
            train,
            fit.transition_over(train),  # over the recorded symbols, whatever fit.objects
            fit.assignments,
            b0=posterior,
            irl_iterations=s.irl_iterations,
            seed=s.seed,
        )
        irl_time += time.perf_counter() - t
        t = time.perf_counter()
        learned = solve_model(
            learned,
            time_limit=s.solver_time,
            precision=s.solver_precision,
            seed=s.seed,
            max_iterations=s.solver_max_iterations,
        )
        solution = learned
        solve_time += time.perf_counter() - t

        t = time.perf_counter()
        true = expert_index[labels[subject]]
        hand = hand_solutions[tuple(hand_b0[f].tolist())]
        result = simulate_subject(
            task,
            momdp_policies={
                "learned": MOMDPPolicy(learned.momdp, solution.policy, posterior),
                "hand_coded": MOMDPPolicy(
                    build_expert_momdp(expert, hand_b0[f]), hand.policy, hand_b0[f]
                ),
            },
            cross_training=cross,
            subject_index=f,
            orders=orders[subject],
            score=score[..., true],
            epsilons=s.epsilons,
            runs=s.runs,
            generator=generator,
            on_trace=None if sampler is None else sampler.hook("offline", subject, labels[subject]),
        )
        sim_time += time.perf_counter() - t
        for name in POLICY_NAMES:
            rewards[name].append(result[name])
        if online_state is not None:
            _online_fold(
                online_state,
                task,
                learned,
                fit,
                train,
                orders[subject],
                score[..., true],
                labels[subject],
                s,
                on_trace=None if sampler is None else sampler.hook("online", subject,
                                                                   labels[subject]),
            )  # fmt: skip
        folds.append(
            {
                "subject": subject,
                "true_type": labels[subject],
                "predicted_type": predicted,
                "correct": predicted == labels[subject],
                "k": fit.k,
                "cluster_labels": list(cluster_labels),
                "cluster_names": list(learned.type_names),
                "vote": vote.tolist(),
                "posterior": posterior.tolist(),
                "irl_weights": learned.weights.tolist(),
                "solver_gap": float(solution.upper - solution.lower),
            }
        )
        logger.info(
            "fold %d/%d: %s (%s) k=%d predicted %s",
            f + 1,
            len(subjects),
            subject,
            labels[subject],
            fit.k,
            predicted,
        )
        if progress is not None:
            progress("fold", f + 1, len(subjects))
    timings.update(fit=fit_time, irl=irl_time, solve=solve_time, simulate=sim_time)

    t = time.perf_counter()
    full_fit = fit_mixture(
        demos,
        k_min=s.k_min,
        k_max=s.k_max,
        restarts=s.restarts,
        method=s.mixture_method,
        seed=s.seed,  # type: ignore[arg-type]
    )
    timings["full_fit"] = time.perf_counter() - t
    robustness = RobustnessResult(
        epsilon=tuple(float(e) for e in s.epsilons),
        subjects=subjects,
        rewards={name: torch.stack(v, 1) for name, v in rewards.items()},  # (E, S, R)
    )
    online = None
    if online_state is not None:
        online = RobustnessResult(
            epsilon=robustness.epsilon,
            subjects=subjects,
            rewards={n: torch.stack(v, 1) for n, v in online_state["rewards"].items()},
        )
        timings["online"] = online_state["time"]
        for fold, wait in zip(folds, online_state["turn_taking"]):
            fold["turn_taking"] = wait
    separation = None
    if sampler is not None:
        from torchhrc.experiments.separation import separation_study

        separation = separation_study(task, sampler.executions,
                                      threshold=s.separation_threshold, seed=s.seed)  # fmt: skip
        timings["separation"] = separation.pop("time_s", 0.0)
    timings["total"] = time.perf_counter() - start
    timings["total_cpu"] = time.process_time() - cpu_start
    return {
        "separation": separation,
        "online": online,
        "settings": settings,
        "demonstrations": demos,
        "task": task,
        "expert": expert,
        "robustness": robustness,
        "folds": folds,
        "full_fit": full_fit,
        "timings": timings,
    }


def metrics_from_study(study: dict[str, Any]) -> dict[str, Any]:
    """The ``metrics.json`` content (deterministic for a seed: no timings)."""
    from torchhrc.experiments.robustness import mean_ci95

    s: StudySettings = study["settings"]
    rob: RobustnessResult = study["robustness"]
    folds = study["folds"]

    def rounded(x: torch.Tensor) -> list[float]:
        return [round(float(v), 6) for v in x.tolist()]

    subject_ci = {}
    for name in POLICY_NAMES:
        subject_ci[name] = rounded(mean_ci95(rob.subject_means(name), over="subjects")[1])
    return {
        "subjects": len(rob.subjects),
        "k": int(study["full_fit"].k),
        "objects": study["full_fit"].objects,
        "k_per_fold": [f["k"] for f in folds],
        "loo_accuracy": sum(f["correct"] for f in folds) / len(folds),
        "epsilon": list(rob.epsilon),
        "reward": {name: rounded(rob.mean(name)) for name in POLICY_NAMES},
        "reward_ci95": {name: rounded(rob.ci95(name)) for name in POLICY_NAMES},
        "reward_ci95_subjects": subject_ci,
        "runs_per_subject": rob.runs_per_subject,
        **_online_metrics(study.get("online"), rounded),
        "demonstrations_per_subject": s.demos,
        "positions": s.positions,
        "seed": s.seed,
        "settings": {
            "k_min": s.k_min,
            "k_max": s.k_max,
            "restarts": s.restarts,
            "mixture_method": s.mixture_method,
            "solver": "sarsop",
            "solver_time": s.solver_time,
            "solver_max_iterations": s.solver_max_iterations,
            "irl_iterations": s.irl_iterations,
        },
        "folds": [
            {
                "subject": f["subject"],
                "true_type": f["true_type"],
                "predicted_type": f["predicted_type"],
                "k": f["k"],
                "cluster_names": f["cluster_names"],
                "posterior": [round(p, 6) for p in f["posterior"]],
                **({"turn_taking": f["turn_taking"]} if "turn_taking" in f else {}),
            }
            for f in folds
        ],
        "paper": PAPER,
        **_separation_metrics(study.get("separation"), s),
    }


def _separation_metrics(separation: dict[str, Any] | None, s: StudySettings) -> dict[str, Any]:
    """``separation`` (summary per case, policy and type; the sampling) or nothing."""
    if separation is None:
        return {}
    if not separation.get("available"):
        return {"separation": {"available": False, "note": separation.get("note", "")}}
    return {
        "separation": {
            "available": True,
            "threshold_m": separation["threshold_m"],
            "epsilon": s.separation_epsilon,
            "runs_per_subject": s.separation_runs,
            "subjects_per_type": s.separation_subjects,
            **separation["summary"],
        }
    }


def reproduce_place_and_drill(
    out_dir: str | os.PathLike[str],
    *,
    seed: int = 0,
    subjects: int | None = None,
    runs: int | None = None,
    quick: bool = False,
    force: bool = False,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Reproduce the place-and-drill study and write the report into ``out_dir``.

    Args:
        out_dir: output directory; created; must be empty unless ``force``.
        seed: the seed of everything (same seed, same ``metrics.json``).
        subjects: number of simulated subjects (default 18, the paper's; 6 with ``quick``).
        runs: simulated executions per subject per epsilon (default 100, the paper's; 20
            with ``quick``).
        quick: a small version (6 subjects, 20 runs, smaller searches) for tests.
        force: write into a non-empty ``out_dir`` (files of the same name are replaced).
        progress: ``progress(stage, done, total)`` callback.

    Returns:
        The metrics written to ``metrics.json``.

    Raises:
        FileExistsError: ``out_dir`` is not empty and ``force`` is False.
        ModelError: invalid settings.
    """
    from torchhrc.experiments.report import write_report

    for name, value, low in (("subjects", subjects, 2), ("runs", runs, 1)):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"expected {name} to be an int, got {type(value).__name__}")
        if value < low:
            raise ModelError(f"expected {name} >= {low}, got {value}")
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise TypeError(f"expected seed to be an int, got {type(seed).__name__}")
    settings = StudySettings.quick(seed=seed) if quick else StudySettings(seed=seed)
    settings = dataclasses.replace(
        settings,
        subjects=settings.subjects if subjects is None else subjects,
        runs=settings.runs if runs is None else runs,
    )
    path = prepare_output_dir(out_dir, force=force)
    # Every tensor here is tiny (27 states): one intra-op thread is the fastest, and it keeps
    # the run from spin-waiting on a shared machine (measured 70x on 2 busy cores).
    with torch_threads(1):
        study = run_study(settings, progress=progress)
    metrics = metrics_from_study(study)
    write_report(path, study, metrics)
    return metrics
