"""SARSOP (Kurniawati, Hsu & Lee 2008) with the MOMDP factoring (Ong et al. 2010).

SARSOP ("successive approximations of the reachable space under optimal policies") grows a
tree of beliefs reachable from ``b0``, sampling the parts an optimal policy would visit, and
keeps two bounds on the optimal value function ``V*``:

* the lower bound, a set of alpha vectors ``V_low(b) = max_n alphas[n] . b`` (each the value
  of a conditional plan), initialised by the blind policies ("always do ``a``") and improved
  by point-based backups of the sampled beliefs;
* the upper bound, the sawtooth interpolation over corner values and belief points
  (:class:`~torchhrc.solvers.upper_bound.SawtoothUpperBound`), initialised by the Fast
  Informed Bound (Hauskrecht 2000) and improved by Bellman backups at the sampled beliefs.

One iteration samples a path from ``b0`` (Algorithm "SamplePoints" of the paper): at belief
``b`` at depth ``t`` it stops when the predicted optimal value ``V_hat(b)`` (learned online by
binning beliefs on their upper bound and entropy) cannot raise the root's lower bound past the
target ``L`` and ``V_up(b) <= max(U, V_low(b) + eps * gamma^-t)``; otherwise it takes the
action with the highest upper bound ``a* = argmax_a Q_up(b, a)`` and the observation with the
largest weighted excess uncertainty
``o* = argmax_o P(o | b, a*) (V_up - V_low)(tau(b, a*, o)) - eps gamma^-(t+1)``, passing down
the targets ``L_t``, ``U_t`` solved from
``L' = R(b, a*) + gamma (P(o*) L_t + sum_{o != o*} P(o) V_low(tau(b, a*, o)))`` with
``L' = max(L, max_a Q_low(b, a))`` and ``U' = max(U, max_a Q_low(b, a) + eps gamma^-t)`` (and
the same with ``V_up`` for ``U_t``). A MOMDP with a random first observed value
(:attr:`~torchhrc.pomdp.MOMDP.initial`) has one root per first ``x`` (nodes ``0..R-1``, beliefs
``P(. | x)``); the bounds at the start are theirs weighted by ``P(x)``, and a trial enters the
root of largest weighted gap ``P(x) (V_up - V_low)`` with the targets of a step without reward
or discount (as APPL's SARSOP does for such files, e.g. ``TagAvoid.pomdpx``). The path is then
backed up leaf to root; a belief the trial reaches a second time (a cycle of the model) is also
backed up when reached, as APPL backs up every node a trial reaches. Tree nodes holding the same
belief share its cached evaluation. Dominated alpha vectors and alpha vectors that win at no
tree belief, unless they were the best at a child of an active tree belief at its last
evaluation (as APPL keeps the vectors best at the unexpanded children in its belief cache) or a
kept vector was built from them (so that the greedy policy of the written vectors keeps the
lower bound's value), redundant upper-bound points and belief nodes reached by sub-optimal
actions (``Q_up(b, a) < max_a' Q_low(b, a')``) are pruned.

One model interface: the solver asks the model only through
:class:`~torchhrc.solvers.forms.base.SolverModel` (children of beliefs with their
probabilities, rewards, the pieces of a backup, the initial bounds, the tree that stores
beliefs), picked once by :func:`~torchhrc.solvers.forms.as_solver_model`; it never tests
which form it holds. The forms: dense flat POMDP, MOMDP, sparse flat
(:mod:`torchhrc.solvers.forms`).

MOMDP (Ong et al. 2010): beliefs are ``(x, b_y)``; alpha vectors belong to one observed value
and live over ``Y``, and are stored grouped by ``x`` (one contiguous ``(N_x, Y)`` block each);
the upper-bound points too (per-``x`` point lists, and for ``Y <= 256`` a dense per-``x``
table), so bounding a belief at ``x`` touches only ``x``'s vectors and points, never the
whole sets. Every expansion only touches the next observed values reachable from ``x`` (see
:class:`~torchhrc.solvers.forms.momdp.MOMDPForm`, whose per-``x`` slices are built when
the search first reaches ``x``), so a factored backup costs about ``Y / S = 1 / X`` of the
flat one's flops. The initial bounds use the reachable-``x2`` FIB operator, never the flat
``(X Y) x (X Y)`` matrix. A flat POMDP is the same model with ``X = 1``.

Reproducibility and time: with a fixed ``max_iterations`` (or ``precision``) and a
``time_limit`` that is not reached, a solve is bit-identical run to run: the default FIB
initialisation stops on its tolerance (``init_tol``) or iteration cap, not on the clock
(``init_time_fraction`` of the limit is only a safety net; ``Solution.info["init"]`` says how
it stopped). ``time_limit`` is checked between iterations, at every step of a trial and
between the backups of its path, so one long trial does not overrun it; the solve stays
anytime and returns the bounds and policy reached so far.

Every tensor computation at a belief is batched over all ``(a, x2, o)`` children at once (one
expansion, one matrix product against all alpha vectors, one sawtooth evaluation against all
points); :attr:`SARSOPConfig.sweep_interval` also backs up all active tree beliefs of an
observed value together as one batched backup.

Batched models (leading batch dims) are not solved together: the tree search is sequential
per problem, so :func:`sarsop` raises for them; solve ``model`` per batch index.

Sparse flat models (:class:`~torchhrc.pomdp.SparsePOMDP`, e.g. RockSample(7, 8) read with
``read_pomdp(path, sparse=True)``: 12545 states, a dense ``T`` of 2e9 entries) take a sparse
form with the same algorithm (:class:`~torchhrc.solvers.forms.sparse.SparseForm`): ``T`` as
per-action CSR (:class:`~torchhrc.solvers.sparse_model.SparseFlatModel`), tree beliefs stored
by their support (:class:`~torchhrc.solvers.belief_tree.SparseBeliefTree`), each belief's
children formed and bounded only on the union of their supports, blind lower bound and
QMDP/FIB upper bound by sparse value iteration, alpha vectors dense ``(S,)``. Belief pruning
is one sparse product; the ``N^2 S`` pointwise-dominance test is skipped. On small models it
gives the same bounds and policy as the dense path (tested).

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> sol = sarsop(tiger(), SARSOPConfig(time_limit=60.0, precision=0.5))
    >>> sol.info["stop_reason"], sol.upper - sol.lower <= 0.5, sol.policy.action(tiger().b0).item()
    ('precision', True, 0)
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

# np.unique reads np.ma, and the tie-break draws from np.random: numpy loads both on first use
# (20 ms), so they load with this module rather than on the first solve's clock
import numpy.ma
import numpy.random
import torch
from threadpoolctl import threadpool_limits

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP, SparsePOMDP
from torchhrc.solvers import backup_kernel
from torchhrc.solvers._memory import (
    MemoryGuard,
    check_checkpoint,
    check_memory_limit,
    release_free_memory,
)
from torchhrc.solvers.clock import Clock, Deadline, check_clock, clock_function
from torchhrc.solvers.eval_cache import EvaluationCache
from torchhrc.solvers.forms import SolverModel, as_solver_model
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.pruning import prune_dominated
from torchhrc.solvers.solution import Solution
from torchhrc.solvers.sparse_model import SparseFlatModel
from torchhrc.solvers.upper_bound import _ROWS, SawtoothUpperBound

__all__ = ["SARSOPConfig", "fib_corner_values", "sarsop"]

LowerInit = Callable[[POMDP | MOMDP], AlphaVectorPolicy]
UpperInit = Callable[[POMDP | MOMDP], torch.Tensor]

#: the most steps of a trial. Its targets end a trial after some ``ln(2) / (1 - gamma)`` to
#: ``ln(4) / (1 - gamma)`` steps (``eps = gap / 2``): 7,000-14,000 at discount 0.9999, where
#: the former cap of 1,000 cut every trial on the same few beliefs. A step adds a node (Y
#: floats), so this bounds what one trial adds to the tree.
_MAX_DEPTH = 100_000


def fib_corner_values(model: POMDP | MOMDP | SparsePOMDP | SparseFlatModel, *,
                      tol: float = 1e-8, time_limit: float = math.inf,
                      max_iterations: int = 100_000) -> torch.Tensor:  # fmt: skip
    """Fast Informed Bound corner values (SARSOP's default upper-bound initialisation).

    Iterates :func:`~torchhrc.solvers.fib.fib_backup` from the QMDP vectors; the operator is
    monotone and QMDP is an upper bound it maps below itself, so every iterate is an upper
    bound and stopping early is safe (Hauskrecht 2000). The iteration stops
    deterministically, when the largest change is below ``tol`` or after ``max_iterations``;
    ``time_limit`` is only a safety net (hitting it makes the result depend on the machine's
    speed). For a MOMDP with a static hidden value FIB equals QMDP (the next hidden value is
    known given the current one), so no FIB iteration runs.

    Args:
        model: an unbatched POMDP or MOMDP, or a flat model with sparse transitions
            (:class:`~torchhrc.pomdp.SparsePOMDP` or
            :class:`~torchhrc.solvers.sparse_model.SparseFlatModel`).
        tol: stop when the largest change is below ``tol``.
        time_limit: seconds allowed for the whole computation (QMDP included).
        max_iterations: cap on the FIB iterations.

    Returns:
        ``(S,)`` (flat) or ``(X, Y)`` (MOMDP) corner values ``max_a alpha_a``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> round(float(fib_corner_values(tiger())[0]), 2)  # FIB ignores listening noise
        92.82
    """
    deadline = Deadline.after(time_limit)
    return as_solver_model(model).fib_corner_values(tol, deadline, max_iterations)[0]


@dataclass(frozen=True, kw_only=True)
class SARSOPConfig:
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
            net: it normally converges long before; when it does not, the result depends on
            the machine's speed, reported as
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
        callback: called after each iteration with the history entry (a dict); returning
            True stops the solve.
        dtype: floating dtype of the solve (default float64).
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
    callback: Callable[[dict[str, Any]], bool | None] | None = None
    dtype: torch.dtype = torch.float64
    clock: Clock = "wall"
    memory_limit: float | None = None
    memory_reserve: float = 1.5
    policy_interval: float | None = None
    checkpoint: Callable[[Solution], None] | None = None

    def __post_init__(self) -> None:
        check_memory_limit(self.memory_limit, reserve=self.memory_reserve)
        check_checkpoint(self.policy_interval, self.checkpoint)
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
        for name in ("max_iterations", "max_depth"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 0):
                raise ValueError(f"expected {name} to be None or an int >= 0, got {value!r}")
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
        check_clock(self.clock)


class _AlphaSet:
    """Alpha vectors ``(N, Y)`` with their action and observed value, grown geometrically.

    On CPU the vectors are also kept grouped by observed value (Ong et al. 2010: a MOMDP
    lower bound is a set of vectors over ``Y`` per ``x``): ``group(x)`` returns the ``(N_x, Y)``
    contiguous block of ``x``'s vectors and their indices in the flat storage, so bounding a
    belief at ``x`` touches only ``N_x`` vectors, not all ``N``.

    Each vector also keeps ``refs[n]``, the indices of the vectors its backup chose at the
    possible children (the plan it is the value of: ``alpha = R_a + gamma sum P Z alpha_ref``).
    :meth:`keep` keeps what a kept vector refers to, so the vectors stay the values of plans
    made of vectors in the set: the value function stays uniformly improvable
    (``V_low(b) <= max_a Q_low(b, a)`` at every belief, Pineau et al. 2003) and the greedy
    policy of the written vectors earns at least ``V_low(b0)``. The initial vectors (blind
    policies: fixed points of their own action) refer to none.
    """

    def __init__(self, alphas: torch.Tensor, actions: torch.Tensor, observed: torch.Tensor,
                 num_observed: int = 1) -> None:  # fmt: skip
        n = alphas.shape[0]
        self.refs: list[np.ndarray] = [np.zeros(0, dtype=np.int64) for _ in range(n)]
        cap = max(64, 2 * n)
        self.num_observed = int(num_observed)
        self.vectors = alphas.new_zeros(cap, alphas.shape[1])
        self.actions = torch.zeros(cap, dtype=torch.long, device=alphas.device)
        self.observed = torch.zeros(cap, dtype=torch.long, device=alphas.device)
        self.vectors[:n], self.actions[:n], self.observed[:n] = alphas, actions, observed
        self.size = n
        self._views()
        self._regroup()

    def _dominating(self, need: np.ndarray, kept: np.ndarray) -> np.ndarray:
        """``(len(need),)``: for each vector of ``need``, a vector of ``kept`` of the same
        observed value that is >= it at every entry, or -1 (CPU storage; -1 elsewhere, or when
        the comparison would exceed 2e8 entries)."""
        out = np.full(need.size, -1, dtype=np.int64)
        if self.np_vectors is None or self.np_observed is None or not kept.size:
            return out
        V, obs, Y = self.np_vectors, self.np_observed, self.np_vectors.shape[1]
        probe = np.linspace(0, Y - 1, min(Y, 8)).astype(np.int64)
        for x in np.unique(obs[need]).tolist():
            rows = np.flatnonzero(obs[need] == x)
            cand = kept[obs[kept] == x]
            if not cand.size or rows.size * cand.size * Y > 2e8:
                continue
            C = V[cand]  # (c, Y)
            # a few probe entries first (a candidate dominates only if it does there; most
            # pairs fail), the full rows for the survivors; the first dominating candidate
            # wins, as an argmax over the full comparison would pick
            Cp = C[:, probe]  # (c, k)
            # (step, c, k) booleans at once: 4 MB (16 MB raised Hallway2's peak memory)
            step = max(1, (1 << 22) // (cand.size * probe.size))
            for start in range(0, rows.size, step):
                chunk = rows[start : start + step]
                Vn = V[need[chunk]]  # (n, Y)
                ii, jj = np.nonzero((Cp[None, :, :] >= Vn[:, None, probe]).all(-1))
                # the survivors' full rows in blocks of about 256k floats (2 MB), not all at
                # once (up to 2e8 floats: the peak memory of a solve)
                ok = np.empty(ii.size, dtype=bool)
                block = max(1, (1 << 18) // Y)
                for b0 in range(0, ii.size, block):
                    sl = slice(b0, b0 + block)
                    ok[sl] = (C[jj[sl]] >= Vn[ii[sl]]).all(-1)
                ii, jj = ii[ok], jj[ok]
                first, at = np.unique(ii, return_index=True)  # ii is sorted, jj rising
                out[chunk[first]] = cand[jj[at]]
        return out

    def _views(self) -> None:
        """Numpy views of the storage (CPU only; refreshed after every reallocation)."""
        cpu = self.vectors.device.type == "cpu"
        self.np_vectors = self.vectors.numpy() if cpu else None
        self.np_actions = self.actions.numpy() if cpu else None
        self.np_observed = self.observed.numpy() if cpu else None

    def _regroup(self) -> None:
        """Rebuild the per-``x`` blocks from the flat storage (CPU only)."""
        if self.np_vectors is None:
            return
        assert self.np_observed is not None
        n, Y = self.size, self.np_vectors.shape[1]
        obs = self.np_observed[:n]
        order = np.argsort(obs, kind="stable")
        counts = np.bincount(obs, minlength=self.num_observed)
        ends = np.cumsum(counts)
        self._gn = counts.astype(np.int64)
        self._gcol: list[np.ndarray] = []
        self._gid: list[np.ndarray] = []
        for x in range(self.num_observed):
            ids = order[ends[x] - counts[x] : ends[x]]
            cap = max(4, 2 * ids.size)
            col = np.empty((Y, cap), dtype=self.np_vectors.dtype)
            col[:, : ids.size] = self.np_vectors[ids].T
            gid = np.empty(cap, dtype=np.int64)
            gid[: ids.size] = ids
            self._gcol.append(col)
            self._gid.append(gid)

    def group(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """``(N_x, Y)`` the vectors of observed value ``x`` (a transposed view of
        :meth:`group_columns`) and ``(N_x,)`` their indices."""
        cols, ids = self.group_columns(x)
        return cols.T, ids

    def group_columns(self, x: int) -> tuple[np.ndarray, np.ndarray]:
        """``(Y, N_x)`` the vectors of observed value ``x`` as columns (a view of the group's
        ``(Y, capacity)`` copy: ``rows @ columns`` is a plain BLAS product, a third faster
        than ``rows @ vectors.T`` on aloha-10max's 28 x 30 x 600) and ``(N_x,)`` their
        indices in the flat storage."""
        m = self._gn[x]
        return self._gcol[x][:, :m], self._gid[x][:m]

    def group_scores(self, kernel: Any, rows: np.ndarray, rows_x: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """``(B,)`` the best score of each row among its own observed value's vectors and
        ``(B,)`` that vector's index, in one compiled call over the group columns
        (:func:`~torchhrc.solvers.backup_kernel.group_scores`; ``rows`` ``(B, Y)``
        C-contiguous, or ``(1, Y)``: one belief under each ``x`` of ``rows_x``)."""
        return backup_kernel.group_scores(kernel, rows, rows_x.astype(np.int64, copy=False),
                                          self._gcol, self._gid, self._gn)  # fmt: skip

    def _append_group(self, x: int, alpha: np.ndarray, index: int) -> None:
        m = self._gn[x]
        if m == self._gid[x].shape[0]:
            old = self._gcol[x]
            col = np.empty((old.shape[0], 2 * m), dtype=old.dtype)
            col[:, :m] = old[:, :m]
            gid = np.empty(2 * m, dtype=np.int64)
            gid[:m] = self._gid[x]
            self._gcol[x], self._gid[x] = col, gid
        self._gcol[x][:, m] = alpha
        self._gid[x][m] = index
        self._gn[x] = m + 1

    def add_np(self, alpha: np.ndarray, action: int, observed: int,
               refs: np.ndarray | None = None) -> None:  # fmt: skip
        """Add one vector ``alpha (Y,)`` from numpy (CPU storage only), built from the vectors
        ``refs``."""
        if self.size == self.vectors.shape[0]:
            self._reserve(self.size + 1)
        assert self.np_vectors is not None
        assert self.np_actions is not None and self.np_observed is not None
        n = self.size
        self.np_vectors[n] = alpha
        self.np_actions[n] = action
        self.np_observed[n] = observed
        self.size = n + 1
        self.refs.append(np.asarray(() if refs is None else refs, dtype=np.int64))
        self._append_group(observed, self.np_vectors[n], n)

    def _reserve(self, need: int) -> None:
        cap = self.vectors.shape[0]
        while cap < need:
            cap *= 2
        for name in ("vectors", "actions", "observed"):
            old = getattr(self, name)
            # rows past ``size`` are written before they are read; empty leaves their pages
            # untouched (not resident) until then
            new = old.new_empty(cap, *old.shape[1:])
            new[: self.size] = old[: self.size]
            setattr(self, name, new)
        self._views()

    def add(self, alphas: torch.Tensor, actions: torch.Tensor, observed: torch.Tensor,
            refs: list[np.ndarray] | None = None) -> None:  # fmt: skip
        m = alphas.shape[0]
        if refs is None:
            refs = [np.zeros(0, dtype=np.int64)] * m
        self.refs.extend(np.asarray(r, dtype=np.int64) for r in refs)
        if self.size + m > self.vectors.shape[0]:
            self._reserve(self.size + m)
        s = slice(self.size, self.size + m)
        self.vectors[s], self.actions[s], self.observed[s] = alphas, actions, observed
        self.size += m
        if self.np_vectors is not None:
            assert self.np_observed is not None
            for i in range(s.start, s.stop):
                self._append_group(int(self.np_observed[i]), self.np_vectors[i], i)

    def keep(self, mask: torch.Tensor) -> np.ndarray:
        """Keep the vectors of ``mask (N,)`` and, transitively, those they refer to; a
        referred vector that a kept one of its ``x`` dominates pointwise is replaced by it in
        the references instead (the plan only gains).

        Returns ``(N,)`` the new index of each old vector (of its replacement, for a replaced
        one; -1 for a dropped one)."""
        m = mask[: self.size].cpu().numpy().copy()
        target = np.arange(self.size)  # reference i now means vector target[i]
        frontier = np.flatnonzero(m)
        while frontier.size:
            refs = [self.refs[i] for i in frontier.tolist() if self.refs[i].size]
            if not refs:
                break
            r = np.unique(np.concatenate(refs))
            need = r[~m[r] & (target[r] == r)]
            if not need.size:
                break
            sub = self._dominating(need, np.flatnonzero(m))
            target[need[sub >= 0]] = sub[sub >= 0]
            frontier = need[sub < 0]
            m[frontier] = True
        remap = np.full(self.size, -1, dtype=np.int64)
        kept = np.flatnonzero(m)
        remap[kept] = np.arange(kept.size)
        self.refs = [remap[target[self.refs[i]]] for i in kept.tolist()]
        moved = remap[target]
        idx = torch.from_numpy(kept).to(self.vectors.device)
        n = idx.numel()
        self.vectors[:n] = self.vectors[idx]
        self.actions[:n] = self.actions[idx]
        self.observed[:n] = self.observed[idx]
        self.size = n
        self._regroup()
        return moved


@dataclass
class _Evaluation:
    """Bounds at ``B`` beliefs of one observed value and at all their children."""

    xs: torch.Tensor  # (K,) reachable next observed values
    J: torch.Tensor  # (B, A, K, O, Y) unnormalised children
    prob: torch.Tensor  # (B, A, K, O) P(x2, o | x, b, a)
    low: torch.Tensor  # (B, A, K, O) P * V_low(child)
    best: torch.Tensor  # (B, A, K, O) index of the best alpha vector at each child
    up: torch.Tensor  # (B, A, K, O) P * V_up(child)
    q_low: torch.Tensor  # (B, A)
    q_up: torch.Tensor  # (B, A)
    self_low: torch.Tensor  # (B,) V_low(b) under the current alpha vectors
    self_up: torch.Tensor  # (B,) V_up(b) under the current sawtooth


class _Bins:
    """SARSOP's lower-bound predictor ``V_hat``, as APPL's ``BinManagerSet`` computes it.

    One predictor per observed value ``x`` (a flat model has one), two levels of bins over
    (initial upper bound, entropy): ``ceil(n / 2)`` and ``n`` bins per axis (APPL: 5 and 10).
    A belief is binned once, by the value at it of the *initial* upper bound (the corner
    values, fixed: its bin never moves) over the range of its ``x``'s corner values, and by
    its entropy over ``log Y``; a bin holds the mean of the latest lower bounds of its beliefs
    (one entry per distinct belief, not per tree node) and the sum of its beliefs' squared
    prediction errors, and the prediction comes from the level whose bin has the smaller
    error (Kurniawati et al. 2008, section 4.2; APPL ``BinManager.cpp``). A belief alone in
    its coarse bin is predicted at its upper bound, which sends the search on to explore it.
    """

    def __init__(self, corner: np.ndarray, max_entropy: float, n: int) -> None:
        self.corner = corner  # (X, Y) initial upper-bound corner values
        self.lo = corner.min(1)
        self.span = np.maximum(corner.max(1) - self.lo, 1e-12)
        self.max_entropy = max(max_entropy, 1e-12)
        self.sizes = (max(1, (n + 1) // 2), n) if n > 1 else (1,)
        # per level, the bins in use: (x, i, j) -> [sum of lower bounds, count, squared error]
        # (plain floats in lists: a backup updates two bins, where numpy scalar access cost
        # more than the arithmetic)
        self.cells: list[dict[tuple[int, int, int], list[float]]] = [{} for _ in self.sizes]
        # belief id -> (x, its bin (i, j) per level, last lower bound, squared error per
        # level, those bins' cells)
        self.state: dict[int, tuple[int, list[tuple[int, int]], float, list[float],
                                    list[list[float]]]] = {}  # fmt: skip

    def update(self, key: int, x: int, belief: np.ndarray, entropy: float, upper: float,
               lower: float) -> None:  # fmt: skip
        """Record the lower bound ``lower`` of the belief ``key`` (of observed value ``x``)."""
        st = self.state.get(key)
        if st is None:
            u0 = float(self.corner[x] @ belief)
            where, cells, errs = [], [], []
            for lv, k in enumerate(self.sizes):
                i = int(min(k - 1, max(0.0, (u0 - self.lo[x]) / self.span[x] * k)))
                j = int(min(k - 1, max(0.0, entropy / self.max_entropy * k)))
                cell = self.cells[lv].setdefault((x, i, j), [0.0, 0.0, 0.0])
                c = cell[1]
                err = upper - lower if c == 0 else cell[0] / c - lower
                cell[2] += err * err
                cell[0] += lower
                cell[1] = c + 1
                where.append((i, j))
                cells.append(cell)
                errs.append(err * err)
            self.state[key] = (x, where, lower, errs, cells)
            return
        _, where, prev, errs, cells = st
        for lv, cell in enumerate(cells):
            c = cell[1]
            if c == 1:
                err = upper - lower
                cell[2] = err * err
            else:
                err = cell[0] / c - lower
                cell[2] += err * err - errs[lv]
            errs[lv] = err * err
            cell[0] += lower - prev
        self.state[key] = (x, where, lower, errs, cells)

    def predict(self, key: int, upper: float, lower: float) -> float:
        """The predicted optimal value at the belief ``key``, within ``[lower, upper]``."""
        st = self.state.get(key)
        if st is None:
            return upper
        cells = st[4]
        if cells[0][1] <= 1:
            return upper
        best = 0
        smallest = cells[0][2]
        for lv in range(1, len(cells)):
            e = cells[lv][2]
            if e + 1e-10 < smallest:
                best, smallest = lv, e
        total, count, _ = cells[best]
        return min(upper, max(lower, total / count))


class _SARSOP:
    def __init__(self, model: POMDP | MOMDP | SparsePOMDP | SolverModel, cfg: SARSOPConfig,
                 start: float, clock_start: float | None = None) -> None:  # fmt: skip
        self.cfg = cfg
        self.start = start
        # the clock of time_limit (wall: the deadline counts from ``start``; another clock
        # from ``clock_start``, its reading when the solve began)
        self.clock: Callable[[], float] = clock_function(cfg.clock)
        if cfg.clock == "wall":
            clock_start = start
        elif clock_start is None:
            clock_start = self.clock()
        # the one place the model's form is chosen; everything below asks the form
        self.form = form = as_solver_model(model, dtype=cfg.dtype)
        if form.discount >= 1.0:
            raise ModelError(f"SARSOP needs discount < 1, got {form.discount}")
        self.gamma = form.discount
        self.X, self.Y = form.num_observed, form.num_hidden
        self.rng = np.random.default_rng(int(cfg.seed))
        self.device = form.b0.device
        self.deadline = clock_start + cfg.time_limit
        # the initial bounds' safety net, on the same clock as the limit: a share of what is
        # left once the model's form is built (building it can take seconds on a large model)
        now = self.clock()
        init_deadline = Deadline(
            now + max(0.0, self.deadline - now) * cfg.init_time_fraction, self.clock
        )
        # upper bound: corner values (FIB by default), first: it is the part the safety net
        # (init_deadline) may cut, so it gets its share of the budget before the lower bound
        self.init_info: dict[str, Any] = {}
        t_upper = time.perf_counter()
        if cfg.upper_bound_init is None:
            tol = cfg.init_tol
            if tol is None:
                tol = 0.01 * cfg.precision  # APPL: CB_INITIALIZATION_PRECISION_FACTOR
            corner, fib = form.fib_corner_values(tol, init_deadline, cfg.init_max_iterations)
            self.init_info["upper_iterations"] = fib["iterations"]
            self.init_info["upper_stop"] = fib["stop"]
        else:
            corner = cfg.upper_bound_init(form.init_argument)
        self.init_info["upper_s"] = time.perf_counter() - t_upper
        corner = form.corner_values(corner.to(dtype=cfg.dtype), "upper_bound_init")
        self.ub = SawtoothUpperBound(corner)
        t_init = time.perf_counter()
        # lower bound: alpha vectors of a policy (blind policies by default)
        if cfg.lower_bound_init is None:
            policy = form.blind_policy()
        else:
            policy = cfg.lower_bound_init(form.init_argument)
        policy = form.check_policy(policy, "lower_bound_init")
        self.init_info["lower_s"] = time.perf_counter() - t_init
        observed = torch.zeros_like(policy.actions) if policy.observed is None else policy.observed
        if self.X > 1 and int(torch.bincount(observed, minlength=self.X).min()) == 0:
            raise ModelError("lower_bound_init's policy must have a vector for every observed x")
        self.alphas = _AlphaSet(
            policy.alphas.to(cfg.dtype), policy.actions.long(), observed.long(), self.X
        )
        n = self.alphas.size
        self.alphas.keep(prune_dominated(self.alphas.vectors[:n], self.alphas.observed[:n]))
        self.tree = form.new_tree()
        self._child_x: dict[tuple[int, int], torch.Tensor] = {}
        # per distinct belief (``belief_id``): the last evaluation, shared by the tree nodes
        # that hold the same belief (its stale bounds stay valid bounds there)
        self._cache = EvaluationCache()
        self._rows_cache: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
        # per distinct belief evaluated since the last alpha pruning: the best alpha vector at
        # each child ``(A, K, O)`` of its last evaluation; pruning keeps them (see
        # :meth:`_child_winners`)
        self._child_best: dict[int, np.ndarray] = {}
        # the roots: nodes 0..R-1, one per first observed value (R = 1 unless the model
        # starts at a random x), weighted by its probability (see :meth:`sample`)
        root_x, root_b, self.root_w = form.roots
        self.n_roots = R = int(root_x.shape[0])
        self.root_low = np.full(R, -np.inf)  # per root, the lower bound last recorded
        cap = max(1024, 2 * R)
        self.entropy = np.zeros(cap)
        self.entropy[:R] = self._entropy(root_b).cpu().double().numpy()
        # one id per distinct belief (APPL's belief cache): tree nodes holding the same belief
        # share its cached evaluation, and a trial that reaches a belief again is in a cycle
        self._belief_ids: dict[tuple[int, bytes], int] = {}
        self.belief_id = np.zeros(cap, dtype=np.int64)
        for r, row in enumerate(root_b.cpu().numpy()):
            self.belief_id[r] = self._belief_key(int(root_x[r]), row)
        self.children: dict[int, list[int]] = {}
        span = float(form.R.max() - form.R.min()) / (1.0 - self.gamma)
        if cfg.max_depth is not None:
            self.max_depth = cfg.max_depth
        else:
            target = max(cfg.precision, 1e-6 * max(span, 1.0))
            depth = math.log(target / max(span, 1e-12)) / math.log(self.gamma) if span > 0 else 1
            self.max_depth = int(min(max(math.ceil(depth), 1), _MAX_DEPTH))
        corners = corner.reshape(self.X, -1).cpu().double().numpy()
        self.bins = _Bins(corners, math.log(self.Y), cfg.bins)

        self.last_alpha_prune = self.alphas.size
        self.last_point_prune = 1
        self._prune_cost: dict[str, tuple[float, int]] = {}  # kind -> (seconds, size) of last
        self.history: list[dict[str, Any]] = []
        self.backups = 0
        self._forward: set[int] = set()
        # the sequential one-belief path runs in numpy on the CPU, whose per-op overhead at
        # these sizes is several times below torch's dispatch
        self._np = self.device.type == "cpu"
        # the compiled steps of a belief's evaluation (backup_kernel): float64 on the CPU
        self._kernel = backup_kernel.load() if self._np and cfg.dtype == torch.float64 else None
        R = self.n_roots
        self.tree.lower[:R], self.tree.upper[:R] = self._root_bounds()
        # the memory limit, watched from here (what the initialisation holds is its base)
        self._longest = 64  # the most nodes a trial added so far (at least 64)
        self.memory = (None if cfg.memory_limit is None
                       else MemoryGuard(cfg.memory_limit, min_interval=1e-3))  # fmt: skip
        # the first policy checkpoint, ``policy_interval`` seconds into the solve
        self._next_checkpoint = (clock_start or 0.0) + (cfg.policy_interval or 0.0)

    # -- budget ----------------------------------------------------------------------------
    def _pending_bytes(self) -> int:
        """What the search may allocate at once next, beyond its steady growth:
        ``memory_reserve`` times the alpha vectors' bytes (the final policy's copy and its
        check, or a pruning's gather of the kept vectors, and the caller's writing of the
        policy), and the copy a doubling of the alpha storage or of the belief tree makes when
        it is within a trial's reach of its capacity."""
        alphas, tree = self.alphas, self.tree
        row = alphas.vectors.shape[1] * alphas.vectors.element_size()
        pending = int(alphas.size * row * self.cfg.memory_reserve)
        if alphas.vectors.shape[0] - alphas.size <= self._longest:
            pending += alphas.size * row
        if tree.x.shape[0] - tree.size <= self._longest:
            beliefs = getattr(tree, "_beliefs", None)
            per_node = 64 + (beliefs.shape[1] * beliefs.element_size()
                             if isinstance(beliefs, torch.Tensor) else 0)  # fmt: skip
            pending += tree.size * per_node
        return pending

    def _out_of_budget(self) -> bool:
        """Whether the time limit has passed or the memory limit is near."""
        if self.clock() >= self.deadline:
            return True
        return self.memory is not None and self.memory.exceeded(self._pending_bytes)

    # -- bounds ----------------------------------------------------------------------------
    def lower_value(
        self, beliefs: torch.Tensor, x: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(B,)`` max alpha . b over the vectors of each ``x``, and the argmax index."""
        n = self.alphas.size
        scores = beliefs @ self.alphas.vectors[:n].T  # (B, N)
        if self.X > 1:
            scores = scores.masked_fill(x.unsqueeze(-1) != self.alphas.observed[:n], -torch.inf)
        return scores.max(-1)

    def evaluate(self, x: int, beliefs: torch.Tensor) -> _Evaluation:
        """Expand ``B`` beliefs of observed value ``x``; bound them and all their children.

        One expansion, one matrix product against the alpha vectors and one sawtooth
        evaluation cover the ``B * A * K * O`` children and the ``B`` beliefs themselves.
        """
        xs, J = self.form.expand(x, beliefs)  # (B, A, K, O, Y)
        B, A, K, O, Y = J.shape
        C = B * A * K * O
        key = (x, B)
        cx = self._child_x.get(key)
        if cx is None:
            cx = torch.cat([xs.view(1, 1, K, 1).expand(B, A, K, O).reshape(-1),
                            xs.new_full((B,), x)])  # fmt: skip
            self._child_x[key] = cx
        prob = J.sum(-1)  # (B, A, K, O)
        nz = prob.reshape(-1).nonzero().squeeze(-1)
        shape = (B, A, K, O)
        if nz.numel() * 4 < C * 3:
            # most children are impossible (deterministic moves, observations tied to the
            # state): bound only the possible ones; the others weigh 0 (the bounds are
            # homogeneous) and take the best vector of their x2 at the parent belief
            # (:meth:`_impossible_best`)
            rows = torch.cat([J.reshape(C, Y)[nz], beliefs])
            rows_x = torch.cat([cx[nz], cx[C:]])
            low_r, best_r = self.lower_value(rows, rows_x)
            up_r = self.ub.value(rows, rows_x)
            m = nz.numel()
            low_c = J.new_zeros(C).index_copy_(0, nz, low_r[:m]).view(shape)
            up_c = J.new_zeros(C).index_copy_(0, nz, up_r[:m]).view(shape)
            best_c = self._impossible_best(beliefs, xs, shape).index_copy_(0, nz, best_r[:m])
            best_c = best_c.view(shape)
            self_low, self_up = low_r[m:], up_r[m:]
        else:
            flat = torch.cat([J.reshape(C, Y), beliefs])  # (C + B, Y)
            low, best = self.lower_value(flat, cx)
            up = self.ub.value(flat, cx)
            best_c = torch.where(prob.reshape(-1) > 0, best[:C],
                                 self._impossible_best(beliefs, xs, shape)).view(shape)  # fmt: skip
            low_c, up_c = low[:C].view(shape), up[:C].view(shape)
            self_low, self_up = low[C:], up[C:]
        reward = self.form.reward(x, beliefs)  # (B, A)
        q_low = reward + self.gamma * low_c.sum((-1, -2))
        q_up = reward + self.gamma * up_c.sum((-1, -2))
        return _Evaluation(xs, J, prob, low_c, best_c, up_c, q_low, q_up, self_low, self_up)

    def _impossible_best(self, beliefs: torch.Tensor, xs: torch.Tensor,
                         shape: tuple[int, int, int, int]) -> torch.Tensor:  # fmt: skip
        """``(B * A * K * O,)`` the best vector of each child's ``x2`` at its parent belief.

        What a backup uses at an impossible child (:meth:`_impossible_best_np`).
        """
        B, _, K, _ = shape
        rows = beliefs.unsqueeze(1).expand(B, K, beliefs.shape[-1]).reshape(B * K, -1)
        _, ids = self.lower_value(rows, xs.repeat(B))  # (B * K,)
        return ids.view(B, 1, K, 1).expand(shape).contiguous().view(-1)

    # -- numpy path (CPU, one belief) -------------------------------------------------------
    def _lower_np(self, rows: np.ndarray, rows_x: np.ndarray, cols: np.ndarray | None = None,
                  ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """``(B,)`` max alpha . b over the vectors of each ``x`` and the argmax (numpy).

        Only the vectors of the rows' own observed values are scored (``alphas.group(x)``,
        ``N_x * Y`` per row instead of ``N * Y``); ties go to the lowest index, as a scan of
        the whole set would. Rows given on the columns ``cols`` only (children of a sparse
        belief, :class:`~torchhrc.solvers.forms.base.Children`) are scored against the
        groups' columns restricted to them.
        """
        if self.X == 1:
            Vt, ids = self.alphas.group_columns(0)
            return self._score_np(rows, Vt if cols is None else Vt[cols], ids)
        if self._kernel is not None and cols is None:  # each row against its own x's, compiled
            return self.alphas.group_scores(self._kernel, np.ascontiguousarray(rows), rows_x)
        B = rows.shape[0]
        first = rows_x[0]
        if (rows_x == first).all():
            Vt, ids = self.alphas.group_columns(int(first))
            return self._score_np(rows, Vt if cols is None else Vt[cols], ids)
        # one product against the vectors of all the rows' observed values, masked to each
        # row's own: fewer array ops than one product per observed value
        xs = np.unique(rows_x)
        blocks = [self.alphas.group_columns(int(u)) for u in xs]
        Vt = np.concatenate([v for v, _ in blocks], axis=1)  # (Y, sum N_x)
        if cols is not None:
            Vt = Vt[cols]
        ids = np.concatenate([i for _, i in blocks])
        label = np.repeat(xs, [i.size for _, i in blocks])  # (sum N_x,) observed value
        scores = rows @ Vt  # (B, sum N_x)
        scores[rows_x[:, None] != label[None, :]] = -np.inf
        j = scores.argmax(-1)
        return scores[np.arange(B), j], ids[j]

    @staticmethod
    def _score_np(rows: np.ndarray, Vt: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, ...]:
        """``max_n rows . V[n]`` ``(B,)`` and ``ids`` of the argmax, for the vectors given as
        columns ``Vt (Y, N)``."""
        if rows.shape[1] >= 64:
            cols = np.flatnonzero(rows.any(0))
            if cols.size * 2 <= rows.shape[1]:  # sparse beliefs: only their support matters
                scores = rows[:, cols] @ Vt[cols]  # (B, N)
            else:
                scores = rows @ Vt
        else:
            scores = rows @ Vt  # (B, N)
        j = scores.argmax(-1)  # one pass; the maximum is the score there
        B = rows.shape[0]
        return scores[_ROWS[:B] if B <= _ROWS.size else np.arange(B), j], ids[j]

    def _upper_np(
        self,
        value: Any,
        nz: np.ndarray,
        reward: np.ndarray,
        C: int,
        stale: tuple[np.ndarray, ...] | None,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Upper bounds of a belief's possible children ``nz`` (of ``C``, ``C / A`` per
        action, in action order), ``Q_up``, ``V_up``.

        ``value(ids)`` bounds rows ``ids`` of the children (row ``nz.size`` is ``b`` itself).
        Without ``stale`` every child is bounded. With ``stale`` (the node's cached
        ``q_low, q_up, prob, low, up`` of an earlier evaluation) only the children of the
        action with the highest ``Q_up`` are re-bounded, repeatedly, until the best action is
        one just refreshed (APPL's ``getNewUBValueUseCache``): every earlier sawtooth value is
        still an upper bound, so stale ``Q_up`` of the other actions stay valid, and a backup
        bounds one or two actions' children instead of all ``A``.
        """
        m, A = nz.size, reward.shape[0]
        if stale is None:
            up_r = value(np.arange(m + 1))
            up = np.zeros(C, dtype=reward.dtype)
            up[nz] = up_r[:m]
            q_up = reward + self.gamma * up.reshape(A, -1).sum(-1)
            return up, q_up, float(up_r[m])
        q_up = stale[1].copy()
        up = stale[4].reshape(-1).copy()
        # plain floats and lists: the loop runs over A values one to three times per
        # backup, where each numpy call costs more than the arithmetic (aloha: 9 actions)
        q = q_up.tolist()
        fresh = [False] * A
        top = None  # the highest Q_up of a refreshed action
        every = m == C  # every child possible (dense models): action a's rows are a block
        if every:
            blocks = self._action_rows(A, C)
        else:  # action a: rows ends[a] to ends[a + 1] of nz
            ends = np.searchsorted(nz // (C // A), np.arange(A + 1)).tolist()
        cu = None
        while True:
            # refresh the best stale action while it beats every fresh one (ties within
            # 1e-12 relative, resolved to the lowest index, so that round-off in the cached
            # values does not change which children are bounded)
            if top is None:
                cand = range(A)
            else:
                over = top + 1e-12 * max(1.0, abs(top))
                cand = [i for i in range(A) if not fresh[i] and q[i] > over]
                if not cand:
                    break
            best = max(q[i] for i in cand)
            floor = best - 1e-12 * max(1.0, abs(best))
            a = next(i for i in cand if q[i] >= floor)
            if every:
                sel, with_b = blocks[a]
                ids = sel if cu is not None else with_b
            else:
                sel = np.arange(ends[a], ends[a + 1])
                ids = sel if cu is not None else np.append(sel, m)
            vals = value(ids)
            if cu is None:
                cu, vals = float(vals[-1]), vals[:-1]
            if every:
                up[sel] = vals
            else:
                up.reshape(A, -1)[a] = 0.0
                up[nz[sel]] = vals
            q_up[a] = reward[a] + self.gamma * up.reshape(A, -1)[a].sum()
            q[a] = float(q_up[a])
            fresh[a] = True
            top = q[a] if top is None else max(top, q[a])
        assert cu is not None
        return up, q_up, cu

    def _action_rows(self, A: int, C: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """When all ``C`` children of a belief are possible (``C / A`` per action): per action
        ``a``, its rows ``(C / A,)`` and the same with the belief's own row ``C`` appended
        (built once per ``(A, C)``)."""
        key = (A, C)
        rows = self._rows_cache.get(key)
        if rows is None:
            n = C // A
            rows = [(np.arange(a * n, (a + 1) * n), np.append(np.arange(a * n, (a + 1) * n), C))
                    for a in range(A)]  # fmt: skip
            self._rows_cache[key] = rows
        return rows

    def _evaluate_np(
        self, x: int, b: np.ndarray, stale: tuple[np.ndarray, ...] | None = None
    ) -> tuple[np.ndarray, ...]:
        """:meth:`evaluate` for one belief ``b (Y,)`` in numpy.

        The form gives the possible children (:meth:`SolverModel.children_np`, on the columns
        they live on); they and ``b`` are bounded by one product against the alpha vectors
        and one sawtooth evaluation. Returns ``q_low (A,)``, ``q_up (A,)``, ``prob``, ``low``,
        ``up`` (``(A, K, O)`` each, as :class:`_Evaluation`), ``best (A, K, O)``,
        ``V_low(b)``, ``V_up(b)``, the children's observed values ``child_x (A * K * O,)`` and
        the best vector at ``b`` itself. ``best`` holds the possible children's vectors only
        (0 elsewhere): a backup fills the impossible children of the one action it takes
        (:meth:`_impossible_best_np`); the sampling and the pruning read possible ones only.
        ``stale``: the node's cached evaluation, see :meth:`_upper_np`.
        """
        ch = self.form.children_np(x, b)
        A, K, O = ch.prob.shape
        low_r, best_r = self._lower_np(ch.rows, ch.rows_x, ch.cols)
        m = ch.nz.size
        if self._kernel is not None and ch.cols is None and ch.rows.flags.c_contiguous:
            # float64 on the CPU, the children on all columns: the rest in one compiled call
            xs = (0,) if self.X == 1 else set(ch.rows_x.tolist())
            low, best, q_low, up, q_up, cu = backup_kernel.bound_children(
                self._kernel, ch.rows, ch.rows_x.astype(np.int64, copy=False), ch.nz, low_r,
                best_r, ch.reward, self.gamma,
                None if stale is None else (stale[1], stale[4].reshape(-1)),
                self.ub.loop_storage(xs), A * K * O,
            )  # fmt: skip
            shape = (A, K, O)
            low, up, best = low.reshape(shape), up.reshape(shape), best.reshape(shape)
            lo, own = float(low_r[m]), int(best_r[m])
            return q_low, q_up, ch.prob, low, up, best, lo, cu, ch.child_x, own
        if m == A * K * O:  # every child possible: the rows are the children in order
            low, best = low_r[:m], best_r[:m]
        else:
            low = np.zeros(A * K * O, dtype=b.dtype)
            low[ch.nz] = low_r[:m]
            best = np.zeros(A * K * O, dtype=np.int64)
            best[ch.nz] = best_r[:m]
        q_low = ch.reward + self.gamma * low.reshape(A, K * O).sum(-1)
        rows, rows_x, cols = ch.rows, ch.rows_x, ch.cols
        up, q_up, cu = self._upper_np(
            lambda ids: self.ub.value_np(rows[ids], rows_x[ids], cols),
            ch.nz, ch.reward, A * K * O, stale,
        )  # fmt: skip
        shape = (A, K, O)
        return (q_low, q_up, ch.prob, low.reshape(shape), up.reshape(shape), best.reshape(shape),
                float(low_r[m]), cu, ch.child_x, int(best_r[m]))  # fmt: skip

    def _impossible_best_np(self, x: int, b: np.ndarray, child_x: np.ndarray, possible: np.ndarray,
                            own: int | None = None) -> np.ndarray:  # fmt: skip
        """``(C,)`` the vector a backup of ``b`` uses at each impossible child (``P = 0``;
        ``possible (C,)`` bool marks the others).

        An impossible child weighs 0 in ``V_low(b)``, but its vector still shapes the new
        alpha vector away from ``b``'s support, i.e. its value at the other beliefs of the
        same ``x``. As APPL's ``BackupAlphaPlaneMOMDP::getNewAlphaPlaneQ`` (a ``NULL`` edge
        takes ``getBestAlphaPlane`` of the belief ``b`` under ``x2``), it is the best vector
        of its ``x2`` at ``b`` itself, not an arbitrary vector of ``x2`` (formerly the last
        one added: on RockSample_7_8 as a MOMDP its new vectors then generalised poorly to
        the beliefs the search had not backed up). Possible children's entries are left to
        the caller. ``own``: the best vector at ``b`` under ``x`` when the caller has it (an
        evaluation scores ``b`` itself), used for the children that stay at ``x``: with one
        observed value, every child.
        """
        if own is not None and self.X == 1:
            return np.full(child_x.shape[0], own, dtype=np.int64)
        best = np.zeros(child_x.shape[0], dtype=np.int64)
        imp = ~possible
        cx = child_x[imp]
        # the distinct x2 of the impossible children, a few among many, as a plain sorted
        # list: np.unique(return_inverse=True) cost 26 us a backup on RockSample(8,4) as a
        # MOMDP, a quarter of the backup, for one or two values
        distinct = sorted(set(cx.tolist()))
        if not distinct:
            return best
        if own is not None and distinct == [x]:  # a flat model: always
            best[imp] = own
            return best
        # b itself under each distinct x2
        ux = np.array(distinct, dtype=np.int64)
        if self._kernel is not None:  # one compiled call
            ids = self.alphas.group_scores(self._kernel, b.reshape(1, -1), ux)[1]
        else:
            ids = self._lower_np(np.broadcast_to(b, (ux.size, b.shape[0])), ux)[1]
        best[imp] = ids[0] if ux.size == 1 else ids[np.searchsorted(ux, cx)]
        return best

    def _backup_one_np(self, x: int, node: int) -> None:
        """:meth:`backup` of one node in numpy (the sequential path of a trial)."""
        tree = self.tree
        b = tree.beliefs_np[node]
        stale = self._cache.get(int(self.belief_id[node])) if self.cfg.lazy_upper else None
        q_low, q_up, prob, low_c, up_c, best, lo, cu, child_x, own = self._evaluate_np(x, b, stale)
        a = int(q_low.argmax())
        use = best[a]  # (K, O); the impossible children's vectors for this action only
        if np.count_nonzero(prob[a]) < prob[a].size:  # some child of a is impossible (P >= 0)
            possible = prob[a] > 0
            ch_a = child_x.reshape(best.shape[0], -1)[a]
            fill = self._impossible_best_np(x, b, ch_a, possible.reshape(-1), own)
            use = np.where(possible, use, fill.reshape(use.shape))
        alpha = self.form.backup_vector_np(x, a, use, self.alphas.np_vectors, self.gamma)
        nl = float(alpha @ b)
        q_up_list = q_up.tolist()
        nu = max(q_up_list)
        self._cache[int(self.belief_id[node])] = (q_low, q_up, prob, low_c, up_c)
        self._child_best[int(self.belief_id[node])] = best
        if nl > lo + 1e-10 * max(abs(nl), 1.0):
            self.alphas.add_np(alpha, a, x, best[a][prob[a] > 0])
        if nu < cu - 1e-10 * max(abs(cu), 1.0):
            self.ub.add_np(b, x, nu)
        low, up = max(lo, nl), min(cu, nu)
        tree.lower[node], tree.upper[node] = low, up
        self.backups += 1
        if self.cfg.prune_nodes and min(q_up_list) < q_low[a]:  # q_low[a] = max Q_low
            bad = q_up < q_low[a]  # (A,)
            for c in self.children.get(node, ()):
                if bad[tree.action[c]]:
                    tree.active[c] = False
        if self.cfg.prediction == "binning":
            self.bins.update(int(self.belief_id[node]), x, b, float(self.entropy[node]), up, low)

    def _root_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R,)`` the lower and upper bound at each root."""
        xs, b, _ = self.form.roots
        if self._np:
            rows = b.numpy()
            return self._lower_np(rows, xs)[0], self.ub.value_np(rows, xs)
        x = torch.from_numpy(xs).to(b.device)
        lo = self.lower_value(b, x)[0].cpu().double().numpy()
        return lo, self.ub.value(b, x).cpu().double().numpy()

    # -- backup ----------------------------------------------------------------------------
    def backup(self, x: int, nodes: np.ndarray) -> None:
        """Point-based backup of tree nodes sharing observed value ``x``, all at once.

        Lower bound: for the action ``a`` maximising ``Q_low(b, a)``, the alpha vector
        ``alpha(y) = R(a, x, y) + gamma sum_{x2, o, y2} Tx Ty Z(a, x2, y2, o) alpha_{x2, o}(y2)``
        with ``alpha_{x2, o}`` the best vector at ``tau(b, a, x2, o)`` (Pineau et al. 2003); it
        is added when it raises ``V_low(b)``. Upper bound: the point
        ``(b, max_a Q_up(b, a))`` is added when below the sawtooth at ``b``.
        """
        if self._np and (len(nodes) == 1 or not self.form.batch_backups):
            for node in nodes.tolist():
                self._backup_one_np(x, int(node))
            return
        tree, form = self.tree, self.form
        B = len(nodes)
        beliefs = (
            tree.beliefs[torch.from_numpy(nodes).to(self.device)]
            if B > 1
            else tree.beliefs[int(nodes[0])][None]
        )
        ev = self.evaluate(x, beliefs)
        a = ev.q_low.argmax(-1)  # (B,)
        sel = ev.best[torch.arange(B, device=self.device), a]  # (B, K, O) alpha index per child
        possible = ev.prob[torch.arange(B, device=self.device), a] > 0  # (B, K, O)
        refs = [sel[i][possible[i]].cpu().numpy() for i in range(B)]
        W = self.alphas.vectors[sel]  # (B, K, O, Y)
        z = form.observation_slice(x, a)  # (B, K, O, Y)
        alpha = form.R[a, x, :] + self.gamma * form.backproject(x, a, (z * W).sum(2))  # (B, Y)
        new_low = (alpha * beliefs).sum(-1)
        new_up = ev.q_up.amax(-1)
        cur_low, cur_up = ev.self_low, ev.self_up
        xb = self._child_x[(x, B)][-B:]
        for i, node in enumerate(nodes.tolist()):
            self._store(node, ev, i)
        if B == 1:
            lo, nl, cu, nu = cur_low.item(), new_low.item(), cur_up.item(), new_up.item()
            if nl > lo + 1e-10 * max(abs(nl), 1.0):
                self.alphas.add(alpha, a, xb, refs)
            if nu < cu - 1e-10 * max(abs(cu), 1.0):
                self.ub.add(beliefs, xb, new_up)
            tree.lower[nodes[0]], tree.upper[nodes[0]] = max(lo, nl), min(cu, nu)
            low, up = np.array([max(lo, nl)]), np.array([min(cu, nu)])
        else:
            better = new_low > cur_low + 1e-10 * new_low.abs().clamp(min=1.0)
            if better.any():
                keep = better.nonzero().squeeze(-1)
                self.alphas.add(alpha[keep], a[keep], xb[keep], [refs[i] for i in keep.tolist()])
            improve = new_up < cur_up - 1e-10 * cur_up.abs().clamp(min=1.0)
            if improve.any():
                keep = improve.nonzero().squeeze(-1)
                self.ub.add(beliefs[keep], xb[keep], new_up[keep])
            low = torch.maximum(new_low, cur_low).cpu().numpy()
            up = torch.minimum(new_up, cur_up).cpu().numpy()
            tree.lower[nodes], tree.upper[nodes] = low, up
        self.backups += B
        # sub-optimal action pruning: children reached by a with Q_up(b, a) < max Q_low(b, .)
        if self.cfg.prune_nodes:
            bad = (ev.q_up < ev.q_low.amax(-1, keepdim=True)).cpu().numpy()  # (B, A)
            for i, n in enumerate(nodes.tolist()):
                for c in self.children.get(n, ()):
                    if bad[i, tree.action[c]]:
                        tree.active[c] = False
        if self.cfg.prediction == "binning":
            ent = self.entropy[nodes]
            rows = beliefs.cpu().double().numpy()
            for i, (n, u, e, lo) in enumerate(
                zip(nodes.tolist(), up.tolist(), ent.tolist(), low.tolist())
            ):
                self.bins.update(int(self.belief_id[n]), x, rows[i], e, u, lo)

    @staticmethod
    def _entropy(beliefs: torch.Tensor) -> torch.Tensor:
        p = beliefs.clamp(min=0)
        return -(torch.where(p > 0, p * p.clamp(min=1e-300).log(), p.new_zeros(()))).sum(-1)

    # -- sampling --------------------------------------------------------------------------
    def sample(self, eps: float) -> list[int]:
        tree, g = self.tree, self.gamma
        node, t = 0, 0
        L = float(tree.lower[0])
        U = L + eps
        if self.n_roots > 1:
            # a random first x: the roots are the outcomes of a step without reward or
            # discount, taken with probability ``w``; the trial enters the root of largest
            # weighted gap (the observation choice below) with the targets of that step
            R, w = self.n_roots, self.root_w
            lo, up = tree.lower[:R], tree.upper[:R]
            total = float(w @ lo)
            node = int(np.argmax(w * (up - lo)))
            L = float(lo[node])  # (total - sum of the others' w lo) / w[node]
            U = float(up[node]) + (total + eps - float(w @ up)) / float(w[node])
        path = [node]
        seen = {int(self.belief_id[node])}
        forward = self._forward = set()
        while t < self.max_depth and not self._out_of_budget():
            lo, up = float(tree.lower[node]), float(tree.upper[node])
            if self.cfg.prediction == "binning":
                v_hat = self.bins.predict(int(self.belief_id[node]), up, lo)
            else:
                v_hat = up
            if up - lo <= 0.5 * eps * g ** (-t):
                # APPL's final precision: the gap here is within half the trial's target
                # error, whatever the predictor says (SampleBP::sample, ``finalExcess``);
                # it ends a trial that a cycle's backups keep raising (shuttle: 238 steps)
                break
            if v_hat <= L and up <= max(U, lo + eps * g ** (-t)):
                break
            x = int(tree.x[node])
            cached = self._cache.get(int(self.belief_id[node]))
            if cached is None:
                if self._np:
                    full = self._evaluate_np(x, tree.beliefs_np[node])
                    cached = full[:5]
                    self._cache[int(self.belief_id[node])] = cached
                    self._child_best[int(self.belief_id[node])] = full[5]
                else:
                    ev = self.evaluate(x, tree.beliefs[node].unsqueeze(0))
                    cached = self._store(node, ev, 0)
            q_low, q_up, prob_all, low_all, up_all = cached
            q_low_max = float(q_low.max())
            L1 = max(L, q_low_max)
            U1 = max(U, q_low_max + eps * g ** (-t))
            a = self._argmax_tie(q_up)
            prob, up_a, low_a = prob_all[a], up_all[a], low_all[a]  # (K, O) each
            excess = np.where(prob > 0, (up_a - low_a) - eps * g ** (-(t + 1)) * prob, -np.inf)
            k, o = np.unravel_index(int(excess.argmax()), prob.shape)
            k, o = int(k), int(o)
            p = float(prob[k, o])
            if p <= 0:
                break
            low_c, up_c = float(low_a[k, o]), float(up_a[k, o])
            L = (L1 - float(q_low[a]) + g * low_c) / (g * p)
            U = (U1 - float(q_up[a]) + g * up_c) / (g * p)
            x2 = int(self.form.reach_np(x)[k]) if self._np else int(self.form.reach[x][k])
            child = tree.child(node, a, x2, o)
            if child < 0:
                if self._np:
                    row = self.form.child_np(x, tree.beliefs_np[node], a, k, o) / p
                    child = self._add_node(row, x2, node, a, o)
                else:
                    _, J = self.form.expand(x, tree.beliefs[node].unsqueeze(0))
                    child = self._add_node(J[0, a, k, o] / p, x2, node, a, o)
                tree.lower[child] = low_c / p
                tree.upper[child] = up_c / p
            node = child
            t += 1
            path.append(node)
            bid = int(self.belief_id[node])
            if self.cfg.forward_backups and bid in seen:
                # the trial reached a belief it already passed (a cycle of the model): back
                # it up now, as APPL backs up every node a trial reaches, so that the descent
                # itself propagates values around the cycle
                self.backup(x2, np.array([node]))
                forward.add(node)
            seen.add(bid)
        return path

    def _store(self, node: int, ev: _Evaluation, i: int) -> tuple[np.ndarray, ...]:
        """Cache a node's action and child bounds (row ``i`` of ``ev``) for the sampling.

        As in APPL, sampling reads the bounds of a node's last backup; they stay valid bounds
        (upper bounds only decrease and lower bounds only increase afterwards).
        """
        entry = tuple(t[i].cpu().numpy() for t in (ev.q_low, ev.q_up, ev.prob, ev.low, ev.up))
        self._cache[int(self.belief_id[node])] = entry
        self._child_best[int(self.belief_id[node])] = ev.best[i].cpu().numpy()
        return entry

    def _child_winners(self, nodes: np.ndarray) -> np.ndarray:
        """The alpha vectors best at a child of the beliefs of ``nodes`` at their last
        evaluation, if it came after the last alpha pruning, for the children a later backup
        of the belief may combine: possible ones (``P > 0``) under an action whose ``Q_up``
        reaches ``max_a Q_low`` (the others are never the backup's action again: upper bounds
        only fall, lower bounds only rise).

        APPL's SARSOP keeps, besides the vectors certified at tree beliefs, the vector best at
        each belief of its cache when the belief was created, the unexpanded children of the
        tree included, until a newer vector beats it there (``AlphaPlaneMaxMeta``,
        ``PruneAlphaPlane::updateMax``). Here a child's best vector is recorded at each
        evaluation of its parent, and the records start afresh at each pruning: a record from
        before the last pruning is mostly stale (aloha-10max after 20 CPU-s: 1,708 recorded
        vectors, 40 of them still best at a child when formed again, and the kept set grew to
        4,000 vectors by 60 s). A belief the search has not evaluated since then protects
        none of its children's vectors; the tree beliefs keep theirs (:meth:`prune`), so no
        bound at a tree belief falls, and an unexpanded child's is restored when the search
        evaluates its parent again.
        """
        parts = []
        for b in np.unique(self.belief_id[nodes]).tolist():
            best = self._child_best.get(b)
            if best is None:
                continue
            q_low, q_up, prob = self._cache[b][:3]
            parts.append(best[(q_up >= q_low.max())[:, None, None] & (prob > 0)])
        if not parts:
            return np.zeros(0, dtype=np.int64)
        ids = np.unique(np.concatenate(parts))
        return ids[ids >= 0]  # (an entry is -1 only if its vector was dropped: never counted)

    def _add_node(self, belief: torch.Tensor | np.ndarray, x: int, parent: int, action: int,
                  obs: int) -> int:  # fmt: skip
        """Add a tree node (``belief`` a numpy row on the numpy path) with its entropy and the
        id of its distinct belief."""
        node = self.tree.add(belief, x, parent, action, obs)
        if node >= self.entropy.shape[0]:
            grown = np.zeros(2 * self.entropy.shape[0])
            grown[: self.entropy.shape[0]] = self.entropy
            self.entropy = grown
            ids = np.zeros(2 * self.belief_id.shape[0], dtype=np.int64)
            ids[: self.belief_id.shape[0]] = self.belief_id
            self.belief_id = ids
        if isinstance(belief, np.ndarray):
            nz = np.flatnonzero(belief)  # the support (a belief has no negative entry)
            p = belief[nz]
            self.entropy[node] = float(-(p * np.log(p)).sum())
            self.belief_id[node] = self._belief_key(x, belief, nz)
        else:
            self.entropy[node] = float(self._entropy(belief.unsqueeze(0))[0])
            self.belief_id[node] = self._belief_key(x, belief.cpu().numpy())
        self.children.setdefault(parent, []).append(node)
        return node

    def _belief_key(self, x: int, row: np.ndarray, nz: np.ndarray | None = None) -> int:
        """The id of the distinct belief ``(x, row)`` (support and values to 12 digits).

        Keyed by a 128-bit digest of the support and the rounded values rather than their
        bytes (RockSample_7_8.pomdpx: 4 kB a belief, 16 MB after 10 s), with the same ids
        unless two of the beliefs collide (probability about ``n^2 / 2^129``).
        """
        if nz is None:
            nz = np.flatnonzero(row)  # (the caller's, when it has the support)
        digest = hashlib.blake2b(nz.tobytes(), digest_size=16)
        digest.update(np.round(row[nz], 12).tobytes())  # same length: the split is unambiguous
        return self._belief_ids.setdefault((x, digest.digest()), len(self._belief_ids))

    def _argmax_tie(self, q: np.ndarray) -> int:
        """The action of highest ``q`` (ties within 1e-12 relative: the first, or one drawn
        by the seeded generator); on a plain list, as ``q`` has a few entries."""
        values = q.tolist()
        top = max(values)
        floor = top - 1e-12 * max(1.0, abs(top))
        ties = [i for i, v in enumerate(values) if v >= floor]
        if len(ties) == 1 or self.cfg.tie_break == "first":
            return ties[0]
        return ties[int(self.rng.integers(len(ties)))]

    # -- pruning ---------------------------------------------------------------------------
    def _affordable(self, kind: str, size: int) -> bool:
        """Whether a pruning of ``kind`` at ``size`` items ends before the deadline, judged by
        the last one's duration scaled to ``size`` (its cost grows about linearly): a pruning
        is skipped near the end rather than overrun the limit (it only bounds the sets'
        growth; the bounds stay valid without it)."""
        last = self._prune_cost.get(kind)
        if last is None:
            return True
        seconds, at = last
        return self.clock() + seconds * size / max(at, 1) < self.deadline

    def prune(self) -> None:
        pruned = self._prune_alphas()
        if self._prune_points() or pruned:
            release_free_memory()  # what the pruning freed, back to the OS (see _memory)
        if self.cfg.prune_nodes:
            self.tree.refresh_active()

    def _prune_alphas(self) -> bool:
        """Prune the alpha vectors when the set has grown enough; whether it ran."""
        cfg = self.cfg
        if not (
            cfg.prune_alphas
            and self.alphas.size > cfg.prune_growth * max(self.last_alpha_prune, 16)
            and self._affordable("alphas", self.alphas.size)
        ):
            return False
        t0 = self.clock()
        n = self.alphas.size
        vec, obs = self.alphas.vectors[:n], self.alphas.observed[:n]
        groups = obs if self.X > 1 else None
        act = np.flatnonzero(self.tree.active[: self.tree.size])
        # the winners at the tree beliefs, and (in keep) every vector they were built
        # from: a backup chooses child vectors at children outside the tree, and without
        # them the greedy policy cannot realise a kept vector's value (before:
        # RockSample_7_8.pomdpx, written policy 16.4 simulated against a lower bound 20.3)
        mask = self.tree.keep_alphas(vec, groups, act)
        # and the best vectors at the children of the active tree beliefs (APPL certifies
        # a vector at any belief of its cache, the unexpanded children of the tree
        # included): a backup of a tree belief combines the best vectors at its children,
        # and pruning those would lower the children's bounds, which only a search that
        # reaches each child again restores
        mask[torch.from_numpy(self._child_winners(act)).to(mask.device)] = True
        self.alphas.keep(mask)
        # the next pruning protects the children of the beliefs evaluated from now on
        self._child_best = {}
        self.last_alpha_prune = self.alphas.size
        self._prune_cost["alphas"] = (self.clock() - t0, n)
        return True

    def _prune_points(self) -> bool:
        """Prune the upper-bound points when they have grown enough; whether it ran."""
        cfg = self.cfg
        n = self.ub.size
        if n <= cfg.prune_growth * max(self.last_point_prune, 64) or not self._affordable(
            "points", n
        ):
            return False
        t0 = self.clock()
        self.ub.prune()
        self.last_point_prune = self.ub.size
        self._prune_cost["points"] = (self.clock() - t0, n)
        return True

    def sweep(self) -> None:
        """Back up every active tree node, one batched backup per observed value."""
        tree = self.tree
        act = np.flatnonzero(tree.active[: tree.size])
        xs = tree.x[act]
        for x in np.unique(xs).tolist():
            nodes = act[xs == x]
            # deepest first within the batch order does not matter: one batched backup
            for start in range(0, nodes.size, 256):
                if self._out_of_budget():
                    return  # every backup leaves valid bounds: the rest waits (as a trial)
                self.backup(int(x), nodes[start : start + 256])

    # -- main loop -------------------------------------------------------------------------
    def record(self, iteration: int) -> dict[str, Any]:
        """The bounds at the start (the roots' weighted by their probability), kept
        monotone per root, as a history entry."""
        lo_r, up_r = self._root_bounds()
        tree, R = self.tree, self.n_roots
        lo_r = np.maximum(lo_r, self.root_low)
        up_r = np.minimum(up_r, tree.upper[:R])
        tree.lower[:R], tree.upper[:R] = lo_r, up_r
        self.root_low = lo_r
        lo, up = float(self.root_w @ lo_r), float(self.root_w @ up_r)
        entry = {
            "time_s": time.perf_counter() - self.start,
            "lower": lo,
            "upper": up,
            "n_alphas": self.alphas.size,
            "n_beliefs": tree.size,
            "n_points": self.ub.size,
            "iteration": iteration,
        }
        self.history.append(entry)
        return entry

    def run(self) -> Solution:
        cfg = self.cfg
        entry = self.record(0)
        reason = "time_limit"
        iteration = 0
        try:
            while True:
                if entry["upper"] - entry["lower"] <= cfg.precision:
                    reason = "precision"
                    break
                if cfg.max_iterations is not None and iteration >= cfg.max_iterations:
                    reason = "max_iterations"
                    break
                if self._out_of_budget():
                    memory = self.memory is not None and self.memory.tripped
                    reason = "memory" if memory else "time_limit"
                    break
                iteration += 1
                eps = cfg.kappa * (entry["upper"] - entry["lower"])
                # the time limit is also checked inside the iteration (at every step of the
                # trial and between backups): a long trial is cut short, and what was backed
                # up so far is kept (every backup leaves valid bounds)
                path = self.sample(eps)
                self._longest = max(self._longest, len(path))
                if len(path) > 1 and path[-1] in self._forward:
                    path = path[:-1]  # the leaf was backed up when the trial reached it
                for node in reversed(path):
                    self.backup(int(self.tree.x[node]), np.array([node]))
                    if self._out_of_budget():
                        break
                if cfg.sweep_interval and iteration % cfg.sweep_interval == 0:
                    self.sweep()  # (it reads the budget before each of its batches)
                if not self._out_of_budget():
                    self.prune()
                entry = self.record(iteration)
                if cfg.callback is not None and cfg.callback(dict(entry)):
                    reason = "callback"
                    break
                if cfg.checkpoint is not None and self.clock() >= self._next_checkpoint:
                    self._checkpoint(iteration)
        except KeyboardInterrupt:
            reason = "interrupted"
            entry = self.record(iteration)
        return self.solution(reason, iteration)

    def _policy(self) -> AlphaVectorPolicy:
        """The alpha vectors so far as the form's policy (a copy)."""
        n = self.alphas.size
        return self.form.policy(self.alphas.vectors[:n].clone(),
                                self.alphas.actions[:n].clone(),
                                self.alphas.observed[:n].clone())  # fmt: skip

    def _checkpoint(self, iteration: int) -> None:
        """Hand the policy and bounds so far to ``checkpoint``; schedule the next."""
        cfg = self.cfg
        assert cfg.checkpoint is not None and cfg.policy_interval is not None
        last = self.history[-1]
        cfg.checkpoint(Solution(self._policy(), lower=last["lower"], upper=last["upper"],
                                history=list(self.history),
                                info={"checkpoint": True, "iterations": iteration}))  # fmt: skip
        self._next_checkpoint = self.clock() + cfg.policy_interval

    def solution(self, reason: str, iterations: int) -> Solution:
        last = self.history[-1]
        last["stop_reason"] = reason
        info = {
            "stop_reason": reason,
            "iterations": iterations,
            "backups": self.backups,
            "n_beliefs": self.tree.size,
            "n_points": self.ub.size,
            "init": dict(self.init_info),
        }
        if reason == "memory":
            # the search's belief tree, upper-bound points and caches are done with: freed
            # before the policy copies the vectors (and checks them: about twice their size
            # at its peak)
            self._cache, self._child_best, self.children = EvaluationCache(), {}, {}
            self.tree = self.form.new_tree()
            del self.ub, self.bins  # (the solver is not used after this)
            self.alphas._gcol, self.alphas._gid = [], []  # the vectors' per-x copy
            release_free_memory()
        policy = self._policy()
        return Solution(policy, lower=last["lower"], upper=last["upper"],
                        history=self.history, info=info)  # fmt: skip


def sarsop(model: POMDP | MOMDP | SparsePOMDP, config: SARSOPConfig | None = None) -> Solution:
    """Solve a POMDP or MOMDP with SARSOP; anytime, stops on ``time_limit`` or ``precision``.

    Args:
        model: an unbatched :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.MOMDP`
            with ``discount < 1``, or a :class:`~torchhrc.pomdp.SparsePOMDP` (the sparse
            flat path, see the module docstring; custom ``lower_bound_init`` and
            ``upper_bound_init`` then receive the ``SparsePOMDP``).
        config: the settings (default :class:`SARSOPConfig()`).

    Returns:
        :class:`~torchhrc.solvers.solution.Solution`: an
        :class:`~torchhrc.solvers.policy.AlphaVectorPolicy` (MOMDP: vectors over ``Y`` tagged
        with ``observed``), ``lower <= V*(b0) <= upper`` (for a random start, ``V*`` of the
        start: ``sum_x P(x) V*(x, P(. | x))``), and ``history``, one dict per
        iteration with ``time_s``, ``lower``, ``upper``, ``n_alphas``, ``n_beliefs``,
        ``n_points``, ``iteration``. ``info["stop_reason"]`` is ``"precision"``,
        ``"time_limit"``, ``"memory"`` (``memory_limit``), ``"max_iterations"``,
        ``"callback"`` or ``"interrupted"``
        (KeyboardInterrupt: the best policy so far is returned); ``info["init"]`` has the
        initialisation's times (``lower_s``, ``upper_s``) and, for the default FIB, its
        ``upper_iterations`` and ``upper_stop`` (``"converged"``, ``"max_iterations"`` or
        ``"time_limit"``, the last making the result depend on the machine's speed).

    Raises:
        ModelError: a batched model, ``discount >= 1``, or an initialiser of the wrong shape.
        TypeError: ``model`` or ``config`` of the wrong type.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> sol = sarsop(random_momdp(3, 2, 2, 2, seed=0), SARSOPConfig(time_limit=2.0))
        >>> sol.lower <= sol.upper and sol.policy.is_momdp
        True
    """
    start = time.perf_counter()
    if config is None:
        config = SARSOPConfig()
    if not isinstance(config, SARSOPConfig):
        raise TypeError(f"expected config to be a SARSOPConfig, got {type(config).__name__}")
    clock_start = clock_function(config.clock)()
    # The sequential path multiplies small matrices (tens of rows) in numpy; a multi-threaded
    # OpenBLAS spends more time waking and spinning threads than computing (measured:
    # RockSample(7, 8), 2 busy cores, 28 ms against 1.6 ms per lower-bound evaluation; dense
    # RockSample(4, 4), 300 iterations: 7.4-8.1 s with 2 BLAS threads, 5.4-6.3 s with one).
    with threadpool_limits(limits=1, user_api="blas"):
        return _SARSOP(model, config, start, clock_start).run()
