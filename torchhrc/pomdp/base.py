"""What every form of a MOMDP shares: its fields after the transition, their checks, and the
random start; and the names check every container uses.

The two forms of a MOMDP, :class:`~torchhrc.pomdp.MOMDP` (dense ``Tx``, ``Ty``) and
:class:`~torchhrc.pomdp.SparseMOMDP` (their product ``Tx Ty`` as nonzeros), differ only in
how they hold the transition. Everything after it is :class:`MOMDPBase`'s::

    Z:  (..., A, X, Y, O)   Z[..., a, x2, y2, o] = P(o | x2, y2, a)
    R:  (..., A, X, Y)      R[..., a, x, y]      = reward of a in (x, y)
    x0: int                 initial observed value, in [0, X)
    b0: (..., Y)            initial belief over the hidden value
    discount: float         in (0, 1]
    observed_states, hidden_states, actions, observations: optional names (X, Y, A, O)
    initial: (X, Y) or None the joint P(x, y) of a random first state (see
                            MOMDPBase.with_initial); then x0 is its most probable x and
                            b0 = P(y | x0)

Example:
    >>> import torch
    >>> j = torch.tensor([[0.25, 0.25], [0.5, 0.0]], dtype=torch.float64)
    >>> mass, given = split_initial(j)
    >>> mass.tolist(), given[1].tolist()
    ([0.5, 0.5], [1.0, 0.0])
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import torch

from torchhrc._checks import check_discount, check_probabilities, check_tensor
from torchhrc.errors import ModelError

__all__ = ["MOMDPBase", "check_initial", "initial_joint", "split_initial", "start_from"]

_Model = TypeVar("_Model", bound="MOMDPBase")


def _check_names(name: str, names: tuple[str, ...] | None, size: int) -> tuple[str, ...] | None:
    if names is None:
        return None
    names = tuple(names)
    if len(names) != size:
        raise ModelError(f"expected {size} {name}, got {len(names)}: {names!r}")
    if not all(isinstance(n, str) for n in names):
        raise TypeError(f"expected {name} to be strings, got {names!r}")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ModelError(f"{name} must be distinct, {dup!r} appears twice")
    return names


def split_initial(initial: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``P(x) (X,)`` and ``P(y | x) (X, Y)`` of a joint ``initial (X, Y)`` (a random start,
    :attr:`MOMDP.initial`); the row of an ``x`` without mass is all zeros.

    Example:
        >>> j = torch.tensor([[0.25, 0.25], [0.0, 0.0], [0.5, 0.0]], dtype=torch.float64)
        >>> mass, given = split_initial(j)
        >>> mass.tolist(), given.tolist()
        ([0.5, 0.0, 0.5], [[0.5, 0.5], [0.0, 0.0], [1.0, 0.0]])
    """
    mass = initial.sum(-1)
    return mass, initial / torch.where(mass > 0, mass, torch.ones_like(mass)).unsqueeze(-1)


def initial_joint(x0: int, b0: torch.Tensor, initial: torch.Tensor | None, X: int) -> torch.Tensor:
    """``(..., X, Y)`` the joint distribution of a model's first state: ``initial``, or
    ``b0 (..., Y)`` placed at ``x0``.

    Example:
        >>> initial_joint(1, torch.tensor([0.5, 0.5]), None, 2).tolist()
        [[0.0, 0.0], [0.5, 0.5]]
    """
    if initial is not None:
        return initial
    onehot = torch.zeros(X, dtype=b0.dtype, device=b0.device)
    onehot[x0] = 1.0
    return onehot.unsqueeze(-1) * b0.unsqueeze(-2)


