"""The one model interface under the point-based solvers (SARSOP, PBVI): :class:`SolverModel`.

A point-based solver asks a model a handful of questions, whatever the model's
representation (dense flat, MOMDP-factored, sparse flat, and later a device backend):

* its sizes and the reward, as a mixed-observability model ``(A, X, Y)`` (Ong et al. 2010; a
  flat POMDP is the MOMDP with one observed value, ``X = 1``, ``Y = S``), and the initial
  belief ``(x0, b0)``;
* the **children** of beliefs under every action ``a``, reachable next observed value ``x2``
  and observation ``o``, unnormalised (paper Eq. 3)::

      J[i, a, k, o, y2] = P(x2_k, o | x, b_i, a) * tau(b_i, a, x2_k, o)[y2]

  batched in torch (:meth:`SolverModel.expand`) and, for one belief on the CPU, as the rows
  of its possible children on the columns they live on (:meth:`SolverModel.children_np`);
* the pieces of a point-based **backup** against a set of alpha vectors (Pineau et al. 2003):
  the observation slice ``Z[a, x2_k, y2, o]`` and the back-projection
  ``g[y] = sum_{k, y2} Tx Ty values[k, y2]`` (:meth:`SolverModel.backproject`);
* the **initial bounds**: the blind-policy lower bound (Hauskrecht 2000) and the Fast
  Informed Bound corner values (:meth:`SolverModel.fib_corner_values`);
* the **belief representation**: the tree that stores beliefs (dense rows or supports), and
  how a policy's vectors are tagged (``observed`` for a MOMDP);
* for PBVI: a simulation step, a batched point backup and the value of a policy at beliefs.

Each form implements it once in its own module (:mod:`~torchhrc.solvers.forms.dense`,
:mod:`~torchhrc.solvers.forms.momdp`, :mod:`~torchhrc.solvers.forms.sparse`), and
:func:`~torchhrc.solvers.forms.as_solver_model` picks the form once, at the solver's entry.
SARSOP and PBVI never test which form they hold. What several forms share (the FIB
iteration, the per-observed-value caches, the one-belief children of a dense belief, the
shape checks of user-supplied initialisers) lives here once.

Shapes (``B`` beliefs, ``A`` actions, ``K`` reachable next observed values of ``x``, ``O``
observations, ``Y`` hidden values; a flat model has ``X = K = 1`` and ``Y = S``):

==========================  =============================================================
``R``                       ``(A, X, Y)`` rewards
``reward(x, b)``            ``(B, A)`` expected immediate rewards of ``b (B, Y)``
``expand(x, b)``            ``xs (K,)``, ``J (B, A, K, O, Y)``
``observation_slice(x, a)`` ``(B, K, O, Y)`` for ``a (B,)``
``backproject(x, a, v)``    ``(B, Y)`` for ``a (B,)``, ``v (B, K, Y)``
``children_np(x, b)``       :class:`Children` of one ``b (Y,)``
``backproject_np(x, a, v)`` ``(Y,)`` for one action, ``v (K, Y)``
``fib_corner_values``       ``(S,)`` flat, ``(X, Y)`` MOMDP (the model's own state shape)
==========================  =============================================================

Example:
    >>> from torchhrc.solvers.forms import as_solver_model
    >>> from torchhrc.tasks.classic import tiger
    >>> form = as_solver_model(tiger())
    >>> xs, J = form.expand(form.x0, form.b0.unsqueeze(0))
    >>> tuple(J.shape), form.num_observed, form.factored
    ((1, 3, 1, 2, 2), 1, False)
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch

from torchhrc._host import alloc, host_view, rows, to_numpy
from torchhrc.errors import ModelError
from torchhrc.pomdp import split_initial
from torchhrc.solvers import backup_kernel
from torchhrc.solvers._factored import SPARSE_DIRECT_SOLVE_SIZE, Expectation
from torchhrc.solvers.backup import BackupResult
from torchhrc.solvers.belief_tree import BeliefTree
from torchhrc.solvers.blind import blind_policy
from torchhrc.solvers.clock import NEVER, Deadline
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import sample_categorical
from torchhrc.solvers.sparse_model import qmdp_iteration_np
from torchhrc.solvers.tensor_bounds import _iterate_fib, mdp_upper_vectors

__all__ = [
    "Children",
    "FIBOperator",
    "PerObserved",
    "SimStep",
    "SolverModel",
    "TensorModelForm",
]

#: One Fast Informed Bound step ``(A, *state_shape) -> (A, *state_shape)`` (Hauskrecht 2000).
FIBOperator = Callable[[torch.Tensor], torch.Tensor]


class PerObserved(Sequence[Any]):
    """``build(x)`` for each observed value ``x``, computed on first use and cached.

    The search of a large MOMDP usually visits a small part of ``X``: per-``x`` slices are
    built when it first reaches ``x``.

    Example:
        >>> squares = PerObserved(3, lambda x: x * x)
        >>> squares[2], len(squares)
        (4, 3)
    """

    _MISSING = object()

    def __init__(self, n: int, build: Callable[[int], Any]) -> None:
        self._build = build
        self._items: list[Any] = [self._MISSING] * n

    def __len__(self) -> int:
        return len(self._items)

    def built(self) -> list[bool]:
        """Which observed values have been built so far."""
        return [item is not self._MISSING for item in self._items]

    def __getitem__(self, x: int) -> Any:  # type: ignore[override]
        if not isinstance(x, (int, np.integer)):
            raise TypeError(f"expected an int observed value, got {type(x).__name__}")
        item = self._items[x]
        if item is self._MISSING:
            item = self._items[x] = self._build(int(x))
        return item


def field(cache: PerObserved, i: int) -> PerObserved:
    """The per-``x`` view of field ``i`` of the tuples of ``cache`` (shares its cache)."""
    return PerObserved(len(cache), lambda x: cache[x][i])


class SimStep(NamedTuple):
    """One simulated step of ``M`` simulations at once (:meth:`SolverModel.step`).

    Attributes:
        x: ``(M,)`` next observed value (flat forms: 0).
        y: ``(M,)`` next hidden value (flat forms: the state).
        observation: ``(M,)`` the observation received.
        belief: ``(M, Y)`` the updated belief over the hidden value.
    """

    x: torch.Tensor
    y: torch.Tensor
    observation: torch.Tensor
    belief: torch.Tensor


@dataclass
class Children:
    """The possible children of one belief ``b (Y,)`` at observed value ``x`` (numpy).

    Attributes:
        rows: ``(m + 1, C)`` the ``m`` possible unnormalised children (``P(x2, o) tau``,
            ``prob > 0``), then ``b`` itself, on the columns ``cols``.
        rows_x: ``(m + 1,)`` the observed value of each row.
        cols: ``(C,)`` sorted hidden values the rows are given on (``None``: all ``Y``).
        nz: ``(m,)`` flat indices of the possible children into ``(A, K, O)``.
        prob: ``(A, K, O)`` ``P(x2_k, o | x, b, a)``.
        child_x: ``(A K O,)`` the next observed value of every child.
        reward: ``(A,)`` the expected immediate reward ``R(b, a)``.
    """

    rows: np.ndarray
    rows_x: np.ndarray
    cols: np.ndarray | None
    nz: np.ndarray
    prob: np.ndarray
    child_x: np.ndarray
    reward: np.ndarray


class SolverModel(ABC):
    """What a point-based solver asks of a model (see the module docstring for shapes).

    Attributes:
        num_actions, num_observed, num_hidden, num_observations: ``A``, ``X``, ``Y``, ``O``.
        discount: the discount factor.
        R: ``(A, X, Y)`` rewards.
        x0: the initial observed value; b0: ``(Y,)`` the initial hidden belief (the most
            probable first ``x`` and the belief there when the model starts at a random
            ``x``: see :attr:`roots`).
        factored: True when policies carry ``observed`` tags (MOMDP vectors over ``Y`` per
            ``x``); False for flat ``(N, S)`` policies.
        state_shape: the model's own shape of a value function (``(S,)`` or ``(X, Y)``);
            ``state_doc`` the same in words, for error messages.
        reach: per ``x``, the ``(K_x,)`` long tensor of reachable next observed values.
        batch_backups: whether batched backups of many tree beliefs pay on the CPU (a sparse
            form backs up one belief at a time: a batch would hold ``B A O`` dense children).
        source: the model the user gave.
        init_argument: what custom bound initialisers receive (SARSOP's
            ``lower_bound_init``, ``upper_bound_init``): the model in the solve's dtype, or
            the ``source`` where no such copy exists.
    """

    num_actions: int
    num_observed: int
    num_hidden: int
    num_observations: int
    discount: float
    R: torch.Tensor
    x0: int
    b0: torch.Tensor
    factored: bool
    state_shape: tuple[int, ...]
    state_doc: str
    reach: Sequence[torch.Tensor]
    batch_backups: bool = True
    source: Any

    @property
    def init_argument(self) -> Any:
        return self.source

    # -- the children of beliefs (torch, batched) -------------------------------------------
    @abstractmethod
    def predict(self, x: int, beliefs: torch.Tensor) -> torch.Tensor:
        """``(B, A, K, Y)`` ``sum_y b[y] Tx[a, x, y, x2_k] Ty[a, x, y, x2_k, y2]`` of
        ``beliefs (B, Y)`` at observed value ``x`` (the prediction before ``Z``)."""

    @abstractmethod
    def observation(self, x: int) -> torch.Tensor:
        """``(A, K, O, Y)`` ``Z[a, x2_k, y2, o]`` over the reachable ``x2_k`` of ``x``."""

    def expand(self, x: int, beliefs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Unnormalised children of ``beliefs (B, Y)`` sharing the observed value ``x``.

        Returns:
            ``xs (K,)`` the reachable next observed values and ``J (B, A, K, O, Y)``,
            ``J[i, a, k, o, y2] = P(xs[k], o | x, b_i, a) * tau(b_i, a, xs[k], o)[y2]``.
        """
        return self.reach[x], self.predict(x, beliefs).unsqueeze(-2) * self.observation(x)

    def reward(self, x: int, beliefs: torch.Tensor) -> torch.Tensor:
        """``(B, A)`` expected immediate rewards ``R(b, a) = sum_y b[y] R[a, x, y]`` of
        ``beliefs (B, Y)`` at observed value ``x``."""
        return beliefs @ self._reward_table(x)

    def _reward_table(self, x: int) -> torch.Tensor:
        """``(Y, A)`` ``R[:, x, :]`` transposed, contiguous (built once per ``x``)."""

        def build() -> torch.Tensor:
            r = host_view(self.R)
            if r is None:
                return self.R[:, x, :].T.contiguous()
            return torch.from_numpy(np.ascontiguousarray(r[:, x, :].T))

        return self._cached("RT", x, build)

    def observation_slice(self, x: int, actions: torch.Tensor) -> torch.Tensor:
        """``(B, K, O, Y)``: ``Z[a_i, x2_k, y2, o]`` for ``actions (B,)``."""
        return self.observation(x)[actions]

    @abstractmethod
    def backproject(self, x: int, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """``(B, Y)`` ``g[i, y] = sum_{k, y2} Tx[a_i, x, y, x2_k] Ty[a_i, x, y, x2_k, y2]
        values[i, k, y2]`` for ``actions (B,)`` and ``values (B, K, Y)`` (already summed
        over observations with ``Z``)."""

    # -- one belief on the CPU (numpy) -------------------------------------------------------
    def observation_np(self, x: int) -> np.ndarray:
        """``(A, K, O, Y)`` :meth:`observation` as a numpy view (CPU)."""
        return self._cached("z", x, lambda: self.observation(x).numpy())

    def reach_np(self, x: int) -> np.ndarray:
        """``(K,)`` :attr:`reach` of ``x`` as a numpy view (CPU)."""
        return self._cached("reach", x, lambda: self.reach[x].numpy())

    def _cached(self, name: str, x: int, build: Callable[[], Any]) -> Any:
        """``build()`` cached under ``(name, x)`` (per-``x`` views and tables, built once)."""
        caches = self.__dict__.setdefault("_form_cache", {})
        key = (name, x)
        if key not in caches:
            caches[key] = build()
        return caches[key]

    @abstractmethod
    def predict_np(self, x: int, b: np.ndarray) -> np.ndarray:
        """``(A, K, Y)`` :meth:`predict` of one belief ``b (Y,)`` in numpy."""

    @abstractmethod
    def predict_action_np(self, x: int, b: np.ndarray, a: int, k: int) -> np.ndarray:
        """``(Y,)`` row ``(a, k)`` of :meth:`predict_np` alone."""

    @abstractmethod
    def backproject_np(self, x: int, a: int, values: np.ndarray) -> np.ndarray:
        """``(Y,)`` :meth:`backproject` of one action ``a`` and ``values (K, Y)``."""

    def child_np(self, x: int, b: np.ndarray, a: int, k: int, o: int) -> np.ndarray:
        """``(Y,)`` the unnormalised child ``J[a, k, o]`` of one belief ``b (Y,)``."""
        return self.predict_action_np(x, b, a, k) * self.observation_np(x)[a, k, o]

    def children_np(self, x: int, b: np.ndarray) -> Children:
        """The possible children of one belief ``b (Y,)`` at ``x`` and its rewards (numpy).

        Impossible children weigh 0 (the bounds are positively homogeneous), so only the
        possible ones are formed: ``J[a, k, o] = pred[a, k] * Z[a, x2_k, ., o]``.
        """
        pred = self.predict_np(x, b)  # (A, K, Y)
        z, zt, cx, cx_all, RT = self._cached("children", x, lambda: self._children_tables(x))
        A, K, O, Y = z.shape
        prob = np.matmul(pred[:, :, None, :], zt)[:, :, 0, :]  # (A, K, O)
        nz = np.flatnonzero(prob)
        rows = np.empty((nz.size + 1, Y), dtype=z.dtype)
        if nz.size == cx.size:  # every child possible (dense models): formed in place
            np.multiply(pred[:, :, None, :], z, out=rows[:-1].reshape(A, K, O, Y))
            rows_x = cx_all
        else:
            J = (pred[:, :, None, :] * z).reshape(-1, Y)  # (A K O, Y) every child, unnormalised
            J.take(nz, axis=0, out=rows[:-1])
            rows_x = np.empty(nz.size + 1, dtype=cx.dtype)
            cx.take(nz, out=rows_x[:-1])
            rows_x[-1] = x
        rows[-1] = b
        reward = b @ RT  # (A,)
        return Children(rows, rows_x, None, nz, prob, cx, reward)

    def _children_tables(self, x: int) -> tuple[np.ndarray, ...]:
        """What :meth:`children_np` reads at ``x`` (built once): ``Z (A, K, O, Y)``, the same
        ``(A, K, Y, O)``, the children's observed values ``(A K O,)``, those with ``x``
        appended (read only) and ``R[:, x, :]`` transposed ``(Y, A)``."""
        z = self.observation_np(x)
        A, K, O, _ = z.shape
        cx = np.broadcast_to(self.reach_np(x)[None, :, None], (A, K, O)).reshape(-1).copy()
        cx_all = np.append(cx, x).astype(cx.dtype)
        cx_all.flags.writeable = False
        return z, np.ascontiguousarray(z.transpose(0, 1, 3, 2)), cx, cx_all, self.reward_np(x)

    def compiled_tables(self, x: int) -> tuple[np.ndarray, ...] | None:
        """The tables at ``x`` that one compiled call needs to back up a belief whole
        (:func:`~torchhrc.solvers.backup_kernel.backup_one`: ``tx, tyk, z, RT, cx`` as
        :func:`~torchhrc.solvers.backup_kernel.children` takes them), or ``None``: this form
        has none (the sparse forms), the extension is not built, or the model is not float64.
        The search then takes :meth:`children_np` and :meth:`backup_vector_np`."""
        return None

    def backup_vector_np(self, x: int, a: int, use: np.ndarray, vectors: np.ndarray,
                         gamma: float) -> np.ndarray:  # fmt: skip
        """``(Y,)`` the alpha vector a point-based backup builds at ``x`` for action ``a``::

            alpha(y) = R(a, x, y) + gamma sum_{x2_k, y2, o} Tx Ty Z(a, x2_k, y2, o)
                                                          vectors[use[k, o], y2]

        Args:
            use: ``(K, O)`` int the vector taken at each child ``(x2_k, o)``.
            vectors: ``(N, Y)`` the alpha vectors ``use`` indexes.
        """
        W = vectors[use]  # (K, O, Y)
        vals = (self.observation_np(x)[a] * W).sum(1)  # (K, Y)
        return self.rewards_np()[a, x] + gamma * self.backproject_np(x, a, vals)

    def rewards_np(self) -> np.ndarray:
        """``(A, X, Y)`` :attr:`R` as a contiguous numpy view (CPU)."""
        return self._cached("R_np", 0, lambda: np.ascontiguousarray(to_numpy(self.R)))

    def reward_np(self, x: int) -> np.ndarray:
        """``(Y, A)`` ``R[:, x, :]`` transposed, contiguous (numpy, CPU)."""
        return self._cached("RT_np", x, lambda: self._reward_table(x).numpy())

    # -- initial bounds ----------------------------------------------------------------------
    @abstractmethod
    def blind_policy(self, max_iterations: int | None = None) -> AlphaVectorPolicy:
        """The blind-policy lower bound ("always do ``a``", Hauskrecht 2000) as a policy;
        every iterate of its evaluation is a lower bound (``max_iterations=None``: the
        form's default for SARSOP, where the discounted tail is negligible)."""

    def fib_corner_values(self, tol: float, deadline: Deadline, max_iterations: int,
                          ) -> tuple[torch.Tensor, dict[str, Any]]:  # fmt: skip
        """Fast Informed Bound corner values ``max_a alpha_a`` (:attr:`state_shape`) from
        QMDP, and how the iteration stopped: ``{"iterations", "stop"}``.

        ``stop`` is ``"converged"`` (change below ``tol``, or FIB = QMDP), ``"max_iterations"``
        or ``"time_limit"`` (the only outcome that depends on the wall clock).
        """
        vectors, info = self.fib_vectors(tol, deadline, max_iterations)
        v = host_view(vectors)
        return (vectors.amax(0) if v is None else torch.from_numpy(v.max(0))), info

    def fib_vectors(self, tol: float, deadline: Deadline = NEVER, max_iterations: int = 100_000,
                    ) -> tuple[torch.Tensor, dict[str, Any]]:  # fmt: skip
        """``(A, *state_shape)`` the per-action FIB vectors of :meth:`fib_corner_values`."""
        info: dict[str, Any] = {"iterations": 0, "stop": "converged"}
        start, step = self.fib_start(tol, deadline, info)
        if step is None:  # FIB = QMDP, or the budget is spent
            return start, info
        return _iterate_fib(start, step, tol, deadline, max_iterations, info, self.discount), info

    @abstractmethod
    def fib_start(self, tol: float, deadline: Deadline, info: dict[str, Any],
                  ) -> tuple[torch.Tensor, FIBOperator | None]:  # fmt: skip
        """QMDP vectors ``(A, *state_shape)`` (an upper bound) and the FIB operator, or None
        when no FIB iteration is needed: FIB = QMDP, the vectors are FIB's fixed point already
        (``info["method"] = "policy iteration"``: :mod:`~torchhrc.solvers.fib_exact`), or
        ``info["stop"]`` is set."""

    def corner_values(self, corner: torch.Tensor, what: str) -> torch.Tensor:
        """``(X, Y)`` corner values from ``corner``: ``state_shape`` corner values or
        per-action vectors ``(A, *state_shape)`` (maximised over actions).

        Raises:
            ModelError: ``corner`` has another shape (``what`` names its origin).
        """
        c = host_view(corner)
        if corner.dim() == len(self.state_shape) + 1:  # per-action vectors
            corner = corner.amax(0) if c is None else torch.from_numpy(c.max(0))
        if tuple(corner.shape) != self.state_shape:
            raise ModelError(
                f"expected {what} to return corner values {self.state_doc} or per-action "
                f"vectors, got {tuple(corner.shape)}"
            )
        shape = (self.num_observed, self.num_hidden)
        if c is None:
            return corner.reshape(shape)
        return torch.from_numpy(corner.numpy().reshape(shape))

    def check_policy(self, policy: object, what: str) -> AlphaVectorPolicy:
        """``policy`` if it is an :class:`AlphaVectorPolicy` of this form's vectors.

        Raises:
            TypeError: not an AlphaVectorPolicy. ModelError: wrong width or tagging.
        """
        if not isinstance(policy, AlphaVectorPolicy):
            raise TypeError(
                f"expected {what} to return an AlphaVectorPolicy, got {type(policy).__name__}"
            )
        if policy.alphas.shape[-1] != self.num_hidden or policy.is_momdp != self.factored:
            kind = "MOMDP (N, Y) with observed" if self.factored else "flat (N, S)"
            raise ModelError(
                f"expected {what} to return a {kind} policy over {self.num_hidden} values, "
                f"got alphas {tuple(policy.alphas.shape)} (is_momdp={policy.is_momdp})"
            )
        return policy

    def policy(self, alphas: torch.Tensor, actions: torch.Tensor,
               observed: torch.Tensor) -> AlphaVectorPolicy:  # fmt: skip
        """The solver's vectors ``(N, Y)`` as this form's policy (flat here: ``observed``,
        all zero, is dropped; a factored form keeps it)."""
        return AlphaVectorPolicy(alphas, actions)

    # -- the belief representation -------------------------------------------------------------
    _roots: tuple[np.ndarray, torch.Tensor, np.ndarray] | None = None

    @property
    def roots(self) -> tuple[np.ndarray, torch.Tensor, np.ndarray]:
        """The first states of an episode: ``xs (R,)`` observed values, ``beliefs (R, Y)``
        over the hidden value at each, ``weights (R,)`` their probabilities. One root
        ``(x0, b0, 1)`` unless the model starts at a random ``x``
        (:attr:`~torchhrc.pomdp.MOMDP.initial`, see :meth:`_start_from`)."""
        if self._roots is None:  # the one root (kept: a search reads it at each iteration)
            b0 = host_view(self.b0)
            row = self.b0.unsqueeze(0) if b0 is None else torch.from_numpy(b0[None])
            self._roots = (np.array([self.x0]), row, np.ones(1))
        return self._roots

    def _start_from(self, initial: torch.Tensor | None) -> None:
        """Set :attr:`roots` from a model's random start ``initial (X, Y)`` (one root per
        ``x`` with mass, in the dtype and device of ``b0``; ``None``: the one root)."""
        if initial is None:
            self._roots = None
            return
        mass, given = split_initial(initial.to(device=self.b0.device, dtype=self.b0.dtype))
        xs = torch.nonzero(mass > 0).squeeze(-1)
        self._roots = (xs.cpu().numpy(), given[xs], mass[xs].cpu().double().numpy())

    def new_tree(self) -> BeliefTree:
        """An empty SARSOP belief tree (dense rows) with :attr:`roots` as nodes ``0..R-1``."""
        xs, beliefs, _ = self.roots
        first, *others = rows(beliefs)
        tree = BeliefTree(first, int(xs[0]))
        for x, belief in zip(xs[1:].tolist(), others):
            tree.add(belief, x, -1, -1, -1)
        return tree

    # -- PBVI --------------------------------------------------------------------------------
    def flattened(self) -> SolverModel:
        """The same model as a flat form (a MOMDP's ``to_pomdp()``; flat forms: itself)."""
        return self

    @abstractmethod
    def upper_vectors(self, kind: str, tol: float, max_iterations: int = 100_000) -> torch.Tensor:
        """``(A, *state_shape)`` FIB (``kind="fib"``) or QMDP upper-bound vectors (PBVI,
        :func:`~torchhrc.solvers.qmdp.qmdp_vectors`), iterated to ``tol`` (at most
        ``max_iterations`` steps, where the form's iteration has a cap)."""

    @abstractmethod
    def step(self, x: torch.Tensor, y: torch.Tensor, beliefs: torch.Tensor, actions: torch.Tensor,
             generator: torch.Generator) -> SimStep:  # fmt: skip
        """One sampled step of ``M`` simulations at true states ``(x (M,), y (M,))`` with
        beliefs ``(M, Y)`` under ``actions (M,)``: the successor ``(x2, y2)`` and the
        observation ``o`` drawn from the model, then the Bayes update (the uniform belief
        where ``P(o) = 0``, which a sampled ``o`` never has). Returns :class:`SimStep`."""

    def self_loop_probs(self) -> torch.Tensor | None:
        """``(A, X, Y)`` ``P(x, y | x, y, a)``, the probability that ``a`` leaves the state
        in place (None where a form does not say)."""
        return None

    def absorbing(self) -> torch.Tensor | None:
        """``(X, Y)`` bool: the states every action leaves in place with reward 0 (APPL's
        terminal states: a simulation there earns nothing more), or None where unknown.

        Example:
            >>> from torchhrc.solvers.forms import as_solver_model
            >>> from torchhrc.tasks.classic import tiger
            >>> as_solver_model(tiger()).absorbing().any().item()
            False
        """
        loops = self.self_loop_probs()
        if loops is None:
            return None
        stay = (loops.to(self.R.dtype) >= 1.0 - 1e-12).all(0)
        return stay & (self.R == 0).all(0)

    def simulate(self, x: torch.Tensor, beliefs: torch.Tensor, actions: torch.Tensor,
                 generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """One sampled step of beliefs ``(x (M,), beliefs (M, Y))`` under ``actions (M,)``:
        a hidden value drawn from the belief, then :meth:`step`. Returns ``x2 (M,)`` and
        ``beliefs2 (M, Y)``."""
        y = sample_categorical(beliefs, generator)
        out = self.step(x, y, beliefs, actions, generator)
        return out.x, out.belief

    @abstractmethod
    def point_backup(self, policy: AlphaVectorPolicy, x: torch.Tensor,
                     beliefs: torch.Tensor) -> BackupResult:  # fmt: skip
        """The batched point backup of ``(x (M,), beliefs (M, Y))`` against ``policy``
        (Pineau et al. 2003): ``alphas (M, Y)``, ``actions (M,)``, ``values (M,)``,
        ``q_values (M, A)``."""

    def value(self, policy: AlphaVectorPolicy, x: torch.Tensor,
              beliefs: torch.Tensor) -> torch.Tensor:  # fmt: skip
        """``(M,)`` ``policy``'s value at ``(x (M,), beliefs (M, Y))`` (flat here: ``x`` is
        all zero and unused; a factored form overrides)."""
        return policy.value(beliefs)

    def value_at_roots(self, policy: AlphaVectorPolicy) -> float:
        """``policy``'s value at the start: ``sum_r w_r V(x_r, b_r)`` over :attr:`roots` (the
        value at ``(x0, b0)``, or its expectation over a random first ``x``, which the agent
        sees before it acts).

        Example:
            >>> from torchhrc.solvers.forms import as_solver_model
            >>> from torchhrc.tasks.classic import tiger
            >>> form = as_solver_model(tiger())
            >>> round(form.value_at_roots(form.blind_policy()), 6)  # always listen: -1 / 0.05
            -20.0
        """
        xs, beliefs, weights = self.roots
        x = torch.from_numpy(xs).to(beliefs.device)
        w = torch.from_numpy(weights).to(device=beliefs.device, dtype=self.R.dtype)
        return float((self.value(policy, x, beliefs) * w).sum())

    def prune(self, policy: AlphaVectorPolicy, x: torch.Tensor,
              beliefs: torch.Tensor) -> AlphaVectorPolicy:  # fmt: skip
        """``policy`` restricted to the vectors that win at some ``(x, belief)`` (flat here;
        a factored form overrides)."""
        return policy.prune(beliefs)


class TensorModelForm(SolverModel):
    """What the dense flat and the MOMDP forms share: a :class:`~torchhrc.pomdp.POMDP` or
    :class:`~torchhrc.pomdp.MOMDP` ``model`` held in the solve's dtype, whose bound kernels
    (:func:`~torchhrc.solvers.blind.blind_policy`,
    :func:`~torchhrc.solvers.tensor_bounds.mdp_upper_vectors`,
    :func:`~torchhrc.solvers.tensor_bounds.fib_backup`) take it directly.

    Args:
        model: the unbatched model, already in the solve's dtype.
        source: what the user passed (default ``model``).
    """

    def __init__(self, model: Any, source: Any = None) -> None:
        self.model = model
        self.source = model if source is None else source
        self._kernel = backup_kernel.load()  # None: the numpy children (SolverModel's)

    @property
    def init_argument(self) -> Any:
        return self.model

    def children_np(self, x: int, b: np.ndarray) -> Children:
        """:meth:`~.SolverModel.children_np` in one compiled call
        (:func:`~torchhrc.solvers.backup_kernel.children`) where the extension is built and
        the model is float64; the numpy body of :class:`SolverModel` otherwise."""
        if self._kernel is None or b.dtype != np.float64 or not b.flags.c_contiguous:
            return super().children_np(x, b)
        tx, tyk, z, RT, cx = self._kernel_tables(x)
        A, K, O, Y = z.shape
        C = A * K * O
        rows, rows_x, prob = np.empty((C + 1, Y)), np.empty(C + 1, dtype=np.int64), np.empty(C)
        nz, reward = np.empty(C, dtype=np.int64), np.empty(A)
        m = backup_kernel.children(self._kernel, b, tx, tyk, z, RT, cx, rows, rows_x, prob, nz,
                                   reward, x)  # fmt: skip
        return Children(rows[: m + 1], rows_x[: m + 1], None, nz[:m], prob.reshape(A, K, O), cx,
                        reward)  # fmt: skip

    def backup_vector_np(self, x: int, a: int, use: np.ndarray, vectors: np.ndarray,
                         gamma: float) -> np.ndarray:  # fmt: skip
        """:meth:`~.SolverModel.backup_vector_np` in one compiled call over the tables of
        :meth:`children_np` (``backup_vector`` of ``_backup.c``) where the extension is built
        and the vectors are float64 (the numpy body of :class:`SolverModel` otherwise). A flat
        model gives the same floats either way; a MOMDP's sums over ``x2`` and ``y2`` are
        sequential here (within about 1e-15 of numpy's)."""
        if self._kernel is None or vectors.dtype != np.float64 or not vectors.flags.c_contiguous:
            return super().backup_vector_np(x, a, use, vectors, gamma)
        tx, tyk, z, _, _ = self._kernel_tables(x)
        out = np.empty(z.shape[-1])
        use = use.astype(np.int64, copy=False).ravel()
        self._kernel.backup_vector(tx, tyk, z, self.rewards_np()[a, x], vectors, use, a, gamma,
                                   out)  # fmt: skip
        return out

    def compiled_tables(self, x: int) -> tuple[np.ndarray, ...] | None:
        """:meth:`~.SolverModel.compiled_tables`: :meth:`_kernel_tables` where the extension
        is built and the model is float64."""
        if self._kernel is None or self.R.dtype != torch.float64 or self.R.device.type != "cpu":
            return None
        return self._kernel_tables(x)

    def _kernel_tables(self, x: int) -> tuple[np.ndarray, ...]:
        """What :meth:`children_np` hands the compiled loop at ``x`` (float64, C-contiguous,
        built once): ``tx (A, Y, K)`` and ``tyk (A, K, Y, Y)`` (empty where
        :meth:`_transition_tables` gives None), ``Z (A, K, O, Y)``, ``R[:, x, :]`` as
        ``(Y, A)`` and the children's observed values ``(A K O,)`` int64."""

        def build() -> tuple[np.ndarray, ...]:
            z, _, cx, _, RT = self._cached("children", x, lambda: self._children_tables(x))
            tx, tyk = self._transition_tables(x)
            return (np.empty((0, 0, 0)) if tx is None else np.ascontiguousarray(tx),
                    np.empty((0, 0, 0, 0)) if tyk is None else np.ascontiguousarray(tyk),
                    np.ascontiguousarray(z), np.ascontiguousarray(RT),
                    cx.astype(np.int64, copy=False))  # fmt: skip

        return self._cached("kernel", x, build)

    @abstractmethod
    def _transition_tables(self, x: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``tx (A, Y, K)`` ``Tx[a, x, y, x2_k]`` (None: 1, a flat model) and ``tyk (A, K, Y,
        Y)`` ``Ty[a, x, y, x2_k, y2]`` (None: the identity, a static hidden value) at ``x``,
        as numpy (CPU): the prediction of :meth:`children_np`'s compiled loop."""

    def blind_policy(self, max_iterations: int | None = None) -> AlphaVectorPolicy:
        if max_iterations is not None:
            return blind_policy(self.model, max_iterations=max_iterations)
        # every iterate of the blind evaluation is a lower bound: it stops on its tolerance,
        # or once the discounted tail is below 1e-12 of the first step's (small dense
        # models are solved exactly by LU instead)
        k = int(min(2000, math.ceil(math.log(1e-12) / math.log(self.discount))))
        return blind_policy(self.model, max_iterations=k)

    def _host_expect(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """:meth:`qmdp_start`'s default ``expect`` in numpy where this form has one for its
        model (a small MOMDP's joint table); ``None``: the torch ``Expectation``."""
        return None

    def _blind_by_lu(self, P: np.ndarray | None, R: np.ndarray | None) -> np.ndarray | None:
        """``(A, S)`` the blind policies' values ``alpha_a = (I - gamma P_a)^-1 R_a`` by
        numpy's LU, from a CPU model's transition ``P (A, S, S)`` and rewards ``R (A, S)``,
        for at most :data:`~torchhrc.solvers._factored.SPARSE_DIRECT_SOLVE_SIZE` states (as
        :func:`~torchhrc.solvers.blind.blind_vectors` solves them exactly); ``None`` where
        that does not apply (no numpy view, more states, ``discount >= 1``, a singular
        system): the caller then takes the torch path."""
        if P is None or R is None or P.dtype != R.dtype or self.discount >= 1.0:
            return None
        S = P.shape[-1]
        if S > SPARSE_DIRECT_SOLVE_SIZE:
            return None
        try:
            return np.linalg.solve(np.eye(S, dtype=P.dtype) - self.discount * P, R[..., None])[
                ..., 0
            ]
        except np.linalg.LinAlgError:
            return None

    def upper_vectors(self, kind: str, tol: float, max_iterations: int = 100_000) -> torch.Tensor:
        if kind == "fib":
            return self.fib_vectors(tol, NEVER, max_iterations)[0]
        return mdp_upper_vectors(self.model, tol=tol, max_iterations=max_iterations)

    def qmdp_start(
        self,
        tol: float,
        deadline: Deadline = NEVER,
        expect: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> torch.Tensor:
        """``(A, *state_shape)`` QMDP vectors, where SARSOP's FIB iteration starts.

        On the CPU by :func:`~torchhrc.solvers.sparse_model.qmdp_iteration_np`, as the sparse
        forms: from zero with the contraction bound, an upper bound wherever it stops, and it
        stops at ``deadline``; ``expect(V)`` maps values ``(*state_shape)`` to their
        expectations under each action ``(A, *state_shape)`` (default: the model's
        :class:`~torchhrc.solvers._factored.Expectation`). Elsewhere
        :func:`~torchhrc.solvers.tensor_bounds.mdp_upper_vectors`, to its tolerance.

        Example:
            >>> from torchhrc.solvers.forms import as_solver_model
            >>> from torchhrc.tasks.classic import tiger
            >>> q = as_solver_model(tiger()).qmdp_start(1e-8)
            >>> tuple(q.shape), bool((q >= -100).all())
            ((3, 2), True)
        """
        model = self.model
        if model.R.device.type != "cpu":
            return mdp_upper_vectors(model, tol=tol)
        if expect is None:
            expect = self._host_expect()
        if expect is None:
            E = Expectation(model)

            def expect(V: np.ndarray) -> np.ndarray:
                return E(torch.from_numpy(V)).numpy()

        R = model.R.numpy()
        return torch.from_numpy(qmdp_iteration_np(R, self.discount, expect, tol, deadline))


class FlatFields:
    """What the flat forms (dense and sparse ``T``) share: one observed value (``X = K = 1``,
    ``x0 = 0``), hidden value = state, policies untagged, ``Z (A, S, O)`` seen as the
    ``(A, 1, O, S)`` observation slice of the one reachable ``x2``."""

    def _flat(self, Z: torch.Tensor, R: torch.Tensor, b0: torch.Tensor, discount: float) -> None:
        form: Any = self
        A, S, O = Z.shape
        form.num_actions, form.num_observed, form.num_hidden, form.num_observations = A, 1, S, O
        form.discount = float(discount)
        form.x0, form.b0 = 0, b0
        form.factored = False
        form.state_shape, form.state_doc = (S,), "(S,)"
        form.reach = [alloc(1, torch.long, b0.device)]
        z, r = host_view(Z), host_view(R)
        if z is not None and r is not None:  # (numpy on the CPU: torchhrc._host)
            form.R = torch.from_numpy(r.reshape(A, 1, S))
            self._z = torch.from_numpy(np.ascontiguousarray(z.transpose(0, 2, 1)[:, None]))
        else:
            form.R = R.reshape(A, 1, S)
            self._z = Z.permute(0, 2, 1).unsqueeze(1).contiguous()  # (A, 1, O, S)

    def observation(self, x: int) -> torch.Tensor:
        return self._z
