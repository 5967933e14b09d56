"""The hand-finishing task: a MOMDP with the person's preferred side hidden.

See :mod:`.model` (the task MOMDP) and :mod:`.person` (simulated persons).
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
