"""The dense flat form: a :class:`~torchhrc.pomdp.POMDP` with a dense ``T (A, S, S)``.

A flat POMDP is the mixed-observability model with one observed value (``X = K = 1``,
``Y = S``). The prediction is one ``(B, S) x (A, S, S)`` product; a single belief of a
structured problem (RockSample: the robot's position known) touches only the rows of ``T`` on
its support. The FIB and QMDP initialisations run on per-action sparse CSR copies of ``T``
when ``T`` is under 10 % dense (Tag, RockSample), else on the dense kernels of
:mod:`torchhrc.solvers.tensor_bounds`.

Example:
    >>> from torchhrc.solvers.forms import as_solver_model
    >>> from torchhrc.tasks.classic import tiger
    >>> form = as_solver_model(tiger())
    >>> form.predict(0, form.b0.unsqueeze(0)).shape  # (B, A, K, Y)
    torch.Size([1, 3, 1, 2])
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import torch

from torchhrc._host import host_view
from torchhrc.pomdp import POMDP
from torchhrc.solvers.backup import BackupResult, point_backup
from torchhrc.solvers.clock import NEVER, Deadline
from torchhrc.solvers.fib_exact import fib_exact_pays, fib_fixed_point
from torchhrc.solvers.forms.base import FIBOperator, FlatFields, SimStep, TensorModelForm
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import flat_step
from torchhrc.solvers.tensor_bounds import fib_backup

__all__ = ["DenseForm"]


class DenseForm(FlatFields, TensorModelForm):
    """A dense flat POMDP under the solver interface (:class:`~.base.SolverModel`); built
    from an unbatched :class:`~torchhrc.pomdp.POMDP` (see :class:`~.base.TensorModelForm`)."""

    def __init__(self, model: POMDP, source: Any = None) -> None:
        super().__init__(model, source)
        self._flat(model.Z, model.R, model.b0, model.discount)
        T = host_view(model.T)
        self.T = model.T.contiguous() if T is None else torch.from_numpy(np.ascontiguousarray(T))

    # -- torch ---------------------------------------------------------------------------------
    def predict(self, x: int, beliefs: torch.Tensor) -> torch.Tensor:
        B, S = beliefs.shape
        if B == 1 and S >= 64:
            # one belief: only the rows of T on its support matter (beliefs of structured
            # problems are sparse, e.g. RockSample's robot position is known)
            supp = beliefs[0].nonzero().squeeze(-1)
            if supp.numel() * 4 <= S:
                rows = self.T.index_select(1, supp)  # (A, w, S)
                return torch.matmul(beliefs[0, supp], rows).view(1, -1, 1, S)
        return torch.matmul(beliefs[:, None, None, :], self.T)  # (B, A, 1, S)

    def backproject(self, x: int, actions: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        if actions.numel() == 1:  # a view of T[a], no (S, S) copy
            return torch.mv(self.T[int(actions[0])], values[0, 0]).unsqueeze(0)
        return torch.matmul(self.T[actions], values[:, 0, :].unsqueeze(-1)).squeeze(-1)

    # -- numpy ---------------------------------------------------------------------------------
    def _T_np(self) -> np.ndarray:
        return self._cached("T", 0, lambda: self.T.numpy())

    def predict_np(self, x: int, b: np.ndarray) -> np.ndarray:
        T = self._T_np()
        if np.count_nonzero(b) * 4 <= b.shape[0]:  # only the rows of T on the support of b
            supp = np.flatnonzero(b)
            return (b[supp] @ T[:, supp, :])[:, None, :]  # (A, 1, S)
        return (b @ T)[:, None, :]

    def predict_action_np(self, x: int, b: np.ndarray, a: int, k: int) -> np.ndarray:
        supp = np.flatnonzero(b)
        return b[supp] @ self._T_np()[a][supp]

    def backproject_np(self, x: int, a: int, values: np.ndarray) -> np.ndarray:
        return self._T_np()[a] @ values[0]

    def _transition_tables(self, x: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        T = self._T_np()  # a flat model: no tx (K = 1), tyk = T
        return None, T.reshape(T.shape[0], 1, *T.shape[1:])

    # -- initial bounds ----------------------------------------------------------------------
    def blind_policy(self, max_iterations: int | None = None) -> AlphaVectorPolicy:
        """:meth:`~.base.SolverModel.blind_policy`; a small CPU model by numpy's LU
        (:meth:`~.base.TensorModelForm._blind_by_lu`: the same LU on the same floats as
        :func:`~torchhrc.solvers.blind.blind_vectors`, without the model's expectation
        operator in torch)."""
        R = host_view(self.model.R)
        values = None if max_iterations is not None else self._blind_by_lu(host_view(self.T), R)
        if values is None:
            return super().blind_policy(max_iterations)
        return AlphaVectorPolicy.from_action_vectors(torch.from_numpy(values), momdp=False)

    def fib_start(self, tol: float, deadline: Deadline, info: dict[str, Any],
                  ) -> tuple[torch.Tensor, FIBOperator | None]:  # fmt: skip
        """QMDP vectors and the FIB operator (Hauskrecht 2000)::

            fib(alpha)[a, s] = R[a, s] + gamma sum_o max_a2 sum_s2 T[a, s, s2] Z[a, s2, o]
                                                                 alpha[a2, s2]

        On the CPU both run in numpy: QMDP by :func:`~torchhrc.solvers.sparse_model.\
qmdp_iteration_np` (from zero, with the contraction bound; to ``tol`` whatever
        ``deadline`` says: see ``_iterate_fib``), FIB as one batched product per step, or one
        sparse ``(S, S) x (S, O A)`` product per action when ``T`` is sparse. Elsewhere the
        torch kernels (:func:`~torchhrc.solvers.tensor_bounds.mdp_upper_vectors`,
        :func:`~torchhrc.solvers.tensor_bounds.fib_backup`). aloha-10max (discount 0.999,
        30 states): the torch QMDP took 1.2 CPU-s of a 10 s solve, its FIB steps 92 us each.

        A small float64 model on the CPU (:func:`~torchhrc.solvers.fib_exact.fib_exact_pays`)
        gets FIB's fixed point itself instead, by policy iteration
        (:func:`~torchhrc.solvers.fib_exact.fib_fixed_point`), and no operator:
        ``info["method"]`` says ``"policy iteration"`` and ``info["iterations"]`` counts its
        linear solves (Tiger at tolerance 1e-5: 1 solve in 0.16 ms, where the iteration took
        329 steps and 7.4 ms).
        """
        T, model = self.T, self.model
        if T.device.type != "cpu":
            return self.qmdp_start(tol), lambda alpha: fib_backup(model, alpha)
        R, Z, g = model.R, model.Z, self.discount
        A, S, O = Z.shape
        if S < 64 or np.count_nonzero(T.numpy()) * 10 > T.numel():  # dense products
            Tn, Zn, Rn = T.numpy(), Z.numpy(), R.numpy()

            def expect(V: np.ndarray) -> np.ndarray:
                return Tn @ V  # (A, S)

            def fib(alpha: torch.Tensor) -> torch.Tensor:
                # Yv[a, s2, o, a2] = Z[a, s2, o] * alpha[a2, s2]
                Yv = Zn[:, :, :, None] * alpha.numpy().T[None, :, None, :]  # (A, S, O, A2)
                G = np.matmul(Tn, Yv.reshape(A, S, O * A)).reshape(A, S, O, A)
                return torch.from_numpy(Rn + g * G.max(-1).sum(-1))

            if R.dtype == torch.float64 and fib_exact_pays(A, S, O):
                # a few states: FIB's fixed point itself, by policy iteration from the choices
                # of QMDP (fib_exact), where iterating would take hundreds of steps. The
                # choices need QMDP to 1e-3 of the values' scale only (an upper bound wherever
                # its iteration stops, so the result's minimum with it stays one): on the
                # suite's small problems the same choices as to 1e-11, at a third of the cost
                loose = max(tol, 1e-3 * float(np.abs(Rn).max(initial=0.0)) / (1.0 - g))
                exact = fib_fixed_point(
                    Tn, Zn, Rn, g, start=self.qmdp_start(loose, NEVER, expect).numpy()
                )
                if exact is not None:
                    info["iterations"], info["method"] = exact.iterations, "policy iteration"
                    return torch.from_numpy(exact.vectors), None
            return self.qmdp_start(tol, NEVER, expect), fib
        else:
            with warnings.catch_warnings():  # "sparse CSR support is in beta"
                warnings.simplefilter("ignore", UserWarning)
                Ts = [T[a].to_sparse_csr() for a in range(A)]

            def expect(V: np.ndarray) -> np.ndarray:
                v = torch.from_numpy(V)
                return torch.stack([t @ v for t in Ts]).numpy()  # (A, S)

            def fib(alpha: torch.Tensor) -> torch.Tensor:
                # Yv[a, s2, o, a2] = Z[a, s2, o] * alpha[a2, s2]
                Yv = Z.unsqueeze(-1) * alpha.T.unsqueeze(1).unsqueeze(0)  # (A, S, O, A2)
                G = torch.stack([Ts[a] @ Yv[a].reshape(S, O * A) for a in range(A)])
                return R + g * G.view(A, S, O, A).amax(-1).sum(-1)

        return self.qmdp_start(tol, NEVER, expect), fib

    # -- PBVI ----------------------------------------------------------------------------------
    def self_loop_probs(self) -> torch.Tensor:
        return self.model.T.diagonal(dim1=-2, dim2=-1).unsqueeze(1)  # (A, 1, S)

    def step(self, x: torch.Tensor, y: torch.Tensor, beliefs: torch.Tensor, actions: torch.Tensor,
             generator: torch.Generator) -> SimStep:  # fmt: skip
        out = flat_step(self.model, y, beliefs, actions, generator)
        return SimStep(torch.zeros_like(out.state), out.state, out.observation, out.belief)

    def point_backup(self, policy: AlphaVectorPolicy, x: torch.Tensor,
                     beliefs: torch.Tensor) -> BackupResult:  # fmt: skip
        return point_backup(self.model, policy, beliefs)
