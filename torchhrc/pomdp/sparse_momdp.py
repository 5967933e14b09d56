"""A MOMDP whose transitions are kept as their nonzeros: :class:`SparseMOMDP`.

APPL's RockSample(7, 8) as a MOMDP (Ong et al. 2010) has ``X = 50`` observed robot positions,
``Y = 256`` rock states and ``A = 13`` actions: the dense ``Ty (A, X, Y, X, Y)`` of
:class:`~torchhrc.pomdp.MOMDP` would hold 2.1e9 entries, but the rocks change only when
sampled, so each ``(a, x, y)`` has one or two successors ``(x2, y2)``. :class:`SparseMOMDP`
keeps the joint transition ``P(x2, y2 | x, y, a) = Tx[a, x, y, x2] Ty[a, x, y, x2, y2]`` as a
coordinate list and ``Z``, ``R`` dense (``A X Y O`` entries are few); it converts to and from
the dense :class:`~torchhrc.pomdp.MOMDP` when that fits and is solved as a MOMDP by the
form :class:`~torchhrc.solvers.forms.sparse_momdp.SparseMOMDPForm`.

Shapes::

    transitions: (index (M, 5) int64 [a, x, y, x2, y2], prob (M,))   nonzeros of Tx * Ty
    Z:           (A, X, Y, O)   P(o | x2, y2, a)
    R:           (A, X, Y)      expected immediate rewards
    x0, b0:      the initial observed value and (Y,) hidden belief

Example:
    >>> from torchhrc.tasks.classic import rock_sample
    >>> sm = SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp"))
    >>> sm.num_observed, sm.num_hidden, int(sm.transitions[0].shape[0])  # one per (a, x, y)
    (17, 16, 2448)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchhrc._checks import all_finite, check_probabilities, check_shape, check_tensor
from torchhrc._host import to_numpy
from torchhrc.errors import ModelError
from torchhrc.pomdp.base import MOMDPBase, initial_joint
from torchhrc.pomdp.dense import MOMDP, POMDP
from torchhrc.pomdp.sparse import SparsePOMDP, check_dense_size

__all__ = ["SparseMOMDP"]


def _names(name: str, names: tuple[str, ...] | None, size: int) -> tuple[str, ...] | None:
    if names is None:
        return None
    names = tuple(names)
    if len(names) != size:
        raise ModelError(f"expected {size} {name}, got {len(names)}")
    return names


@dataclass(frozen=True)
class _SparseTransition:
    """``transitions``: :class:`SparseMOMDP`'s first field (see
    :class:`~torchhrc.pomdp.base.MOMDPBase` for why a base)."""

    transitions: tuple[torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class SparseMOMDP(MOMDPBase, _SparseTransition):
    """A MOMDP with its joint transition as a coordinate list (see the module docstring).

    Attributes:
        transitions: ``(index (M, 5) [a, x, y, x2, y2], prob (M,))``, the nonzeros of
            ``Tx[a, x, y, x2] * Ty[a, x, y, x2, y2]`` (duplicates are summed by users).
        Z: ``(A, X, Y, O)`` observation probabilities ``P(o | x2, y2, a)``.
        R: ``(A, X, Y)`` expected immediate rewards.
        x0: the initial observed value; b0: ``(Y,)`` the initial hidden belief.
        discount: the discount factor.
        observed_states, hidden_states, actions, observations: optional names.
        initial: ``(X, Y)`` the joint ``P(x, y)`` of a random first state, or ``None``; as
            :attr:`torchhrc.pomdp.MOMDP.initial` (:meth:`with_initial` sets it).
    """

    # transitions comes from _SparseTransition, Z .. initial from MOMDPBase, in that order

    def __post_init__(self) -> None:
        Z = check_tensor("Z", self.Z)
        check_shape("Z", Z, (None, None, None, None), "(A, X, Y, O)")
        A, X, Y, O = Z.shape
        R = check_tensor("R", self.R)
        check_shape("R", R, (A, X, Y), f"(A={A}, X={X}, Y={Y})")
        b0 = check_tensor("b0", self.b0)
        check_shape("b0", b0, (Y,), f"(Y={Y},)")
        if not all_finite(R):
            raise ModelError("R has non-finite entries")
        check_probabilities("Z", Z)
        check_probabilities("b0", b0)
        self._check_start(X)
        coo = self.transitions
        if not (isinstance(coo, tuple) and len(coo) == 2):
            raise TypeError("expected transitions to be a tuple (index (M, 5), prob (M,))")
        index, prob = coo
        if not isinstance(index, torch.Tensor) or index.dtype != torch.long or index.dim() != 2:
            raise TypeError("expected transitions index to be an int64 tensor (M, 5)")
        if (index.shape[1] != 5 or not isinstance(prob, torch.Tensor)
                or prob.shape != index.shape[:1]):  # fmt: skip
            raise ModelError(
                "expected transitions as (index (M, 5), prob (M,)), got shapes "
                f"{tuple(index.shape)}, {tuple(getattr(prob, 'shape', ()))}"
            )
        sizes = (A, X, Y, X, Y)
        idx, p = to_numpy(index), to_numpy(prob)  # (numpy: torchhrc._host)
        if idx.size:
            bad = ((idx < 0) | (idx >= np.array(sizes))).any(1)
            if bad.any():
                row = int(np.flatnonzero(bad)[0])
                raise ModelError(
                    f"transitions index {idx[row].tolist()} is out of range for sizes {sizes}"
                )
            if not (p.min() >= 0 and p.max() <= 1 + 1e-6):  # (NaN fails both)
                raise ModelError("transitions has entries outside [0, 1]")
        rows = np.bincount((idx[:, 0] * X + idx[:, 1]) * Y + idx[:, 2],
                           weights=p.astype(np.float64), minlength=A * X * Y)  # fmt: skip
        off = np.abs(rows - 1) > 1e-6
        if off.any():
            i = int(np.flatnonzero(off)[0])
            a, x, y = i // (X * Y), i // Y % X, i % Y
            raise ModelError(
                f"P(x2, y2 | a={a}, x={x}, y={y}) sums to {rows[i].item():.6g}, expected 1"
            )
        self._check_names_and_initial((A, X, Y, O), _names)

    @property
    def batch_shape(self) -> torch.Size:
        return torch.Size()

    @classmethod
    def from_dense(cls, model: MOMDP) -> SparseMOMDP:
        """The coordinate form of an unbatched dense :class:`~torchhrc.pomdp.MOMDP`.

        Example:
            >>> from torchhrc.testing import random_momdp
            >>> SparseMOMDP.from_dense(random_momdp(3, 2, 2, 2, seed=0)).num_observed
            3
        """
        if not isinstance(model, MOMDP):
            raise TypeError(f"expected a MOMDP, got {type(model).__name__}")
        if len(model.batch_shape):
            raise ModelError(
                f"expected an unbatched MOMDP, got batch shape {tuple(model.batch_shape)}"
            )
        A, X, Y, O = model.num_actions, model.num_observed, model.num_hidden, model.num_observations
        Tx = model.Tx.expand(A, X, Y, X)
        nz = torch.nonzero(Tx)  # (m, 4)
        tx = Tx[tuple(nz.T)]
        if model.Ty is None:
            index = torch.cat([nz, nz[:, 2:3]], 1)
            prob = tx
        else:
            ty = model.Ty.expand(A, X, Y, X, Y)[tuple(nz.T)]  # (m, Y2)
            e, y2 = torch.nonzero(ty).unbind(-1)
            index = torch.cat([nz[e], y2[:, None]], 1)
            prob = tx[e] * ty[e, y2]
        return cls(
            transitions=(index, prob),
            Z=model.Z.expand(A, X, Y, O),
            R=model.R.expand(A, X, Y),
            x0=model.x0,
            b0=model.b0,
            initial=model.initial,
            discount=model.discount,
            observed_states=model.observed_states,
            hidden_states=model.hidden_states,
            actions=model.actions,
            observations=model.observations,
        )

    def joint_dense(self) -> torch.Tensor:
        """``(A, X, Y, X, Y)`` the dense joint transition ``Tx * Ty`` (small models only)."""
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        check_dense_size("Tx * Ty", A * (X * Y) ** 2, hint="keep the SparseMOMDP form")
        P = torch.zeros(A, X, Y, X, Y, dtype=self.R.dtype)
        index, prob = self.transitions
        P.index_put_(tuple(index.T), prob.to(self.R.dtype), accumulate=True)
        return P

    def to_dense(self) -> MOMDP:
        """The dense :class:`~torchhrc.pomdp.MOMDP` (raises :class:`ModelError` when too large).

        ``Ty`` is ``P / Tx`` where ``Tx > 0``; on impossible ``(a, x, y, x2)`` it is the
        hidden part's move ``sum_x2 P(x2, y2 | a, x, y)``, so a ``Ty`` that does not depend
        on ``x2`` (RockSample's rocks) comes back as it was. Memory: one ``(A, X, Y, X, Y)``
        tensor (RockSample(5, 7): 1.06 GB in float64).

        Example:
            >>> from torchhrc.testing import random_momdp
            >>> SparseMOMDP.from_dense(random_momdp(3, 2, 2, 2, seed=0)).to_dense().num_hidden
            2
        """
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        check_dense_size("Tx * Ty", A * (X * Y) ** 2, hint="keep the SparseMOMDP form")
        dtype = self.R.dtype
        index, prob = self.transitions
        a, x, y, x2, y2 = index.unbind(-1)
        Tx = torch.zeros(A, X, Y, X, dtype=dtype)
        Tx.index_put_((a, x, y, x2), prob.to(dtype), accumulate=True)
        # where x2 is impossible, Ty is the hidden part's move averaged over x2:
        # sum_x2 P(x2, y2 | a, x, y); then one (A, X, Y, X, Y) tensor in all
        marginal = torch.zeros(A, X, Y, Y, dtype=dtype)
        marginal.index_put_((a, x, y, y2), prob.to(dtype), accumulate=True)
        Ty = marginal.unsqueeze(-2).expand(A, X, Y, X, Y).contiguous()
        Ty[Tx > 0] = 0.0
        Ty.index_put_((a, x, y, x2, y2), prob.to(dtype) / Tx[a, x, y, x2], accumulate=True)
        return MOMDP(
            Tx=Tx,
            Ty=Ty,
            Z=self.Z,
            R=self.R,
            x0=self.x0,
            b0=self.b0,
            discount=self.discount,
            observed_states=self.observed_states,
            hidden_states=self.hidden_states,
            actions=self.actions,
            observations=self.observations,
            initial=self.initial,
        )

    def to_sparse_pomdp(self) -> SparsePOMDP:
        """The flat :class:`~torchhrc.pomdp.SparsePOMDP` over ``s = x * Y + y`` with
        observations ``x2 * O + o`` (as :meth:`~torchhrc.pomdp.MOMDP.to_pomdp`).

        Example:
            >>> from torchhrc.testing import random_momdp
            >>> sm = SparseMOMDP.from_dense(random_momdp(3, 2, 2, 2, seed=0))
            >>> sm.to_sparse_pomdp().num_states
            6
        """
        A, X, Y, O = self.num_actions, self.num_observed, self.num_hidden, self.num_observations
        index, prob = self.transitions
        a, x, y, x2, y2 = index.unbind(-1)
        t_index = torch.stack([a, x * Y + y, x2 * Y + y2], 1)
        zi = torch.nonzero(self.Z)  # (m, 4) [a, x2, y2, o]
        z_index = torch.stack([zi[:, 0], zi[:, 1] * Y + zi[:, 2], zi[:, 1] * O + zi[:, 3]], 1)
        # with a random start it acts before it sees x: see MOMDP.to_pomdp
        b0 = initial_joint(self.x0, self.b0, self.initial, X).to(self.b0.dtype)
        xs = self.observed_states or tuple(str(i) for i in range(X))
        ys = self.hidden_states or tuple(str(i) for i in range(Y))
        os_ = self.observations or tuple(str(i) for i in range(O))
        return SparsePOMDP(
            transitions=(t_index, prob),
            observations_=(z_index, self.Z[tuple(zi.T)]),
            R=self.R.reshape(A, X * Y),
            b0=b0.reshape(-1),
            discount=self.discount,
            states=tuple(f"{u}|{v}" for u in xs for v in ys),
            actions=self.actions or tuple(str(i) for i in range(A)),
            observations=tuple(f"{u}|{v}" for u in xs for v in os_),
        )

    def to_pomdp(self) -> POMDP:
        """The dense flat POMDP of :meth:`to_sparse_pomdp` (small models only)."""
        return self.to_sparse_pomdp().to_dense()
