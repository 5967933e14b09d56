"""POMDP and MOMDP containers: validated, frozen dataclasses of tensors.

Notation (shared/DESIGN.md): S states, A actions, O observations; for a MOMDP, X observed
state values and Y hidden values (the human type in the paper). Leading batch dims ``...``
come first and broadcast: a batch of problems of one shape, e.g. one per noise level.

Flat POMDP::

    T:  (..., A, S, S)   T[..., a, s, s2] = P(s2 | s, a)
    Z:  (..., A, S, O)   Z[..., a, s2, o] = P(o | s2, a)
    R:  (..., A, S)      R[..., a, s]     = expected immediate reward of a in s
    b0: (..., S)         initial belief

MOMDP (Ong et al. 2010, "Planning under uncertainty for robotic tasks with mixed
observability"; paper Eq. 3)::

    Tx: (..., A, X, Y, X)        Tx[..., a, x, y, x2]        = P(x2 | x, y, a)
    Ty: (..., A, X, Y, X, Y)     Ty[..., a, x, y, x2, y2]    = P(y2 | x, y, a, x2)
        or None: the hidden value is static (Ty = identity), the fast path.
    Z:  (..., A, X, Y, O)        Z[..., a, x2, y2, o]        = P(o | x2, y2, a)
    R:  (..., A, X, Y)           R[..., a, x, y]             = reward of a in (x, y)
    x0: int                      initial observed value
    b0: (..., Y)                 initial belief over the hidden value
    initial: (X, Y) or None      a random start: the joint P(x, y) of the first state (then
                                 x0 is its most probable x and b0 = P(y | x0)); see
                                 MOMDP.with_initial

The flat form of a MOMDP numbers states ``s = x * Y + y`` and observations
``o_flat = x2 * O + o`` (the observed part of the next state is seen exactly).

Example:
    >>> import torch
    >>> from torchhrc.pomdp import POMDP
    >>> T = torch.eye(2, dtype=torch.float64).expand(1, 2, 2)
    >>> Z = torch.full((1, 2, 2), 0.5, dtype=torch.float64)
    >>> m = POMDP(T=T, Z=Z, R=torch.zeros(1, 2, dtype=torch.float64),
    ...           b0=torch.tensor([0.5, 0.5], dtype=torch.float64), discount=0.95)
    >>> m.num_states, m.num_actions, m.num_observations, m.batch_shape
    (2, 1, 2, torch.Size([]))
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch

from torchhrc._checks import (
    all_finite,
    broadcast_shapes,
    check_discount,
    check_probabilities,
    check_shape,
    check_tensor,
)
from torchhrc.errors import ModelError
from torchhrc.pomdp.base import MOMDPBase, _check_names

__all__ = ["MOMDP", "POMDP"]


def _tensor_fields_to(obj: object, device: torch.device | str | None, dtype: torch.dtype | None):
    changes = {}
    for f in dataclasses.fields(obj):  # type: ignore[arg-type]
        value = getattr(obj, f.name)
        if isinstance(value, torch.Tensor) and value.is_floating_point():
            changes[f.name] = value.to(device=device, dtype=dtype)
        elif isinstance(value, torch.Tensor):
            changes[f.name] = value.to(device=device)
    return dataclasses.replace(obj, **changes)  # type: ignore[type-var]


@dataclass(frozen=True)
class POMDP:
    """A discrete POMDP (batched over leading dims). See the module docstring for shapes.

    Args:
        T: ``(..., A, S, S)`` transition probabilities ``P(s2 | s, a)``.
        Z: ``(..., A, S, O)`` observation probabilities ``P(o | s2, a)``.
        R: ``(..., A, S)`` expected immediate rewards.
        b0: ``(..., S)`` initial belief.
        discount: discount factor in (0, 1].
        states, actions, observations: optional names.

    Raises:
        ModelError: shapes disagree, or a probability is out of range / not normalised.
        TypeError: a field has the wrong type.
    """

    T: torch.Tensor
    Z: torch.Tensor
    R: torch.Tensor
    b0: torch.Tensor
    discount: float
    states: tuple[str, ...] | None = None
    actions: tuple[str, ...] | None = None
    observations: tuple[str, ...] | None = None
    validate_probabilities: bool = field(default=True, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check shapes, ranges and normalisation; raise :class:`ModelError` if invalid."""
        T = check_tensor("T", self.T)
        check_shape("T", T, (None, None, None), "(..., A, S, S)")
        A, S = T.shape[-3], T.shape[-1]
        if T.shape[-2] != S:
            raise ModelError(
                f"expected T to have shape (..., A, S, S), actual shape = {tuple(T.shape)}"
            )
        Z = check_tensor("Z", self.Z)
        check_shape("Z", Z, (A, S, None), f"(..., A={A}, S={S}, O)")
        R = check_tensor("R", self.R)
        check_shape("R", R, (A, S), f"(..., A={A}, S={S})")
        b0 = check_tensor("b0", self.b0)
        check_shape("b0", b0, (S,), f"(..., S={S})")
        object.__setattr__(self, "discount", check_discount(self.discount))
        try:
            broadcast_shapes(T.shape[:-3], Z.shape[:-3], R.shape[:-2], b0.shape[:-1])
        except RuntimeError:
            raise ModelError(
                "batch dims of T, Z, R, b0 do not broadcast: "
                f"{tuple(T.shape[:-3])}, {tuple(Z.shape[:-3])}, {tuple(R.shape[:-2])}, "
                f"{tuple(b0.shape[:-1])}"
            ) from None
        if not all_finite(R):
            raise ModelError("R has non-finite entries")
        if self.validate_probabilities:
            check_probabilities("T", T)
            check_probabilities("Z", Z)
            check_probabilities("b0", b0)
        object.__setattr__(self, "states", _check_names("states", self.states, S))
        object.__setattr__(self, "actions", _check_names("actions", self.actions, A))
        object.__setattr__(
            self, "observations", _check_names("observations", self.observations, Z.shape[-1])
        )

    @property
    def num_states(self) -> int:
        return self.T.shape[-1]

    @property
    def num_actions(self) -> int:
        return self.T.shape[-3]

    @property
    def num_observations(self) -> int:
        return self.Z.shape[-1]

    @property
    def batch_shape(self) -> torch.Size:
        """The broadcast batch shape of all tensors."""
        return broadcast_shapes(
            self.T.shape[:-3], self.Z.shape[:-3], self.R.shape[:-2], self.b0.shape[:-1]
        )

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> POMDP:
        """Return a copy with every tensor moved to ``device`` / cast to ``dtype``."""
        return _tensor_fields_to(self, device, dtype)


