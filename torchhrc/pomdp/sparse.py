"""A flat POMDP in coordinate (sparse) form, for problems too large to hold densely.

RockSample(7, 8) has ``S = 12545`` states: its dense ``T (A, S, S)`` would hold 2e9 entries,
while only 163085 are nonzero. :class:`SparsePOMDP` keeps the nonzeros of ``T`` and ``Z``
as coordinate lists, converts to and from the dense :class:`~torchhrc.pomdp.POMDP` when it
fits, and is what the ``.pomdp`` writer consumes.

Shapes::

    transitions:   (index (M, 3) int64 [a, s, s2], prob (M,))    nonzeros of T
    observations_: (index (M, 3) int64 [a, s2, o], prob (M,))    nonzeros of Z
    R:             (A, S)   expected immediate rewards
    b0:            (S,)     initial belief

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> sp = SparsePOMDP.from_dense(tiger())
    >>> sp.num_states, int(sp.transitions[0].shape[0])
    (2, 10)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp.dense import POMDP

__all__ = ["MAX_DENSE_ENTRIES", "SparsePOMDP", "check_dense_size", "coalesce"]

#: Largest number of entries of a dense tensor that builders and readers allocate
#: (200 million: 1.6 GB in float64).
MAX_DENSE_ENTRIES = 200_000_000


def check_dense_size(name: str, entries: int, *, hint: str = "") -> None:
    """Raise :class:`ModelError` when a dense tensor of ``entries`` entries is too large.

    Example:
        >>> check_dense_size("T", 10)
    """
    if entries > MAX_DENSE_ENTRIES:
        raise ModelError(
            f"the dense {name} would have {entries:.3g} entries (more than "
            f"{MAX_DENSE_ENTRIES:.3g})" + (f"; {hint}" if hint else "")
        )


def coalesce(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One entry per cell of a coordinate list: the cells of linear ``keys (M,)`` sorted,
    the ``values (M,)`` of a repeated cell summed (as a coordinate list means; in float64,
    then back in the dtype of ``values``), zeros dropped. Returns ``cells (K,)`` and their
    ``values (K,)``.

    Example:
        >>> cells, values = coalesce(np.array([5, 2, 5, 7]), np.array([0.25, 0.5, 0.25, 0.0]))
        >>> cells.tolist(), values.tolist()
        ([2, 5], [0.5, 0.5])
    """
    cells, inverse = np.unique(keys, return_inverse=True)
    summed = np.bincount(inverse.reshape(-1), weights=values, minlength=cells.size)
    summed = summed.astype(values.dtype, copy=False)
    keep = summed != 0
    return cells[keep], summed[keep]


def _check_coo(name: str, coo: object, sizes: tuple[int, int, int]) -> None:
    if not (isinstance(coo, tuple) and len(coo) == 2):
        raise TypeError(f"expected {name} to be a tuple (index (M, 3), prob (M,))")
    index, prob = coo
    if not isinstance(index, torch.Tensor) or index.dtype != torch.long or index.dim() != 2:
        raise TypeError(f"expected {name} index to be an int64 tensor (M, 3)")
    if index.shape[1] != 3 or not isinstance(prob, torch.Tensor) or prob.shape != index.shape[:1]:
        raise ModelError(
            f"expected {name} as (index (M, 3), prob (M,)), got shapes "
            f"{tuple(index.shape)}, {tuple(getattr(prob, 'shape', ()))}"
        )
    if index.numel():
        bound = torch.tensor(sizes)
        bad = (index < 0) | (index >= bound)
        if bad.any():
            row = int(torch.nonzero(bad)[0, 0])
            raise ModelError(
                f"{name} index {index[row].tolist()} is out of range for sizes {sizes}"
            )
    if prob.numel() and (prob.min() < 0 or prob.max() > 1 + 1e-6):
        raise ModelError(f"{name} has entries outside [0, 1]")


