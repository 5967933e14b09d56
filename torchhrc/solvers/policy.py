"""Alpha-vector policies for flat POMDPs and MOMDPs.

A policy is a set of alpha vectors, each tagged with an action; the value at a belief is the
largest inner product and the action is that of the maximising vector (Sondik 1971; Kaelbling,
Littman, Cassandra 1998)::

    V(b) = max_n alphas[n] . b,    pi(b) = actions[argmax_n alphas[n] . b]

Flat POMDP: ``alphas: (N, S)``, ``actions: (N,)``. MOMDP (Ong et al. 2010): each vector
belongs to one observed value ``x`` and lives over the hidden values, ``alphas: (N, Y)``,
``actions: (N,)``, ``observed: (N,)``; at ``(x, b_y)`` only the vectors of ``x`` compete::

    V(x, b_y) = max_{n : observed[n] = x} alphas[n] . b_y

Example:
    >>> import torch
    >>> policy = AlphaVectorPolicy(torch.tensor([[1.0, 0.0], [0.0, 1.0]]), torch.tensor([0, 1]))
    >>> policy.action(torch.tensor([[0.9, 0.1], [0.2, 0.8]])).tolist()
    [0, 1]
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc._host import arange as alloc_range
from torchhrc._host import host_view
from torchhrc.errors import ModelError
from torchhrc.solvers.pruning import prune_by_beliefs, prune_dominated

__all__ = ["AlphaVectorPolicy"]


@dataclass(frozen=True)
class AlphaVectorPolicy:
    """A piecewise-linear value function and its greedy policy, batched over beliefs.

    Args:
        alphas: ``(N, S)`` alpha vectors of a flat POMDP, or ``(N, Y)`` of a MOMDP, where
            ``alphas[n, s]`` is the value of following vector ``n``'s plan from state ``s``.
        actions: ``(N,)`` int64, the first action of each vector's plan.
        observed: ``(N,)`` int64 or None; for a MOMDP policy the observed value ``x`` each
            vector belongs to.

    Raises:
        ModelError: shapes disagree, values are not finite, or indices are negative.
        TypeError: a field is not a tensor of the right kind.
    """

    alphas: torch.Tensor
    actions: torch.Tensor
    observed: torch.Tensor | None = None

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check shapes, dtypes and values; raise :class:`ModelError` if invalid."""
        alphas = check_tensor("alphas", self.alphas)
        if alphas.dim() != 2:
            raise ModelError(
                f"expected alphas to have shape (N, S), actual shape = {tuple(alphas.shape)}"
            )
        # finite iff the least and the largest entry are (aminmax propagates NaN): a pass
        # without a temporary of the vectors' size. torch.isfinite makes a float copy (its
        # abs) besides its mask, and at the end of a 20,000-state solve those blocks of
        # 20 MB left 85 MB more resident than before the check
        host = host_view(alphas)  # (numpy on the CPU: torchhrc._host)
        if not alphas.numel():
            finite = True
        elif host is not None:
            finite = bool(np.isfinite([host.min(), host.max()]).all())
        else:
            finite = bool(torch.isfinite(torch.stack(torch.aminmax(alphas))).all())
        if not finite:
            bad = torch.nonzero(~torch.isfinite(alphas))[0].tolist()
            raise ModelError(f"alphas{bad} = {alphas[tuple(bad)].item()} is not finite")
        N = alphas.shape[0]
        for name in ("actions", "observed"):
            value = getattr(self, name)
            if value is None:
                continue
            value = check_tensor(name, value, floating=False)
            if value.is_floating_point() or value.dtype == torch.bool:
                raise TypeError(f"expected {name} to have an integer dtype, got {value.dtype}")
            if value.shape != (N,):
                raise ModelError(
                    f"expected {name} to have shape (N={N},), actual shape = {tuple(value.shape)}"
                )
            host = host_view(value)
            lowest = (host.min() if host is not None else value.min().item()) if N else 0
            if lowest < 0:
                raise ModelError(f"expected {name} >= 0, got {lowest}")
            if value.dtype != torch.long:
                object.__setattr__(self, name, value.long())

    @classmethod
    def from_action_vectors(cls, vectors: torch.Tensor, *, momdp: bool) -> AlphaVectorPolicy:
        """One vector per action (QMDP, FIB, blind bounds) as a policy.

        Args:
            vectors: flat ``(A, S)``, ``vectors[a]`` tagged with action ``a``; or, with
                ``momdp=True``, ``(A, X, Y)``, ``vectors[a, x]`` tagged with ``a`` and ``x``.
            momdp: whether ``vectors`` has the MOMDP layout.

        Example:
            >>> p = AlphaVectorPolicy.from_action_vectors(torch.zeros(2, 3, 4), momdp=True)
            >>> p.alphas.shape, p.observed.tolist()
            (torch.Size([6, 4]), [0, 0, 1, 1, 2, 2])
        """
        vectors = check_tensor("vectors", vectors)
        device = vectors.device
        if not momdp:
            if vectors.dim() != 2:
                raise ModelError(
                    f"expected vectors to have shape (A, S), actual shape = {tuple(vectors.shape)}"
                )
            return cls(vectors, alloc_range(vectors.shape[0], device))
        if vectors.dim() != 3:
            raise ModelError(
                f"expected vectors to have shape (A, X, Y), actual shape = {tuple(vectors.shape)}"
            )
        A, X, Y = vectors.shape
        host = host_view(vectors)
        if host is not None:  # (numpy on the CPU: torchhrc._host)
            return cls(
                alphas=torch.from_numpy(host.transpose(1, 0, 2).reshape(X * A, Y)),
                actions=torch.from_numpy(np.tile(np.arange(A, dtype=np.int64), X)),
                observed=torch.from_numpy(np.repeat(np.arange(X, dtype=np.int64), A)),
            )
        return cls(
            alphas=vectors.transpose(0, 1).reshape(X * A, Y),
            actions=torch.arange(A, device=device).repeat(X),
            observed=torch.arange(X, device=device).repeat_interleave(A),
        )

    @property
    def num_vectors(self) -> int:
        """N, the number of alpha vectors."""
        return self.alphas.shape[0]

    @property
    def is_momdp(self) -> bool:
        """True for a MOMDP policy (vectors tagged with an observed value)."""
        return self.observed is not None

    def _scores(self, belief: torch.Tensor, x: torch.Tensor | int | None) -> torch.Tensor:
        belief = check_tensor("belief", belief)
        size = self.alphas.shape[1]
        dim_name = "Y" if self.is_momdp else "S"
        check_shape("belief", belief, (size,), f"(..., {dim_name}={size})")
        if self.num_vectors == 0:
            raise ModelError("the policy has no alpha vectors")
        scores = self._products(belief)  # (..., N)
        if not self.is_momdp:
            if x is not None:
                raise ModelError("x is only accepted by a MOMDP policy (observed is None)")
            return scores
        if x is None:
            raise ModelError("a MOMDP policy needs the observed value x: value(x, belief_y)")
        x = torch.as_tensor(x, device=self.alphas.device)
        if x.is_floating_point():
            raise TypeError(f"expected x to be integer, got {x.dtype}")
        mine = x.unsqueeze(-1) == self.observed  # (..., N)
        covered = mine.any(-1)
        if not bool(covered.all()):
            missing = x.expand(covered.shape)[~covered].unique().tolist()
            raise ModelError(f"the policy has no alpha vector for observed value(s) x = {missing}")
        return scores.masked_fill(~mine, -torch.inf)

    def _products(self, belief: torch.Tensor) -> torch.Tensor:
        """``(..., N)`` ``belief . alphas[n]``, in the wider of the two dtypes: vectors held
        narrower than the beliefs (``SARSOPConfig(alpha_dtype=torch.float32)``) are widened a
        block of rows at a time, never all at once."""
        wide = belief.is_floating_point() and (
            torch.finfo(belief.dtype).bits > torch.finfo(self.alphas.dtype).bits
        )
        if not wide:
            return belief.to(self.alphas.dtype) @ self.alphas.T
        step = max(1, (1 << 21) // max(1, self.alphas.shape[1]))
        return torch.cat([belief @ self.alphas[i : i + step].to(belief.dtype).T
                          for i in range(0, self.alphas.shape[0], step)], -1)  # fmt: skip

    def value(
        self, x_or_belief: torch.Tensor | int, belief_y: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``max_n alphas[n] . b`` for each belief.

        Flat: ``value(belief (..., S)) -> (...)``. MOMDP: ``value(x (...), belief_y (..., Y))
        -> (...)``, where ``x`` broadcasts against the belief's batch dims.

        Example:
            >>> p = AlphaVectorPolicy(torch.tensor([[1.0, 0.0]]), torch.tensor([0]))
            >>> p.value(torch.tensor([0.25, 0.75])).item()
            0.25
        """
        if belief_y is None:
            return self._scores(torch.as_tensor(x_or_belief), None).amax(-1)
        return self._scores(belief_y, x_or_belief).amax(-1)

    def best_vector(
        self, x_or_belief: torch.Tensor | int, belief_y: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Index ``(...)`` of the maximising alpha vector (same calling forms as ``value``)."""
        if belief_y is None:
            return self._scores(torch.as_tensor(x_or_belief), None).argmax(-1)
        return self._scores(belief_y, x_or_belief).argmax(-1)

    def action(
        self, x_or_belief: torch.Tensor | int, belief_y: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The greedy action ``(...)`` int64 (same calling forms as ``value``).

        Example:
            >>> p = AlphaVectorPolicy(torch.tensor([[1.0], [2.0]]), torch.tensor([3, 4]),
            ...                       observed=torch.tensor([0, 1]))
            >>> p.action(torch.tensor([0, 1]), torch.ones(2, 1)).tolist()
            [3, 4]
        """
        return self.actions[self.best_vector(x_or_belief, belief_y)]

    def prune(
        self,
        beliefs: torch.Tensor | None = None,
        *,
        x: torch.Tensor | None = None,
        atol: float = 0.0,
    ) -> AlphaVectorPolicy:
        """Drop redundant vectors; returns a new policy.

        Without ``beliefs``: pointwise-dominated vectors (the value function is unchanged).
        With ``beliefs (M, S)`` (and ``x (M,)`` for a MOMDP policy): keep only vectors that are
        the maximum at one of the beliefs (the value at those beliefs is unchanged).

        Example:
            >>> p = AlphaVectorPolicy(torch.tensor([[1.0, 1.0], [0.0, 0.0]]), torch.tensor([0, 1]))
            >>> p.prune().num_vectors
            1
        """
        if beliefs is None:
            keep = prune_dominated(self.alphas, self.observed, atol=atol)
        else:
            if self.is_momdp and x is None:
                raise ModelError("pruning a MOMDP policy at beliefs needs their x (M,)")
            belief_groups = None if x is None else torch.as_tensor(x, device=self.alphas.device)
            keep = prune_by_beliefs(self.alphas, beliefs, self.observed, belief_groups)
        return self.select(keep)

    def select(self, index: torch.Tensor) -> AlphaVectorPolicy:
        """The policy made of the vectors ``index`` selects (a bool mask or int indices)."""
        return AlphaVectorPolicy(
            alphas=self.alphas[index],
            actions=self.actions[index],
            observed=None if self.observed is None else self.observed[index],
        )

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> AlphaVectorPolicy:
        """A copy with tensors moved to ``device`` and the alphas cast to ``dtype``."""
        return dataclasses.replace(
            self,
            alphas=self.alphas.to(device=device, dtype=dtype),
            actions=self.actions.to(device=device),
            observed=None if self.observed is None else self.observed.to(device=device),
        )
