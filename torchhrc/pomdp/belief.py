"""Belief updates for flat POMDPs and MOMDPs: batched, log space, differentiable.

Every function is pure: ``(model, belief, action, observation) -> BeliefUpdate``, the
argument order of POMDPs.jl's ``update(updater, b, a, o)``. The update is split into a
prediction (what solvers reuse across observations) and a correction by the observation.

Flat POMDP (Kaelbling, Littman, Cassandra 1998)::

    predicted[s2] = sum_s b[s] T[a, s, s2]                       (predict)
    b'[s2]        = Z[a, s2, o] predicted[s2] / P(o | b, a)        (correct)
    P(o | b, a)   = sum_s2 Z[a, s2, o] predicted[s2]              (the normaliser)

MOMDP (paper Eq. 3; Ong et al. 2010), the observed part ``x`` known, the belief over the
hidden part ``y``; the observed next value ``x2`` is seen together with ``o``::

    predicted[y2] = sum_y Tx[a, x, y, x2] Ty[a, x, y, x2, y2] b[y]     (momdp_predict)
    b'[y2]        = eta Z[a, x2, y2, o] predicted[y2]                  (momdp_correct)
    1 / eta       = P(x2, o | x, b, a)

With a static hidden value (``Ty is None``) the prediction is ``Tx[a, x, y2, x2] b[y2]``,
an elementwise product instead of a ``Y x Y`` matrix product (the fast path).

Shapes (letters of shared/DESIGN.md; ``...`` are batch dims that broadcast between the
model's batch shape, the belief's and the index tensors')::

    belief:         (..., S)      flat belief, sums to 1
    belief_y:       (..., Y)      belief over the hidden part of a MOMDP
    action, observation, x, x_next: int or int64 tensor (...)

Actions and observations may be Python ints or integer tensors; tensors broadcast with the
batch dims. The result is a :class:`BeliefUpdate` ``(belief, log_normalizer)``, where
``log_normalizer = log P(o | b, a)`` (``log P(x2, o | x, b, a)`` for a MOMDP).

An observation of probability zero under the belief raises :class:`~torchhrc.errors.ModelError`
naming the action and observation (``on_zero="raise"``, the default of the single updates), or
returns ``log_normalizer = -inf`` with a uniform stand-in belief (``on_zero="ninf"``, the
default of the ``*_all`` functions, where impossible observations are routine). Never NaN, in
values or gradients.

Log-space versions (``log_update``, ``log_update_all``, ``momdp_log_update``,
``momdp_log_update_all``) take and return ``log_belief``. The prediction shifts by the
belief's maximum (pyro's ``logmatmulexp`` trick, guarded so that ``-inf - -inf`` never occurs)
and treats entries that underflow after the shift in further passes, so a belief like
``log b = (0, -1000)`` keeps its second component. Gradients flow to the belief and to every
model tensor; in log space an exactly-zero model entry gets gradient zero (its log is ``-inf``).

Example:
    >>> import torch
    >>> from torchhrc.tasks.classic import tiger
    >>> m = tiger()
    >>> update(m, m.b0, action=0, observation=0).belief  # listen, hear the tiger left
    tensor([0.8500, 0.1500], dtype=torch.float64)
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import torch

from torchhrc._checks import broadcast_shapes, check_index
from torchhrc.errors import ModelError
from torchhrc.pomdp.dense import MOMDP, POMDP

__all__ = [
    "BeliefUpdate",
    "correct",
    "log_matmul_exp",
    "log_update",
    "log_update_all",
    "momdp_correct",
    "momdp_log_update",
    "momdp_log_update_all",
    "momdp_predict",
    "momdp_predict_all",
    "momdp_update",
    "momdp_update_all",
    "predict",
    "predict_all",
    "update",
    "update_all",
]

Index = int | torch.Tensor
OnZero = Literal["raise", "ninf"]


class BeliefUpdate(NamedTuple):
    """The result of a belief update.

    Attributes:
        belief: the updated belief (``(..., S)``, ``(..., Y)``, or ``(..., A, O, S)`` etc. for
            the ``*_all`` functions); a log belief for the ``log_*`` functions.
        log_normalizer: ``log P(o | b, a)`` (MOMDP: ``log P(x2, o | x, b, a)``), the shape of
            ``belief`` without its last dim; ``-inf`` where the observation is impossible.
    """

    belief: torch.Tensor
    log_normalizer: torch.Tensor


# ----------------------------------------------------------------------------- helpers


def _safe_log(x: torch.Tensor) -> torch.Tensor:
    """``log(x)`` with ``log(0) = -inf`` and a zero (not NaN / inf) gradient there."""
    positive = x > 0
    return torch.where(positive, torch.where(positive, x, torch.ones_like(x)).log(), -torch.inf)


def _safe_logsumexp(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """``logsumexp`` over ``dim`` returning ``-inf`` (gradient zero) when every entry is -inf."""
    m = x.amax(dim=dim, keepdim=True).detach()
    m = torch.where(torch.isfinite(m), m, torch.zeros_like(m))
    total = (x - m).exp().sum(dim=dim, keepdim=True)
    return (_safe_log(total) + m).squeeze(dim)


def log_matmul_exp(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Stable ``log(exp(x) @ exp(y))``: ``x (..., n, k)``, ``y (..., k, m)`` -> ``(..., n, m)``.

    Shifts each row of ``x`` and column of ``y`` by its maximum (a finite stand-in where the
    whole row is ``-inf``), so ``-inf - -inf`` never occurs; an all ``-inf`` contraction gives
    ``-inf`` with a zero gradient. Terms more than ~700 (float64) below their row's maximum
    underflow, as in pyro's ``logmatmulexp``.

    Example:
        >>> x = torch.tensor([[0.0, -float("inf")]])
        >>> log_matmul_exp(x, torch.zeros(2, 1)).item()
        0.0
    """
    x_shift = x.amax(dim=-1, keepdim=True).detach()
    x_shift = torch.where(torch.isfinite(x_shift), x_shift, torch.zeros_like(x_shift))
    y_shift = y.amax(dim=-2, keepdim=True).detach()
    y_shift = torch.where(torch.isfinite(y_shift), y_shift, torch.zeros_like(y_shift))
    xy = torch.matmul((x - x_shift).exp(), (y - y_shift).exp())
    return _safe_log(xy) + x_shift + y_shift


