"""The settings of :func:`~torchhrc.solvers.sarsop.sarsop` (:class:`SARSOPConfig`) and the
types of its bound initialisers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import torch

from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.solvers._budget import SolverBudget
from torchhrc.solvers.policy import AlphaVectorPolicy

__all__ = ["ALPHA_FLOAT32_MIN_WIDTH", "EXPLORE_AFTER", "EXPLORE_MIN_WIDTH", "SARSOPConfig"]

LowerInit = Callable[[POMDP | MOMDP], AlphaVectorPolicy]
UpperInit = Callable[[POMDP | MOMDP], torch.Tensor]


#: ``SARSOPConfig(alpha_dtype=None)`` holds the alpha vectors in float32 (rounded down) where
#: a vector has at least this many entries (``S`` of a flat model, ``Y`` of a MOMDP) and the
#: solve is float64: there the vectors are most of the solve's memory (a 20,000-state model's
#: 2,000 vectors at 10 s are 320 MB in float64; the scale check set's 5,000-state model's
#: 2,500 are 94 MB of its 176), and below it they are a few MB (its 2,000-state model: 700
#: vectors, 11 MB, where float32 changed neither the peak nor the bounds). It was 10,000 until
#: the forty-second session (``docs/benchmarks.md``, "The alpha vectors in float32 from 4,096
#: entries").
ALPHA_FLOAT32_MIN_WIDTH = 4_096

#: ``SARSOPConfig(explore_after="auto")`` draws among near-equal children after this many
#: trials without a rise of the lower bound at the start ...
EXPLORE_AFTER = 10
#: ... where a belief has at least this many entries (``S`` of a flat model, ``Y`` of a
#: MOMDP), and never below: on the large sparse models of ``make_suite.py --check-set scale``
#: the draw raised the lower bound or left it (20,000 states, seeds 701 and 705; 100,000
#: states), on TagAvoid (870 states) it lowered it on every seed tried, below APPL's
#: (``docs/benchmarks.md``, "The draw among near-equal children: large models only").
EXPLORE_MIN_WIDTH = 10_000


@dataclass(frozen=True, kw_only=True)
class SARSOPConfig(SolverBudget):
    """Settings of :func:`sarsop` (keyword-only; a typo is a TypeError).

    Attributes:
        time_limit: budget in seconds of ``clock``, including the bound initialisation
            (default 10). The solver is anytime: it returns the best policy so far.
        precision: target gap ``upper - lower`` at ``b0``, absolute (as APPL's ``pomdpsol
            --precision``; default 1e-3). The solve stops once the gap is at most this.
        max_iterations: cap on the number of sampling iterations (None: no cap).
        seed: seed of the tie-breaking among actions with equal upper bound.
        tie_break: how a trial picks among actions of equal upper bound (within 1e-12
            relative): ``"random"`` (default; seeded by ``seed``, as ``pomdpsol
            --randomization``) or ``"first"`` (the lowest action index, as ``pomdpsol`` by
            default).
        kappa: a trial's ``eps`` is ``kappa * gap(b0)`` (default 0.5).
        max_depth: cap on the depth of a trial (default: where ``gamma^t`` times the reward
            span over ``1 - gamma`` falls below the precision, at most 100,000).
        prediction: ``"binning"`` (SARSOP's learned ``V_hat``) or ``"upper"`` (``V_hat = V_up``,
            i.e. a pure gap-driven search, as HSVI).
        bins: number of bins per axis (initial upper bound, entropy) of the finer of the two
            levels of the ``V_hat`` predictor, one predictor per observed value (the coarser
            level has ``ceil(bins / 2)``; default 10, APPL's 10 and 5).
        lower_bound_init: ``model -> AlphaVectorPolicy`` whose vectors are lower bounds
            (flat ``(N, S)``; MOMDP ``(N, Y)`` with ``observed`` covering every ``x``), e.g. a
            PBVI solution's policy; default :func:`~torchhrc.solvers.blind.blind_policy`.
        upper_bound_init: ``model -> corner values`` ``(S,)`` / ``(X, Y)``, or per-action
            upper-bound vectors ``(A, S)`` / ``(A, X, Y)`` (maximised over ``A``); default
            :func:`fib_corner_values` (FIB from QMDP, stopped by ``init_tol`` /
            ``init_max_iterations``).
        init_tol: the default FIB initialisation stops when an iteration changes the corner
            values by less than this (default ``0.01 * precision``, APPL's residual for its
            FIB; every FIB iterate from an upper start is an upper bound, so stopping early
            only leaves the corners looser, which the search then tightens; the former
            ``0.01 * precision * (1 - discount)`` spent 10,000 iterations, most of a 10 s
            budget, on aloha-10max's discount 0.999).
        init_max_iterations: cap on the FIB iterations (default 10,000).
        init_time_fraction: share of ``time_limit`` (of what is left of it once the model's
            solver form is built) the default FIB initialisation may use at most (a safety
            net, read from its second FIB step on: QMDP and the first step always run, so
            the start is never looser than one FIB step from QMDP; it normally converges
            long before; when it does not, the result depends on the machine's speed,
            reported as
            ``Solution.info["init"]["upper_stop"] == "time_limit"``).
        prune_alphas: prune dominated alpha vectors and those that win at no tree belief,
            except the vectors best at a child of an active tree belief (at the belief's last
            evaluation, if it came after the last pruning, under an action not sub-optimal)
            and those a kept vector was built from.
        prune_growth: prune when the number of alpha vectors (or upper-bound points) has
            grown by this factor since the last pruning.
        prune_nodes: deactivate tree nodes reached by sub-optimal actions.
        sweep_interval: every this many iterations, back up all active tree beliefs at once
            (grouped by observed value, in batches of 256; the time limit is read between
            batches; 0 disables).
        lazy_upper: a one-belief backup re-bounds only the children of the action with the
            highest cached ``Q_up`` until that action is one just refreshed (APPL's
            ``getNewUBValueUseCache``); ``False`` re-bounds every child at every backup.
        forward_backups: a trial that reaches a belief it already passed on its way down (a
            cycle of the model: aloha-10max's trials of ~700 steps visit 3 distinct beliefs)
            backs it up at once, as APPL backs up every node a trial reaches, besides the
            leaf-to-root backups of the path; on discount 0.999 this multiplies the value
            propagation per trial (aloha-10max at 10 CPU-s: lower 531.9 -> 533.4). A trial
            also ends, as APPL's, where the gap is within half its target error.
        explore_after: after this many trials in a row without a rise of the lower bound at
            the start, each step of a trial draws its child (seeded by ``seed``) among those
            whose excess gap is at least ``explore_within`` times the largest, instead of
            taking the first of largest excess, until the lower bound rises again; ``None``:
            never, APPL's rule. Default ``"auto"``: :data:`EXPLORE_AFTER` (10) where a belief
            has at least :data:`EXPLORE_MIN_WIDTH` entries, else ``None``
            (``solution.info["explore_after"]`` says which). Where several children are
            nearly equal the deterministic choice keeps sending trials down the same ones,
            and a region of high reward under another may wait thousands of backups (the
            20,000-state model of ``make_suite.py --check-set scale`` at 60 CPU-s: lower
            5.94 against 6.41-6.88 with the draw); on a small model whose trials are many
            and cheap the deterministic deepening raises the lower bound faster (TagAvoid at
            10 CPU-s: -6.27 to -6.33 against -6.40 to -6.55 with the draw; both in
            ``docs/benchmarks.md``). The bounds stay bounds either way.
        explore_within: the share of the largest excess a child needs to be drawn, in
            ``(0, 1]`` (default 0.9; 1: exact ties only).
        callback: called after each iteration with the history entry (a dict); returning
            True stops the solve.
        dtype: floating dtype of the solve (default float64). ``torch.float32`` halves the
            memory of the model, the beliefs and the alpha vectors (a 20,000-state sparse
            model's net peak at 60 s: 796 against 1,223 MB, ``docs/benchmarks.md``, "The
            alpha vectors in float32"), with both bounds in single precision.
        alpha_dtype: the dtype the lower bound's alpha vectors are held in. ``torch.float32``
            under a float64 solve halves the vectors' memory, most of a large model's, and
            keeps the lower bound a bound: each vector is rounded toward minus infinity as it is
            stored, so it stays below the plan's value it was computed as, and beliefs are
            scored against it in float64 (the policy returned holds the float32 vectors).
            Default ``None``: float32 where a vector has at least
            :data:`ALPHA_FLOAT32_MIN_WIDTH` entries under a float64 solve (a 20,000-state
            sparse model's net peak at 10 s: 328 against 553 MB, ``docs/benchmarks.md``,
            "The alpha vectors in float32"), else ``dtype``; ``solution.info["alpha_dtype"]``
            says which.
        clock: what ``time_limit`` counts: ``"wall"`` (``time.perf_counter``, default),
            ``"process"`` (``time.process_time``: the process's CPU time, user and system, as
            APPL's ``pomdpsol --timeout`` counts it, so that a solve on a shared machine gets
            the CPU seconds it is given), or any callable returning seconds (e.g. a
            deterministic clock in tests). The limit is checked between iterations, at every
            step of a trial, between the backups of its path, and before a pruning that the
            last one's duration says would end past the limit; the initial bounds' safety net
            (``init_time_fraction``) counts on the same clock.
        memory_limit: bytes of resident memory the process may hold (as APPL's ``pomdpsol
            --memory``, which counts MB; None: no limit). Checked where the time limit is
            (``MemoryGuard`` of ``torchhrc/solvers/_memory.py``): the solve stops before the
            resident memory plus what the next steps are expected to add (a doubling of the
            belief tree or the alpha set, the final policy's copy of the vectors) would reach
            it, and returns the bounds and policy so far with ``stop_reason == "memory"``. It
            counts the whole process (interpreter, libraries and the model included): a limit
            below what the process holds when the search starts stops it at once, with the
            initial bounds.
        memory_reserve: bytes kept free under ``memory_limit`` per byte of the alpha vectors,
            for what follows the stop or a checkpoint (default 1.5: the policy's copy of the
            vectors and its check, or a pruning's gather); a caller that writes the policy
            adds its writer's share (``torchhrc solve``: 6 more for ``.policyx`` text, 1.5
            for safetensors).
        policy_interval: every this many seconds of ``clock`` (between iterations), call
            ``checkpoint`` with the solution so far (as APPL's ``pomdpsol
            --policy-interval``; None: never). Both or neither must be given.
        checkpoint: ``Solution -> None``, called every ``policy_interval`` seconds with the
            policy and bounds so far (``info["checkpoint"] is True``, ``info["iterations"]``),
            e.g. ``lambda s: save_policy(s.policy, "p.policyx")`` (an atomic write: a solve
            killed at any moment leaves the last complete policy). Its time counts in
            ``time_limit``.
    """

    time_limit: float = 10.0
    precision: float = 1e-3
    max_iterations: int | None = None
    seed: int = 0
    tie_break: Literal["random", "first"] = "random"
    kappa: float = 0.5
    max_depth: int | None = None
    prediction: Literal["binning", "upper"] = "binning"
    bins: int = 10
    lower_bound_init: LowerInit | None = None
    upper_bound_init: UpperInit | None = None
    init_tol: float | None = None
    init_max_iterations: int = 10_000
    init_time_fraction: float = 0.25
    prune_alphas: bool = True
    prune_growth: float = 2.0
    prune_nodes: bool = True
    sweep_interval: int = 0
    lazy_upper: bool = True
    forward_backups: bool = True
    explore_after: int | Literal["auto"] | None = "auto"
    explore_within: float = 0.9
    callback: Callable[[dict[str, Any]], bool | None] | None = None
    dtype: torch.dtype = torch.float64
    alpha_dtype: torch.dtype | None = None

    def __post_init__(self) -> None:
        super().__post_init__()  # clock, memory_limit, memory_reserve, policy_interval, checkpoint
        for name in ("time_limit", "precision", "kappa", "prune_growth", "init_time_fraction"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                raise ValueError(f"expected {name} to be a non-negative number, got {value!r}")
        if not 0.0 < self.kappa <= 1.0:
            raise ValueError(f"expected kappa in (0, 1], got {self.kappa}")
        if self.prune_growth <= 1.0:
            raise ValueError(f"expected prune_growth > 1, got {self.prune_growth}")
        if self.init_tol is not None and (
            not isinstance(self.init_tol, (int, float)) or not self.init_tol > 0
        ):
            raise ValueError(f"expected init_tol to be None or a number > 0, got {self.init_tol!r}")
        if not isinstance(self.init_max_iterations, int) or self.init_max_iterations < 0:
            raise ValueError(
                f"expected init_max_iterations to be an int >= 0, got {self.init_max_iterations!r}"
            )
        for name in ("max_iterations", "max_depth", "explore_after"):
            value = getattr(self, name)
            if name == "explore_after" and value == "auto":
                continue
            if value is not None and (not isinstance(value, int) or value < 0):
                also = ", 'auto'" if name == "explore_after" else ""
                raise ValueError(f"expected {name} to be None{also} or an int >= 0, got {value!r}")
        if (
            not isinstance(self.explore_within, (int, float))
            or isinstance(self.explore_within, bool)
            or not 0.0 < self.explore_within <= 1.0
        ):
            raise ValueError(f"expected explore_within in (0, 1], got {self.explore_within!r}")
        if self.tie_break not in ("random", "first"):
            raise ValueError(f"expected tie_break 'random' or 'first', got {self.tie_break!r}")
        if self.prediction not in ("binning", "upper"):
            raise ValueError(f"expected prediction 'binning' or 'upper', got {self.prediction!r}")
        if not isinstance(self.bins, int) or self.bins < 1:
            raise ValueError(f"expected bins to be an int >= 1, got {self.bins!r}")
        if not isinstance(self.sweep_interval, int) or self.sweep_interval < 0:
            raise ValueError(
                f"expected sweep_interval to be an int >= 0, got {self.sweep_interval!r}"
            )
        if not isinstance(self.dtype, torch.dtype) or not self.dtype.is_floating_point:
            raise TypeError(f"expected dtype to be a floating torch.dtype, got {self.dtype!r}")
        if self.alpha_dtype is not None and (
            not isinstance(self.alpha_dtype, torch.dtype) or not self.alpha_dtype.is_floating_point
        ):
            raise TypeError(
                f"expected alpha_dtype to be None or a floating torch.dtype, got "
                f"{self.alpha_dtype!r}"
            )
