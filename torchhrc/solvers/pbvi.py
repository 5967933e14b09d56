"""Point-based value iteration (Pineau, Gordon, Thrun 2003), flat and MOMDP-factored.

PBVI alternates two phases on a finite set ``B`` of reachable beliefs, starting from
``B = {b0}``:

1. *Backups*: every belief of ``B`` is backed up at once (:mod:`torchhrc.solvers.backup`)
   against the current vectors; the new vectors join the set, which is then pruned to the
   vectors that are the maximum at some belief of ``B`` (so values on ``B`` never decrease).
2. *Expansion*: each belief simulates one step per action (stochastic simulation with
   explorative action, SSEA) and the successor farthest (L1) from ``B`` joins ``B``; the
   set at most doubles (Pineau et al. 2003, Sec. 3.2). ``expansion="random"`` takes one
   random action instead (SSRA).

The vectors start from the blind-policy lower bound, and each backed-up vector is the value
of a real plan, so ``lower = V(b0)`` is a lower bound on the optimal value at every
iteration. The upper bound is the Fast Informed Bound at ``b0`` (Hauskrecht 2000), so
``Solution.upper - Solution.lower`` bounds the policy's loss.

For a MOMDP (Ong et al. 2010) the beliefs are pairs ``(x, b_y)``, the vectors live over
``Y`` per observed ``x``, and backups run factored; ``factored=False`` solves the flat
``to_pomdp()`` model instead (for comparison). The algorithm is written once: it asks the
model only through :class:`~torchhrc.solvers.forms.base.SolverModel` (a simulation step, a
batched point backup, the bounds, the value of a policy at beliefs), picked by
:func:`~torchhrc.solvers.forms.as_solver_model`.

Anytime: the loop stops at ``time_limit``, when the gap at ``b0`` falls below ``precision``,
after ``max_iterations`` backup sweeps or ``expansions`` expansions, or on
``KeyboardInterrupt``, and returns the best policy so far.

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> solution = pbvi(tiger(), PBVIConfig(time_limit=10, expansions=4, seed=0))
    >>> solution.lower <= 19.38 <= solution.upper
    True
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP, SparsePOMDP
from torchhrc.solvers._budget import SolverBudget
from torchhrc.solvers._memory import MemoryGuard
from torchhrc.solvers.clock import clock_function
from torchhrc.solvers.forms import SolverModel, as_solver_model
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.solution import Solution

__all__ = ["PBVIConfig", "pbvi"]

logger = logging.getLogger(__name__)

#: L1 distance standing for "a belief at an observed value not yet in B" (max L1 is 2).
_NEW_X_DISTANCE = 3.0


@dataclass(frozen=True, kw_only=True)
class PBVIConfig(SolverBudget):
    """Settings of :func:`pbvi` (keyword-only; a typo is a TypeError).

    Attributes:
        time_limit: budget in seconds of ``clock``.
        precision: stop when ``upper - lower`` at ``b0`` is below this.
        max_iterations: cap on the total number of backup sweeps.
        expansions: number of belief-set expansions (the set at most doubles each time).
        backups_per_expansion: backup sweeps between two expansions (fewer when the values on
            ``B`` stop improving by more than ``precision * (1 - discount)``).
        expansion: ``"explore"`` (SSEA: the farthest successor over all actions) or
            ``"random"`` (SSRA: a random action).
        max_beliefs: cap on ``|B|``.
        factored: for a MOMDP, back up factored (True) or solve ``to_pomdp()`` (False).
        upper_bound: ``"fib"`` (Fast Informed Bound) or ``"qmdp"`` for ``Solution.upper``.
        seed: seed of the belief expansion.
        callback: called with each history entry (a dict), e.g. to print progress.
        clock: what ``time_limit`` counts: ``"wall"`` (default), ``"process"`` (the process's
            CPU seconds) or a callable (:mod:`torchhrc.solvers.clock`); checked after every
            backup sweep.
        memory_limit: bytes of resident memory the process may hold (None: no limit; the
            whole process counts, see ``MemoryGuard`` in ``torchhrc/solvers/_memory.py``).
            Checked after every backup sweep and before every expansion (which may double
            the next sweep's temporaries): the solve stops before the limit with the policy
            so far and ``stop_reason == "memory"``.
        memory_reserve: bytes kept free under ``memory_limit`` per byte of the policy's
            vectors, for what follows the stop (see
            :class:`~torchhrc.solvers.sarsop.SARSOPConfig`; default 1.5).
        policy_interval: every this many seconds of ``clock`` (checked after every backup
            sweep), call ``checkpoint`` with the solution so far (None: never; both or
            neither must be given).
        checkpoint: ``Solution -> None`` (see :class:`~torchhrc.solvers.sarsop.SARSOPConfig`).
    """

    time_limit: float = 60.0
    precision: float = 1e-3
    max_iterations: int = 10_000
    expansions: int = 8
    backups_per_expansion: int = 30
    expansion: str = "explore"
    max_beliefs: int = 4096
    factored: bool = True
    upper_bound: str = "fib"
    seed: int = 0
    callback: Callable[[dict[str, Any]], None] | None = None

    def __post_init__(self) -> None:
        super().__post_init__()  # clock, memory_limit, memory_reserve, policy_interval, checkpoint
        if not self.time_limit > 0:
            raise ValueError(f"expected time_limit > 0, got {self.time_limit}")
        if not self.precision >= 0:
            raise ValueError(f"expected precision >= 0, got {self.precision}")
        for name in ("max_iterations", "backups_per_expansion", "max_beliefs"):
            if getattr(self, name) < 1:
                raise ValueError(f"expected {name} >= 1, got {getattr(self, name)}")
        if self.expansions < 0:
            raise ValueError(f"expected expansions >= 0, got {self.expansions}")
        if self.expansion not in ("explore", "random"):
            raise ValueError(f"expected expansion in ('explore', 'random'), got {self.expansion!r}")
        if self.upper_bound not in ("fib", "qmdp"):
            raise ValueError(f"expected upper_bound in ('fib', 'qmdp'), got {self.upper_bound!r}")


class _BeliefSet:
    """Beliefs ``(M, D)`` with their observed ``x (M,)`` (all zero for a flat POMDP)."""

    def __init__(self, x: torch.Tensor, beliefs: torch.Tensor) -> None:
        self.x = x
        self.beliefs = beliefs

    def __len__(self) -> int:
        return self.beliefs.shape[0]

    def distance(self, x: torch.Tensor, beliefs: torch.Tensor) -> torch.Tensor:
        """L1 distance ``(K,)`` of each candidate to the nearest belief with the same x."""
        d = torch.cdist(beliefs, self.beliefs, p=1.0)  # (K, M)
        d = d.masked_fill(x.unsqueeze(1) != self.x.unsqueeze(0), _NEW_X_DISTANCE)
        return d.amin(1)

    def add(self, x: torch.Tensor, beliefs: torch.Tensor) -> None:
        self.x = torch.cat([self.x, x])
        self.beliefs = torch.cat([self.beliefs, beliefs])


def _expand(
    form: SolverModel,
    belief_set: _BeliefSet,
    config: PBVIConfig,
    generator: torch.Generator,
) -> int:
    """Add at most one successor per belief; returns the number added."""
    M = len(belief_set)
    A = form.num_actions
    device = belief_set.beliefs.device
    if config.expansion == "explore":
        idx = torch.arange(M, device=device).repeat_interleave(A)
        actions = torch.arange(A, device=device).repeat(M)
    else:
        idx = torch.arange(M, device=device)
        actions = torch.randint(0, A, (M,), generator=generator, device=device)
    new_x, new_b = form.simulate(belief_set.x[idx], belief_set.beliefs[idx], actions, generator)
    distance = belief_set.distance(new_x, new_b)
    if config.expansion == "explore":
        distance = distance.view(M, A)
        best = distance.argmax(1)
        rows = torch.arange(M, device=device) * A + best
        distance = distance.gather(1, best.unsqueeze(1)).squeeze(1)
        new_x, new_b = new_x[rows], new_b[rows]
    keep = distance > 1e-9
    room = config.max_beliefs - M
    new_x, new_b, distance = new_x[keep], new_b[keep], distance[keep]
    if new_b.shape[0] > room:
        order = distance.argsort(descending=True)[:room]
        new_x, new_b = new_x[order], new_b[order]
    # drop duplicates among the new beliefs themselves
    if new_b.shape[0] > 1:
        rounded = torch.cat([new_x.unsqueeze(1).to(new_b.dtype), new_b.round(decimals=9)], 1)
        _, inverse = torch.unique(rounded, dim=0, return_inverse=True)
        first = torch.full((int(inverse.max()) + 1,), new_b.shape[0], device=device)
        first = first.scatter_reduce(
            0, inverse, torch.arange(inverse.numel(), device=device), reduce="amin"
        )
        new_x, new_b = new_x[first], new_b[first]
    belief_set.add(new_x, new_b)
    return int(new_b.shape[0])


def _merge(form: SolverModel, policy: AlphaVectorPolicy, new: AlphaVectorPolicy,
           belief_set: _BeliefSet) -> AlphaVectorPolicy:  # fmt: skip
    """The union of ``policy`` and ``new``, pruned to the vectors that win at some belief."""
    observed = None
    if policy.observed is not None and new.observed is not None:
        observed = torch.cat([policy.observed, new.observed])
    union = AlphaVectorPolicy(
        torch.cat([policy.alphas, new.alphas]), torch.cat([policy.actions, new.actions]), observed
    )
    return form.prune(union, belief_set.x, belief_set.beliefs)


def pbvi(model: POMDP | MOMDP | SparsePOMDP, config: PBVIConfig | None = None) -> Solution:
    """Solve a POMDP or MOMDP by point-based value iteration (Pineau et al. 2003).

    Args:
        model: an unbatched :class:`POMDP` or :class:`MOMDP` with discount < 1, or a
            :class:`~torchhrc.pomdp.SparsePOMDP` (sparse ``T``; beliefs and vectors dense
            ``(S,)``).
        config: :class:`PBVIConfig` (defaults if None).

    Returns:
        :class:`Solution` with the policy, ``lower = V(b0)`` (a lower bound on the optimum),
        ``upper`` (FIB or QMDP at ``b0``), and ``history`` entries with ``time_s``, ``lower``,
        ``upper``, ``gap``, ``n_alphas``, ``n_beliefs``, ``iteration``. ``info`` holds
        ``stop_reason`` (``"precision"``, ``"time_limit"``, ``"memory"``, ``"max_iterations"``,
        ``"expansions"``, ``"belief set converged"`` or ``"interrupted"``; also in the last
        history entry), ``iterations`` and the final belief set (``belief_x (M,)``,
        ``beliefs (M, S)`` or ``(M, Y)``).

    Raises:
        ModelError: the model is batched or undiscounted.
        TypeError: ``config`` is not a PBVIConfig, or ``model`` of no known form.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> s = pbvi(random_momdp(4, 2, 2, 2, seed=0), PBVIConfig(time_limit=5, expansions=2))
        >>> s.policy.is_momdp, s.lower <= s.upper
        (True, True)
    """
    config = PBVIConfig() if config is None else config
    if not isinstance(config, PBVIConfig):
        raise TypeError(f"expected config to be a PBVIConfig, got {type(config).__name__}")
    form = as_solver_model(model)
    if form.discount >= 1.0:
        raise ModelError(f"pbvi needs discount < 1, got {form.discount}")
    start = time.perf_counter()
    read_clock = clock_function(config.clock)
    clock_start = read_clock()
    if not config.factored:
        form = form.flattened()
    device = form.R.device
    generator = torch.Generator(device=device).manual_seed(config.seed)

    if config.upper_bound == "fib":
        upper_vectors = form.upper_vectors("fib", max(1e-9, config.precision * 1e-3))
    else:
        upper_vectors = form.upper_vectors("qmdp", 1e-8)
    # the start: one root (x0, b0), or one per first x of a random start, weighted by P(x)
    upper = form.value_at_roots(
        AlphaVectorPolicy.from_action_vectors(upper_vectors, momdp=form.factored)
    )
    root_x, roots, _ = form.roots
    x0 = torch.from_numpy(root_x).to(device)
    policy = form.blind_policy(100_000)
    belief_set = _BeliefSet(x0, roots)
    lower = form.value_at_roots(policy)
    history: list[dict[str, Any]] = []
    stop_reason = "expansions"
    iteration = 0

    def report() -> None:
        entry = {
            "time_s": time.perf_counter() - start,
            "lower": lower,
            "upper": upper,
            "gap": upper - lower,
            "n_alphas": policy.num_vectors,
            "n_beliefs": len(belief_set),
            "iteration": iteration,
        }
        history.append(entry)
        logger.debug("pbvi %s", entry)
        if config.callback is not None:
            config.callback(entry)

    report()
    # the memory limit, watched from here (the model and the initial bounds are its base)
    memory = None if config.memory_limit is None else MemoryGuard(config.memory_limit)
    next_checkpoint = clock_start + (config.policy_interval or 0.0)

    def reserve() -> int:  # what follows a stop: the policy's copies (memory_reserve)
        return int(policy.alphas.numel() * policy.alphas.element_size() * config.memory_reserve)

    def bounds() -> tuple[float, float]:  # (upper within round-off of lower: lower)
        return lower, max(upper, lower) if math.isclose(upper, lower, abs_tol=1e-9) else upper

    try:
        for expansion in range(config.expansions + 1):
            if memory is not None and memory.exceeded(
                reserve() + (memory.margin if expansion else 0)
            ):
                stop_reason = "memory"  # (an expansion may double the next sweep's temporaries)
                break
            if expansion > 0:
                if _expand(form, belief_set, config, generator) == 0:
                    stop_reason = "belief set converged"
                    break
            values = form.value(policy, belief_set.x, belief_set.beliefs)
            for _ in range(config.backups_per_expansion):
                result = form.point_backup(policy, belief_set.x, belief_set.beliefs)
                policy = _merge(form, policy, result.as_policy(), belief_set)
                iteration += 1
                new_values = form.value(policy, belief_set.x, belief_set.beliefs)
                improvement = float((new_values - values).max())
                values = new_values
                lower = form.value_at_roots(policy)
                report()
                if config.checkpoint is not None and read_clock() >= next_checkpoint:
                    low, up = bounds()
                    config.checkpoint(
                        Solution(
                            policy,
                            low,
                            up,
                            list(history),
                            {"checkpoint": True, "iterations": iteration},
                        )
                    )
                    next_checkpoint = read_clock() + float(config.policy_interval or 0.0)
                if upper - lower < config.precision:
                    stop_reason = "precision"
                    raise StopIteration
                if read_clock() - clock_start > config.time_limit:
                    stop_reason = "time_limit"
                    raise StopIteration
                if memory is not None and memory.exceeded(reserve()):
                    stop_reason = "memory"
                    raise StopIteration
                if iteration >= config.max_iterations:
                    stop_reason = "max_iterations"
                    raise StopIteration
                if improvement < config.precision * (1.0 - form.discount):
                    break
    except StopIteration:
        pass
    except KeyboardInterrupt:
        stop_reason = "interrupted"
        logger.info("pbvi interrupted; returning the best policy so far")
    if not history or history[-1]["iteration"] != iteration:
        report()
    history[-1]["stop_reason"] = stop_reason
    low, up = bounds()
    return Solution(
        policy=policy,
        lower=low,
        upper=up,
        history=history,
        info={
            "stop_reason": stop_reason,
            "iterations": iteration,
            "n_beliefs": len(belief_set),
            # the belief set B: x (M,) (zeros for a flat POMDP) and beliefs (M, S) / (M, Y)
            "belief_x": belief_set.x,
            "beliefs": belief_set.beliefs,
        },
    )