def _as_index(name: str, value: Index, size: int, device: torch.device) -> torch.Tensor:
    """Validate an int / integer tensor (or NumPy) index in ``[0, size)``; return int64."""
    return check_index(name, value, size, device=device)


def _take(t: torch.Tensor, core_ndim: int, indices: list[torch.Tensor | None]) -> torch.Tensor:
    """Index the last ``core_ndim`` dims of ``t`` with batched index tensors.

    ``indices[i]`` indexes core dim ``i`` (``None`` keeps the dim). The index tensors and
    ``t``'s leading (batch) dims broadcast together into ``B``; the result is
    ``B + (kept core dims in order)``, gathering only what is selected.
    """
    k = t.dim() - core_ndim
    batch = t.shape[:k]
    chosen = [i for i, v in enumerate(indices) if v is not None]
    kept = [i for i, v in enumerate(indices) if v is None]
    t = t.permute(*range(k), *(k + i for i in chosen), *(k + i for i in kept))
    index_tensors = [indices[i] for i in chosen]
    full = broadcast_shapes(batch, *(v.shape for v in index_tensors))  # type: ignore[union-attr]
    n = len(full)
    batch_index = []
    for d, size in enumerate(batch):
        shape = [1] * n
        shape[n - k + d] = size
        batch_index.append(torch.arange(size, device=t.device).view(shape))
    return t[(*batch_index, *index_tensors)]


def _unpermute(values: torch.Tensor, order: torch.Tensor) -> torch.Tensor:
    """Rows ``values[k]`` belong at ``order[k]``: return them in original order."""
    inverse = torch.empty_like(order)
    inverse[order] = torch.arange(order.numel(), device=order.device)
    return values[inverse]


