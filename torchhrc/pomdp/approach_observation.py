"""An observation model of a hand that *approaches* its target: a learned motion per type.

:class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation` (the paper's form) says the hand
is ``N(mean[x, y], Sigma)`` around the surface of type ``y`` in task state ``x``, whatever
happened before. A real hand walks there: it starts where the person stands and closes a
fraction of the remaining distance at every step, so its first positions of an approach sit
between the start and the surface, and a static Gaussian fitted to such tracks has to absorb
the lag in a shifted, wider cloud, which pushes the belief the wrong way on the first
observations.

:class:`ApproachObservation` models the motion: under type ``y`` the hand follows the
first-order (exponential) approach

    ``m_t(y) = m_t-1(y) + a (g(x_t, y) - m_t-1(y))``,   ``m_-1 = start``

to the targets ``g(x, y) = offset[x, y] + loc[y]`` of a stationary
:class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation` (its ``mean()``), and the sensor
reports the grid cell of ``N(m_t(y), Sigma[x_t, y])``. Given the observed task states
``x_0..t`` (observed in a MOMDP) and a type ``y``, ``m_t(y)`` is deterministic, so the
belief filter stays exact: it carries one hand mean per type beside the belief
(:meth:`ApproachObservation.filter_start`, :meth:`ApproachObservation.filter_update`;
paper Eq. 3 with ``Z_t(o | x_0..t, y)``). The approach rate ``a = sigmoid(raw_approach)``,
the start, and the stationary model's ``loc`` and ``log_scale`` are ``nn.Parameter``s,
learned from tracks with the type unknown by maximum marginal likelihood
(:func:`fit_approach_observation`, the same objective as
:func:`~torchhrc.pomdp.observation_fit.fit_observation_model`: the belief filter's log normalisers),
differentiable end to end (gradcheck in float64, ``tests/pomdp/test_approach_observation.py``).

For planning, :attr:`ApproachObservation.stationary` is a MOMDP observation model (the hand
at its target): a MOMDP's ``Z(o | x', y, a)`` cannot depend on the hand's history, so this
is as far as the motion enters the plan. ``torchhrc reproduce hand-finishing`` solves the
MOMDP on it and filters with the full model (``torchhrc.experiments.hand_finishing``).

Example:
    >>> import torch
    >>> from torchhrc.pomdp.observation import DiscretizedGaussianObservation, ObservationGrid
    >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
    >>> target = DiscretizedGaussianObservation(g, torch.tensor([[-0.5, 0.0], [0.5, 0.0]],
    ...     dtype=torch.float64), torch.full((2,), 0.3, dtype=torch.float64),
    ...     num_observed=1, num_hidden=2)
    >>> m = ApproachObservation(target, approach=0.5, start=(0.0, 0.0))
    >>> m.means(torch.zeros(1, 3, dtype=torch.long))[0, :, 1, 0].tolist()  # type 1's x
    [0.25, 0.375]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from torchhrc._checks import check_tensor
from torchhrc.errors import ModelError
from torchhrc.pomdp.dense import MOMDP
from torchhrc.pomdp.observation import DiscretizedGaussianObservation, log_discretized_gaussian
from torchhrc.pomdp.observation_fit import HandTracks, _safe_log, _unpack_transition

__all__ = [
    "ApproachFit",
    "ApproachObservation",
    "approach_log_likelihood",
    "fit_approach_observation",
]


class ApproachObservation(nn.Module):
    """A hand that approaches the targets of a stationary Gaussian model (module docstring).

    Args:
        stationary: the targets and sensor noise (its ``loc`` / ``log_scale`` are learned
            with this module).
        approach: initial fraction of the remaining distance covered per step, in (0, 1).
        start: initial ``(x, y)`` hand position before the first step (learned).

    Example:
        >>> import torch
        >>> from torchhrc.pomdp.observation import ObservationGrid
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> s = DiscretizedGaussianObservation(g, torch.zeros(2, dtype=torch.float64),
        ...     torch.ones(2, dtype=torch.float64), num_observed=2, num_hidden=2)
        >>> round(ApproachObservation(s, approach=0.8).approach().item(), 6)
        0.8
    """

    raw_approach: nn.Parameter
    start: nn.Parameter

    def __init__(
        self,
        stationary: DiscretizedGaussianObservation,
        *,
        approach: float = 0.5,
        start: tuple[float, float] | torch.Tensor = (0.0, 0.0),
    ) -> None:
        super().__init__()
        if not isinstance(stationary, DiscretizedGaussianObservation):
            raise TypeError(
                "expected stationary to be a DiscretizedGaussianObservation, got "
                f"{type(stationary).__name__}"
            )
        if not (isinstance(approach, (int, float)) and 0.0 < approach < 1.0):
            raise ModelError(f"expected approach in (0, 1), got {approach!r}")
        dtype = stationary.loc.dtype
        start_t = torch.as_tensor(start, dtype=dtype).detach().clone()
        if start_t.shape != (2,) or not torch.isfinite(start_t).all():
            raise ModelError(f"expected start to be two finite numbers (x, y), got {start!r}")
        self.stationary = stationary
        self.raw_approach = nn.Parameter(torch.logit(torch.tensor(float(approach), dtype=dtype)))
        self.start = nn.Parameter(start_t)

    @property
    def num_hidden(self) -> int:
        """``Y``."""
        return self.stationary.num_hidden

    def approach(self) -> torch.Tensor:
        """``()`` the approach rate ``a = sigmoid(raw_approach)`` in (0, 1)."""
        return torch.sigmoid(self.raw_approach)

    def means(self, observed: torch.Tensor) -> torch.Tensor:
        """``(N, L, Y, 2)`` hand means ``m_t(y)`` after steps ``t = 0 .. L-1``.

        Args:
            observed: ``(N, L + 1)`` int64 observed states ``x_0 .. x_L`` (the target of step
                ``t`` is ``g(x_t+1, y)``).

        The recursion in closed form, all steps at once:
        ``m_t = (1 - a)^(t+1) start + sum_k<=t a (1 - a)^(t-k) g_k`` (a lower-triangular
        ``(L, L)`` matrix applied to the targets).
        """
        observed = check_tensor("observed", observed, floating=False)
        if observed.dim() != 2 or observed.shape[-1] < 2:
            raise ModelError(
                f"expected observed of shape (N, L + 1) with L >= 1, got {tuple(observed.shape)}"
            )
        targets = self.stationary.mean()[observed[:, 1:]]  # (N, L, Y, 2)
        L = targets.shape[1]
        a = self.approach()
        t = torch.arange(L, dtype=targets.dtype, device=targets.device)
        lag = t.unsqueeze(-1) - t  # (L, L): t - k
        keep = 1.0 - a
        weights = torch.where(lag >= 0, a * keep ** lag.clamp(min=0), torch.zeros_like(lag))
        from_start = (keep ** (t + 1)).unsqueeze(-1) * self.start  # (L, 2)
        return torch.einsum("tk,nkyc->ntyc", weights, targets) + from_start[:, None, :]

    def cell_log_probs(
        self, means: torch.Tensor, x_next: torch.Tensor, cells: torch.Tensor
    ) -> torch.Tensor:
        """``(..., Y)`` ``log P(cell | m(y), Sigma[x_next, y])`` for means ``(..., Y, 2)``,
        states ``x_next (...)`` and observed cells ``(...)``."""
        scale = self.stationary.scale()[x_next]  # (..., Y, 2)
        rho = self.stationary.correlation()
        logp = log_discretized_gaussian(
            self.stationary.grid,
            means,
            scale=scale,
            correlation=None if rho is None else rho[x_next],
        )  # (..., Y, O)
        index = cells.unsqueeze(-1).unsqueeze(-1).expand(*logp.shape[:-1], 1)
        return logp.gather(-1, index).squeeze(-1)

    # ------------------------------------------------------------------ online filter
    def filter_start(self, n: int) -> torch.Tensor:
        """``(n, Y, 2)`` the filter's hand means before the first step (the start)."""
        return self.start.detach().expand(n, self.num_hidden, 2).clone()

    def filter_update(
        self,
        model: MOMDP,
        x: torch.Tensor,
        belief: torch.Tensor,
        action: torch.Tensor,
        x_next: torch.Tensor,
        cell: torch.Tensor,
        hands: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One exact belief update with this model: ``(belief (n, Y), hands (n, Y, 2))``.

        ``m' = m + a (g(x_next, y) - m)``; ``b'(y) ∝ b(y) Tx[a, x, y, x_next]
        P(cell | m'(y))`` (static type, paper Eq. 3 with the motion model's ``Z``).

        Raises:
            ModelError: the step is impossible under every type the belief allows.
        """
        with torch.no_grad():
            a = self.approach()
            target = self.stationary.mean()[x_next]  # (n, Y, 2)
            hands = hands + a * (target - hands)
            log_z = self.cell_log_probs(hands, x_next, cell)  # (n, Y)
            log_tx = _safe_log(model.Tx[action, x, :, x_next])  # (n, Y)
            joint = _safe_log(belief) + log_tx + log_z
            norm = torch.logsumexp(joint, dim=-1, keepdim=True)
            if not torch.isfinite(norm).all():
                raise ModelError("a step of the episode is impossible under every type")
            return (joint - norm).exp(), hands


def approach_log_likelihood(
    model: ApproachObservation,
    transition: MOMDP | torch.Tensor,
    tracks: HandTracks,
    *,
    b0: torch.Tensor | None = None,
) -> torch.Tensor:
    """``(N,)`` log marginal likelihood of each track with the (static) type unknown.

    ``log sum_y b0(y) prod_t Tx[a_t, x_t, y, x_t+1] P(o_t | m_t(y), Sigma[x_t+1, y])``: the
    sum of the belief filter's log normalisers, as
    :func:`~torchhrc.pomdp.observation_fit.track_log_likelihood`, with the approach model's means.

    Example:
        >>> import torch
        >>> from torchhrc.pomdp.observation import ObservationGrid
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (2, 2))
        >>> s = DiscretizedGaussianObservation(g, torch.zeros(2, dtype=torch.float64),
        ...     torch.full((2,), 1e3, dtype=torch.float64), num_observed=1, num_hidden=2)
        >>> t = HandTracks(torch.zeros(1, 3, dtype=torch.long),
        ...     torch.zeros(1, 2, dtype=torch.long), torch.tensor([[0, 3]]), torch.tensor([2]))
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> round(approach_log_likelihood(ApproachObservation(s), Tx, t).item(), 3)  # 2 log 1/4
        -2.773
    """
    Tx, Ty, b0 = _unpack_transition(transition, b0, None)
    if Ty is not None:
        raise ModelError("approach_log_likelihood supports static types only (Ty = None)")
    A, X, Y = Tx.shape[-4], Tx.shape[-3], Tx.shape[-2]
    if (X, Y) != (model.stationary.num_observed, model.num_hidden):
        raise ModelError(
            f"expected a transition with X = {model.stationary.num_observed} observed values "
            f"and Y = {model.num_hidden} types (the model's), got X = {X}, Y = {Y}"
        )
    tracks.check_against(A, X, model.stationary.num_observations)
    mask = tracks.mask  # (N, L)
    x, x2 = tracks.observed[:, :-1], tracks.observed[:, 1:]
    means = model.means(tracks.observed)  # (N, L, Y, 2)
    log_z = model.cell_log_probs(means, x2, tracks.cells)  # (N, L, Y)
    log_tx = _safe_log(Tx[tracks.actions, x, :, x2])  # (N, L, Y)
    step = torch.where(mask.unsqueeze(-1), log_tx + log_z, torch.zeros_like(log_z))
    return torch.logsumexp(_safe_log(b0) + step.sum(dim=1), dim=-1)


@dataclass(frozen=True)
class ApproachFit:
    """Result of :func:`fit_approach_observation` (as
    :class:`~torchhrc.pomdp.observation_fit.ObservationFit`)."""

    log_likelihood: float
    initial_log_likelihood: float
    history: tuple[float, ...]
    steps: int
    converged: bool


def fit_approach_observation(
    model: ApproachObservation,
    transition: MOMDP | torch.Tensor,
    tracks: HandTracks,
    *,
    b0: torch.Tensor | None = None,
    steps: int = 200,
    lr: float = 0.05,
    tol: float = 1e-9,
) -> ApproachFit:
    """Learn the approach model (rate, start, targets, noise) from tracks, type unknown.

    Maximises the tracks' log marginal likelihood (:func:`approach_log_likelihood`) with
    Adam on the full batch (deterministic); the parameters are updated in place.

    Args:
        model: the model to fit (its parameters are the starting point).
        transition: a MOMDP (``Tx``, ``b0``) or ``Tx: (A, X, Y, X)``.
        tracks: the recorded tracks (each from the hand's start).
        b0: override the initial type belief.
        steps: maximum optimiser steps.
        lr: Adam learning rate.
        tol: stop when the relative change of the log likelihood is below this.

    Returns:
        :class:`ApproachFit`.

    Raises:
        ModelError: no steps to learn from, or a non-finite likelihood.

    Example:
        >>> import torch
        >>> from torchhrc.pomdp.observation import ObservationGrid
        >>> g = ObservationGrid.uniform((-1.0, 1.0), (-1.0, 1.0), (4, 4))
        >>> s = DiscretizedGaussianObservation(g, torch.zeros(2, 2, dtype=torch.float64),
        ...     torch.full((2,), 0.5, dtype=torch.float64), num_observed=1, num_hidden=2)
        >>> t = HandTracks(torch.zeros(2, 4, dtype=torch.long),
        ...     torch.zeros(2, 3, dtype=torch.long), torch.tensor([[5, 6, 6], [9, 10, 10]]),
        ...     torch.tensor([3, 3]))
        >>> Tx = torch.ones(1, 1, 2, 1, dtype=torch.float64)
        >>> fit = fit_approach_observation(ApproachObservation(s), Tx, t, steps=5)
        >>> fit.steps, fit.log_likelihood > fit.initial_log_likelihood
        (5, True)
    """
    if not isinstance(steps, int) or steps < 1:
        raise ModelError(f"expected steps to be a positive int, got {steps!r}")
    n_steps = int(tracks.lengths.sum())
    if n_steps == 0:
        raise ModelError("tracks has no steps to learn from")
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=lr)
    with torch.no_grad():
        initial = float(approach_log_likelihood(model, transition, tracks, b0=b0).sum())
    previous, history, converged, step = initial, [], False, 0
    for step in range(1, steps + 1):
        opt.zero_grad()
        ll = approach_log_likelihood(model, transition, tracks, b0=b0).sum()
        (-ll / n_steps).backward()
        opt.step()
        value = float(ll.detach())  # the likelihood before this step (one evaluation a step)
        if not math.isfinite(value):
            raise ModelError("the tracks' log likelihood became non-finite")
        history.append(value)
        if step > 1 and abs(value - previous) <= tol * max(1.0, abs(previous)):
            converged = True
            break
        previous = value
    with torch.no_grad():
        final = float(approach_log_likelihood(model, transition, tracks, b0=b0).sum())
    return ApproachFit(
        log_likelihood=final,
        initial_log_likelihood=initial,
        history=tuple(history),
        steps=step,
        converged=converged,
    )
