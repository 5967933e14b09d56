"""Learning an observation model from recorded hand tracks, through the MOMDP belief filter.

The paper specifies its observation model by hand and leaves learning it to future work
(Nikolaidis et al., Evaluation, "Online estimation of human type"). Here the tracks of
:class:`HandTracks` (observed states, robot actions and the hand's grid cells, the type
unknown) score a model by the sum of the belief filter's log normalisers
(:func:`track_log_likelihood`, paper Eq. 3), and :func:`fit_observation_model` maximises it
over a :class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation`'s parameters;
:func:`simulate_tracks` draws tracks from a model.

Shapes::

    observed:  (N, L + 1)   observed states x_0 .. x_L
    actions:   (N, L)       robot actions
    cells:     (N, L)       observed grid cells, P(o | x2, y)
    lengths:   (N,)         steps of each track, in [1, L]

Example:
    >>> import torch
    >>> t = HandTracks(observed=torch.zeros(1, 3, dtype=torch.long),
    ...     actions=torch.zeros(1, 2, dtype=torch.long),
    ...     cells=torch.zeros(1, 2, dtype=torch.long), lengths=torch.tensor([2]))
    >>> t.num_tracks, t.mask.tolist()
    (1, [[True, True]])
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.pomdp.dense import MOMDP
from torchhrc.pomdp.observation import (
    DiscretizedGaussianObservation,
    ObservationGrid,  # noqa: F401  (the doctests use it)
    discretize_positions,
)

__all__ = [
    "HandTracks",
    "ObservationFit",
    "fit_observation_model",
    "simulate_tracks",
    "track_log_likelihood",
]


@dataclass(frozen=True)
class HandTracks:
    """Recorded hand tracks: observed states, robot actions, and the hand's grid cells.

    Step ``t`` of track ``n`` (``t < lengths[n]``): in observed state ``observed[n, t]`` the
    robot takes ``actions[n, t]``, the state becomes ``observed[n, t + 1]`` and the hand is
    seen in cell ``cells[n, t]`` (``P(o | x2, y)``). Entries past a track's length are
    padding (any valid index).

    Args:
        observed: ``(N, L + 1)`` int64 observed states ``x_0 .. x_L``.
        actions: ``(N, L)`` int64 robot actions.
        cells: ``(N, L)`` int64 observed grid cells.
        lengths: ``(N,)`` int64 number of steps of each track, in ``[1, L]``.
        positions: optional ``(N, L, 2)`` continuous hand positions behind ``cells``.
        types: optional ``(N,)`` int64 true hidden values (for scoring only, never used by
            :func:`fit_observation_model`).
    """

    observed: torch.Tensor
    actions: torch.Tensor
    cells: torch.Tensor
    lengths: torch.Tensor
    positions: torch.Tensor | None = field(default=None, repr=False)
    types: torch.Tensor | None = None

    def __post_init__(self) -> None:
        for name in ("observed", "actions", "cells", "lengths"):
            v = check_tensor(name, getattr(self, name), floating=False)
            if v.dtype != torch.int64:
                raise TypeError(f"expected {name} to be int64, got {v.dtype}")
        if self.actions.dim() != 2:
            raise ModelError(
                f"expected actions to have shape (N, L), actual shape = {tuple(self.actions.shape)}"
            )
        n, length = self.actions.shape
        if tuple(self.observed.shape) != (n, length + 1):
            raise ModelError(
                f"expected observed to have shape (N, L + 1) = {(n, length + 1)}, "
                f"actual shape = {tuple(self.observed.shape)}"
            )
        if tuple(self.cells.shape) != (n, length):
            raise ModelError(
                f"expected cells to have shape (N, L) = {(n, length)}, "
                f"actual shape = {tuple(self.cells.shape)}"
            )
        if tuple(self.lengths.shape) != (n,):
            raise ModelError(
                f"expected lengths to have shape (N,) = ({n},), "
                f"actual shape = {tuple(self.lengths.shape)}"
            )
        if n and ((self.lengths < 1).any() or (self.lengths > length).any()):
            raise ModelError(f"expected lengths in [1, {length}], got {self.lengths.tolist()}")
        for name in ("observed", "actions", "cells"):
            if (getattr(self, name) < 0).any():
                raise ModelError(f"expected {name} to be non-negative indices")

    @property
    def num_tracks(self) -> int:
        return self.actions.shape[0]

    @property
    def mask(self) -> torch.Tensor:
        """``(N, L)`` bool, True on real steps."""
        steps = torch.arange(self.actions.shape[1], device=self.actions.device)
        return steps < self.lengths.unsqueeze(-1)

    def check_against(self, num_actions: int, num_observed: int, num_observations: int) -> None:
        """Raise :class:`ModelError` if an index is out of range for a model of these sizes."""
        mask = self.mask
        for name, values, size in (
            ("actions", self.actions[mask], num_actions),
            ("cells", self.cells[mask], num_observations),
            ("observed", self.observed, num_observed),
        ):
            if values.numel() and int(values.max()) >= size:
                raise ModelError(f"expected {name} in [0, {size}), got {int(values.max())}")


def _unpack_transition(
    transition: MOMDP | torch.Tensor, b0: torch.Tensor | None, Ty: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
    if isinstance(transition, MOMDP):
        return (
            transition.Tx,
            transition.Ty if Ty is None else Ty,
            (transition.b0 if b0 is None else b0),
        )
    Tx = check_tensor("transition", transition)
    check_shape("transition", Tx, (None, None, None, None), "(A, X, Y, X)")
    if b0 is None:
        Y = Tx.shape[-2]
        b0 = Tx.new_full((Y,), 1.0 / Y)
    return Tx, Ty, b0


def _safe_log(x: torch.Tensor) -> torch.Tensor:
    # log(0) = -inf with a zero (not NaN) gradient where x == 0.
    pos = x > 0
    return torch.where(pos, torch.log(torch.where(pos, x, torch.ones_like(x))), -torch.inf)


def track_log_likelihood(
    observation: torch.Tensor,
    transition: MOMDP | torch.Tensor,
    tracks: HandTracks,
    *,
    b0: torch.Tensor | None = None,
    Ty: torch.Tensor | None = None,
) -> torch.Tensor:
    """Log marginal likelihood of each track with the hidden type unknown.

    The sum over time of the MOMDP belief filter's log normalisers (paper Eq. 3):
    ``log p(x_1:T, o_1:T | x_0, a_0:T-1) = sum_t log P(x_t+1, o_t+1 | x_t, a_t, b_t)``.
    ``Tx`` does not involve the observation model, so its gradient is that of
    ``log p(o_1:T | x_0:T, a)``. With a static type (``Ty is None``) this is computed in closed
    form, vectorised over time: ``logsumexp_y [log b0(y) + sum_t log Tx[a_t, x_t, y, x_t+1] +
    log Z[a_t, x_t+1, y, o_t]]``; otherwise by running
    :func:`torchhrc.pomdp.belief.momdp_log_update` along the tracks.

    Args:
        observation: ``(A, X, Y, O)`` observation probabilities (e.g. ``model()``), or
            ``(X, Y, O)`` when they do not depend on the action.
        transition: a :class:`~torchhrc.pomdp.MOMDP` (its ``Tx``, ``Ty``, ``b0``; its ``Z``
            is ignored) or ``Tx: (A, X, Y, X)``.
        tracks: the tracks.
        b0: ``(Y,)`` initial type belief (default: the MOMDP's, or uniform).
        Ty: ``(A, X, Y, X, Y)`` type transitions (default: the MOMDP's, or static).

    Returns:
        ``(N,)`` log likelihoods; ``-inf`` for a track impossible under the model.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> Z = torch.full((1, 1, 2, 4), 0.25, dtype=torch.float64)
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> t = HandTracks(torch.zeros(1, 3, dtype=torch.long), torch.zeros(1, 2, dtype=torch.long),
        ...                torch.tensor([[0, 3]]), torch.tensor([2]))
        >>> round(track_log_likelihood(Z, Tx, t).item(), 6) == round(2 * math.log(0.25), 6)
        True
    """
    Tx, Ty, b0 = _unpack_transition(transition, b0, Ty)
    Z = check_tensor("observation", observation)
    if Z.dim() == 3:
        Z = Z.unsqueeze(0)
    A, X, Y = Tx.shape[-4], Tx.shape[-3], Tx.shape[-2]
    check_shape("observation", Z, (None, X, Y, None), f"(A, X={X}, Y={Y}, O)")
    if Z.shape[0] not in (1, A):
        raise ModelError(f"expected observation to have A = 1 or {A}, got {Z.shape[0]}")
    tracks.check_against(A, X, Z.shape[-1])
    if Ty is not None:
        return _sequential_log_likelihood(Z.expand(A, *Z.shape[1:]), Tx, Ty, b0, tracks)
    mask = tracks.mask  # (N, L)
    x, x2 = tracks.observed[:, :-1], tracks.observed[:, 1:]
    a = tracks.actions
    aZ = a if Z.shape[0] == A else torch.zeros_like(a)
    log_tx = _safe_log(Tx[a, x, :, x2])  # (N, L, Y)
    log_z = _safe_log(Z[aZ, x2, :, tracks.cells])  # (N, L, Y)
    step = torch.where(mask.unsqueeze(-1), log_tx + log_z, torch.zeros_like(log_z))
    joint = _safe_log(b0) + step.sum(dim=1)  # (N, Y)
    return torch.logsumexp(joint, dim=-1)


def _sequential_log_likelihood(
    Z: torch.Tensor, Tx: torch.Tensor, Ty: torch.Tensor, b0: torch.Tensor, tracks: HandTracks
) -> torch.Tensor:
    from torchhrc.pomdp.belief import momdp_log_update

    model = MOMDP(
        Tx=Tx,
        Ty=Ty,
        Z=Z,
        R=Z.new_zeros(Tx.shape[:-1]),
        x0=0,
        b0=b0,
        discount=1.0,
        validate_probabilities=False,
    )
    n = tracks.num_tracks
    log_b = _safe_log(b0).expand(n, b0.shape[-1])
    total = Z.new_zeros(n)
    lengths = tracks.lengths
    for t in range(int(lengths.max()) if n else 0):  # the filter is a recursion in time
        active = torch.nonzero(lengths > t).squeeze(-1)
        r = momdp_log_update(
            model,
            tracks.observed[active, t],
            log_b[active],
            tracks.actions[active, t],
            tracks.observed[active, t + 1],
            tracks.cells[active, t],
            on_zero="ninf",
        )
        log_b = log_b.index_put((active,), r.belief)
        total = total.index_add(0, active, r.log_normalizer)
    return total


@dataclass(frozen=True)
class ObservationFit:
    """Result of :func:`fit_observation_model`.

    Attributes:
        log_likelihood: final total log marginal likelihood of the tracks.
        initial_log_likelihood: the same before the first step.
        history: total log likelihood after each optimiser step.
        steps: optimiser steps taken.
        converged: the relative change fell below ``tol``.
    """

    log_likelihood: float
    initial_log_likelihood: float
    history: tuple[float, ...]
    steps: int
    converged: bool


def fit_observation_model(
    model: DiscretizedGaussianObservation,
    transition: MOMDP | torch.Tensor,
    tracks: HandTracks,
    *,
    b0: torch.Tensor | None = None,
    Ty: torch.Tensor | None = None,
    steps: int = 300,
    lr: float = 0.05,
    optimizer: str = "adam",
    batch_size: int | None = None,
    tol: float = 1e-9,
    seed: int = 0,
    callback: Callable[[int, float], None] | None = None,
) -> ObservationFit:
    """Learn the observation model from hand tracks by maximum marginal likelihood.

    Maximises ``sum_n log p(x_1:T, o_1:T | x_0, a)`` of :func:`track_log_likelihood`, the
    MOMDP belief filter's log normalisers with the type unknown, by gradient ascent with
    autograd (Adam, or L-BFGS with a strong-Wolfe line search). The model's parameters are
    updated in place. The loss is the negative mean log likelihood per step.

    Args:
        model: the observation model to fit (its parameters are the starting point).
        transition: a MOMDP (``Tx``, ``Ty``, ``b0``; ``Z`` ignored) or ``Tx: (A, X, Y, X)``.
        tracks: the recorded tracks.
        b0, Ty: override the MOMDP's initial type belief / type transitions.
        steps: maximum optimiser steps.
        lr: learning rate.
        optimizer: ``"adam"`` or ``"lbfgs"``.
        batch_size: tracks per minibatch (Adam only; default all tracks).
        tol: stop when the relative change of the full log likelihood is below this.
        seed: seeds the minibatch order.
        callback: called as ``callback(step, log_likelihood)`` after each step.

    Returns:
        :class:`ObservationFit`.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (4, 4))
        >>> m = DiscretizedGaussianObservation(g, torch.zeros(1, 2, 2, dtype=torch.float64),
        ...     torch.ones(2, dtype=torch.float64), num_observed=1, num_hidden=2)
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> t = simulate_tracks(m, Tx, num_tracks=4, length=3, seed=0)
        >>> fit_observation_model(m, Tx, t, steps=2).steps
        2
    """
    if optimizer not in ("adam", "lbfgs"):
        raise ModelError(f"expected optimizer 'adam' or 'lbfgs', got {optimizer!r}")
    if not isinstance(steps, int) or steps < 1:
        raise ModelError(f"expected steps to be a positive int, got {steps!r}")
    n_steps = int(tracks.lengths.sum())
    if n_steps == 0:
        raise ModelError("tracks has no steps to learn from")
    params = [p for p in model.parameters() if p.requires_grad]
    gen = torch.Generator()
    gen.manual_seed(int(seed))

    def full_ll() -> torch.Tensor:
        return track_log_likelihood(model(), transition, tracks, b0=b0, Ty=Ty).sum()

    history: list[float] = []
    converged = False
    with torch.no_grad():
        initial = float(full_ll())
    previous = initial
    if optimizer == "lbfgs":
        opt: torch.optim.Optimizer = torch.optim.LBFGS(
            params, lr=lr, max_iter=20, line_search_fn="strong_wolfe"
        )

        def closure() -> torch.Tensor:
            opt.zero_grad()
            loss = -full_ll() / n_steps
            loss.backward()
            return loss

    else:
        opt = torch.optim.Adam(params, lr=lr)
    step = 0
    for step in range(1, steps + 1):
        if optimizer == "lbfgs":
            opt.step(closure)  # type: ignore[arg-type]
        elif batch_size is None or batch_size >= tracks.num_tracks:
            opt.zero_grad()
            loss = -full_ll() / n_steps
            loss.backward()
            opt.step()
        else:
            order = torch.randperm(tracks.num_tracks, generator=gen)
            for start in range(0, tracks.num_tracks, batch_size):
                idx = order[start : start + batch_size]
                sub = _subset(tracks, idx)
                opt.zero_grad()
                ll = track_log_likelihood(model(), transition, sub, b0=b0, Ty=Ty).sum()
                (-ll / n_steps).backward()
                opt.step()
        with torch.no_grad():
            value = float(full_ll())
        if not math.isfinite(value):
            raise ModelError(
                "the tracks' log likelihood became non-finite: an observed cell has probability "
                "zero under the model (check the grid and the initial parameters)"
            )
        history.append(value)
        if callback is not None:
            callback(step, value)
        if abs(value - previous) <= tol * max(1.0, abs(previous)):
            converged = True
            break
        previous = value
    return ObservationFit(
        log_likelihood=history[-1],
        initial_log_likelihood=initial,
        history=tuple(history),
        steps=step,
        converged=converged,
    )


def _subset(tracks: HandTracks, idx: torch.Tensor) -> HandTracks:
    return HandTracks(
        observed=tracks.observed[idx],
        actions=tracks.actions[idx],
        cells=tracks.cells[idx],
        lengths=tracks.lengths[idx],
        positions=None if tracks.positions is None else tracks.positions[idx],
        types=None if tracks.types is None else tracks.types[idx],
    )


@torch.no_grad()
def simulate_tracks(
    model: DiscretizedGaussianObservation,
    transition: MOMDP | torch.Tensor,
    *,
    num_tracks: int,
    length: int,
    b0: torch.Tensor | None = None,
    x0: int | None = None,
    actions: torch.Tensor | None = None,
    seed: int = 0,
) -> HandTracks:
    """Simulate hand tracks of persons with a static hidden type.

    Each track draws a type ``y ~ b0`` once, then for ``t < length`` takes the action
    ``actions[n, t]`` (default: uniform random), samples ``x_t+1 ~ Tx[a, x_t, y, :]`` and the
    hand position from the model's Gaussian for ``(x_t+1, y)``, and records its grid cell.

    Args:
        model: the (true) observation model.
        transition: a MOMDP (``Tx``, ``b0``, ``x0``) or ``Tx: (A, X, Y, X)``.
        num_tracks: ``N``.
        length: ``L`` steps per track.
        b0: ``(Y,)`` type distribution (default the MOMDP's, or uniform).
        x0: initial observed state (default the MOMDP's, or 0).
        actions: ``(N, L)`` int64 actions (default uniform random).
        seed: seed of the generator.

    Returns:
        :class:`HandTracks` with ``positions`` and ``types`` filled.

    Example:
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> m = DiscretizedGaussianObservation(g, torch.zeros(2), torch.ones(2),
        ...                                    num_observed=1, num_hidden=1)
        >>> simulate_tracks(m, torch.ones(1, 1, 1, 1), num_tracks=2, length=3).cells.shape
        torch.Size([2, 3])
    """
    Tx, _, b0 = _unpack_transition(transition, b0, None)
    if x0 is None:
        if isinstance(transition, MOMDP) and transition.random_start:
            raise ValueError(
                "the MOMDP has a random first x (initial): pass x0, the observed value the "
                "tracks start at"
            )
        x0 = transition.x0 if isinstance(transition, MOMDP) else 0
    A, X = Tx.shape[-4], Tx.shape[-3]
    if (model.num_observed, model.num_hidden) != (X, Tx.shape[-2]):
        raise ModelError(
            f"model has (X, Y) = {(model.num_observed, model.num_hidden)}, the transition "
            f"{(X, Tx.shape[-2])}"
        )
    gen = torch.Generator(device=Tx.device)
    gen.manual_seed(int(seed))
    device = Tx.device
    if actions is None:
        actions = torch.randint(A, (num_tracks, length), generator=gen, device=device)
    elif tuple(actions.shape) != (num_tracks, length):
        raise ModelError(
            f"expected actions to have shape (N, L) = {(num_tracks, length)}, "
            f"actual shape = {tuple(actions.shape)}"
        )
    types = torch.multinomial(b0.expand(num_tracks, -1), 1, generator=gen).squeeze(-1)
    observed = torch.empty(num_tracks, length + 1, dtype=torch.long, device=device)
    observed[:, 0] = int(x0)
    for t in range(length):  # sampling a Markov chain is sequential in time
        p = Tx[actions[:, t], observed[:, t], types]  # (N, X)
        observed[:, t + 1] = torch.multinomial(p, 1, generator=gen).squeeze(-1)
    positions = model.sample(observed[:, 1:], types.unsqueeze(-1), generator=gen)
    cells = discretize_positions(model.grid, positions)
    return HandTracks(
        observed=observed,
        actions=actions.long(),
        cells=cells,
        lengths=torch.full((num_tracks,), length, dtype=torch.long, device=device),
        positions=positions,
        types=types,
    )
