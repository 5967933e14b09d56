"""Tensor kernels shared by the bound computations (internal): flat and MOMDP expectations.

Flat::

    expect(T, V)[..., a, s]    = sum_s2 T[..., a, s, s2] V[..., s2]           V: (..., S)
    expect(T, V, per_action)   = sum_s2 T[..., a, s, s2] V[..., a, s2]        V: (..., A, S)

MOMDP (Ong et al. 2010), never forming the flat ``(X Y) x (X Y)`` matrix::

    expect(Tx, Ty, V)[..., a, x, y] = sum_{x2, y2} Tx[..., a, x, y, x2] Ty[..., a, x, y, x2, y2]
                                      V[..., x2, y2]                         V: (..., X, Y)

with ``Ty = None`` (static hidden value) reducing to ``sum_x2 Tx[..., a, x, y, x2] V[..., x2, y]``.
"""

from __future__ import annotations

import torch

from torchhrc.pomdp import MOMDP, POMDP

__all__: list[str] = []


def flat_expect(T: torch.Tensor, V: torch.Tensor, *, per_action: bool = False) -> torch.Tensor:
    """``(..., A, S)`` expected next values under ``T (..., A, S, S)``."""
    if per_action:
        return (T @ V.unsqueeze(-1)).squeeze(-1)
    return (T @ V.unsqueeze(-2).unsqueeze(-1)).squeeze(-1)


#: Largest system solved directly by :meth:`Expectation.solve_fixed_point` (states per system).
DIRECT_SOLVE_SIZE = 2048


class Expectation:
    """The transition operator of a POMDP or MOMDP, prepared once for repeated use.

    Flat: ``T (..., A, S, S)``. Static MOMDP: ``Tx`` permuted to ``(..., A, Y, X, X2)`` so an
    expectation is one batched matmul per hidden value. General MOMDP: ``Tx * Ty`` flattened
    to ``(..., A, X Y, X2 Y2)`` (the size of ``Ty`` itself), then as flat.
    """

    def __init__(self, model: POMDP | MOMDP) -> None:
        self.momdp = isinstance(model, MOMDP)
        if not self.momdp:
            self.kind = "flat"
            self.matrix = model.T  # (..., A, S, S)
            return
        assert isinstance(model, MOMDP)
        X, Y = model.num_observed, model.num_hidden
        self.X, self.Y = X, Y
        if model.Ty is None:
            self.kind = "static"
            self.matrix = model.Tx.transpose(-3, -2).contiguous()  # (..., A, Y, X, X2)
        else:
            self.kind = "joint"
            P = model.Tx.unsqueeze(-1) * model.Ty  # (..., A, X, Y, X2, Y2)
            self.matrix = P.reshape(*P.shape[:-4], X * Y, X * Y)

    def __call__(self, V: torch.Tensor, *, per_action: bool = False) -> torch.Tensor:
        """Expected next values: ``V`` is ``(..., S)`` / ``(..., X, Y)``, or per action."""
        if self.kind == "flat":
            return flat_expect(self.matrix, V, per_action=per_action)
        if self.kind == "static":
            # V^T: (..., [A,] Y, X2) -> (..., A or 1, Y, X2, 1)
            Vt = V.transpose(-1, -2).unsqueeze(-1)
            if not per_action:
                Vt = Vt.unsqueeze(-4)
            return (self.matrix @ Vt).squeeze(-1).transpose(-1, -2)
        flat_V = V.reshape(*V.shape[:-2], self.X * self.Y)
        out = flat_expect(self.matrix, flat_V, per_action=per_action)
        return out.reshape(*out.shape[:-1], self.X, self.Y)

    def solve_fixed_point(self, R: torch.Tensor, discount: float) -> torch.Tensor | None:
        """Exact ``alpha_a = R_a + discount E_a alpha_a`` per action, or None if too large.

        ``R`` is ``(..., A, S)`` or ``(..., A, X, Y)``; solves ``(I - discount T_a) alpha_a =
        R_a`` by LU (for a static MOMDP one ``X x X`` system per action and hidden value).
        """
        if self.kind == "static":
            n = self.X
            if n > DIRECT_SOLVE_SIZE:
                return None
            eye = torch.eye(n, dtype=self.matrix.dtype, device=self.matrix.device)
            rhs = R.transpose(-1, -2).unsqueeze(-1)  # (..., A, Y, X, 1)
            lhs = eye - discount * self.matrix
            batch = torch.broadcast_shapes(lhs.shape[:-2], rhs.shape[:-2])
            out = torch.linalg.solve(lhs.expand(*batch, n, n), rhs.expand(*batch, n, 1))
            return out.squeeze(-1).transpose(-1, -2)
        n = self.matrix.shape[-1]
        if n > DIRECT_SOLVE_SIZE:
            return None
        eye = torch.eye(n, dtype=self.matrix.dtype, device=self.matrix.device)
        flat_R = R if self.kind == "flat" else R.reshape(*R.shape[:-2], n)
        lhs = eye - discount * self.matrix
        rhs = flat_R.unsqueeze(-1)
        batch = torch.broadcast_shapes(lhs.shape[:-2], rhs.shape[:-2])
        out = torch.linalg.solve(lhs.expand(*batch, n, n), rhs.expand(*batch, n, 1)).squeeze(-1)
        return out if self.kind == "flat" else out.reshape(*out.shape[:-1], self.X, self.Y)


def momdp_expect(
    Tx: torch.Tensor, Ty: torch.Tensor | None, V: torch.Tensor, *, per_action: bool = False
) -> torch.Tensor:
    """``(..., A, X, Y)`` expected next values by einsum (the reference form)."""
    if Ty is None:
        if per_action:  # V: (..., A, X2, Y)
            return torch.einsum("...axyz,...azy->...axy", Tx, V)
        return torch.einsum("...axyz,...zy->...axy", Tx, V)
    if per_action:
        return torch.einsum("...axyz,...axyzw,...azw->...axy", Tx, Ty, V)
    return torch.einsum("...axyz,...axyzw,...zw->...axy", Tx, Ty, V)


def expect(model: POMDP | MOMDP, V: torch.Tensor, *, per_action: bool = False) -> torch.Tensor:
    """Expected next values for either model kind (see the module docstring)."""
    if isinstance(model, MOMDP):
        return momdp_expect(model.Tx, model.Ty, V, per_action=per_action)
    return flat_expect(model.T, V, per_action=per_action)


def state_dims(model: POMDP | MOMDP) -> int:
    """Number of trailing state dims of a value tensor: 1 (S) or 2 (X, Y)."""
    return 2 if isinstance(model, MOMDP) else 1


def reward_bounds(model: POMDP | MOMDP) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-problem ``(min R, max R)``, each of shape ``batch_shape``."""
    R = model.R
    flat = R.reshape(*R.shape[: R.dim() - 1 - state_dims(model)], -1)
    return flat.amin(-1), flat.amax(-1)


def check_model(model: object) -> POMDP | MOMDP:
    """Raise TypeError unless ``model`` is a POMDP or MOMDP."""
    if not isinstance(model, (POMDP, MOMDP)):
        raise TypeError(f"expected model to be a POMDP or MOMDP, got {type(model).__name__}")
    return model


def check_unit_discount(model: POMDP | MOMDP, what: str) -> None:
    """The infinite-horizon bounds need discount < 1."""
    from torchhrc.errors import ModelError

    if model.discount >= 1.0:
        raise ModelError(f"{what} needs discount < 1, got {model.discount}")
