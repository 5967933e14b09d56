"""Point-based Bellman backups of many beliefs at once, flat and MOMDP-factored.

The backup of a belief ``b`` against a set of alpha vectors ``Gamma`` (Pineau, Gordon, Thrun
2003, Eq. 8-10; shared by PBVI and SARSOP)::

    Gamma_{a,o}(n, s) = discount * sum_s2 T(a, s, s2) Z(a, s2, o) alpha_n(s2)
    alpha_{b,a}       = R(a) + sum_o Gamma_{a,o}(argmax_n b . Gamma_{a,o}(n), :)
    backup(b)         = argmax_a b . alpha_{b,a}

Every step is a tensor operation over all beliefs, actions and observations at once. Two
equivalent flat kernels are chosen by cost: the projections ``Gamma (A, O, N, S)`` computed
by one batched matmul and gathered (cheap when there are more beliefs than vectors), or the
belief side ``b T Z`` scored against the vectors (cheap for few beliefs); both are chunked
to bound memory.

MOMDP (Ong et al. 2010): vectors are per observed value, ``alphas (N, Y)`` with
``observed (N,)``; a belief is ``(x, b_y)``. The observed successor ``x2`` is seen exactly, so
the backed-up vector sums over the reachable ``(a, x2)`` and ``o`` with the vectors of ``x2``
only::

    alpha_{b,a}(y) = R(a, x, y) + discount * sum_{x2, o} sum_y2 Tx(a, x, y, x2)
                     Ty(a, x, y, x2, y2) Z(a, x2, y2, o) alpha*_{x2, o}(y2),
    alpha*_{x2, o} = argmax_{n : observed[n] = x2} sum_y2 alpha_n(y2) Z(a, x2, y2, o)
                     sum_y b(y) Tx(a, x, y, x2) Ty(a, x, y, x2, y2)

Only the ``(belief, a, x2)`` triples with ``Tx > 0`` are touched, so the cost grows with the
branching of ``x``, not with ``X``: much cheaper than the flat backup over ``X * Y`` states.

The backed-up vector of every action is complete (defined at every state, including those
outside the belief's support), so it is the value of a real one-step-lookahead plan: backups
of lower-bound vectors are lower-bound vectors.

Example:
    >>> import torch
    >>> from torchhrc.testing import random_pomdp
    >>> from torchhrc.solvers.blind import blind_policy
    >>> model = random_pomdp(4, 2, 3, seed=0)
    >>> result = point_backup(model, blind_policy(model), torch.eye(4, dtype=torch.float64))
    >>> result.alphas.shape, result.actions.shape
    (torch.Size([4, 4]), torch.Size([4]))
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Iterator
from typing import NamedTuple

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.solvers._factored import state_dims
from torchhrc.solvers.policy import AlphaVectorPolicy

__all__ = ["BackupResult", "momdp_point_backup", "point_backup"]

#: Largest number of tensor elements one chunk of a backup materialises.
CHUNK_ELEMENTS = 1 << 23


class BackupResult(NamedTuple):
    """The backed-up vectors of ``M`` beliefs.

    Attributes:
        alphas: ``(M, S)`` (flat) or ``(M, Y)`` (MOMDP), the new vector of each belief.
        actions: ``(M,)`` int64, the action of each new vector.
        values: ``(M,)`` ``b . alphas`` (the backed-up value at each belief).
        q_values: ``(M, A)`` the value of each action's backed-up vector at the belief.
        observed: ``(M,)`` int64 ``x`` of each new vector (MOMDP), or None.
    """

    alphas: torch.Tensor
    actions: torch.Tensor
    values: torch.Tensor
    q_values: torch.Tensor
    observed: torch.Tensor | None = None

    def as_policy(self) -> AlphaVectorPolicy:
        """The new vectors as an :class:`AlphaVectorPolicy`."""
        return AlphaVectorPolicy(self.alphas, self.actions, self.observed)


def _check_unbatched(model: POMDP | MOMDP) -> None:
    if len(model.batch_shape) != 0:
        raise ModelError(
            f"point-based backups take one model, got batch_shape {tuple(model.batch_shape)}; "
            "index the batch first"
        )


def _check_beliefs(beliefs: torch.Tensor, name: str, size: int) -> torch.Tensor:
    """``beliefs`` as a ``(M, size)`` tensor, or a ModelError naming the expected shape."""
    beliefs = check_tensor("beliefs", beliefs)
    check_shape("beliefs", beliefs, (size,), f"(M, {name}={size})")
    if beliefs.dim() != 2:
        raise ModelError(
            f"expected beliefs to have shape (M, {name}), actual shape = {tuple(beliefs.shape)}"
        )
    return beliefs


def _select_action(
    beliefs: torch.Tensor, vectors: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    # vectors: (M, A, S); q: (M, A)
    q = torch.einsum("ms,mas->ma", beliefs, vectors)
    values, actions = q.max(-1)
    alphas = vectors.gather(1, actions.view(-1, 1, 1).expand(-1, 1, vectors.shape[-1])).squeeze(1)
    return alphas, actions, values, q


def _new_result(beliefs: torch.Tensor, num_actions: int) -> BackupResult:
    """An unfilled result for ``beliefs (M, D)``, filled chunk by chunk by :func:`_select_into`."""
    M, D = beliefs.shape
    actions = torch.empty(M, dtype=torch.int64, device=beliefs.device)
    return BackupResult(beliefs.new_empty(M, D), actions, beliefs.new_empty(M),
                        beliefs.new_empty(M, num_actions))  # fmt: skip


def _select_into(result: BackupResult, rows: slice | torch.Tensor, beliefs: torch.Tensor,
                 vectors: torch.Tensor) -> None:  # fmt: skip
    """Each belief's best action among its vectors ``(m, A, D)`` (beliefs ``(m, D)``), written
    into ``rows`` of ``result``: only the chosen ``(m, D)`` vectors are kept, so a backup holds
    its ``(M, D)`` result and one chunk's ``(m, A, D)`` vectors, never an ``(M, A, D)`` block."""
    new, actions, values, q = _select_action(beliefs, vectors)
    result.alphas[rows], result.actions[rows], result.values[rows] = new, actions, values
    result.q_values[rows] = q