@dataclass(frozen=True)
class SparsePOMDP:
    """A flat POMDP with ``T`` and ``Z`` as coordinate lists (see the module docstring).

    Attributes:
        transitions: ``(index (M, 3) [a, s, s2], prob (M,))``, the nonzeros of ``T``.
        observations_: ``(index (M, 3) [a, s2, o], prob (M,))``, the nonzeros of ``Z``.
        R: ``(A, S)`` expected immediate rewards.
        b0: ``(S,)`` initial belief.
        discount: the discount factor.
        states, actions, observations: names (their lengths fix ``S``, ``A``, ``O``).
    """

    transitions: tuple[torch.Tensor, torch.Tensor]
    observations_: tuple[torch.Tensor, torch.Tensor]
    R: torch.Tensor
    b0: torch.Tensor
    discount: float
    states: tuple[str, ...]
    actions: tuple[str, ...]
    observations: tuple[str, ...]

    def __post_init__(self) -> None:
        A, S, O = self.num_actions, self.num_states, self.num_observations
        _check_coo("transitions", self.transitions, (A, S, S))
        _check_coo("observations_", self.observations_, (A, S, O))
        if tuple(self.R.shape) != (A, S):
            raise ModelError(f"expected R to have shape (A={A}, S={S}), got {tuple(self.R.shape)}")
        if tuple(self.b0.shape) != (S,):
            raise ModelError(f"expected b0 to have shape (S={S},), got {tuple(self.b0.shape)}")
        row_t = torch.zeros(A * S, dtype=torch.float64)
        idx, p = self.transitions
        row_t.index_add_(0, idx[:, 0] * S + idx[:, 1], p.double())
        row_z = torch.zeros(A * S, dtype=torch.float64)
        idx, p = self.observations_
        row_z.index_add_(0, idx[:, 0] * S + idx[:, 1], p.double())
        for name, rows in (("T", row_t), ("Z", row_z)):
            off = (rows - 1).abs() > 1e-6
            if off.any():
                i = int(torch.nonzero(off)[0])
                raise ModelError(
                    f"{name}[{i // S}, {i % S}] row sums to {rows[i].item():.6g}, expected 1"
                )

    @property
    def num_states(self) -> int:
        return len(self.states)

    @property
    def num_actions(self) -> int:
        return len(self.actions)

    @property
    def num_observations(self) -> int:
        return len(self.observations)

    @classmethod
    def from_dense(cls, model: POMDP) -> SparsePOMDP:
        """The coordinate form of an unbatched dense :class:`POMDP` (names default to
        indices).

        Example:
            >>> from torchhrc.tasks.classic import tiger
            >>> SparsePOMDP.from_dense(tiger()).to_dense().R.shape
            torch.Size([3, 2])
        """
        if not isinstance(model, POMDP):
            raise TypeError(f"expected a POMDP, got {type(model).__name__}")
        if len(model.batch_shape):
            raise ModelError(
                f"expected an unbatched POMDP, got batch shape {tuple(model.batch_shape)}"
            )
        A, S, O = model.num_actions, model.num_states, model.num_observations
        t_index = torch.nonzero(model.T)
        z_index = torch.nonzero(model.Z)
        return cls(
            transitions=(t_index, model.T[tuple(t_index.T)]),
            observations_=(z_index, model.Z[tuple(z_index.T)]),
            R=model.R.expand(A, S),
            b0=model.b0,
            discount=model.discount,
            states=model.states or tuple(str(i) for i in range(S)),
            actions=model.actions or tuple(str(i) for i in range(A)),
            observations=model.observations or tuple(str(i) for i in range(O)),
        )

    def to_dense(self, *, validate: bool = True) -> POMDP:
        """The dense :class:`POMDP` (raises :class:`ModelError` when too large).

        Example:
            >>> from torchhrc.tasks.classic import tiger
            >>> SparsePOMDP.from_dense(tiger()).to_dense().num_actions
            3
        """
        A, S, O = self.num_actions, self.num_states, self.num_observations
        check_dense_size("T", A * S * S, hint="keep the SparsePOMDP form")
        dtype, device = self.R.dtype, self.R.device
        T = torch.zeros(A, S, S, dtype=dtype, device=device)
        idx, p = self.transitions
        T.index_put_((idx[:, 0], idx[:, 1], idx[:, 2]), p.to(dtype), accumulate=True)
        Z = torch.zeros(A, S, O, dtype=dtype, device=device)
        idx, p = self.observations_
        Z.index_put_((idx[:, 0], idx[:, 1], idx[:, 2]), p.to(dtype), accumulate=True)
        return POMDP(
            T=T,
            Z=Z,
            R=self.R,
            b0=self.b0,
            discount=self.discount,
            states=self.states,
            actions=self.actions,
            observations=self.observations,
            validate_probabilities=validate,
        )
