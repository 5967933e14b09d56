"""Reproduction of the hand-finishing study (paper, "Online estimation of human type").

Pipeline (:func:`reproduce_hand_finishing`):

1. kinematic checks of every box configuration (Panda reach, person comfort;
   :func:`torchhrc.tasks.hand_finishing.geometry.feasible_box_configurations`); the others leave
   the MOMDP;
2. demonstrations of 6 simulated subjects (3 left-first, 3 right-first, labels hidden) are
   clustered with the Markov-chain mixture (BIC picks ``k``); each cluster becomes a value of
   ``y`` and is mapped to a preference by its learned transitions
   (``P(present_right | work_left)`` against ``P(present_left | work_right)``);
3. at each noise level, the robot's hand model is learned from hand tracks of the simulated
   persons (their hands walk towards the side they work on,
   :mod:`torchhrc.tasks.hand_finishing.person`) with the type unknown: the approach model
   (:func:`torchhrc.pomdp.approach_observation.fit_approach_observation`, a learned motion per
   type), and, for the baseline, the paper's static Gaussian
   (:func:`torchhrc.pomdp.observation_fit.fit_observation_model`); both are compared with the
   generating one;
4. the MOMDP is solved with SARSOP in the factored form on the approach model's stationary
   part (the hand at its target: a MOMDP's ``Z`` cannot hold the hand's history), with the
   unwanted-move cost priced from the risk tolerance
   (:meth:`~torchhrc.tasks.hand_finishing.model.HandFinishingTask.unwanted_cost_for_risk`); the
   same solve on the flat POMDP (``to_pomdp``) of a reduced instance gives the speed-up at
   the same bound gap;
5. closed-loop episodes against simulated persons of each type, the approach model as the
   robot's belief filter: the robot's waiting before its first move and the type accuracy
   (the MAP type at its first move), over noise levels, beside the baseline robot (the
   static model as filter and planning model, ``baseline_unwanted_cost``, the robot before
   issue 12);
6. when SAPIEN is installed (the ``sim`` extra), one episode per true type is replayed in the
   physics scene (:func:`torchhrc.tasks.hand_finishing.replay.replay_box_moves`): the arm
   follows the policy's box moves with joint position targets, and the box's settle error at
   each commanded pose is reported.

Determinism: every solve whose policy is simulated stops on its precision or on
``max_iterations`` (the time limit is only a safety net, far above the solve times), and
every random draw is seeded, so a seed gives the same ``metrics.json`` on any machine except
for the timing fields (:data:`TIMING_KEYS`).

Example:
    >>> s = HandFinishingSettings.create(quick=True)
    >>> s.work_units, s.paper_noise
    (2, 0.2)
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import torch

from torchhrc._deprecation import moved_attribute
from torchhrc.errors import ModelError
from torchhrc.experiments.place_and_drill import prepare_output_dir
from torchhrc.experiments.report import _pyplot, _save, write_json_atomic, write_text_atomic
from torchhrc.pomdp.approach_observation import ApproachObservation
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.tasks.hand_finishing.collaborative import (
    HandFinishingCollaborativeTask,
    first_sides_from_chains,
)
from torchhrc.tasks.hand_finishing.model import SIDES, HandFinishingTask
from torchhrc.tasks.hand_finishing.person import (
    Episodes,
    simulate_demonstrations,
    simulate_episodes,
)
from torchhrc.tasks.hand_finishing.sensing import (
    TRUE_HAND_LOC,
    learn_approach_observation,
    learn_static_observation,
    observation_fit_error,
    observation_grid,
    true_observation,
)
from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings
from torchhrc.tasks.hand_finishing.speedup import speedup_momdp
from torchhrc.tasks.pipeline import solve_momdp

__all__ = [
    "METRIC_KEYS",
    "TIMING_KEYS",
    "HandFinishingSettings",
    "check_hand_finishing_metrics",
    "cluster_preferences",
    "reproduce_hand_finishing",
]

Progress = Callable[[str, int, int], None]

# The study's settings and hand models live with the task (issue 32):
# torchhrc.tasks.hand_finishing.settings and .sensing; HandFinishingSettings, TRUE_HAND_LOC and
# observation_grid stay importable from here, APPROACH_START_GUESS is a deprecated alias.

#: Keys every ``metrics.json`` has.
METRIC_KEYS: tuple[str, ...] = (
    "n_states",
    "type_accuracy",
    "mean_wait_steps",
    "reachable_fraction",
    "solve_time_s",
    "factored_speedup",
    "observation_fit_error",
)

#: Metrics that measure time (they differ between runs of the same seed).
TIMING_KEYS: tuple[str, ...] = ("solve_time_s", "factored_speedup", "speedup_detail", "sim_time_s")


def cluster_preferences(fit: Any, vocabulary: tuple[tuple[str, str], ...]) -> tuple[str, ...]:
    """Map each cluster to a first side from its learned transition matrix.

    A left-first person goes from working the left side to the robot presenting the right
    one; a right-first person the other way round. Cluster ``k`` is ``"left"``-first when
    ``T[k, work_left, present_right] + T[k, work_left, work_right] >
    T[k, work_right, present_left] + T[k, work_right, work_left]``.
    """
    return first_sides_from_chains(fit.model.transition, vocabulary)


def _qmdp_upper(model: Any) -> torch.Tensor:
    from torchhrc.solvers import qmdp_vectors

    return qmdp_vectors(model)


def _solve(model: Any, time_limit: float, precision: float, seed: int, *,
           typed_bound: bool, qmdp_upper: bool = False,
           max_iterations: int | None = None) -> tuple[Any, float]:  # fmt: skip
    from torchhrc.solvers import SARSOPConfig, solve

    config = SARSOPConfig(
        time_limit=time_limit,
        precision=precision,
        max_iterations=max_iterations,
        seed=seed,
        lower_bound_init=type_policy_lower_bound if typed_bound else None,
        upper_bound_init=_qmdp_upper if qmdp_upper else None,
    )
    start = time.perf_counter()
    # the robot's plan (the typed lower bound, as the pipeline solves a task's MOMDP) goes
    # through the pipeline's solve_momdp, with these settings; the factored-vs-flat timing
    # compares the solver on two forms (blind lower bound, the flat POMDP too): solve()
    sol = solve_momdp(model, config=config) if typed_bound else solve(model, config)
    return sol, time.perf_counter() - start


def _time_to_gap(solution: Any, target: float) -> float | None:
    for entry in solution.history:
        if entry["upper"] - entry["lower"] <= target + 1e-12:
            return float(entry["time_s"])
    return None


def factored_vs_flat(model: Any, *, precision: float, time_limit: float, flat_time: float,
                     seed: int = 0) -> dict[str, Any]:  # fmt: skip
    """Time SARSOP on a MOMDP, factored and flat (``to_pomdp``), to the same bound gap.

    Both solves use the same initialisers: blind-policy lower bound and QMDP upper bound
    (FIB, SARSOP's default, is not interruptible within one sweep, and one FIB sweep of the
    flat POMDP of the task, with its ``X * O`` observations, takes minutes). The
    factored solve runs to ``precision`` (or ``time_limit``); the target gap is the gap it
    reached; the flat solve runs to that gap (or ``flat_time``). Times are read from the
    solvers' histories (wall clock since the solve started, initialisation included). When
    the flat solve does not reach the gap, its time limit stands in and the speed-up is a
    lower bound (``flat_reached_gap`` False).

    Returns:
        ``{"factored_time_s", "flat_time_s", "target_gap", "flat_gap", "flat_reached_gap",
        "speedup", "n_states", "n_flat_observations"}``.
    """
    fact, t_total = _solve(model, time_limit, precision, seed, typed_bound=False,
                           qmdp_upper=True)  # fmt: skip
    target = max(fact.gap, precision)
    t_fact = _time_to_gap(fact, target)
    t_fact = t_total if t_fact is None else t_fact
    flat, t_flat_total = _solve(model.to_pomdp(), flat_time, target, seed, typed_bound=False,
                                qmdp_upper=True)  # fmt: skip
    t_flat = _time_to_gap(flat, target)
    reached = t_flat is not None
    t_flat = t_flat_total if t_flat is None else t_flat
    return {
        "factored_time_s": t_fact,
        "flat_time_s": t_flat,
        "target_gap": target,
        "flat_gap": flat.gap,
        "flat_reached_gap": bool(reached),
        "speedup": t_flat / max(t_fact, 1e-9),
        "n_states": model.num_observed * model.num_hidden,
        "n_flat_observations": model.num_observed * model.num_observations,
    }


def _episodes(
    task: HandFinishingTask,
    robot_momdp: Callable[[Any], Any],
    noise: float,
    settings: HandFinishingSettings,
    learned: Any,
    *,
    observer: ApproachObservation | None = None,
) -> tuple[Episodes, Any, float]:
    """Solve the robot's MOMDP (``robot_momdp(learned)``: the task pipeline's model with the
    ``learned`` observation model) and run it against simulated persons whose sensed hands
    have ``noise`` (half of each type; their rewards are ``task``'s); the robot's belief
    filter is ``observer`` when given (an approach model whose stationary part is
    ``learned``), else the planning model's ``Z``."""
    true_obs = true_observation(task, noise)
    truth = task.momdp(true_obs)
    robot = robot_momdp(learned)
    # QMDP upper bound: FIB's first sweep at the paper's size can use up the time budget
    solution, t_solve = _solve(robot, settings.solve_time, settings.plan_precision,
                               settings.seed, typed_bound=True, qmdp_upper=True,
                               max_iterations=settings.max_iterations)  # fmt: skip
    types = torch.arange(settings.episodes) % task.num_types
    ep = simulate_episodes(robot, solution.policy, truth, true_obs, types, steps=settings.steps,
                           motion=settings.motion, seed=settings.seed + 7,
                           observer=observer)  # fmt: skip
    return ep, solution, t_solve


def _accuracy(ep: Episodes, true_sides: tuple[str, ...], robot_sides: tuple[str, ...]) -> float:
    map_y = ep.belief_at_first_move().argmax(-1)
    guess = torch.tensor([SIDES.index(robot_sides[int(y)]) for y in map_y])
    truth = torch.tensor([SIDES.index(true_sides[int(y)]) for y in ep.types])
    return float((guess == truth).double().mean())


def _replay_in_sapien(task: HandFinishingTask, ep: Episodes, *,
                      seed: int) -> dict[str, Any]:  # fmt: skip
    """Replay the first episode of each true type in the SAPIEN scene (when installed)."""
    import importlib.util

    if importlib.util.find_spec("sapien") is None:
        note = "SAPIEN is not installed (pip install torchhrc[sim]): replay skipped"
        return {"available": False, "note": note}
    from torchhrc.tasks.hand_finishing.replay import replay_box_moves

    start = time.perf_counter()
    per_type = []
    for y, side in enumerate(("left", "right")):
        n = int(torch.nonzero(ep.types == y)[0])
        config = ep.observed[n] // task.num_progress  # (L + 1,) kept configuration indices
        result = replay_box_moves(task.kept[config], geometry=task.geometry, seed=seed)
        per_type.append({"true_type": f"{side}-first", "episode": n,
                         "path": result.path.tolist(), **result.summary()})  # fmt: skip
    moved = [r for r in per_type if r["moves"]]
    return {
        "available": True,
        "moves": sum(r["moves"] for r in per_type),
        "max_position_error_m": max((r["max_position_error_m"] for r in moved), default=0.0),
        "max_rotation_error_rad": max((r["max_rotation_error_rad"] for r in moved), default=0.0),
        "all_settled": all(r["all_settled"] for r in per_type),
        "episodes": per_type,
        "time_s": time.perf_counter() - start,
    }


def run_study(settings: HandFinishingSettings, *, progress: Progress | None = None,
              feasibility: Any | None = None) -> dict[str, Any]:  # fmt: skip
    """Run the study and return its results (metrics and the data behind the plots)."""
    from torchhrc.mixture import fit_mixture
    from torchhrc.tasks.hand_finishing.geometry import feasible_box_configurations

    def tick(stage: str, done: int, total: int) -> None:
        if progress is not None:
            progress(stage, done, total)

    seed = settings.seed
    stages = 6
    tick("hand-finishing", 0, stages)
    if feasibility is None:
        feasibility = feasible_box_configurations(settings.geometry, seed=seed)
    tick("hand-finishing", 1, stages)
    # 2. types found by clustering demonstrations of 6 simulated subjects
    half = settings.subjects // 2
    demos = simulate_demonstrations(
        ["left"] * half + ["right"] * (settings.subjects - half), seed=seed
    )
    # objects="raw": the types are side preferences (left/right first), mirror images of one
    # strategy, which exchangeable objects would merge into one type (docs/clustering.md)
    fit = fit_mixture(demos, k_min=1, k_max=4, seed=seed, initial=True, objects="raw")
    robot_sides = cluster_preferences(fit, demos.vocabulary)
    subject_cluster = {}
    for s, c in zip(demos.subjects, fit.assignments.tolist(), strict=True):
        subject_cluster.setdefault(s, c)
    truth_of = dict(zip(demos.subjects, demos.types or (), strict=True))
    cluster_accuracy = sum(robot_sides[c] == truth_of[s] for s, c in subject_cluster.items()) / len(
        subject_cluster
    )
    tick("hand-finishing", 2, stages)
    true_sides = ("left", "right")
    build = dict(feasible=feasibility.comfortable, reachable=feasibility.reachable,
                 geometry=settings.geometry, work_units=settings.work_units)  # fmt: skip
    task = HandFinishingTask.build(first_sides=true_sides, rewards=settings.rewards, **build)
    robot_task = HandFinishingTask.build(first_sides=robot_sides, rewards=settings.rewards,
                                         **build)  # fmt: skip

    def pipeline_momdp(base: HandFinishingTask) -> Callable[[Any], Any]:
        # the robot's model goes through the task pipeline (torchhrc.tasks.pipeline), as any
        # task's
        pipeline = HandFinishingCollaborativeTask(base)
        return lambda observation: pipeline.learned_momdp(
            demos, fit.model.transition, fit.assignments, observation
        )

    robot_momdp = pipeline_momdp(robot_task)
    baseline = settings.baseline_unwanted_cost
    if baseline is not None:  # the robot before issue 12: static model, a set cost
        old_rewards = replace(settings.rewards, unwanted_cost=baseline)
        task_old = HandFinishingTask.build(first_sides=true_sides, rewards=old_rewards, **build)
        robot_momdp_old = pipeline_momdp(
            HandFinishingTask.build(first_sides=robot_sides, rewards=old_rewards, **build)
        )

    # 3.-5. at each noise level: learn the observation models from hand tracks (type
    # unknown); solve the MOMDP on the approach model's stationary part (the hand at its
    # target: the MOMDP's Z cannot hold the hand's history) and run it against simulated
    # persons with the approach model as the robot's belief filter; the baseline robot
    # plans and filters with the static model
    noise = settings.paper_noise
    levels = sorted(set(settings.noise_levels) | {noise})
    table, runs = [], {}
    for i, level in enumerate(levels):
        learned, obs_fit, static_error = learn_static_observation(task, robot_task, level, settings)
        approach, approach_fit = learn_approach_observation(task, robot_task, level, settings)
        ep, solution, solve_time = _episodes(task, robot_momdp, level, settings,
                                             approach.stationary, observer=approach)  # fmt: skip
        runs[level] = (learned, obs_fit, approach, approach_fit, ep, solution, solve_time)
        if level in settings.noise_levels:
            row = {
                "noise": level,
                "type_accuracy": _accuracy(ep, true_sides, robot_sides),
                "mean_wait_steps": float(ep.wait_steps().double().mean()),
                "mean_belief_at_move": float(ep.belief_at_first_move().amax(-1).mean()),
                "mean_reward": float(ep.rewards.sum(-1).mean()),
                "observation_fit_error": observation_fit_error(approach.stationary, level),
                "learned_approach": float(approach.approach().detach()),
                "static_observation_fit_error": static_error,
                "solve_gap": solution.gap,
                "solve_iterations": int(solution.info["iterations"]),
            }
            if baseline is not None:
                ep_old, sol_old, _ = _episodes(task_old, robot_momdp_old, level, settings,
                                               learned)  # fmt: skip
                row["baseline_type_accuracy"] = _accuracy(ep_old, true_sides, robot_sides)
                row["baseline_mean_wait_steps"] = float(ep_old.wait_steps().double().mean())
                row["baseline_solve_iterations"] = int(sol_old.info["iterations"])
            table.append(row)
        tick("hand-finishing", 2 + (i + 1) * 2 // len(levels), stages)
    learned, obs_fit, approach, approach_fit, ep, solution, solve_time = runs[noise]
    true_obs = true_observation(task, noise)
    at_noise = next((r for r in table if r["noise"] == noise), {})
    # factored vs flat (a timing: the factored solve's limit is the flat one's)
    plan = approach.stationary  # the robot's planning model
    speed_model = speedup_momdp(settings, feasibility, robot_task, plan)
    if settings.speedup:
        speed = factored_vs_flat(speed_model, precision=settings.precision,
                                 time_limit=settings.flat_time, flat_time=settings.flat_time,
                                 seed=seed)  # fmt: skip
    else:
        speed = {"speedup": None, "note": "not measured (settings.speedup = False)"}
    tick("hand-finishing", 5, stages)
    # 6. the arm follows one episode's box moves per true type in the physics scene
    sim = (_replay_in_sapien(task, ep, seed=seed) if settings.sim
           else {"available": False, "note": "replay disabled (settings.sim = False)"})  # fmt: skip
    H, V, T = settings.geometry.shape
    metrics: dict[str, Any] = {
        "n_states": robot_task.num_states,
        "n_observed": robot_task.num_observed,
        "type_accuracy": _accuracy(ep, true_sides, robot_sides),
        "mean_wait_steps": float(ep.wait_steps().double().mean()),
        "reachable_fraction": float(task.num_configurations / (H * V * T)),
        "solve_time_s": solve_time,
        "solve_gap": solution.gap,
        "solve_iterations": int(solution.info["iterations"]),
        "solve_stop_reason": solution.info["stop_reason"],
        "factored_speedup": speed["speedup"],
        "speedup_detail": speed,
        "observation_fit_error": observation_fit_error(approach.stationary, noise),
        "mean_belief_at_move": float(ep.belief_at_first_move().amax(-1).mean()),
        "unwanted_cost": robot_task.unwanted_cost,
        "risk_tolerance": settings.rewards.risk_tolerance,
        "unwanted_cost_priced": settings.rewards.unwanted_cost is None,
        "baseline_unwanted_cost": baseline,
        "baseline_type_accuracy": at_noise.get("baseline_type_accuracy"),
        "baseline_mean_wait_steps": at_noise.get("baseline_mean_wait_steps"),
        "approach_fit": {
            "approach": float(approach.approach().detach()),
            "start": approach.start.detach().tolist(),
            "loc": approach.stationary.loc.detach().reshape(-1, 2).tolist(),
            "scale": approach.stationary.log_scale.detach().exp().reshape(-1, 2).tolist(),
            "true_approach": settings.motion.approach,
            "true_start": list(settings.motion.start),
            "log_likelihood": approach_fit.log_likelihood,
            "static_log_likelihood": obs_fit.log_likelihood,
        },
        "observation_fit": {  # the static (paper's) model, the baseline's
            "fit_error": observation_fit_error(learned, noise),
            "learned_loc": learned.loc.detach().reshape(-1, 2).tolist(),
            "learned_scale": learned.log_scale.detach().exp().reshape(-1, 2).tolist(),
            "true_loc": list(TRUE_HAND_LOC),
            "true_scale": [noise, noise],
            "log_likelihood": obs_fit.log_likelihood,
            "steps": obs_fit.steps,
        },
        "sim_settle_error_m": sim.get("max_position_error_m"),
        "sim_settle_rotation_error_rad": sim.get("max_rotation_error_rad"),
        "sim_time_s": sim.pop("time_s", None),
        "sim": sim,
        "k": fit.k,
        "cluster_sides": list(robot_sides),
        "cluster_accuracy": cluster_accuracy,
        "subjects": settings.subjects,
        "paper_noise": noise,
        "noise_table": table,
        "episodes": settings.episodes,
        "seed": seed,
    }
    tick("hand-finishing", stages, stages)
    return {"metrics": metrics, "episodes": ep, "task": task, "robot_task": robot_task,
            "learned": learned, "approach": approach, "true_obs": true_obs,
            "feasibility": feasibility, "robot_sides": robot_sides}  # fmt: skip


def check_hand_finishing_metrics(metrics: dict[str, Any]) -> None:
    """Raise :class:`ModelError` naming the first missing or ill-typed key of ``metrics``.

    Example:
        >>> check_hand_finishing_metrics({"n_states": 90})
        Traceback (most recent call last):
        ...
        torchhrc.errors.ModelError: metrics: missing key 'type_accuracy'
    """
    for key in METRIC_KEYS:
        if key not in metrics:
            raise ModelError(f"metrics: missing key {key!r}")
    if not isinstance(metrics["n_states"], int):
        raise ModelError(f"metrics: 'n_states' must be an int, got {metrics['n_states']!r}")
    for key in METRIC_KEYS[1:]:
        if not isinstance(metrics[key], float) or not math.isfinite(metrics[key]):
            raise ModelError(f"metrics: {key!r} must be a finite float, got {metrics[key]!r}")
    for key in ("type_accuracy", "reachable_fraction"):
        if not 0.0 <= metrics[key] <= 1.0:
            raise ModelError(f"metrics: {key!r} must be in [0, 1], got {metrics[key]!r}")


# ------------------------------------------------------------------------- plots
def _plot_fig4b(study: dict[str, Any], path: Path) -> None:
    """The paper's Fig. 4(b) for one episode of each true type: the hand's path in the
    horizontal plane (top view, the robot at the bottom, so the box's left side ``+y`` is on
    the left) beside the belief over the type against time; the robot's moves are marked in
    both (orange)."""
    plt = _pyplot()
    ep: Episodes = study["episodes"]
    task: HandFinishingTask = study["task"]
    sides = study["robot_sides"]
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    for row, true_y in enumerate(range(2)):
        n = int(torch.nonzero(ep.types == true_y)[0])
        moving = (ep.actions[n] != 0).tolist()  # (L,) robot moves at step t
        ax = axes[row, 0]
        if ep.hands is not None:
            hand = ep.hands[n].numpy()  # (L + 1, 2): the start, then after each step
            ax.plot(hand[:, 1], hand[:, 0], "-", color="tab:blue", lw=2, zorder=2,
                    label="hand (true path)")  # fmt: skip
            for t, m in enumerate(moving):
                if m:
                    ax.plot(hand[t : t + 2, 1], hand[t : t + 2, 0], "-", color="orange", lw=5,
                            alpha=0.7, zorder=1)  # fmt: skip
            ax.plot(hand[1:, 1], hand[1:, 0], "o", color="tab:blue", ms=3, zorder=3)
            ax.plot(hand[0, 1], hand[0, 0], "gs", ms=8, label="start", zorder=4)
        pos = ep.positions[n].numpy()  # (L, 2) sensed
        ax.plot(pos[:, 1], pos[:, 0], "x", color="0.5", ms=5, label="sensed (noisy)")
        # the surface centres the person works on, at the box's start pose
        config = int(task.start)
        for s_idx, (name, mark) in enumerate((("left", "<"), ("right", ">"))):
            pt = task.geometry.work_points(name)[tuple(task.kept[config].tolist())]
            ax.plot(float(pt[1]), float(pt[0]), mark, color="k", ms=9,
                    label="surface centres (box at start)" if s_idx == 0 else None)  # fmt: skip
            ax.annotate(name, (float(pt[1]), float(pt[0])), textcoords="offset points",
                        xytext=(0, -14), ha="center", fontsize=8)  # fmt: skip
        ax.invert_xaxis()  # top view: x forward (up), +y (the box's left) to the left
        ax.set_xlabel("lateral y (m), box's left side on the left")
        ax.set_ylabel("forward x (m)")
        ax.set_title(f"hand, top view: true type {('left', 'right')[true_y]}-first "
                     "(orange: robot moves)", fontsize=10)  # fmt: skip
        ax.legend(fontsize=7, loc="upper right")
        ax.set_aspect("equal", adjustable="datalim")
        ax = axes[row, 1]
        steps = list(range(ep.beliefs.shape[1]))
        for y, side in enumerate(sides):
            ax.plot(steps, ep.beliefs[n, :, y].numpy(), label=f"P(y={y}: {side}-first)")
        for t, m in enumerate(moving):
            if m:
                ax.axvspan(t, t + 1, color="orange", alpha=0.3, lw=0)
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("step (shaded: robot moves)")
        ax.set_ylabel("belief")
        ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _plot_observation(study: dict[str, Any], path: Path) -> None:
    """The hand's cell distribution at the start state, for each type: the generating
    target model, the approach model's stationary part (the robot's planning model, learned)
    and the paper's static model (learned, the baseline's): the static one is shifted
    towards the person and wider, since it absorbs the approach."""
    plt = _pyplot()
    task, robot_task = study["task"], study["robot_task"]
    x0 = task.x0
    grid = observation_grid()
    gx, gy = grid.shape
    with torch.no_grad():
        true_p = study["true_obs"].log_probs()[x0].exp()  # (Y, O)
        approach_p = study["approach"].stationary.log_probs()[robot_task.x0].exp()
        static_p = study["learned"].log_probs()[robot_task.x0].exp()
    fig, axes = plt.subplots(2, 3, figsize=(12, 5))
    for y, side in enumerate(("left", "right")):
        ly = study["robot_sides"].index(side) if side in study["robot_sides"] else y
        panels = (("true target", true_p[y]), ("approach model (learned)", approach_p[ly]),
                  ("static model (learned)", static_p[ly]))  # fmt: skip
        for col, (name, p) in enumerate(panels):
            ax = axes[y, col]
            ax.imshow(p.reshape(gx, gy).numpy(), origin="lower", aspect="auto",
                      extent=(-1.2, 1.2, 0.45, 1.25))  # fmt: skip
            ax.set_title(f"{name}: {side}-first, start state", fontsize=9)
            ax.set_xlabel("y (m)")
            ax.set_ylabel("x (m)")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _plot_reachable(study: dict[str, Any], path: Path) -> None:
    plt = _pyplot()
    f = study["feasibility"]
    geo = study["task"].geometry
    T = geo.shape[2]
    fig, axes = plt.subplots(1, T, figsize=(2.6 * T, 2.8), squeeze=False)
    code = f.reachable.int() + f.comfortable.any(-1).int() * f.reachable.int()
    for t in range(T):
        ax = axes[0, t]
        ax.imshow(code[:, :, t].T.numpy(), origin="lower", vmin=0, vmax=2, cmap="viridis")
        ax.set_title(f"tilt {math.degrees(geo.tilt[t]):.0f} deg", fontsize=9)
        ax.set_xlabel("horizontal index")
        ax.set_ylabel("vertical index")
    fig.suptitle("0 unreachable, 1 reachable but uncomfortable, 2 kept")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _report(metrics: dict[str, Any]) -> str:
    sp = metrics["speedup_detail"]
    af = metrics["approach_fit"]
    st = metrics.get("settings", {})
    motion = st.get("motion", {})
    lines = [
        "# Hand-finishing: online type inference from a noisy hand position",
        "",
        f"- MOMDP: {metrics['n_observed']} observed values x {len(metrics['cluster_sides'])} "
        f"types = **{metrics['n_states']} states**; kept box configurations: "
        f"{metrics['reachable_fraction']:.2f} of the grid (reach + comfort).",
        f"- Types found by clustering {metrics.get('subjects', 6)} simulated subjects: "
        f"k = {metrics['k']}, cluster "
        f"preferences {metrics['cluster_sides']}, subject accuracy "
        f"{metrics['cluster_accuracy']:.2f}.",
        "- Simulated persons: the hand walks from where the person stands "
        f"({motion.get('start', '?')} m) towards the surface they work on next, covering "
        f"{motion.get('approach', '?')} of the remaining distance per step; the sensor adds "
        "Gaussian noise.",
        "- The robot's belief filter is the approach model "
        "(`torchhrc.pomdp.approach_observation`: a learned motion per type towards a Gaussian "
        "around the surface), learned from such tracks with the type unknown: rate "
        f"{af['approach']:.3f} (true {af['true_approach']}), start "
        f"({af['start'][0]:.2f}, {af['start'][1]:.2f}) m (true {tuple(af['true_start'])}), "
        f"max error of the target offset and noise {metrics['observation_fit_error']:.3f} m. "
        "The MOMDP is solved on its stationary part (the hand at its target): the MOMDP's "
        "observation function cannot hold the hand's history.",
        f"- Price of an unwanted move: **{metrics['unwanted_cost']:.2f}**"
        + (
            f", set by the risk tolerance {metrics['risk_tolerance']} (the cost at which "
            "moving at belief b beats waiting a step only when 1 - b <= tolerance, the type "
            "known afterwards: `HandFinishingTask.unwanted_cost_for_risk`)."
            if metrics["unwanted_cost_priced"]
            else " (set directly)."
        ),
        f"- SARSOP (factored, learned model): {metrics['solve_time_s']:.1f} s, gap "
        f"{metrics['solve_gap']:.3g} after {metrics['solve_iterations']} iterations (stopped "
        f"on: {metrics['solve_stop_reason']}).",
        f"- Factored vs flat SARSOP ({sp['n_states']} states, {sp['n_flat_observations']} flat "
        f"observations; blind + QMDP initialisers, same gap {sp['target_gap']:.3g}): "
        f"{sp['factored_time_s']:.1f} s vs {sp['flat_time_s']:.1f} s "
        f"(flat reached the gap: {sp['flat_reached_gap']}; flat gap {sp['flat_gap']:.3g}), "
        f"**speed-up {metrics['factored_speedup']:.1f}x**"
        + ("" if sp["flat_reached_gap"] else " (a lower bound: the flat solve hit its limit)")
        + "."
        if sp.get("speedup") is not None
        else "- Factored vs flat SARSOP: not measured.",
        f"- At noise {metrics['paper_noise']} m: type accuracy (MAP type at the robot's first "
        f"move) **{metrics['type_accuracy']:.3f}**, mean wait before the first move "
        f"**{metrics['mean_wait_steps']:.2f} steps**, mean belief at the move "
        f"{metrics['mean_belief_at_move']:.3f}"
        + (
            f"; the baseline (the paper's static Gaussian model as filter and planning "
            f"model, unwanted cost {metrics['baseline_unwanted_cost']}): "
            f"{metrics['baseline_type_accuracy']:.3f}, wait "
            f"{metrics['baseline_mean_wait_steps']:.2f} steps."
            if metrics.get("baseline_type_accuracy") is not None
            else "."
        ),
        "",
        "## Waiting and accuracy against observation noise",
        "",
        "At each noise level the robot's observation models are learned from hand tracks at "
        "that level, and its MOMDP solved to the same precision. Baseline: the static model "
        "as filter and planning model with the unwanted cost before issue 12.",
        "",
        "| noise (m) | type accuracy | mean wait (steps) | belief at move | baseline accuracy "
        "| baseline wait | mean reward | learned rate | fit error (m) | SARSOP iterations |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in metrics["noise_table"]:
        old_acc, old_wait = row.get("baseline_type_accuracy"), row.get("baseline_mean_wait_steps")
        lines.append(
            f"| {row['noise']:.2f} | {row['type_accuracy']:.3f} | {row['mean_wait_steps']:.2f} "
            f"| {row['mean_belief_at_move']:.3f} "
            f"| {'-' if old_acc is None else f'{old_acc:.3f}'} "
            f"| {'-' if old_wait is None else f'{old_wait:.2f}'} "
            f"| {row['mean_reward']:.2f} | {row['learned_approach']:.2f} "
            f"| {row['observation_fit_error']:.3f} | {row['solve_iterations']} |"
        )
    lines += [
        "",
        "The waiting is not programmed: it is the solved policy's response to the risk of a "
        "move the person did not want.",
        "",
        "## The arm in the physics scene (SAPIEN)",
        "",
    ]
    sim = metrics["sim"]
    if sim.get("available"):
        lines += [
            "One episode per true type (those of Fig. 4(b)) replayed in the SAPIEN scene "
            "(CPU physics): the Panda follows the policy's box moves with joint position "
            "targets from its inverse kinematics.",
            "",
            "| true type | box moves | max settle error (mm) | max rotation error (mrad) "
            "| settled |",
            "|---|---|---|---|---|",
        ]
        for r in sim["episodes"]:
            lines.append(
                f"| {r['true_type']} | {r['moves']} | {1e3 * r['max_position_error_m']:.2f} "
                f"| {1e3 * r['max_rotation_error_rad']:.2f} | {r['all_settled']} |"
            )
        lines += [
            "",
            f"Settle error of the box at the commanded poses, max over {sim['moves']} moves: "
            f"**{1e3 * sim['max_position_error_m']:.2f} mm**, "
            f"{1e3 * sim['max_rotation_error_rad']:.2f} mrad.",
        ]
    else:
        lines.append(f"Not run: {sim.get('note', 'SAPIEN unavailable')}.")
    lines += [
        "",
        "## Determinism",
        "",
        "The solves stop on their precision or on max_iterations = "
        f"{st.get('max_iterations', '?')} (the time limit, {st.get('solve_time', '?')} s, is a "
        "safety net), so the same seed gives the same metrics on any machine, except "
        f"the timings ({', '.join(TIMING_KEYS)}).",
        "",
        "![Fig. 4(b)](fig4b_belief.png)",
        "",
        "![observation model](observation_model.png)",
        "",
        "![reachable configurations](reachable.png)",
        "",
    ]
    return "\n".join(lines)


def reproduce_hand_finishing(
    out_dir: str | os.PathLike[str],
    *,
    seed: int = 0,
    quick: bool = False,
    force: bool = False,
    progress: Progress | None = None,
    **_: Any,
) -> dict[str, Any]:
    """Reproduce the hand-finishing study into ``out_dir`` (report.md, PNGs, metrics.json).

    Args:
        out_dir: output directory (created; must be empty unless ``force``).
        seed: the seed of everything.
        quick: a small instance (9 configurations, 2 work units) for tests.
        force: write into a non-empty directory.
        progress: ``progress(stage, done, total)`` callback.
        **_: options of other pipelines (``subjects``, ``runs``), ignored.

    Returns:
        The metrics written to ``metrics.json``.
    """
    path = prepare_output_dir(out_dir, force=force)
    settings = HandFinishingSettings.create(quick=quick, seed=seed)
    study = run_study(settings, progress=progress)
    metrics = study["metrics"]
    metrics["settings"] = {k: v for k, v in asdict(settings).items() if k != "geometry"}
    metrics["settings"]["noise_levels"] = list(settings.noise_levels)
    check_hand_finishing_metrics(metrics)
    _plot_fig4b(study, path / "fig4b_belief.png")
    _plot_observation(study, path / "observation_model.png")
    _plot_reachable(study, path / "reachable.png")
    write_json_atomic(path / "metrics.json", metrics)
    write_text_atomic(path / "report.md", _report(metrics))
    return metrics


def __getattr__(name: str) -> object:
    return moved_attribute(
        __name__,
        name,
        {"APPROACH_START_GUESS": "torchhrc.tasks.hand_finishing.sensing"},
    )
