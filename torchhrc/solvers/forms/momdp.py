"""The MOMDP-factored form: a :class:`~torchhrc.pomdp.MOMDP` over observed ``x`` and hidden ``y``.

Beliefs are ``(x, b_y)`` (Ong et al. 2010). For every observed value ``x`` the form keeps the
next observed values reachable from ``x`` (``K_x`` of them, usually far fewer than ``X``) and
the slices of ``Tx``, ``Ty`` and ``Z`` restricted to them, built when the search first reaches
``x``: expanding a belief costs ``A K_x Y`` (static hidden value) or ``A K_x Y^2``, never the
flat ``A (X Y)^2``. The expansion is the unnormalised MOMDP belief update of paper Eq. 3::

    J[..., a, k, o, y2] = Z[a, x2_k, y2, o]
                          * sum_y Tx[a, x, y, x2_k] Ty[a, x, y, x2_k, y2] b[..., y]

(it agrees with :func:`torchhrc.pomdp.belief.momdp_update_all`, tested). Policies are vectors over
``Y`` tagged with their observed value.

Example:
    >>> from torchhrc.solvers.forms import as_solver_model
    >>> from torchhrc.testing import random_momdp
    >>> form = as_solver_model(random_momdp(4, 3, 2, 2, static=False, seed=0))
    >>> xs, J = form.expand(0, form.b0.unsqueeze(0))
    >>> J.shape[-1], form.factored
    (3, True)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from torchhrc._host import host_view
from torchhrc.pomdp import MOMDP
from torchhrc.solvers._factored import SPARSE_DIRECT_SOLVE_SIZE
from torchhrc.solvers.backup import BackupResult, momdp_point_backup
from torchhrc.solvers.clock import Deadline
from torchhrc.solvers.forms.base import (
    FIBOperator,
    PerObserved,
    SimStep,
    TensorModelForm,
    field,
)
from torchhrc.solvers.forms.dense import DenseForm
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import momdp_step
from torchhrc.solvers.tensor_bounds import fib_backup

__all__ = ["MOMDPForm"]


class MOMDPForm(TensorModelForm):
    """A MOMDP under the solver interface (:class:`~.base.SolverModel`).

    Attributes:
        Tx: ``(A, X, Y, X)``; Ty: ``(A, X, Y, X, Y)`` or None (static hidden value);
            Z: ``(A, X, Y, O)``, as :class:`~torchhrc.pomdp.MOMDP`.
        reach_mask: ``(X, X)`` bool, ``reach_mask[x, x2]`` iff ``x2`` is reachable from ``x``.
        slices: per ``x`` (built on first use) the tuple ``(reach (K,), tx (A, Y, K),
            tyk (A, K, Y, Y2) or None, z (A, K, O, Y))``; ``reach``, ``_tx``, ``_tyk`` and
            ``_z`` are its per-``x`` fields.

    Built from an unbatched :class:`~torchhrc.pomdp.MOMDP` (see :class:`~.base.TensorModelForm`).
    """

    def __init__(self, model: MOMDP, source: Any = None) -> None:
        super().__init__(model, source)
        self.Tx, self.Ty, self.Z, self.R = model.Tx, model.Ty, model.Z, model.R
        self.x0, self.b0 = int(model.x0), model.b0
        self._start_from(model.initial)
        A, X, Y, _ = self.Tx.shape
        self.num_actions, self.num_observed, self.num_hidden = A, X, Y
        self.num_observations = self.Z.shape[-1]
        self.discount = float(model.discount)
        self.factored = True
        self.state_shape, self.state_doc = (X, Y), "(X, Y)"
        tx = host_view(self.Tx)
        # (X, X2) the x2 reachable from x (on the CPU by numpy: torchhrc._host)
        self.reach_mask = (self.Tx.sum(dim=(0, 2)) > 0 if tx is None
                           else torch.from_numpy(tx.sum(axis=(0, 2)) > 0))  # fmt: skip
        self.slices = PerObserved(X, self._slices)
        self.reach = field(self.slices, 0)
        self._tx = field(self.slices, 1)
        self._tyk = field(self.slices, 2)
        self._z = field(self.slices, 3)

    def _slices(self, x: int) -> tuple[Any, ...]:
        arrays = [host_view(t) for t in (self.reach_mask, self.Tx, self.Z)]
        ty = None if self.Ty is None else host_view(self.Ty)
        if all(a is not None for a in arrays) and (self.Ty is None or ty is not None):
            mask, Tx, Z = arrays  # (the same slices by numpy on the CPU: torchhrc._host)
            k = np.flatnonzero(mask[x])
            tyk = None if ty is None else ty[:, x][:, :, k].transpose(0, 2, 1, 3)
            out = [k, Tx[:, x][:, :, k], tyk, Z[:, k].transpose(0, 1, 3, 2)]
            return tuple(None if a is None else torch.from_numpy(np.ascontiguousarray(a))
                         for a in out)  # fmt: skip
        k = self.reach_mask[x].nonzero().squeeze(-1)
        tx = self.Tx[:, x][:, :, k].contiguous()  # (A, Y, K)
        tyk = None
        if self.Ty is not None:
            # (A, K, Y, Y2): the per-(a, x2) hidden transition matrices, for batched matmuls
            tyk = self.Ty[:, x][:, :, k].permute(0, 2, 1, 3).contiguous()
        z = self.Z[:, k].permute(0, 1, 3, 2).contiguous()  # (A, K, O, Y)
        return k, tx, tyk, z

    def flattened(self) -> DenseForm:
        """The flat form of ``model.to_pomdp()`` (states ``(x, y)``)."""
        return DenseForm(self.model.to_pomdp(), self.source)

    # -- torch ---------------------------------------------------------------------------------
    def observation(self, x: int) -> torch.Tensor:
        return self._z[x]

    def predict(self, x: int, beliefs: torch.Tensor) -> torch.Tensor:
        w = (beliefs[:, None, :, None] * self._tx[x]).transpose(-1, -2)  # (B, A, K, Y)
        if self.Ty is None:
            return w
        # sum_y b[y] tx[a, y, k] ty[a, y, k, y2], as (B, A, K, 1, Y) @ (A, K, Y, Y2)
        return torch.matmul(w.unsqueeze(-2), self._tyk[x]).squeeze(-2)

    def backproject(self, x: int, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        tx = self._tx[x][actions]  # (B, Y, K)
        if self.Ty is None:
            return (tx * values.transpose(-1, -2)).sum(-1)
        # inner[b, k, y] = sum_y2 ty[a_b, y, k, y2] values[b, k, y2]
        inner = torch.matmul(self._tyk[x][actions], values.unsqueeze(-1)).squeeze(-1)
        return (tx * inner.transpose(-1, -2)).sum(-1)

    # -- numpy ---------------------------------------------------------------------------------
    def _np(self, x: int) -> tuple[np.ndarray, np.ndarray | None]:
        """``tx (A, Y, K)`` and ``tyk (A, K, Y, Y2)`` or None of ``x`` as numpy views."""
        tyk = self._tyk[x]
        return self._cached(
            "txy", x, lambda: (self._tx[x].numpy(), None if tyk is None else tyk.numpy())
        )

    def predict_np(self, x: int, b: np.ndarray) -> np.ndarray:
        tx, tyk = self._np(x)
        w = (b[None, :, None] * tx).transpose(0, 2, 1)  # (A, K, Y)
        return w if tyk is None else np.matmul(w[:, :, None, :], tyk)[:, :, 0, :]

    def predict_action_np(self, x: int, b: np.ndarray, a: int, k: int) -> np.ndarray:
        tx, tyk = self._np(x)
        w = b * tx[a, :, k]
        return w if tyk is None else w @ tyk[a, k]

    def _transition_tables(self, x: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        return self._np(x)  # a static hidden value: tyk None (the identity)

    def backproject_np(self, x: int, a: int, values: np.ndarray) -> np.ndarray:
        tx, tyk = self._np(x)
        if tyk is not None:  # inner[k, y] = sum_y2 ty[a, y, k, y2] values[k, y2]
            values = np.matmul(tyk[a], values[:, :, None])[:, :, 0].T  # (Y, K)
        else:
            values = values.T
        return (tx[a] * values).sum(-1)

    # -- initial bounds ----------------------------------------------------------------------
    def fib_start(self, tol: float, deadline: Deadline, info: dict[str, Any],
                  ) -> tuple[torch.Tensor, FIBOperator | None]:  # fmt: skip
        """QMDP, and the FIB operator summed over the reachable ``x2`` only::

            fib(alpha)[a, x, y] = R[a, x, y] + gamma sum_{x2, o} max_a2 sum_y2 Tx Ty Z
                                  alpha[a2, x2, y2]

        one batched ``(A, K, Y, Y2) x (A, K, Y2, O A)`` product per ``x``. With a static
        hidden value FIB equals QMDP (the next hidden value is known given the current one),
        so no FIB iteration runs. QMDP by :meth:`~.base.TensorModelForm.qmdp_start` (on the
        CPU from zero, to ``tol`` whatever ``deadline`` says, as the other forms).
        """
        alpha = self.qmdp_start(tol)
        if self.Ty is None:
            return alpha, None
        if self.Tx.device.type != "cpu":
            model = self.model
            return alpha, lambda a: fib_backup(model, a)
        return alpha, self._fib

    def _fib(self, alpha: torch.Tensor) -> torch.Tensor:
        """:meth:`fib_start`'s operator on the CPU, by numpy over the per-``x`` slices."""
        al = alpha.numpy()  # (A2, X, Y)
        out = np.empty(al.shape, dtype=al.dtype)
        for x in range(self.num_observed):
            k = self.reach[x].numpy()
            tx, tyk = self._np(x)  # (A, Y, K), (A, K, Y, Y2)
            z = self._z[x].numpy()  # (A, K, O, Y2)
            A, K, O, Y = z.shape
            # Kt[a, k, y2, o, a2] = Z[a, x2_k, y2, o] alpha[a2, x2_k, y2]
            Kt = z.transpose(0, 1, 3, 2)[..., None] * al[:, k].transpose(1, 2, 0)[None, :, :, None]
            G = (tx.transpose(0, 2, 1)[..., None] * tyk) @ Kt.reshape(A, K, Y, O * A)
            out[:, x] = G.reshape(A, K, Y, O, A).max(-1).sum((1, 3))  # (A, Y)
        return torch.from_numpy(self.rewards_np() + self.discount * out)

    def _joint_np(self) -> np.ndarray | None:
        """``(A, S, S)`` the joint transition ``P[a, (x, y), (x2, y2)] = Tx Ty`` by numpy, for
        a CPU model of at most ``SPARSE_DIRECT_SOLVE_SIZE`` states ``S = X Y`` (None
        otherwise): QMDP's expectations and the blind policy's LU on it."""

        def build() -> np.ndarray | None:
            A, X, Y = self.num_actions, self.num_observed, self.num_hidden
            tx = host_view(self.Tx)
            ty = None if self.Ty is None else host_view(self.Ty)
            if (
                tx is None
                or (self.Ty is not None and ty is None)
                or X * Y > SPARSE_DIRECT_SOLVE_SIZE
            ):
                return None
            if ty is None:  # a static hidden value: y2 = y
                P = np.zeros((A, X, Y, X, Y), dtype=tx.dtype)
                ys = np.arange(Y)
                P[:, :, ys, :, ys] = tx.transpose(2, 0, 1, 3)  # (Y, A, X, X2)
            else:
                P = tx[..., None] * ty
            return np.ascontiguousarray(P.reshape(A, X * Y, X * Y))

        return self._cached("joint", 0, build)

    def _host_expect(self) -> Callable[[np.ndarray], np.ndarray] | None:
        P = self._joint_np()
        if P is None:
            return None
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        return lambda V: (P @ V.reshape(X * Y)).reshape(A, X, Y)  # one product (numpy)

    def blind_policy(self, max_iterations: int | None = None) -> AlphaVectorPolicy:
        """:meth:`~.base.SolverModel.blind_policy`; a small CPU model by numpy's LU on its
        joint transition (:meth:`_joint_np`, :meth:`~.base.TensorModelForm._blind_by_lu`)."""
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        R = host_view(self.R)
        values = None if max_iterations is not None or R is None else self._blind_by_lu(
            self._joint_np(), R.reshape(A, X * Y))  # fmt: skip
        if values is None:
            return super().blind_policy(max_iterations)
        return AlphaVectorPolicy.from_action_vectors(
            torch.from_numpy(values.reshape(A, X, Y)), momdp=True
        )

    # -- PBVI ----------------------------------------------------------------------------------
    def self_loop_probs(self) -> torch.Tensor:
        m = self.model
        xs = torch.arange(self.num_observed, device=m.R.device)[:, None]
        ys = torch.arange(self.num_hidden, device=m.R.device)[None, :]
        loops = m.Tx[:, xs, ys, xs]  # (A, X, Y)
        return loops if m.Ty is None else loops * m.Ty[:, xs, ys, xs, ys]

    def step(self, x: torch.Tensor, y: torch.Tensor, beliefs: torch.Tensor, actions: torch.Tensor,
             generator: torch.Generator) -> SimStep:  # fmt: skip
        out = momdp_step(self.model, x, y, beliefs, actions, generator)
        return SimStep(out.x, out.y, out.observation, out.belief)

    def point_backup(self, policy: AlphaVectorPolicy, x: torch.Tensor,
                     beliefs: torch.Tensor) -> BackupResult:  # fmt: skip
        return momdp_point_backup(self.model, policy, x, beliefs)

    # -- policies: vectors over Y tagged with their observed value --------------------------------
    def policy(self, alphas: torch.Tensor, actions: torch.Tensor,
               observed: torch.Tensor) -> AlphaVectorPolicy:  # fmt: skip
        return AlphaVectorPolicy(alphas, actions, observed)

    def value(self, policy: AlphaVectorPolicy, x: torch.Tensor,
              beliefs: torch.Tensor) -> torch.Tensor:  # fmt: skip
        return policy.value(x, beliefs)

    def prune(self, policy: AlphaVectorPolicy, x: torch.Tensor,
              beliefs: torch.Tensor) -> AlphaVectorPolicy:  # fmt: skip
        return policy.prune(beliefs, x=x)