def _flat_gamma(model: POMDP, alphas: torch.Tensor, beliefs: torch.Tensor,
                ) -> Iterator[tuple[int, torch.Tensor]]:  # fmt: skip
    """The vectors ``(m, A, S)`` of each chunk of beliefs (with its first row), via the
    projections Gamma (A, O, N, S)."""
    T, Z, R, g = model.T, model.Z, model.R, model.discount
    A, S, O = T.shape[0], T.shape[-1], Z.shape[-1]
    N, M = alphas.shape[0], beliefs.shape[0]
    # W[a, o, n, s2] = Z[a, s2, o] * alpha[n, s2]; Gamma[a, o, n, s] = g sum_s2 T[a, s, s2] W
    W = Z.transpose(-1, -2).unsqueeze(2) * alphas.unsqueeze(0).unsqueeze(0)  # (A, O, N, S)
    gamma = g * (W.reshape(A, O * N, S) @ T.transpose(-1, -2)).reshape(A, O, N, S)
    chunk = max(1, CHUNK_ELEMENTS // max(1, A * O * max(N, S)))
    flat_gamma = gamma.reshape(A * O * N, S)
    a_index = torch.arange(A, device=T.device).view(1, A, 1)
    o_index = torch.arange(O, device=T.device).view(1, 1, O)
    for start in range(0, M, chunk):
        b = beliefs[start : start + chunk]
        scores = (b @ flat_gamma.T).view(-1, A, O, N)  # (m, A, O, N)
        best = scores.argmax(-1)  # (m, A, O)
        chosen = gamma[a_index, o_index, best]  # (m, A, O, S)
        yield start, R + chosen.sum(2)


def _flat_belief_side(model: POMDP, alphas: torch.Tensor, beliefs: torch.Tensor,
                      ) -> Iterator[tuple[int, torch.Tensor]]:  # fmt: skip
    """The vectors ``(m, A, S)`` of each chunk of beliefs (with its first row), by scoring the
    predicted beliefs b T Z against the vectors."""
    T, Z, R, g = model.T, model.Z, model.R, model.discount
    A, S, O = T.shape[0], T.shape[-1], Z.shape[-1]
    N, M = alphas.shape[0], beliefs.shape[0]
    chunk = max(1, CHUNK_ELEMENTS // max(1, A * O * max(N, S)))
    Zt = Z.transpose(-1, -2)  # (A, O, S2)
    for start in range(0, M, chunk):
        b = beliefs[start : start + chunk]
        pred = torch.einsum("ms,ast->mat", b, T)  # (m, A, S2)
        W = pred.unsqueeze(2) * Zt.unsqueeze(0)  # (m, A, O, S2)
        best = (W @ alphas.T).argmax(-1)  # (m, A, O)
        chosen = alphas[best]  # (m, A, O, S2)
        inner = (chosen * Zt.unsqueeze(0)).sum(2)  # (m, A, S2)
        yield start, R.unsqueeze(0) + g * torch.einsum("ast,mat->mas", T, inner)


def point_backup(
    model: POMDP,
    policy: AlphaVectorPolicy,
    beliefs: torch.Tensor,
    *,
    method: str = "auto",
) -> BackupResult:
    """Back up ``M`` beliefs of a flat POMDP against ``policy``'s vectors, all at once.

    Args:
        model: an unbatched :class:`POMDP` (``T (A, S, S)``, ``Z (A, S, O)``, ``R (A, S)``).
        policy: the current vectors ``(N, S)`` (a flat policy).
        beliefs: ``(M, S)`` belief points.
        method: ``"gamma"`` (projections, then gather), ``"belief"`` (score predicted
            beliefs) or ``"auto"`` (the cheaper by flop count). Results are identical.

    Returns:
        :class:`BackupResult` with ``alphas (M, S)``, ``actions (M,)``, ``values (M,)``,
        ``q_values (M, A)``.

    Raises:
        ModelError: shapes disagree, the model is batched, or the policy is a MOMDP one.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> m = random_pomdp(3, 2, 2, seed=0)
        >>> p = AlphaVectorPolicy(torch.zeros(1, 3, dtype=torch.float64), torch.tensor([0]))
        >>> point_backup(m, p, m.b0.unsqueeze(0)).values.shape
        torch.Size([1])
    """
    if state_dims(model) != 1:
        raise TypeError(f"expected model to be a POMDP, got {type(model).__name__}")
    _check_unbatched(model)
    if policy.is_momdp:
        raise ModelError("point_backup takes a flat policy; use momdp_point_backup for a MOMDP")
    S = model.num_states
    beliefs = _check_beliefs(beliefs, "S", S)
    if policy.alphas.shape[1] != S:
        raise ModelError(f"expected policy alphas (N, S={S}), got {tuple(policy.alphas.shape)}")
    if policy.num_vectors == 0:
        raise ModelError("the policy has no alpha vectors to back up against")
    dtype = model.R.dtype
    alphas, beliefs = policy.alphas.to(dtype), beliefs.to(dtype)
    A, O = model.num_actions, model.num_observations
    N, M = alphas.shape[0], beliefs.shape[0]
    if method == "auto":
        gamma_cost = A * O * N * S * S + M * A * O * N * S
        belief_cost = 2 * M * A * S * S + M * A * O * N * S
        method = (
            "gamma"
            if gamma_cost <= belief_cost and A * O * N * S <= 4 * CHUNK_ELEMENTS
            else "belief"
        )
    if method not in ("gamma", "belief"):
        raise ValueError(f"expected method in ('auto', 'gamma', 'belief'), got {method!r}")
    kernel = _flat_gamma if method == "gamma" else _flat_belief_side
    result = _new_result(beliefs, A)
    for start, vectors in kernel(model, alphas, beliefs):  # (m, A, S) a chunk
        stop = start + vectors.shape[0]
        _select_into(result, slice(start, stop), beliefs[start:stop], vectors)
    return result


def _padded_vectors(policy: AlphaVectorPolicy, X: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Vectors grouped by x: ``(X, Nmax, Y)`` and a ``(X, Nmax)`` validity mask."""
    observed = policy.observed
    assert observed is not None
    if observed.numel() and observed.max() >= X:
        raise ModelError(f"policy.observed has x = {observed.max().item()}, expected < X={X}")
    counts = torch.bincount(observed, minlength=X)
    if bool((counts == 0).any()):
        missing = torch.nonzero(counts == 0).flatten()[:10].tolist()
        raise ModelError(f"the policy has no alpha vector for observed value(s) x = {missing}")
    order = torch.argsort(observed, stable=True)
    sorted_x = observed[order]
    starts = torch.cumsum(counts, 0) - counts
    slot = torch.arange(order.numel(), device=order.device) - starts[sorted_x]
    n_max = int(counts.max())
    Y = policy.alphas.shape[1]
    padded = policy.alphas.new_zeros(X, n_max, Y)
    padded[sorted_x, slot] = policy.alphas[order]
    valid = torch.zeros(X, n_max, dtype=torch.bool, device=order.device)
    valid[sorted_x, slot] = True
    return padded, valid


def momdp_point_backup(
    model: MOMDP,
    policy: AlphaVectorPolicy,
    x: torch.Tensor,
    beliefs: torch.Tensor,
) -> BackupResult:
    """Back up ``M`` MOMDP beliefs ``(x, b_y)`` against a MOMDP policy, factored.

    Args:
        model: an unbatched :class:`MOMDP`.
        policy: a MOMDP policy: ``alphas (N, Y)``, ``observed (N,)`` covering every ``x``.
        x: ``(M,)`` int64 observed value of each belief.
        beliefs: ``(M, Y)`` beliefs over the hidden value.

    Returns:
        :class:`BackupResult` with ``alphas (M, Y)``, ``actions (M,)``, ``values (M,)``,
        ``q_values (M, A)`` and ``observed = x``.

    Raises:
        ModelError: shapes disagree, the model is batched, or some ``x`` has no vector.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> from torchhrc.solvers.blind import blind_policy
        >>> m = random_momdp(3, 2, 2, 2, seed=0)
        >>> r = momdp_point_backup(m, blind_policy(m), torch.tensor([0, 2]), m.b0.expand(2, 2))
        >>> r.observed.tolist()
        [0, 2]
    """
    if state_dims(model) != 2:
        raise TypeError(f"expected model to be a MOMDP, got {type(model).__name__}")
    _check_unbatched(model)
    if not policy.is_momdp:
        raise ModelError("momdp_point_backup takes a MOMDP policy (observed set)")
    A, X, Y = model.num_actions, model.num_observed, model.num_hidden
    O = model.num_observations
    beliefs = _check_beliefs(beliefs, "Y", Y)
    x = torch.as_tensor(x, device=beliefs.device)
    if x.is_floating_point() or x.shape != beliefs.shape[:1]:
        raise ModelError(
            f"expected x to be an integer tensor of shape (M={beliefs.shape[0]},), "
            f"got {x.dtype} {tuple(x.shape)}"
        )
    if x.numel() and (x.min() < 0 or x.max() >= X):
        raise ModelError(
            f"expected x in [0, {X}), got values in [{x.min().item()}, {x.max().item()}]"
        )
    if policy.alphas.shape[1] != Y:
        raise ModelError(f"expected policy alphas (N, Y={Y}), got {tuple(policy.alphas.shape)}")
    dtype = model.R.dtype
    beliefs = beliefs.to(dtype)
    Tx, Ty, Z, R, g = model.Tx, model.Ty, model.Z, model.R, model.discount
    padded, valid = _padded_vectors(policy.to(dtype=dtype), X)  # (X, Nmax, Y), (X, Nmax)
    n_max = padded.shape[1]
    M = beliefs.shape[0]
    # reachable (a, x, x2): some hidden value moves x to x2 under a
    reach = Tx.amax(-2) > 0  # (A, X, X2)
    triples = torch.nonzero(reach[:, x, :].permute(1, 0, 2))  # (K, 3): m, a, x2
    per_triple = max(O * Y + n_max * Y + O * n_max, Y * Y if Ty is not None else 0)
    chunk = max(1, CHUNK_ELEMENTS // max(1, per_triple))
    Zt = Z.transpose(-1, -2)  # (A, X2, O, Y2)
    # chunks of whole beliefs (at most `chunk` triples, or one belief), so that each chunk's
    # (m, A, Y) vectors are complete and reduced to the chosen one before the next chunk
    ends = torch.cumsum(torch.bincount(triples[:, 0], minlength=M), 0).tolist()
    result = _new_result(beliefs, A)
    first = lo = 0  # the chunk's first belief and first triple
    while first < M:
        last = max(first + 1, bisect_right(ends, lo + chunk))
        hi = ends[last - 1]  # beliefs first:last, triples lo:hi
        vectors = R[:, x[first:last], :].transpose(0, 1).contiguous()  # (m, A, Y), a fresh copy
        for start in range(lo, hi, chunk):  # one pass unless one belief has > chunk triples
            m, a, x2 = triples[start : min(start + chunk, hi)].unbind(-1)
            xm = x[m]
            tx = Tx[a, xm, :, x2]  # (k, Y): Tx[a, x, y, x2]
            if Ty is None:
                pred = beliefs[m] * tx  # (k, Y2 = Y)
            else:
                ty = Ty[a, xm, :, x2, :]  # (k, Y, Y2)
                pred = torch.einsum("ky,kyw->kw", beliefs[m] * tx, ty)
            z = Zt[a, x2]  # (k, O, Y2)
            W = pred.unsqueeze(1) * z  # (k, O, Y2)
            cand = padded[x2]  # (k, Nmax, Y2)
            scores = (W @ cand.transpose(-1, -2)).masked_fill(~valid[x2].unsqueeze(1), -torch.inf)
            best = scores.argmax(-1)  # (k, O)
            chosen = cand.gather(1, best.unsqueeze(-1).expand(-1, -1, Y))  # (k, O, Y2)
            inner = (z * chosen).sum(1)  # (k, Y2): sum_o Z alpha*
            if Ty is None:
                contrib = tx * inner
            else:
                contrib = tx * torch.einsum("kyw,kw->ky", ty, inner)
            flat_index = (m - first) * A + a
            vectors.view(-1, Y).index_add_(0, flat_index, g * contrib)
        _select_into(result, slice(first, last), beliefs[first:last], vectors)
        first, lo = last, hi
    return result._replace(observed=x.clone())
