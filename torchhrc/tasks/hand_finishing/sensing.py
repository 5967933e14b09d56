"""What the robot senses of the person's hand, and the hand models it learns.

The sensor sees the person's hand in the horizontal plane, discretised on a 4 x 12 grid
(:func:`observation_grid`). The simulated persons' hands go to a point :data:`TRUE_HAND_LOC`
from the centre of the surface they work on, with Gaussian noise of a given spread
(:func:`true_observation`, the generating model; the hands walk there with
:class:`~torchhrc.tasks.hand_finishing.person.HandMotion`). From hand tracks of such persons,
type unknown (:func:`hand_tracks`), the robot learns

* the paper's static Gaussian per type and configuration (:func:`learn_static_observation`,
  :func:`torchhrc.pomdp.observation_fit.fit_observation_model`), and
* the approach model (:func:`learn_approach_observation`,
  :class:`torchhrc.pomdp.approach_observation.ApproachObservation`): a learned motion per type
  towards a Gaussian around the surface;

:func:`observation_fit_error` scores a learned model's stationary part against the generating
one. These are the models of the hand-finishing study
(:func:`torchhrc.experiments.hand_finishing.run_study`) and of the task's env.

Example:
    >>> import torch
    >>> from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
    >>> from torchhrc.tasks.hand_finishing.model import HandFinishingTask
    >>> task = HandFinishingTask.build(
    ...     feasible=torch.ones(1, 1, 3, 2, dtype=torch.bool), work_units=2,
    ...     geometry=BoxGeometry(horizontal=(0.0,), vertical=(0.2,), tilt=(-0.5, 0.0, 0.5)))
    >>> true_observation(task, 0.2).log_probs().shape  # (X, Y, O)
    torch.Size([15, 2, 48])
"""

from __future__ import annotations

from typing import Any

import torch

from torchhrc.pomdp.approach_observation import ApproachObservation, fit_approach_observation
from torchhrc.pomdp.observation import ObservationGrid
from torchhrc.pomdp.observation_fit import fit_observation_model
from torchhrc.tasks.hand_finishing.model import HandFinishingTask
from torchhrc.tasks.hand_finishing.person import simulate_hand_tracks
from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings

__all__ = [
    "APPROACH_START_GUESS",
    "TRUE_HAND_LOC",
    "hand_tracks",
    "learn_approach_observation",
    "learn_static_observation",
    "observation_fit_error",
    "observation_grid",
    "true_observation",
]

#: True hand position relative to the worked surface's centre (m): a little towards the person.
TRUE_HAND_LOC = (0.1, 0.0)

#: Initial guess of the approach model's start (m): the centre of :func:`observation_grid`.
APPROACH_START_GUESS = (0.85, 0.0)


def observation_grid() -> ObservationGrid:
    """The 4 x 12 grid (0.2 m cells) over the horizontal plane in front of the robot."""
    return ObservationGrid.uniform((0.45, 1.25), (-1.2, 1.2), (4, 12))


def true_observation(task: HandFinishingTask, noise: float) -> Any:
    """The generating hand model of ``task``'s persons: their hands at :data:`TRUE_HAND_LOC` from
    the worked surface's centre, Gaussian noise ``noise`` (m, per axis), on
    :func:`observation_grid` (a
    :class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation`, ``log_probs()`` of shape
    ``(X, Y, O)``)."""
    return task.observation_model(
        observation_grid(), loc=torch.tensor(TRUE_HAND_LOC), scale=torch.tensor([noise, noise])
    )


def hand_tracks(task: HandFinishingTask, noise: float, settings: HandFinishingSettings) -> Any:
    """The hand tracks (simulated persons of both types at ``noise``) both models learn from.

    Args:
        task: the true task (the persons' types and rewards).
        noise: the sensor's noise (m, per axis) of :func:`true_observation`.
        settings: ``tracks`` tracks of ``track_length`` steps, hands moving by ``motion``,
            seeded by ``seed + 1``.

    Returns:
        The :func:`~torchhrc.tasks.hand_finishing.person.simulate_hand_tracks` tracks.
    """
    true_obs = true_observation(task, noise)
    return simulate_hand_tracks(
        task.momdp(true_obs),
        true_obs,
        num_tracks=settings.tracks,
        length=settings.track_length,
        motion=settings.motion,
        seed=settings.seed + 1,
    )


