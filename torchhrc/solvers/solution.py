"""The common result of every POMDP/MOMDP solver: a policy and bounds on the optimal value.

Example:
    >>> import torch
    >>> from torchhrc.solvers.policy import AlphaVectorPolicy
    >>> p = AlphaVectorPolicy(torch.zeros(1, 2, dtype=torch.float64), torch.tensor([0]))
    >>> Solution(p, lower=1.0, upper=1.5).gap
    0.5
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from torchhrc.errors import ModelError
from torchhrc.solvers.policy import AlphaVectorPolicy

__all__ = ["Solution"]


@dataclass(frozen=True)
class Solution:
    """A solver's result (the protocol of DESIGN.md: ``solve(model, config) -> Solution``).

    Args:
        policy: the alpha-vector policy (its value at the initial belief is ``lower``).
        lower: a lower bound on the optimal value at the initial belief (the value the policy
            guarantees).
        upper: an upper bound on the optimal value at the initial belief (``inf`` if the
            solver has none).
        history: diagnostics over time, one dict per progress report with at least
            ``time_s``, ``lower``, ``upper``, ``n_alphas`` (solvers add e.g. ``n_beliefs``;
            SARSOP and PBVI add ``stop_reason`` to the last one).
        info: free-form final diagnostics (iterations, ``stop_reason``, ...).

    Raises:
        ModelError: a bound is NaN, or ``lower > upper`` beyond round-off.
    """

    policy: AlphaVectorPolicy
    lower: float
    upper: float
    history: list[dict[str, Any]] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.policy, AlphaVectorPolicy):
            raise TypeError(
                f"expected policy to be an AlphaVectorPolicy, got {type(self.policy).__name__}"
            )
        lower, upper = float(self.lower), float(self.upper)
        if math.isnan(lower) or math.isnan(upper):
            raise ModelError(f"bounds must not be NaN, got lower={lower}, upper={upper}")
        if lower > upper + 1e-6 * max(1.0, abs(upper)):
            raise ModelError(f"lower bound {lower} exceeds upper bound {upper}")
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def stop_reason(self) -> str | None:
        """Why the solver stopped (``info["stop_reason"]``; None if it does not say):
        ``"precision"``, ``"time_limit"``, ``"memory"`` (the solver's ``memory_limit``),
        ``"max_iterations"``, ``"callback"``, ``"interrupted"``, or a solver's own reason."""
        reason = self.info.get("stop_reason")
        return None if reason is None else str(reason)

    @property
    def gap(self) -> float:
        """``upper - lower`` (never negative)."""
        return max(0.0, self.upper - self.lower)

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dict: lower, upper, gap, n_alphas, time_s (of the last history entry)."""
        time_s = self.history[-1].get("time_s", 0.0) if self.history else 0.0
        return {
            "lower": self.lower,
            "upper": self.upper,
            "gap": self.gap,
            "time_s": float(time_s),
            "n_alphas": self.policy.num_vectors,
        }