@dataclass(frozen=True)
class _DenseTransition:
    """``Tx``, ``Ty``: :class:`MOMDP`'s first fields (see :class:`MOMDPBase` for why a base)."""

    Tx: torch.Tensor
    Ty: torch.Tensor | None


@dataclass(frozen=True)
class MOMDP(MOMDPBase, _DenseTransition):
    """A mixed-observability MDP (Ong et al. 2010). See the module docstring for shapes.

    Args:
        Tx: ``(..., A, X, Y, X)`` observed-part transitions ``P(x2 | x, y, a)``.
        Ty: ``(..., A, X, Y, X, Y)`` hidden-part transitions ``P(y2 | x, y, a, x2)``, or
            ``None`` when the hidden value never changes (the human type in the paper).
        Z: ``(..., A, X, Y, O)`` observation probabilities ``P(o | x2, y2, a)``.
        R: ``(..., A, X, Y)`` immediate rewards.
        x0: initial observed value, in ``[0, X)``.
        b0: ``(..., Y)`` initial belief over the hidden value.
        discount: discount factor in (0, 1].
        observed_states, hidden_states, actions, observations: optional names.
        initial: ``(X, Y)`` the joint distribution of the first state when the first
            observed value is random (APPL's ``TagAvoid.pomdpx``: the robot starts in any
            cell), spread over at least two ``x``; ``None`` (default) when every episode
            starts at ``x0``. With it, ``x0`` must have mass and ``b0`` must be
            ``P(y | x0)``; :meth:`with_initial` sets all three from the joint. The agent sees
            the first ``x`` (it is observed), so the value of a policy is
            ``sum_x P(x) V(x, P(. | x))``.

    Example:
        >>> import torch
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> m = MOMDP(Tx=Tx, Ty=None, Z=torch.ones(1, 1, 2, 1, dtype=torch.float64),
        ...           R=torch.zeros(1, 1, 2, dtype=torch.float64), x0=0,
        ...           b0=torch.tensor([0.3, 0.7], dtype=torch.float64), discount=0.9)
        >>> m.to_pomdp().num_states
        2
    """

    # Tx, Ty come from _DenseTransition, Z .. initial from MOMDPBase, in that order
    validate_probabilities: bool = field(default=True, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check shapes, ranges and normalisation; raise :class:`ModelError` if invalid."""
        Tx = check_tensor("Tx", self.Tx)
        check_shape("Tx", Tx, (None, None, None, None), "(..., A, X, Y, X)")
        A, X, Y = Tx.shape[-4], Tx.shape[-3], Tx.shape[-2]
        if Tx.shape[-1] != X:
            raise ModelError(
                f"expected Tx to have shape (..., A, X, Y, X), actual shape = {tuple(Tx.shape)}"
            )
        if self.Ty is not None:
            Ty = check_tensor("Ty", self.Ty)
            check_shape("Ty", Ty, (A, X, Y, X, Y), f"(..., A={A}, X={X}, Y={Y}, X={X}, Y={Y})")
        Z = check_tensor("Z", self.Z)
        check_shape("Z", Z, (A, X, Y, None), f"(..., A={A}, X={X}, Y={Y}, O)")
        R = check_tensor("R", self.R)
        check_shape("R", R, (A, X, Y), f"(..., A={A}, X={X}, Y={Y})")
        b0 = check_tensor("b0", self.b0)
        check_shape("b0", b0, (Y,), f"(..., Y={Y})")
        self._check_start(X)
        shapes = [Tx.shape[:-4], Z.shape[:-4], R.shape[:-3], b0.shape[:-1]]
        if self.Ty is not None:
            shapes.append(self.Ty.shape[:-5])
        try:
            broadcast_shapes(*shapes)
        except RuntimeError:
            raise ModelError(
                f"batch dims of Tx, Z, R, b0 (, Ty) do not broadcast: {[tuple(s) for s in shapes]}"
            ) from None
        if not all_finite(R):
            raise ModelError("R has non-finite entries")
        if self.validate_probabilities:
            check_probabilities("Tx", Tx)
            if self.Ty is not None:
                check_probabilities("Ty", self.Ty)
            check_probabilities("Z", Z)
            check_probabilities("b0", b0)
        self._check_names_and_initial((A, X, Y, Z.shape[-1]), _check_names)

    @property
    def static_hidden(self) -> bool:
        """True when the hidden value never changes (``Ty is None``)."""
        return self.Ty is None

    @property
    def batch_shape(self) -> torch.Size:
        shapes = [self.Tx.shape[:-4], self.Z.shape[:-4], self.R.shape[:-3], self.b0.shape[:-1]]
        if self.Ty is not None:
            shapes.append(self.Ty.shape[:-5])
        return broadcast_shapes(*shapes)

    def hidden_transition(self) -> torch.Tensor:
        """``Ty`` as a dense tensor ``(..., A, X, Y, X, Y)`` (the identity when static)."""
        if self.Ty is not None:
            return self.Ty
        A, X, Y = self.num_actions, self.num_observed, self.num_hidden
        eye = torch.eye(Y, dtype=self.Tx.dtype, device=self.Tx.device)
        return eye.view(1, 1, Y, 1, Y).expand(A, X, Y, X, Y)

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> MOMDP:
        """Return a copy with every tensor moved to ``device`` / cast to ``dtype``."""
        return _tensor_fields_to(self, device, dtype)

    @classmethod
    def from_pomdp(cls, pomdp: POMDP, *, num_hidden: int, atol: float = 1e-9) -> MOMDP:
        """The MOMDP of a flat POMDP whose state factor ``x`` is observed (reverse of
        :meth:`to_pomdp`).

        The POMDP must number states ``s = x * Y + y`` (``S = X * Y``) and observations
        ``o_flat = x2 * O + o`` (``O_flat = X * O``), reveal ``x2`` exactly
        (``Z[a, (x2, y2), (x3, o)] = 0`` unless ``x3 == x2``), and start at one ``x``.
        ``Tx[a, x, y, x2] = sum_y2 T[a, (x, y), (x2, y2)]`` and ``Ty = T / Tx`` (uniform where
        ``Tx = 0``, never reached); ``Ty`` is ``None`` when the hidden value never changes.

        Args:
            pomdp: the flat POMDP (batch dims allowed; all problems must start at the same x).
            num_hidden: ``Y``.
            atol: tolerance of the checks.

        Raises:
            ModelError: the sizes do not factor, ``Z`` does not reveal ``x2``, or ``b0`` is
                spread over several ``x``.

        Example:
            >>> import torch
            >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
            >>> m = MOMDP(Tx=Tx, Ty=None, Z=torch.ones(1, 1, 2, 1, dtype=torch.float64),
            ...           R=torch.zeros(1, 1, 2, dtype=torch.float64), x0=0,
            ...           b0=torch.tensor([0.3, 0.7], dtype=torch.float64), discount=0.9)
            >>> MOMDP.from_pomdp(m.to_pomdp(), num_hidden=2).b0
            tensor([0.3000, 0.7000], dtype=torch.float64)
        """
        if not isinstance(pomdp, POMDP):
            raise TypeError(f"expected pomdp to be a POMDP, got {type(pomdp).__name__}")
        if not isinstance(num_hidden, int) or isinstance(num_hidden, bool) or num_hidden < 1:
            raise TypeError(f"expected num_hidden to be a positive int, got {num_hidden!r}")
        S, A, OF = pomdp.num_states, pomdp.num_actions, pomdp.num_observations
        Y = num_hidden
        if S % Y:
            raise ModelError(f"the {S} states do not factor into X * Y with Y = {Y}")
        X = S // Y
        if OF % X:
            raise ModelError(
                f"the {OF} observations do not factor into X * O with X = {X} (o_flat = x2 * O + o)"
            )
        O = OF // X
        T = pomdp.T.reshape(*pomdp.T.shape[:-3], A, X, Y, X, Y)
        Tx = T.sum(-1)  # (..., A, X, Y, X)
        reached = Tx > atol
        Ty = torch.where(
            reached.unsqueeze(-1),
            T / torch.where(reached, Tx, torch.ones_like(Tx)).unsqueeze(-1),
            torch.full_like(T, 1.0 / Y),
        )
        eye_y = torch.eye(Y, dtype=T.dtype, device=T.device).view(1, 1, Y, 1, Y)
        off_diagonal = (T * (1 - eye_y)).abs()
        static = bool((off_diagonal <= atol).all())
        Zf = pomdp.Z.reshape(*pomdp.Z.shape[:-3], A, X, Y, X, O)  # [a, x2, y2, x3, o]
        eye_x = torch.eye(X, dtype=torch.bool, device=Zf.device).view(X, 1, X, 1)
        leak = Zf.masked_fill(eye_x, 0.0).abs()
        if bool((leak > atol).any()):
            bad = torch.nonzero(leak > atol)[0].tolist()
            *b, a, x2, y2, x3, o = bad
            raise ModelError(
                f"Z does not reveal the observed part: Z[{', '.join(map(str, [*b, a]))}, "
                f"s2={x2 * Y + y2}, o={x3 * O + o}] = {Zf[tuple(bad)].item():.6g} is the "
                f"probability of seeing x = {x3} in a state with x = {x2}"
            )
        idx = torch.arange(X, device=Zf.device)
        Z = Zf[..., idx, :, idx, :]  # advanced indices first: (X, ..., A, Y, O)
        Z = Z.movedim(0, -3)  # (..., A, X, Y, O)
        b0 = pomdp.b0.reshape(*pomdp.b0.shape[:-1], X, Y)
        mass = b0.sum(-1)  # (..., X)
        flat_mass = mass.reshape(-1, X)
        x0 = flat_mass.argmax(-1)
        if bool((x0 != x0[0]).any()) or bool(((flat_mass[:, x0[0]] - 1).abs() > 1e-6).any()):
            raise ModelError(
                f"b0 must put all its mass on one observed value x, got P(x) = {mass.tolist()}: "
                "the flat POMDP acts before it sees its first x, a MOMDP sees it first; for "
                "that start, build the MOMDP from one x and call with_initial(joint)"
            )
        x_start = int(x0[0])
        observed_states = hidden_states = observations = None
        names = pomdp.states
        if names is not None and all(n.count("|") == 1 for n in names):
            parts = [n.split("|") for n in names]
            xs = tuple(parts[x * Y][0] for x in range(X))
            ys = tuple(parts[y][1] for y in range(Y))
            if all(parts[x * Y + y] == [xs[x], ys[y]] for x in range(X) for y in range(Y)):
                if len(set(xs)) == X and len(set(ys)) == Y:
                    observed_states, hidden_states = xs, ys
        if observed_states is not None and pomdp.observations is not None:
            parts = [n.split("|", 1) for n in pomdp.observations]
            if all(len(p) == 2 for p in parts):
                os_ = tuple(parts[o][1] for o in range(O))
                pairs = ((x, o) for x in range(X) for o in range(O))
                if all(parts[x * O + o] == [observed_states[x], os_[o]] for x, o in pairs):
                    observations = os_ if len(set(os_)) == O else None
        return cls(
            Tx=Tx,
            Ty=None if static else Ty,
            Z=Z,
            R=pomdp.R.reshape(*pomdp.R.shape[:-2], A, X, Y),
            x0=x_start,
            b0=b0[..., x_start, :],
            discount=pomdp.discount,
            observed_states=observed_states,
            hidden_states=hidden_states,
            actions=pomdp.actions,
            observations=observations,
            validate_probabilities=pomdp.validate_probabilities,
        )

    def to_pomdp(self) -> POMDP:
        """The equivalent flat POMDP over ``S = X * Y`` states and ``X * O`` observations.

        With a random start (:attr:`initial`) the flat POMDP starts from the joint
        :meth:`initial_distribution` and takes its first action before it sees ``x`` (a
        POMDP has no initial observation), so its optimal value can be below the MOMDP's.

        States are numbered ``s = x * Y + y``; flat observations ``x2 * O + o``.
        ``T[a, (x, y), (x2, y2)] = Tx[a, x, y, x2] * Ty[a, x, y, x2, y2]`` and
        ``Z[a, (x2, y2), (x3, o)] = [x3 == x2] * Z[a, x2, y2, o]``.
        """
        A, X, Y, O = self.num_actions, self.num_observed, self.num_hidden, self.num_observations
        batch = self.batch_shape
        Ty = self.hidden_transition()
        T = self.Tx.unsqueeze(-1) * Ty  # (..., A, X, Y, X, Y)
        T = T.expand(*batch, A, X, Y, X, Y).reshape(*batch, A, X * Y, X * Y)
        eye_x = torch.eye(X, dtype=self.Z.dtype, device=self.Z.device)
        # Zf[..., a, x2, y2, x3, o] = eye[x2, x3] * Z[..., a, x2, y2, o]
        Zf = eye_x.view(X, 1, X, 1) * self.Z.unsqueeze(-2)
        Zf = Zf.expand(*batch, A, X, Y, X, O).reshape(*batch, A, X * Y, X * O)
        R = self.R.expand(*batch, A, X, Y).reshape(*batch, A, X * Y)
        b0 = self.initial_distribution().expand(*batch, X, Y)
        states = None
        if self.observed_states is not None and self.hidden_states is not None:
            states = tuple(f"{x}|{y}" for x in self.observed_states for y in self.hidden_states)
        observations = None
        if self.observed_states is not None and self.observations is not None:
            observations = tuple(
                f"{x}|{o}" for x in self.observed_states for o in self.observations
            )
        return POMDP(
            T=T,
            Z=Zf,
            R=R,
            b0=b0.reshape(*batch, X * Y),
            discount=self.discount,
            states=states,
            actions=self.actions,
            observations=observations,
            validate_probabilities=False,
        )
