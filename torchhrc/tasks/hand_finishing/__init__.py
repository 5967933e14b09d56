"""The hand-finishing task: a MOMDP with the person's preferred side hidden.

Everything specific to the task lives in this folder (:mod:`torchhrc.experiments.hand_finishing`
only orchestrates the study and reports it):

* :mod:`.model`: the task MOMDP; :mod:`.person`: the simulated persons;
  :mod:`.collaborative`: the task through the pipeline's task interface;
* :mod:`.geometry`: the box configurations, the person's comfort and which configurations the
  task keeps (on the arm of :mod:`torchhrc.kinematics`);
* :mod:`.settings`: the study's settings; :mod:`.sensing`: the sensor grid, the generating
  hand model and the robot's learned hand models; :mod:`.speedup`: the instance of the
  factored-vs-flat measurement;
* :mod:`.env`: the gymnasium env (the ``gym`` extra); :mod:`.scene` and :mod:`.replay`: the
  SAPIEN scene of the arm holding the box (the ``sim`` extra).
"""

from __future__ import annotations

from torchhrc.tasks.hand_finishing.model import (
    ACTIONS,
    SIDES,
    HandFinishingTask,
    RewardSettings,
    count_states,
    unwanted_cost_for_risk,
)

__all__ = [
    "ACTIONS",
    "SIDES",
    "HandFinishingTask",
    "RewardSettings",
    "count_states",
    "unwanted_cost_for_risk",
]
