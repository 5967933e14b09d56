"""The budget settings every solver's config shares (internal): what ``time_limit`` counts,
the memory limit, and the checkpoints of the policy so far.

:class:`~torchhrc.solvers.sarsop.SARSOPConfig` and :class:`~torchhrc.solvers.pbvi.PBVIConfig`
derive from :class:`SolverBudget`, which declares these fields once and checks them in its
``__post_init__`` (a derived config calls it first, then checks its own fields). Each config
documents the fields in its own docstring, with what its solver does with them.

Example:
    >>> SolverBudget(memory_limit=-1.0)
    Traceback (most recent call last):
    ...
    ValueError: expected memory_limit to be None or a positive number of bytes, got -1.0
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from torchhrc.solvers._memory import check_checkpoint, check_memory_limit
from torchhrc.solvers.clock import Clock, check_clock
from torchhrc.solvers.solution import Solution

__all__ = ["SolverBudget"]


@dataclass(frozen=True, kw_only=True)
class SolverBudget:
    """The fields of a solver's budget, checked once (keyword-only).

    Attributes:
        clock: what ``time_limit`` counts: ``"wall"``, ``"process"`` or a callable
            (:mod:`torchhrc.solvers.clock`).
        memory_limit: bytes of resident memory the process may hold (None: no limit;
            ``MemoryGuard`` in ``torchhrc/solvers/_memory.py``).
        memory_reserve: bytes kept free under ``memory_limit`` per byte of the policy's
            vectors, for what follows a stop or a checkpoint.
        policy_interval: every this many seconds of ``clock``, call ``checkpoint`` with the
            solution so far (None: never). Both or neither must be given.
        checkpoint: ``Solution -> None``, called every ``policy_interval`` seconds.
    """

    clock: Clock = "wall"
    memory_limit: float | None = None
    memory_reserve: float = 1.5
    policy_interval: float | None = None
    checkpoint: Callable[[Solution], None] | None = None

    def __post_init__(self) -> None:
        check_memory_limit(self.memory_limit, reserve=self.memory_reserve)
        check_checkpoint(self.policy_interval, self.checkpoint)
        check_clock(self.clock)
