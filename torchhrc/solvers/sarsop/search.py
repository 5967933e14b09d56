"""The SARSOP search: :func:`sarsop`, the state and loop of one solve, and the FIB corners.

``_SARSOP`` holds what one solve builds: the initial bounds (FIB corner values, see
:func:`fib_corner_values`, and the blind policies by default), the alpha set
(:mod:`~torchhrc.solvers.sarsop.alpha_set`), the sawtooth upper bound, the belief tree, the
``V_hat`` bins (:mod:`~torchhrc.solvers.sarsop.bins`) and the budget of time and memory
(``memory_limit``, watched by ``MemoryGuard`` of ``torchhrc/solvers/_memory.py``, and the
policy checkpoints). Its loop samples a trial, backs up its path leaf to root, prunes, and
records the bounds at the start. The steps are the methods of its bases:
:mod:`~torchhrc.solvers.sarsop.bounds`, :mod:`~torchhrc.solvers.sarsop.backup`,
:mod:`~torchhrc.solvers.sarsop.trial` and :mod:`~torchhrc.solvers.sarsop.pruning`. The
algorithm: see :mod:`torchhrc.solvers.sarsop`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

# np.unique reads np.ma, and the tie-break draws from np.random: numpy loads both on first use
# (20 ms), so they load with this module rather than on the first solve's clock
import numpy.ma
import numpy.random
import torch

from torchhrc._host import alloc, to_numpy
from torchhrc._threads import blas_threads, torch_threads
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP, SparsePOMDP
from torchhrc.solvers import backup_kernel
from torchhrc.solvers._memory import MemoryGuard, release_free_memory
from torchhrc.solvers.clock import Deadline, clock_function, deadline_watch
from torchhrc.solvers.eval_cache import EvaluationCache
from torchhrc.solvers.forms import SolverModel, as_solver_model
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sarsop.alpha_set import _AlphaSet
from torchhrc.solvers.sarsop.backup import _Backups
from torchhrc.solvers.sarsop.bins import _Bins
from torchhrc.solvers.sarsop.bounds import _Bounds
from torchhrc.solvers.sarsop.config import (
    ALPHA_FLOAT32_MIN_WIDTH,
    EXPLORE_AFTER,
    EXPLORE_MIN_WIDTH,
    SARSOPConfig,
)
from torchhrc.solvers.sarsop.pruning import _Pruning
from torchhrc.solvers.sarsop.trial import _Trials
from torchhrc.solvers.solution import Solution
from torchhrc.solvers.sparse_model import SparseFlatModel
from torchhrc.solvers.upper_bound import SawtoothUpperBound

__all__ = ["fib_corner_values", "sarsop"]

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
    known given the current one), so no FIB iteration runs. A small dense flat model in
    float64 on the CPU gets the fixed point itself, by policy iteration
    (:mod:`~torchhrc.solvers.fib_exact`; ``tol`` and the limits do not apply).

    Args:
        model: an unbatched POMDP or MOMDP, or a flat model with sparse transitions
            (:class:`~torchhrc.pomdp.SparsePOMDP` or
            :class:`~torchhrc.solvers.sparse_model.SparseFlatModel`).
        tol: stop when the largest change is below ``tol``.
        time_limit: a safety net on the FIB iterations after the first: the QMDP start and
            the first FIB step always run, so the bound never depends on the load more than that.
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


def _alpha_dtype(cfg: SARSOPConfig, width: int) -> torch.dtype:
    """The alpha vectors' storage dtype: ``cfg.alpha_dtype``, or by default float32 for
    vectors of at least :data:`~torchhrc.solvers.sarsop.config.ALPHA_FLOAT32_MIN_WIDTH`
    entries under a float64 solve, else the solve's dtype."""
    if cfg.alpha_dtype is not None:
        return cfg.alpha_dtype
    wide = width >= ALPHA_FLOAT32_MIN_WIDTH and cfg.dtype == torch.float64
    return torch.float32 if wide else cfg.dtype