def observation_fit_error(model: Any, noise: float) -> float:
    """Max abs error (m) of a stationary model's hand offsets and noise against the
    generating :data:`TRUE_HAND_LOC` and ``noise``.

    Args:
        model: a :class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation` (``loc`` and
            ``log_scale`` of shape ``(..., 2)``), e.g. an approach model's ``stationary``.
        noise: the generating noise (m, per axis).
    """
    with torch.no_grad():
        loc_err = (model.loc.reshape(-1, 2) - torch.tensor(TRUE_HAND_LOC)).abs().max()
        scale_err = (model.log_scale.exp().reshape(-1, 2) - noise).abs().max()
    return float(max(loc_err, scale_err))


def learn_static_observation(
    task: HandFinishingTask,
    robot_task: HandFinishingTask,
    noise: float,
    settings: HandFinishingSettings,
) -> tuple[Any, Any, float]:
    """Learn the paper's static observation model from hand tracks at ``noise``, type unknown.

    Args:
        task: the true task, whose simulated persons make the tracks (:func:`hand_tracks`).
        robot_task: the robot's task (its types are the clusters'); the model is its
            ``observation_model``, started at the surface centres with spread 0.35 m and fitted
            with :func:`~torchhrc.pomdp.observation_fit.fit_observation_model`
            (``settings.fit_steps`` steps, learning rate 0.05, seeded by ``settings.seed``).
        noise: the sensor's noise (m, per axis).
        settings: the study's settings.

    Returns:
        ``(learned model, ObservationFit, max abs error of its means and standard
        deviations against the generating TRUE_HAND_LOC and noise)``.
    """
    tracks = hand_tracks(task, noise, settings)
    Y = robot_task.num_types
    learned = robot_task.observation_model(
        observation_grid(), loc=torch.zeros(Y, 2), scale=torch.full((Y, 2), 0.35)
    )
    fit = fit_observation_model(
        learned, robot_task.momdp(), tracks, steps=settings.fit_steps, lr=0.05, seed=settings.seed
    )
    return learned, fit, observation_fit_error(learned, noise)


def learn_approach_observation(
    task: HandFinishingTask,
    robot_task: HandFinishingTask,
    noise: float,
    settings: HandFinishingSettings,
) -> tuple[ApproachObservation, Any]:
    """Learn the approach model (:mod:`torchhrc.pomdp.approach_observation`) from the same hand
    tracks as :func:`learn_static_observation`, type unknown; start at the grid's centre.

    Args:
        task: the true task, whose simulated persons make the tracks (:func:`hand_tracks`).
        robot_task: the robot's task; the approach model's target is its
            ``observation_model`` (started as in :func:`learn_static_observation`), its rate
            starts at 0.5 and its start at :data:`APPROACH_START_GUESS`; fitted with
            :func:`~torchhrc.pomdp.approach_observation.fit_approach_observation`
            (``settings.approach_fit_steps`` steps, learning rate 0.05).
        noise: the sensor's noise (m, per axis).
        settings: the study's settings.

    Returns:
        ``(learned ApproachObservation, its fit)``.
    """
    tracks = hand_tracks(task, noise, settings)
    Y = robot_task.num_types
    target = robot_task.observation_model(
        observation_grid(), loc=torch.zeros(Y, 2), scale=torch.full((Y, 2), 0.35)
    )
    model = ApproachObservation(target, approach=0.5, start=APPROACH_START_GUESS)
    fit = fit_approach_observation(
        model, robot_task.momdp(), tracks, steps=settings.approach_fit_steps, lr=0.05
    )
    return model, fit
