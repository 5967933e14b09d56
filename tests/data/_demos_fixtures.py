"""The demonstrations the tests of torchhrc.data share."""

from __future__ import annotations

from torchhrc.data import Demonstrations

H, R = "human", "robot"
SAFE = [(H, "place_A"), (H, "place_B"), (R, "drill_A"), (R, "drill_B")]
EFFICIENT = [(H, "place_B"), (R, "drill_B"), (H, "place_A"), (R, "drill_A"), (H, "wait")]


def _demos(types: bool = True) -> Demonstrations:
    return Demonstrations.from_lists(
        [SAFE, EFFICIENT, SAFE[:2], EFFICIENT[1:]],
        subjects=["s1", "s1", "s2", "s2"],
        types=["safe", "efficient", "safe", "efficient"] if types else None,
    )