def _handle_zero(
    log_norm: torch.Tensor,
    on_zero: str,
    what: str,
    labels: dict[str, torch.Tensor],
) -> None:
    if on_zero not in ("raise", "ninf"):
        raise ValueError(f'expected on_zero to be "raise" or "ninf", got {on_zero!r}')
    if on_zero == "ninf":
        return
    zero = torch.isneginf(log_norm)
    if bool(zero.any()):
        bad = torch.nonzero(zero)[0]
        parts = []
        for name, value in labels.items():
            v = value.expand(log_norm.shape)[tuple(bad)]
            parts.append(f"{name}={int(v)}")
        where = f" at batch index {tuple(bad.tolist())}" if log_norm.dim() else ""
        raise ModelError(
            f"{what} has probability zero under the belief ({', '.join(parts)}){where}; "
            'pass on_zero="ninf" to get a -inf log-normaliser instead'
        )


def _grid_labels(device: torch.device, **sizes: int) -> dict[str, torch.Tensor]:
    """Index tensors of a grid of outcomes, broadcastable against each other in order.

    ``_grid_labels(d, action=A, observation=O)`` gives ``action (A, 1)`` and
    ``observation (O,)``: the labels an error message uses for the offending entry.
    """
    names = list(sizes)
    return {
        name: torch.arange(sizes[name], device=device).view(-1, *[1] * (len(names) - i - 1))
        for i, name in enumerate(names)
    }


def _normalize(
    joint: torch.Tensor, on_zero: str, what: str, labels: dict[str, torch.Tensor]
) -> BeliefUpdate:
    """Normalise ``joint (..., N)`` over its last dim; handle zero normalisers."""
    norm = joint.sum(-1)
    log_norm = _safe_log(norm)
    _handle_zero(log_norm, on_zero, what, labels)
    zero = norm <= 0
    if not bool(zero.any()):
        return BeliefUpdate(joint / norm.unsqueeze(-1), log_norm)
    safe_norm = norm.masked_fill(zero, 1.0).unsqueeze(-1)
    belief = (joint / safe_norm).masked_fill(zero.unsqueeze(-1), 1.0 / joint.shape[-1])
    return BeliefUpdate(belief, log_norm)


def _log_normalize(
    log_joint: torch.Tensor, on_zero: str, what: str, labels: dict[str, torch.Tensor]
) -> BeliefUpdate:
    """Normalise ``log_joint (..., N)`` in log space; handle ``-inf`` normalisers."""
    log_norm = _safe_logsumexp(log_joint, -1)
    _handle_zero(log_norm, on_zero, what, labels)
    zero = torch.isneginf(log_norm)
    if not bool(zero.any()):
        return BeliefUpdate(log_joint - log_norm.unsqueeze(-1), log_norm)
    shift = log_norm.masked_fill(zero, 0.0).unsqueeze(-1)
    uniform = -math.log(log_joint.shape[-1])
    return BeliefUpdate((log_joint - shift).masked_fill(zero.unsqueeze(-1), uniform), log_norm)


