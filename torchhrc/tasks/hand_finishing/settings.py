"""Settings of the hand-finishing study: the box grid, the persons' hands, the solves, the runs.

:class:`HandFinishingSettings` is what :func:`torchhrc.experiments.hand_finishing.run_study`
(and its sweeps) runs, and what the task's env
(:func:`~torchhrc.tasks.hand_finishing.env.quick_hand_finishing_task`) takes its quick
instance from; ``create(quick=...)`` gives the paper-size and the quick presets.

Example:
    >>> s = HandFinishingSettings.create(quick=True)
    >>> s.work_units, s.paper_noise, s.geometry.shape
    (2, 0.2, (3, 1, 3))
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
from torchhrc.tasks.hand_finishing.model import RewardSettings
from torchhrc.tasks.hand_finishing.person import HandMotion

__all__ = ["HandFinishingSettings"]


@dataclass(frozen=True, kw_only=True)
class HandFinishingSettings:
    """Settings of the study (``create(quick=...)`` gives the two presets).

    Attributes:
        geometry: box configuration grid.
        work_units: ``W`` per side.
        paper_noise: the hand noise (m, per axis) of the headline numbers.
        noise_levels: noise levels of the waiting / accuracy table.
        episodes: closed-loop episodes per noise level (half of each type).
        steps: steps per episode.
        tracks, track_length: hand tracks for learning the observation model.
        fit_steps: optimiser steps of the observation fit.
        solve_time: SARSOP time limit (s) of each solve whose policy is simulated: a safety
            net only, far above the solve times, so that the solves stop on
            ``plan_precision`` or ``max_iterations`` (deterministic) on slow machines too.
        max_iterations: cap on the SARSOP iterations of those solves (the default run's
            solves reach ``plan_precision`` within 3 to 20 iterations).
        precision: target gap of the factored-vs-flat measurement.
        plan_precision: target gap of the solves whose policies are simulated (tight: the
            value of waiting for one more observation is a fraction of ``unwanted_cost``, and a
            looser target can stop SARSOP at its initial lower bound, which never waits).
        flat_time: time limit (s) of each solve of the speed-up measurement (a timing, not
            part of the deterministic results).
        motion: how the simulated persons' hands move.
        approach_fit_steps: optimiser steps of the approach model's fit.
        rewards: the task's rewards (default: the unwanted-move cost priced from a risk
            tolerance of 0.02, :class:`~torchhrc.tasks.hand_finishing.RewardSettings`).
        baseline_unwanted_cost: the unwanted-move cost of the baseline robot reported beside
            the study's (the paper's static Gaussian model as filter and planning model, the
            cost before issue 12: 2.0); ``None`` skips the baseline.
        sim: replay one episode per true type in the SAPIEN scene when SAPIEN is installed.
        speedup: measure factored vs flat SARSOP (a timing; sweeps turn it off).
        subjects: demonstrating subjects whose demonstrations are clustered into types (half
            left-first, half right-first).
        speedup_horizontal: indices of the horizontal positions kept in the instance of the
            factored-vs-flat measurement (``None``: the study's own MOMDP). At the paper's
            size the flat POMDP does not fit in memory (its ``Z`` has ``A * X * Y * X * O``,
            about 640 million, entries), so the default measures a reduced instance.
        speedup_work_units: ``W`` of that instance.
        seed: the seed of everything.
    """

    geometry: BoxGeometry
    work_units: int
    paper_noise: float
    noise_levels: tuple[float, ...]
    episodes: int
    steps: int
    tracks: int
    track_length: int
    fit_steps: int
    solve_time: float
    precision: float
    flat_time: float
    max_iterations: int = 200
    plan_precision: float = 0.02
    speedup_horizontal: tuple[int, ...] | None = None
    speedup_work_units: int | None = None
    motion: HandMotion = field(default_factory=HandMotion)
    approach_fit_steps: int = 150
    rewards: RewardSettings = field(default_factory=RewardSettings)
    baseline_unwanted_cost: float | None = 2.0
    sim: bool = True
    speedup: bool = True
    subjects: int = 6
    seed: int = 0

    @classmethod
    def create(cls, *, quick: bool = False, seed: int = 0) -> HandFinishingSettings:
        """The default study (the paper's size, ~2000 states) or a quick small one."""
        if quick:
            return cls(
                geometry=BoxGeometry(
                    horizontal=(-0.3, 0.0, 0.3),
                    vertical=(0.2,),
                    tilt=(-math.pi / 6, 0.0, math.pi / 6),
                ),
                work_units=2,
                paper_noise=0.2,
                noise_levels=(0.1, 0.2, 0.4),
                episodes=200,
                steps=12,
                tracks=40,
                track_length=8,
                fit_steps=60,
                solve_time=120.0,
                precision=0.1,
                flat_time=10.0,
                seed=seed,
            )
        return cls(
            geometry=BoxGeometry(),
            work_units=6,
            paper_noise=0.2,
            noise_levels=(0.1, 0.2, 0.3, 0.4),
            episodes=200,
            steps=30,
            tracks=60,
            track_length=20,
            fit_steps=80,
            solve_time=600.0,
            precision=0.5,
            flat_time=120.0,
            speedup_horizontal=(1, 2, 3),
            speedup_work_units=3,
            seed=seed,
        )