def _joint_mass(initial: torch.Tensor, X: int, Y: int) -> torch.Tensor:
    """``(X,)`` ``P(x)`` of a joint ``initial (X, Y)``, checked to be a distribution."""
    initial = check_tensor("initial", initial)
    if tuple(initial.shape) != (X, Y):
        raise ModelError(
            f"expected initial to have shape (X={X}, Y={Y}) (one joint distribution, no "
            f"batch dims), actual shape = {tuple(initial.shape)}"
        )
    check_probabilities("initial", initial.reshape(-1))
    return initial.sum(-1)


def check_initial(initial: torch.Tensor, x0: int, b0: torch.Tensor, X: int, Y: int) -> None:
    """Check a random start (:attr:`MOMDP.initial`): an ``(X, Y)`` distribution over at least
    two ``x``, ``x0`` with mass, ``b0 = P(y | x0)``; raise :class:`ModelError` if not.

    Example:
        >>> j = torch.tensor([[0.25, 0.25], [0.5, 0.0]], dtype=torch.float64)
        >>> check_initial(j, 1, torch.tensor([1.0, 0.0], dtype=torch.float64), 2, 2)
    """
    mass = _joint_mass(initial, X, Y)
    if int((mass > 0).sum()) < 2:
        raise ModelError(
            "initial puts all its mass on one observed value: give x0 and b0 alone "
            "(initial=None), or build the model with with_initial"
        )
    if float(mass[x0]) <= 0:
        raise ModelError(f"initial gives x0 = {x0} no mass: P(x) = {mass.tolist()}")
    want = split_initial(initial)[1][x0].to(b0.dtype)
    if not torch.allclose(b0, want.expand_as(b0), atol=1e-9, rtol=0.0):
        raise ModelError(
            f"b0 must be initial's P(y | x0 = {x0}) = {want.tolist()}, got {b0.tolist()}; "
            "with_initial sets x0 and b0 from the joint"
        )


def start_from(initial: torch.Tensor, X: int, Y: int, b0: torch.Tensor) -> dict[str, object]:
    """``x0``, ``b0`` and ``initial`` of a model started from the joint ``initial (X, Y)``:
    its most probable ``x`` (the first of ties), ``P(y | x)`` there, and the joint when it
    spreads over several ``x`` (else ``None``); ``b0``'s dtype and device are kept.

    Example:
        >>> j = torch.tensor([[0.25, 0.25], [0.5, 0.0]], dtype=torch.float64)
        >>> s = start_from(j, 2, 2, torch.zeros(2, dtype=torch.float64))
        >>> s["x0"], s["b0"].tolist(), s["initial"] is j
        (0, [0.5, 0.5], True)
    """
    mass = _joint_mass(initial, X, Y)
    x0 = int(mass.argmax())
    start = split_initial(initial)[1][x0].to(dtype=b0.dtype, device=b0.device)
    spread = int((mass > 0).sum()) >= 2
    return {"x0": x0, "b0": start, "initial": initial.to(b0.dtype) if spread else None}


