"""The place-and-drill task's stated rewards, written out by hand (not read from the library),
for the tests of the env (tests/envs) and of the online study (tests/experiments)."""

from __future__ import annotations

#: The task's stated rewards (``models/place_and_drill_expert.json`` and
#: docs/place_and_drill.md: a safe person penalises drilling while a position is still empty,
#: drill_early -10, wait_early 0; an efficient one rewards it and penalises waiting then,
#: drill_early +10, wait_early -5).
STATED_REWARD = {
    "safe": {"drill_ready": 10, "drill_early": -10, "wait_early": 0, "wait_late": -5,
             "wait_idle": 0, "drill_invalid": -5},
    "efficient": {"drill_ready": 10, "drill_early": 10, "wait_early": -5, "wait_late": -5,
                  "wait_idle": 0, "drill_invalid": -5},
}  # fmt: skip


def stated_reward(bench: str, action: int, label: str) -> float:
    """Reward of robot ``action`` (0 wait, 1 + p drill p) on ``bench`` (e.g. ``"PED"``) for a
    person of type ``label``, from the situation definitions of the task; 0 once all is
    drilled."""
    if set(bench) == {"D"}:
        return 0.0
    empty, pending = "E" in bench, "P" in bench
    if action == 0:
        situation = "wait_idle" if not pending else ("wait_early" if empty else "wait_late")
    elif bench[action - 1] != "P":
        situation = "drill_invalid"
    else:
        situation = "drill_early" if empty else "drill_ready"
    return float(STATED_REWARD[label][situation])