def _safe_logaddexp(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``log(exp(a) + exp(b))``: ``-inf`` (gradient zero) when both are ``-inf``."""
    m = torch.maximum(a, b).detach()
    m = torch.where(torch.isfinite(m), m, torch.zeros_like(m))
    return _safe_log((a - m).exp() + (b - m).exp()) + m


def _log_linear(log_x: torch.Tensor, fn, extra_dims: int) -> torch.Tensor:
    """``log(fn(exp(log_x)))`` for a map ``fn`` linear in its ``(..., N)`` argument.

    Shift by the row maximum (pyro's log-matmul-exp), then treat the entries that underflowed
    (more than ~700 nats below it in float64) in further passes with their own shift, so no
    mass is lost however far apart the entries are. ``extra_dims``: how many dims ``fn``'s
    output has beyond ``(..., K)``, for broadcasting the shift. Loops over magnitude levels
    (usually one), never over states.
    """
    result = None
    remaining = log_x
    for _ in range(256):
        m = remaining.amax(dim=-1, keepdim=True).detach()
        m = torch.where(torch.isfinite(m), m, torch.zeros_like(m))
        p = (remaining - m).exp()
        shift = m.reshape(*m.shape, *([1] * extra_dims))
        part = _safe_log(fn(p)) + shift
        result = part if result is None else _safe_logaddexp(result, part)
        counted = p > 0
        remaining = torch.where(counted, torch.full_like(remaining, -torch.inf), remaining)
        if not bool(torch.isfinite(remaining).any()):
            break
    return result  # type: ignore[return-value]


def _check_belief(name: str, belief: object, size: int, doc: str) -> torch.Tensor:
    if not isinstance(belief, torch.Tensor):
        raise TypeError(f"expected {name} to be a torch.Tensor, got {type(belief).__name__}")
    if not belief.is_floating_point():
        raise TypeError(f"expected {name} to have a floating dtype, got {belief.dtype}")
    if belief.dim() < 1 or belief.shape[-1] != size:
        raise ModelError(
            f"expected {name} to have shape {doc} with last dim {size}, "
            f"actual shape = {tuple(belief.shape)}"
        )
    return belief


def _check_model(model: object, kind: type) -> None:
    if not isinstance(model, kind):
        raise TypeError(f"expected model to be a {kind.__name__}, got {type(model).__name__}")


# ----------------------------------------------------------------------------- flat POMDP


def predict_all(model: POMDP, belief: torch.Tensor) -> torch.Tensor:
    """The predicted state distribution for every action.

    ``predicted[..., a, s2] = sum_s belief[..., s] T[..., a, s, s2]``.

    Args:
        model: the POMDP.
        belief: ``(..., S)`` belief.

    Returns:
        ``(..., A, S)`` predicted next-state distributions (each sums to 1).

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> b = torch.tensor([1.0, 0.0], dtype=torch.float64)
        >>> predict_all(tiger(), b)[1]  # open-left resets the tiger
        tensor([0.5000, 0.5000], dtype=torch.float64)
    """
    _check_model(model, POMDP)
    belief = _check_belief("belief", belief, model.num_states, "(..., S)")
    # einsum folds the belief's extra batch dims into the matmul rows (no expanded copy of T)
    return torch.einsum("...s,...ast->...at", belief, model.T)


def predict(model: POMDP, belief: torch.Tensor, action: Index) -> torch.Tensor:
    """The predicted state distribution after ``action``: ``sum_s b[s] T[a, s, s2]``.

    Args:
        model: the POMDP.
        belief: ``(..., S)`` belief.
        action: int or int64 tensor ``(...)``.

    Returns:
        ``(..., S)`` predicted next-state distribution.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> m = tiger()
        >>> predict(m, m.b0, 0)  # listening does not move the tiger
        tensor([0.5000, 0.5000], dtype=torch.float64)
    """
    _check_model(model, POMDP)
    belief = _check_belief("belief", belief, model.num_states, "(..., S)")
    if isinstance(action, int) and not isinstance(action, bool):
        _as_index("action", action, model.num_actions, belief.device)
        Ta = model.T[..., action, :, :]
        return torch.matmul(belief.unsqueeze(-2), Ta).squeeze(-2)
    a = _as_index("action", action, model.num_actions, belief.device)
    if model.T.dim() == 3 and a.dim() > 0:
        # Unbatched model, per-belief actions: one (M, S) @ (S, S) product per action used,
        # A times cheaper than predicting every action (a loop over the few actions only).
        batch = broadcast_shapes(belief.shape[:-1], a.shape)
        S = belief.shape[-1]
        flat_b = belief.expand(*batch, S).reshape(-1, S)
        flat_a = a.expand(batch).reshape(-1)
        order, parts = [], []
        for act in torch.unique(flat_a).tolist():
            rows = torch.nonzero(flat_a == act).squeeze(-1)
            order.append(rows)
            parts.append(flat_b[rows] @ model.T[act])
        out = _unpermute(torch.cat(parts), torch.cat(order))
        return out.reshape(*batch, S)
    return _take(predict_all(model, belief), 2, [a, None])


def correct(
    model: POMDP,
    predicted: torch.Tensor,
    action: Index,
    observation: Index,
    *,
    on_zero: OnZero = "raise",
) -> BeliefUpdate:
    """Condition a predicted distribution on an observation.

    ``b'[s2] = Z[a, s2, o] predicted[s2] / P(o | b, a)``.

    Args:
        model: the POMDP.
        predicted: ``(..., S)`` the output of :func:`predict`.
        action: int or int64 tensor ``(...)``.
        observation: int or int64 tensor ``(...)``.
        on_zero: ``"raise"`` a :class:`ModelError` when ``P(o | b, a) = 0``, or ``"ninf"``.

    Returns:
        :class:`BeliefUpdate` ``(belief (..., S), log_normalizer (...))``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> m = tiger()
        >>> correct(m, m.b0, 0, 1).belief
        tensor([0.1500, 0.8500], dtype=torch.float64)
    """
    _check_model(model, POMDP)
    predicted = _check_belief("predicted", predicted, model.num_states, "(..., S)")
    a = _as_index("action", action, model.num_actions, predicted.device)
    o = _as_index("observation", observation, model.num_observations, predicted.device)
    z = _take(model.Z, 3, [a, None, o])  # (..., S)
    return _normalize(z * predicted, on_zero, "observation", {"action": a, "observation": o})


def update(
    model: POMDP,
    belief: torch.Tensor,
    action: Index,
    observation: Index,
    *,
    on_zero: OnZero = "raise",
) -> BeliefUpdate:
    """Bayes filter step of a flat POMDP: :func:`predict` then :func:`correct`.

    ``b'[s2] = Z[a, s2, o] sum_s T[a, s, s2] b[s] / P(o | b, a)``.

    Args:
        model: the POMDP.
        belief: ``(..., S)`` belief.
        action: int or int64 tensor ``(...)``.
        observation: int or int64 tensor ``(...)``.
        on_zero: ``"raise"`` (default) or ``"ninf"``.

    Returns:
        :class:`BeliefUpdate` ``(belief (..., S), log_normalizer (...))``.

    Raises:
        ModelError: the observation has probability zero and ``on_zero="raise"``, or an
            index is out of range.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> m = tiger()
        >>> update(m, m.b0, 0, 0).log_normalizer.exp()
        tensor(0.5000, dtype=torch.float64)
    """
    return correct(model, predict(model, belief, action), action, observation, on_zero=on_zero)


def update_all(model: POMDP, belief: torch.Tensor, *, on_zero: OnZero = "ninf") -> BeliefUpdate:
    """Update a belief for every action and observation at once (belief-tree expansion).

    Args:
        model: the POMDP.
        belief: ``(..., S)`` belief.
        on_zero: ``"ninf"`` (default: impossible observations get ``-inf`` and a uniform
            stand-in belief) or ``"raise"``.

    Returns:
        :class:`BeliefUpdate` with ``belief (..., A, O, S)`` (the updated belief after action
        ``a`` and observation ``o``) and ``log_normalizer (..., A, O)`` = ``log P(o | b, a)``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> m = tiger()
        >>> update_all(m, m.b0).belief[0, 0]
        tensor([0.8500, 0.1500], dtype=torch.float64)
    """
    predicted = predict_all(model, belief)  # (..., A, S)
    joint = predicted.unsqueeze(-2) * model.Z.transpose(-1, -2)  # (..., A, O, S)
    labels = _grid_labels(
        joint.device, action=model.num_actions, observation=model.num_observations
    )
    return _normalize(joint, on_zero, "observation", labels)


def log_update(
    model: POMDP,
    log_belief: torch.Tensor,
    action: Index,
    observation: Index,
    *,
    on_zero: OnZero = "raise",
) -> BeliefUpdate:
    """:func:`update` in log space: ``log_belief (..., S)`` in, log belief out.

    Args:
        model: the POMDP.
        log_belief: ``(..., S)`` log belief (``-inf`` allowed).
        action: int or int64 tensor ``(...)``.
        observation: int or int64 tensor ``(...)``.
        on_zero: ``"raise"`` (default) or ``"ninf"``.

    Returns:
        :class:`BeliefUpdate` ``(log_belief (..., S), log_normalizer (...))``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> m = tiger()
        >>> log_update(m, m.b0.log(), 0, 0).belief.exp()
        tensor([0.8500, 0.1500], dtype=torch.float64)
    """
    _check_model(model, POMDP)
    log_belief = _check_belief("log_belief", log_belief, model.num_states, "(..., S)")
    log_pred = _log_linear(log_belief, lambda p: predict(model, p, action), 0)  # (..., S)
    a = _as_index("action", action, model.num_actions, log_belief.device)
    o = _as_index("observation", observation, model.num_observations, log_belief.device)
    log_z = _safe_log(_take(model.Z, 3, [a, None, o]))
    return _log_normalize(log_pred + log_z, on_zero, "observation", {"action": a, "observation": o})


def log_update_all(
    model: POMDP, log_belief: torch.Tensor, *, on_zero: OnZero = "ninf"
) -> BeliefUpdate:
    """:func:`update_all` in log space.

    Args:
        model: the POMDP.
        log_belief: ``(..., S)`` log belief.
        on_zero: ``"ninf"`` (default) or ``"raise"``.

    Returns:
        :class:`BeliefUpdate` ``(log_belief (..., A, O, S), log_normalizer (..., A, O))``.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> m = tiger()
        >>> log_update_all(m, m.b0.log()).log_normalizer.exp()[0]
        tensor([0.5000, 0.5000], dtype=torch.float64)
    """
    _check_model(model, POMDP)
    log_belief = _check_belief("log_belief", log_belief, model.num_states, "(..., S)")
    log_pred = _log_linear(log_belief, lambda p: predict_all(model, p), 1)  # (..., A, S)
    log_joint = log_pred.unsqueeze(-2) + _safe_log(model.Z.transpose(-1, -2))  # (..., A, O, S)
    labels = _grid_labels(
        log_joint.device, action=model.num_actions, observation=model.num_observations
    )
    return _log_normalize(log_joint, on_zero, "observation", labels)


# ----------------------------------------------------------------------------- MOMDP


def momdp_predict(
    model: MOMDP, x: Index, belief_y: torch.Tensor, action: Index, x_next: Index
) -> torch.Tensor:
    """Unnormalised joint prediction of a MOMDP (paper Eq. 3 without the observation).

    ``predicted[y2] = sum_y Tx[a, x, y, x2] Ty[a, x, y, x2, y2] b[y] = P(x2, y2 | x, b, a)``;
    with ``Ty is None``: ``Tx[a, x, y2, x2] b[y2]``.

    Args:
        model: the MOMDP.
        x: observed value, int or int64 tensor ``(...)``.
        belief_y: ``(..., Y)`` belief over the hidden value.
        action: int or int64 tensor ``(...)``.
        x_next: next observed value, int or int64 tensor ``(...)``.

    Returns:
        ``(..., Y)`` joint ``P(x2, y2 | x, b, a)``; sums to ``P(x2 | x, b, a)``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> momdp_predict(m, 0, m.b0, 1, 2).shape
        torch.Size([2])
    """
    _check_model(model, MOMDP)
    belief_y = _check_belief("belief_y", belief_y, model.num_hidden, "(..., Y)")
    dev = belief_y.device
    X = model.num_observed
    xi = _as_index("x", x, X, dev)
    a = _as_index("action", action, model.num_actions, dev)
    x2 = _as_index("x_next", x_next, X, dev)
    tx = _take(model.Tx, 4, [a, xi, None, x2])  # (..., Y)
    if model.Ty is None:
        return tx * belief_y
    ty = _take(model.Ty, 5, [a, xi, None, x2, None])  # (..., Y, Y2)
    return torch.matmul((tx * belief_y).unsqueeze(-2), ty).squeeze(-2)


def momdp_predict_all(model: MOMDP, x: Index, belief_y: torch.Tensor) -> torch.Tensor:
    """:func:`momdp_predict` for every action and next observed value.

    Args:
        model: the MOMDP.
        x: observed value, int or int64 tensor ``(...)``.
        belief_y: ``(..., Y)`` belief over the hidden value.

    Returns:
        ``(..., A, X, Y)``: ``[a, x2, y2] = P(x2, y2 | x, b, a)``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> momdp_predict_all(m, 0, m.b0).sum((-2, -1))
        tensor([1.0000, 1.0000], dtype=torch.float64)
    """
    _check_model(model, MOMDP)
    belief_y = _check_belief("belief_y", belief_y, model.num_hidden, "(..., Y)")
    xi = _as_index("x", x, model.num_observed, belief_y.device)
    if model.Tx.dim() == 4 and xi.dim() > 0:
        # Unbatched model, per-belief x: group the beliefs by x instead of gathering a
        # (..., A, Y, X, Y) slice of Ty per belief (a loop over the distinct x present only).
        A, X, Y = model.num_actions, model.num_observed, model.num_hidden
        batch = broadcast_shapes(belief_y.shape[:-1], xi.shape)
        flat_b = belief_y.expand(*batch, Y).reshape(-1, Y)
        flat_x = xi.expand(batch).reshape(-1)
        order, parts = [], []
        for value in torch.unique(flat_x).tolist():
            rows = torch.nonzero(flat_x == value).squeeze(-1)
            weighted = model.Tx[:, value] * flat_b[rows, None, :, None]  # (m, A, Y, X2)
            if model.Ty is None:
                parts.append(weighted.transpose(-1, -2))
            else:
                parts.append(torch.einsum("mayx,ayxz->maxz", weighted, model.Ty[:, value]))
            order.append(rows)
        out = _unpermute(torch.cat(parts), torch.cat(order))
        return out.reshape(*batch, A, X, Y)
    tx = _take(model.Tx, 4, [None, xi, None, None])  # (..., A, Y, X2)
    weighted = tx * belief_y.unsqueeze(-2).unsqueeze(-1)  # (..., A, Y, X2)
    if model.Ty is None:
        return weighted.transpose(-1, -2)  # (..., A, X2, Y)
    ty = _take(model.Ty, 5, [None, xi, None, None, None])  # (..., A, Y, X2, Y2)
    # sum_y weighted[a, y, x2] ty[a, y, x2, y2] (einsum: no expanded copy of ty)
    return torch.einsum("...ayx,...ayxz->...axz", weighted, ty)


def momdp_correct(
    model: MOMDP,
    predicted: torch.Tensor,
    action: Index,
    x_next: Index,
    observation: Index,
    *,
    on_zero: OnZero = "raise",
) -> BeliefUpdate:
    """Condition a MOMDP prediction on ``(x2, o)``: ``b'[y2] = eta Z[a, x2, y2, o] predicted[y2]``.

    Args:
        model: the MOMDP.
        predicted: ``(..., Y)`` output of :func:`momdp_predict`.
        action, x_next, observation: ints or int64 tensors ``(...)``.
        on_zero: ``"raise"`` (default) or ``"ninf"``.

    Returns:
        :class:`BeliefUpdate` ``(belief_y (..., Y), log_normalizer (...))`` with
        ``log_normalizer = log P(x2, o | x, b, a)``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> momdp_correct(m, momdp_predict(m, 0, m.b0, 1, 2), 1, 2, 0).belief.sum().item()
        1.0
    """
    _check_model(model, MOMDP)
    predicted = _check_belief("predicted", predicted, model.num_hidden, "(..., Y)")
    dev = predicted.device
    a = _as_index("action", action, model.num_actions, dev)
    x2 = _as_index("x_next", x_next, model.num_observed, dev)
    o = _as_index("observation", observation, model.num_observations, dev)
    z = _take(model.Z, 4, [a, x2, None, o])  # (..., Y)
    labels = {"action": a, "x_next": x2, "observation": o}
    return _normalize(z * predicted, on_zero, "(x_next, observation)", labels)


def momdp_update(
    model: MOMDP,
    x: Index,
    belief_y: torch.Tensor,
    action: Index,
    x_next: Index,
    observation: Index,
    *,
    on_zero: OnZero = "raise",
) -> BeliefUpdate:
    """MOMDP belief update over the hidden value (paper Eq. 3; Ong et al. 2010).

    ``b'(y2) = eta Z(x2, y2, a, o) sum_y Tx(x, y, a, x2) Ty(x, y, a, x2, y2) b(y)``.

    Args:
        model: the MOMDP.
        x: current observed value, int or int64 tensor ``(...)``.
        belief_y: ``(..., Y)`` belief over the hidden value.
        action: int or int64 tensor ``(...)``.
        x_next: observed value after the action.
        observation: the observation received.
        on_zero: ``"raise"`` (default) or ``"ninf"``.

    Returns:
        :class:`BeliefUpdate` ``(belief_y (..., Y), log_normalizer (...))``,
        ``log_normalizer = log P(x2, o | x, b, a)``.

    Raises:
        ModelError: ``(x_next, observation)`` is impossible and ``on_zero="raise"``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> momdp_update(m, 0, m.b0, 1, 2, 0).belief.shape
        torch.Size([2])
    """
    predicted = momdp_predict(model, x, belief_y, action, x_next)
    return momdp_correct(model, predicted, action, x_next, observation, on_zero=on_zero)


def momdp_update_all(
    model: MOMDP, x: Index, belief_y: torch.Tensor, *, on_zero: OnZero = "ninf"
) -> BeliefUpdate:
    """:func:`momdp_update` for every ``(a, x2, o)`` at once.

    Args:
        model: the MOMDP.
        x: current observed value, int or int64 tensor ``(...)``.
        belief_y: ``(..., Y)`` belief over the hidden value.
        on_zero: ``"ninf"`` (default) or ``"raise"``.

    Returns:
        :class:`BeliefUpdate` with ``belief (..., A, X, O, Y)`` and
        ``log_normalizer (..., A, X, O) = log P(x2, o | x, b, a)``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> momdp_update_all(m, 0, m.b0).log_normalizer.exp().sum((-2, -1))
        tensor([1.0000, 1.0000], dtype=torch.float64)
    """
    predicted = momdp_predict_all(model, x, belief_y)  # (..., A, X, Y)
    joint = predicted.unsqueeze(-2) * model.Z.transpose(-1, -2)  # (..., A, X, O, Y)
    A, X, O = model.num_actions, model.num_observed, model.num_observations
    labels = _grid_labels(joint.device, action=A, x_next=X, observation=O)
    return _normalize(joint, on_zero, "(x_next, observation)", labels)


def momdp_log_update(
    model: MOMDP,
    x: Index,
    log_belief_y: torch.Tensor,
    action: Index,
    x_next: Index,
    observation: Index,
    *,
    on_zero: OnZero = "raise",
) -> BeliefUpdate:
    """:func:`momdp_update` in log space: ``log_belief_y (..., Y)`` in, log belief out.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> r = momdp_log_update(m, 0, m.b0.log(), 1, 2, 0)
        >>> bool(torch.allclose(r.belief.exp(), momdp_update(m, 0, m.b0, 1, 2, 0).belief))
        True
    """
    _check_model(model, MOMDP)
    log_belief_y = _check_belief("log_belief_y", log_belief_y, model.num_hidden, "(..., Y)")
    log_pred = _log_linear(
        log_belief_y, lambda p: momdp_predict(model, x, p, action, x_next), 0
    )  # (..., Y)
    dev = log_belief_y.device
    a = _as_index("action", action, model.num_actions, dev)
    x2 = _as_index("x_next", x_next, model.num_observed, dev)
    o = _as_index("observation", observation, model.num_observations, dev)
    log_z = _safe_log(_take(model.Z, 4, [a, x2, None, o]))
    labels = {"action": a, "x_next": x2, "observation": o}
    return _log_normalize(log_pred + log_z, on_zero, "(x_next, observation)", labels)


def momdp_log_update_all(
    model: MOMDP, x: Index, log_belief_y: torch.Tensor, *, on_zero: OnZero = "ninf"
) -> BeliefUpdate:
    """:func:`momdp_update_all` in log space.

    Returns:
        :class:`BeliefUpdate` ``(log_belief (..., A, X, O, Y), log_normalizer (..., A, X, O))``.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> momdp_log_update_all(m, 0, m.b0.log()).belief.shape
        torch.Size([2, 3, 2, 2])
    """
    _check_model(model, MOMDP)
    log_belief_y = _check_belief("log_belief_y", log_belief_y, model.num_hidden, "(..., Y)")
    log_pred = _log_linear(log_belief_y, lambda p: momdp_predict_all(model, x, p), 2)
    log_joint = log_pred.unsqueeze(-2) + _safe_log(model.Z.transpose(-1, -2))
    A, X, O = model.num_actions, model.num_observed, model.num_observations
    labels = _grid_labels(log_joint.device, action=A, x_next=X, observation=O)
    return _log_normalize(log_joint, on_zero, "(x_next, observation)", labels)