@dataclass(frozen=True)
class MOMDPBase:
    """The fields, checks and random start shared by :class:`~torchhrc.pomdp.MOMDP` and
    :class:`~torchhrc.pomdp.SparseMOMDP` (shapes in the module docstring); a base, not a
    model of its own.

    The fields are declared here, once. Each form keeps its transition first
    (``MOMDP(Tx, Ty, Z, R, x0, b0, discount)`` positionally, as before): a dataclass lists
    the fields of its last base first, so a form is ``class MOMDP(MOMDPBase, _Transition)``
    with its transition in a one-field base of its own. The checks of the fields
    (:meth:`_check_start`, :meth:`_check_names_and_initial`, called from each form's
    validation) and what is computed from them (the sizes, the random start) are here too.

    Example:
        >>> from torchhrc.pomdp import SparseMOMDP
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> s = SparseMOMDP.from_dense(m)
        >>> isinstance(m, MOMDPBase), isinstance(s, MOMDPBase), (s.num_observed, s.num_hidden)
        (True, True, (3, 2))
    """

    Z: torch.Tensor
    R: torch.Tensor
    x0: int
    b0: torch.Tensor
    discount: float
    observed_states: tuple[str, ...] | None = None
    hidden_states: tuple[str, ...] | None = None
    actions: tuple[str, ...] | None = None
    observations: tuple[str, ...] | None = None
    initial: torch.Tensor | None = None

    def _check_start(self, X: int) -> None:
        """Check ``x0`` (an int in ``[0, X)``) and ``discount``; store both normalised."""
        x0 = self.x0.item() if isinstance(self.x0, torch.Tensor) else self.x0
        if not isinstance(x0, int) or isinstance(x0, bool):
            raise TypeError(f"expected x0 to be an int, got {type(self.x0).__name__}")
        if not 0 <= x0 < X:
            raise ModelError(f"expected x0 in [0, {X}), got {x0}")
        object.__setattr__(self, "x0", int(x0))
        object.__setattr__(self, "discount", check_discount(self.discount))

    def _check_names_and_initial(
        self,
        sizes: tuple[int, int, int, int],
        check_names: Callable[[str, tuple[str, ...] | None, int], tuple[str, ...] | None],
    ) -> None:
        """Check the names against ``sizes = (A, X, Y, O)`` with ``check_names`` (each form
        keeps its own strictness) and a random start :attr:`initial`; store the names."""
        A, X, Y, O = sizes
        for name, size in (("observed_states", X), ("hidden_states", Y), ("actions", A),
                           ("observations", O)):  # fmt: skip
            object.__setattr__(self, name, check_names(name, getattr(self, name), size))
        if self.initial is not None:
            check_initial(self.initial, self.x0, self.b0, X, Y)

    @property
    def num_actions(self) -> int:
        """A, the number of actions."""
        return self.Z.shape[-4]

    @property
    def num_observed(self) -> int:
        """X, the number of observed state values."""
        return self.Z.shape[-3]

    @property
    def num_hidden(self) -> int:
        """Y, the number of hidden state values."""
        return self.Z.shape[-2]

    @property
    def num_observations(self) -> int:
        """O, the number of observations."""
        return self.Z.shape[-1]

    @property
    def random_start(self) -> bool:
        """True when the first observed value is random (:attr:`initial` is given)."""
        return self.initial is not None

    def initial_distribution(self) -> torch.Tensor:
        """``(..., X, Y)`` the joint distribution of the first state: :attr:`initial`, or
        ``b0`` placed at ``x0``.

        Example:
            >>> from torchhrc.testing import random_momdp
            >>> m = random_momdp(3, 2, 2, 2, seed=0)
            >>> [round(p, 12) for p in m.initial_distribution().sum(-1).tolist()]  # at x0 = 0
            [1.0, 0.0, 0.0]
        """
        return initial_joint(self.x0, self.b0, self.initial, self.num_observed)

    def with_initial(self: _Model, initial: torch.Tensor) -> _Model:
        """The same MOMDP started from the joint distribution ``initial (X, Y)`` of
        ``(x, y)``: ``x0`` its most probable ``x`` (the first of ties), ``b0 = P(y | x0)``,
        and ``initial`` kept when it spreads over several ``x`` (else ``None``).

        Raises:
            ModelError: ``initial`` is not an ``(X, Y)`` distribution.

        Example:
            >>> import torch
            >>> from torchhrc.testing import random_momdp
            >>> m = random_momdp(3, 2, 2, 2, seed=0)
            >>> joint = torch.tensor([[0.125, 0.125], [0.0, 0.0], [0.25, 0.5]], dtype=torch.float64)
            >>> s = m.with_initial(joint)
            >>> s.x0, s.b0.tolist(), s.random_start
            (2, [0.3333333333333333, 0.6666666666666666], True)
        """
        start = start_from(initial, self.num_observed, self.num_hidden, self.b0)
        return dataclasses.replace(self, **start)  # type: ignore[arg-type]