def _explore_after(cfg: SARSOPConfig, width: int) -> int | None:
    """The trials without a rise after which a trial draws its children:
    ``cfg.explore_after``, or for ``"auto"`` :data:`~torchhrc.solvers.sarsop.config.EXPLORE_AFTER`
    where a belief has at least :data:`~torchhrc.solvers.sarsop.config.EXPLORE_MIN_WIDTH`
    entries, else None (never)."""
    if cfg.explore_after != "auto":
        return cfg.explore_after
    return EXPLORE_AFTER if width >= EXPLORE_MIN_WIDTH else None


class _SARSOP(_Trials, _Backups, _Pruning, _Bounds):
    """The search: its state (the initial bounds, the alpha set, the belief tree, the bins),
    its budget of time and memory, and its loop. Bounding, backups, trials and pruning are
    the methods of its bases (:mod:`~torchhrc.solvers.sarsop`)."""

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
        self.A, self.O = form.num_actions, form.num_observations
        self.rng = np.random.default_rng(int(cfg.seed))
        self.device = form.b0.device
        self.deadline = clock_start + cfg.time_limit
        self._time_up = deadline_watch(cfg.clock, self.deadline)  # (read at every step)
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
            self.init_info["upper_method"] = fib.get("method", "iteration")
        else:
            corner = cfg.upper_bound_init(form.init_argument)
        self.init_info["upper_s"] = time.perf_counter() - t_upper
        if corner.dtype != cfg.dtype:
            corner = corner.to(dtype=cfg.dtype)
        corner = form.corner_values(corner, "upper_bound_init")
        self.ub = SawtoothUpperBound(corner)
        t_init = time.perf_counter()
        # lower bound: alpha vectors of a policy (blind policies by default)
        if cfg.lower_bound_init is None:
            policy = form.blind_policy()
        else:
            policy = cfg.lower_bound_init(form.init_argument)
        policy = form.check_policy(policy, "lower_bound_init")
        self.init_info["lower_s"] = time.perf_counter() - t_init
        N = policy.alphas.shape[0]
        observed = (alloc(N, torch.long, policy.actions.device) if policy.observed is None
                    else policy.observed)  # fmt: skip
        if self.X > 1 and np.bincount(to_numpy(observed), minlength=self.X).min() == 0:
            raise ModelError("lower_bound_init's policy must have a vector for every observed x")
        alphas = policy.alphas if policy.alphas.dtype == cfg.dtype else policy.alphas.to(cfg.dtype)
        self.alphas = _AlphaSet(alphas, policy.actions, observed, self.X,
                                dtype=_alpha_dtype(cfg, policy.alphas.shape[1]))  # fmt: skip
        self.alphas.keep(self.alphas.undominated())
        self.tree = form.new_tree()
        self._child_x: dict[tuple[int, int], torch.Tensor] = {}
        self._reach: dict[int, list[int]] = {}  # per x, the x2 it reaches (the trial's step)
        # per distinct belief (``belief_id``): the last evaluation, shared by the tree nodes
        # that hold the same belief (its stale bounds stay valid bounds there)
        self._cache = EvaluationCache(self.A)
        self._rows_cache: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
        # per observed value x, what the compiled backup reads beside the belief (None: the
        # numpy steps; see _one_call), and its scratch per (children, width)
        self._one_calls: dict[int, Any] = {}
        self._scratch: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}
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
        roots_np = to_numpy(root_b)
        self.entropy[:R] = self._entropy(roots_np)
        # one id per distinct belief (APPL's belief cache): tree nodes holding the same belief
        # share its cached evaluation, and a trial that reaches a belief again is in a cycle
        self._belief_ids: dict[bytes, int] = {}
        self.belief_id = np.zeros(cap, dtype=np.int64)
        for r, row in enumerate(roots_np):
            self.belief_id[r] = self._belief_key(int(root_x[r]), row)
        rewards = to_numpy(form.R)
        span = float(rewards.max() - rewards.min()) / (1.0 - self.gamma)
        if cfg.max_depth is not None:
            self.max_depth = cfg.max_depth
        else:
            target = max(cfg.precision, 1e-6 * max(span, 1.0))
            depth = math.log(target / max(span, 1e-12)) / math.log(self.gamma) if span > 0 else 1
            self.max_depth = int(min(max(math.ceil(depth), 1), _MAX_DEPTH))
        corners = to_numpy(corner).reshape(self.X, -1).astype(np.float64)
        self.bins = _Bins(corners, math.log(self.Y), cfg.bins)

        self.last_alpha_prune = self.alphas.size
        self.last_point_prune = 1
        self._prune_cost: dict[str, tuple[float, int]] = {}  # kind -> (seconds, size) of last
        self.history: list[dict[str, Any]] = []
        self.backups = 0
        self._forward: set[int] = set()
        # trials in a row without a rise of the lower bound at the start (compared with
        # explore_after, cfg.explore_after resolved by the beliefs' width), the bound they have
        # not risen above, and the trials that drew their children
        self._stall, self._stall_lower, self.explored = 0, -math.inf, 0
        self.explore_after = _explore_after(cfg, self.alphas.vectors.shape[1])
        # the sequential one-belief path runs in numpy on the CPU, whose per-op overhead at
        # these sizes is several times below torch's dispatch
        self._np = self.device.type == "cpu"
        # the compiled steps of a belief's evaluation (backup_kernel): float64 on the CPU
        self._kernel = backup_kernel.load() if self._np and cfg.dtype == torch.float64 else None
        # ... and of those that read the alpha vectors' rows: float64 vectors only
        self._vkernel = self._kernel if self.alphas.vectors.dtype == torch.float64 else None
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
            pending += tree.size * tree.node_bytes()
        return pending

    def _out_of_budget(self) -> bool:
        """Whether the time limit has passed or the memory limit is near."""
        if self._time_up():
            return True
        return self.memory is not None and self.memory.exceeded(self._pending_bytes)

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
        self._note_progress(entry["lower"])
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
                tree_x = self.tree.x
                for node in reversed(path):
                    self.backup_node(int(tree_x[node]), node)
                    if self._out_of_budget():
                        break
                if cfg.sweep_interval and iteration % cfg.sweep_interval == 0:
                    self.sweep()  # (it reads the budget before each of its batches)
                if not self._out_of_budget():
                    self.prune()
                entry = self.record(iteration)
                self._note_progress(entry["lower"])
                if cfg.callback is not None and cfg.callback(dict(entry)):
                    reason = "callback"
                    break
                if cfg.checkpoint is not None and self.clock() >= self._next_checkpoint:
                    self._checkpoint(iteration)
        except KeyboardInterrupt:
            reason = "interrupted"
            entry = self.record(iteration)
        return self.solution(reason, iteration)

    def _note_progress(self, lower: float) -> None:
        """Count the trials since the lower bound at the start last rose (by more than
        1e-9 relative): :meth:`sample` draws its children once there are
        ``explore_after`` of them (:class:`SARSOPConfig`)."""
        if lower > self._stall_lower + 1e-9 * max(1.0, abs(lower)):
            self._stall, self._stall_lower = 0, lower
        else:
            self._stall += 1

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
            "alpha_dtype": str(self.alphas.vectors.dtype).removeprefix("torch."),
            "iterations": iterations,
            "backups": self.backups,
            "explore_after": self.explore_after,
            "explored_trials": self.explored,
            "n_beliefs": self.tree.size,
            "n_points": self.ub.size,
            "init": dict(self.init_info),
        }
        if reason == "memory":
            # the search's belief tree, upper-bound points and caches are done with: freed
            # before the policy copies the vectors (and checks them: about twice their size
            # at its peak)
            self._cache, self._child_best = EvaluationCache(self.A), {}
            self.tree = self.form.new_tree()
            del self.ub, self.bins  # (the solver is not used after this)
        # the policy takes the vectors as views of the alpha set's storage, not a copy (a
        # second copy of every vector at the peak otherwise); a later use of the solver
        # (tests, benchmarks) still may add and prune (see _AlphaSet.lend)
        self.alphas.forget_scores()
        release_free_memory()
        policy = self.form.policy(*self.alphas.lend())
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
    # Torch's own OpenMP threads likewise: their spin after each small parallel region is CPU
    # time (a third of the backups under clock="process" on 2 cores; torchhrc._threads)
    with blas_threads(1), torch_threads(1):
        return _SARSOP(model, config, start, clock_start).run()
