"""State-action trajectories for inverse reinforcement learning: container, checks, sampler.

Notation (shared/DESIGN.md): S states, A actions, N trajectories, L the longest length::

    states:  (N, L) int64   states[i, t]  = s_t of trajectory i (0 beyond its length)
    actions: (N, L) int64   actions[i, t] = a_t taken in s_t (0 beyond its length)
    lengths: (N,)   int64   number of real steps of each trajectory, >= 1

Step ``t`` of a trajectory is the pair ``(s_t, a_t)``; ``s_{t+1}`` is the state reached by
taking ``a_t`` in ``s_t``. The action of the last step is only used by state-action features.

Example:
    >>> from torchhrc.irl.trajectories import Trajectories
    >>> demos = Trajectories.from_pairs([[(0, 1), (1, 0)], [(0, 0)]])
    >>> demos.states.tolist(), demos.lengths.tolist()
    ([[0, 1], [0, 0]], [2, 1])
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from torchhrc._checks import broadcast_shapes, check_probabilities, check_shape, check_tensor
from torchhrc.errors import ModelError

__all__ = ["Trajectories", "check_trajectories", "policy_matrix", "sample_trajectories"]


@dataclass(frozen=True)
class Trajectories:
    """A batch of state-action trajectories of unequal lengths, padded to ``L``.

    Args:
        states: ``(N, L)`` int64 visited states, padded with 0 beyond each length.
        actions: ``(N, L)`` int64 actions taken in those states, padded with 0.
        lengths: ``(N,)`` int64 number of real steps per trajectory, in ``[1, L]``.

    Raises:
        ModelError: shapes disagree, a length is out of range, or an index is negative.
        TypeError: a field is not an integer tensor.

    Example:
        >>> import torch
        >>> t = Trajectories(torch.tensor([[0, 1, 2]]), torch.tensor([[1, 1, 0]]),
        ...                  torch.tensor([3]))
        >>> t.num_trajectories, t.max_length
        (1, 3)
    """

    states: torch.Tensor
    actions: torch.Tensor
    lengths: torch.Tensor

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check shapes, dtypes and lengths; raise :class:`ModelError` if invalid."""
        for name in ("states", "actions", "lengths"):
            value = check_tensor(name, getattr(self, name), floating=False)
            if value.is_floating_point() or value.dtype == torch.bool or value.is_complex():
                raise TypeError(f"expected {name} to be an integer tensor, got {value.dtype}")
        states, actions, lengths = self.states, self.actions, self.lengths
        if states.dim() != 2:
            raise ModelError(
                f"expected states to have shape (N, L), actual shape = {tuple(states.shape)}"
            )
        if actions.shape != states.shape:
            raise ModelError(
                f"expected actions to have the shape of states {tuple(states.shape)}, "
                f"actual shape = {tuple(actions.shape)}"
            )
        N, L = states.shape
        if lengths.shape != (N,):
            raise ModelError(
                f"expected lengths to have shape (N={N},), actual shape = {tuple(lengths.shape)}"
            )
        if N and (lengths.min() < 1 or lengths.max() > L):
            bad = int(torch.nonzero((lengths < 1) | (lengths > L))[0, 0])
            raise ModelError(
                f"lengths[{bad}] = {int(lengths[bad])} is out of range, expected a length "
                f"in [1, L={L}]"
            )
        mask = self.mask
        for name, value in (("states", states), ("actions", actions)):
            negative = (value < 0) & mask
            if negative.any():
                i, t = torch.nonzero(negative)[0].tolist()
                raise ModelError(
                    f"{name}[{i}, {t}] = {int(value[i, t])} is negative, expected an index >= 0"
                )
        object.__setattr__(self, "states", states.long())
        object.__setattr__(self, "actions", actions.long())
        object.__setattr__(self, "lengths", lengths.long())

    @property
    def num_trajectories(self) -> int:
        """N, the number of trajectories."""
        return self.states.shape[0]

    @property
    def max_length(self) -> int:
        """L, the padded length."""
        return self.states.shape[1]

    @property
    def mask(self) -> torch.Tensor:
        """``(N, L)`` bool, True on real steps."""
        steps = torch.arange(self.states.shape[1], device=self.states.device)
        return steps < self.lengths.unsqueeze(-1)

    def to(self, device: torch.device | str | None = None) -> Trajectories:
        """Return a copy on ``device``."""
        return Trajectories(
            self.states.to(device), self.actions.to(device), self.lengths.to(device)
        )

    def __getitem__(self, index: slice | torch.Tensor | Sequence[int]) -> Trajectories:
        """Select trajectories (a slice, index list, or boolean mask over ``N``)."""
        if not isinstance(index, (slice, torch.Tensor)):
            index = torch.as_tensor(list(index), dtype=torch.long, device=self.states.device)
        return Trajectories(self.states[index], self.actions[index], self.lengths[index])

    @classmethod
    def from_pairs(
        cls,
        trajectories: Sequence[Sequence[tuple[int, int]]],
        *,
        device: torch.device | str | None = None,
    ) -> Trajectories:
        """Build from Python lists of ``(state, action)`` pairs, one list per trajectory.

        Raises:
            ModelError: no trajectory, or an empty trajectory.

        Example:
            >>> Trajectories.from_pairs([[(2, 0), (3, 1)]]).actions.tolist()
            [[0, 1]]
        """
        trajectories = [list(t) for t in trajectories]
        if not trajectories:
            raise ModelError("expected at least one trajectory, got none")
        for i, t in enumerate(trajectories):
            if not t:
                raise ModelError(f"trajectory {i} is empty, expected at least one (s, a) pair")
        N, L = len(trajectories), max(len(t) for t in trajectories)
        states = torch.zeros(N, L, dtype=torch.long)
        actions = torch.zeros(N, L, dtype=torch.long)
        for i, t in enumerate(trajectories):
            pairs = torch.as_tensor(t, dtype=torch.long).reshape(len(t), 2)
            states[i, : len(t)] = pairs[:, 0]
            actions[i, : len(t)] = pairs[:, 1]
        lengths = torch.tensor([len(t) for t in trajectories], dtype=torch.long)
        return cls(states.to(device), actions.to(device), lengths.to(device))


def policy_matrix(policy: torch.Tensor, num_actions: int, dtype: torch.dtype) -> torch.Tensor:
    """A policy as a ``(..., S, A)`` probability tensor ``pi[..., s, a] = P(a | s)``.

    Args:
        policy: ``(..., S)`` int64 deterministic actions or ``(..., S, A)`` probabilities.
        num_actions: A.
        dtype: floating dtype of the result.

    Raises:
        ModelError: an action is out of range, or a probability row does not sum to one.

    Example:
        >>> policy_matrix(torch.tensor([1, 0]), 2, torch.float64).tolist()
        [[0.0, 1.0], [1.0, 0.0]]
    """
    policy = check_tensor("policy", policy, floating=False)
    if policy.is_floating_point():
        check_shape("policy", policy, (num_actions,), f"(..., S, A={num_actions})")
        check_probabilities("policy", policy.detach())
        return policy.to(dtype)
    if policy.numel() and (policy.min() < 0 or policy.max() >= num_actions):
        raise ModelError(
            f"expected policy actions in [0, {num_actions}), got values in "
            f"[{int(policy.min())}, {int(policy.max())}]"
        )
    return torch.nn.functional.one_hot(policy.long(), num_actions).to(dtype)


def check_trajectories(
    trajectories: Trajectories,
    transition: torch.Tensor,
    *,
    name: str = "demonstrations",
    atol: float = 0.0,
) -> None:
    """Check that trajectories index valid states/actions and only use possible transitions.

    A step ``s_t --a_t--> s_{t+1}`` is impossible when ``T[a_t, s_t, s_{t+1}] <= atol``.

    Args:
        trajectories: the trajectories to check.
        transition: ``(A, S, S)`` transition probabilities ``T[a, s, s2] = P(s2 | s, a)``.
        name: the argument's name, used in messages.
        atol: probabilities at or below this count as impossible.

    Raises:
        ModelError: empty trajectories, an index out of range, or an impossible transition
            (the message names the trajectory, the step and ``(s, a, s2)``).

    Example:
        >>> T = torch.eye(2).expand(1, 2, 2)          # one action that stays put
        >>> check_trajectories(Trajectories.from_pairs([[(0, 0), (0, 0)]]), T)
    """
    if not isinstance(trajectories, Trajectories):
        raise TypeError(f"expected {name} to be Trajectories, got {type(trajectories).__name__}")
    A, S = transition.shape[-3], transition.shape[-1]
    if trajectories.num_trajectories == 0:
        raise ModelError(f"{name} is empty: expected at least one trajectory")
    mask = trajectories.mask
    for what, value, size in (
        ("states", trajectories.states, S),
        ("actions", trajectories.actions, A),
    ):
        bad = (value >= size) & mask
        if bad.any():
            i, t = torch.nonzero(bad)[0].tolist()
            raise ModelError(
                f"{name}.{what}[{i}, {t}] = {int(value[i, t])} is out of range, expected an "
                f"index in [0, {size}) for the MDP's {what}"
            )
    if trajectories.max_length < 2:
        return
    T = transition.to(trajectories.states.device)
    s, a = trajectories.states[:, :-1], trajectories.actions[:, :-1]
    s2 = trajectories.states[:, 1:]
    step_mask = mask[:, 1:]
    # p[i, t] = T[a_t, s_t, s_{t+1}]
    p = T[a.clamp(max=A - 1), s.clamp(max=S - 1), s2.clamp(max=S - 1)]
    impossible = (p <= atol) & step_mask
    if impossible.any():
        i, t = torch.nonzero(impossible)[0].tolist()
        raise ModelError(
            f"{name}[{i}] step {t} visits an impossible transition: state {int(s[i, t])} "
            f"--action {int(a[i, t])}--> state {int(s2[i, t])} has probability "
            f"T[{int(a[i, t])}, {int(s[i, t])}, {int(s2[i, t])}] = {float(p[i, t]):.3g}"
        )


def _sample_categorical(probs: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """Draw one index per row of ``probs (M, K)`` by inverting the CDF (one uniform per row)."""
    cdf = probs.cumsum(-1)
    u = torch.rand((*probs.shape[:-1], 1), generator=generator, dtype=cdf.dtype, device=cdf.device)
    u = u * cdf[..., -1:]
    index = torch.searchsorted(cdf, u, right=True).squeeze(-1)
    return index.clamp_(max=probs.shape[-1] - 1)


def sample_trajectories(
    transition: torch.Tensor,
    policy: torch.Tensor,
    start: torch.Tensor | int,
    num_trajectories: int,
    horizon: int,
    *,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> Trajectories | list[Trajectories]:
    """Sample trajectories of a policy in an MDP, all trajectories (and policies) at once.

    Args:
        transition: ``(A, S, S)`` or ``(B, A, S, S)`` transition probabilities.
        policy: ``(S,)`` int64 actions or ``(S, A)`` probabilities; or a batch of B
            policies ``(B, S)`` / ``(B, S, A)`` (then the result is a list of B batches).
        start: a start state (int) or a ``(S,)`` / ``(B, S)`` start distribution.
        num_trajectories: N trajectories per policy.
        horizon: L steps per trajectory.
        seed: seed of a fresh generator (ignored when ``generator`` is given).
        generator: a ``torch.Generator`` to draw from.

    Returns:
        :class:`Trajectories` of N trajectories of length L, or a list of B of them when a
        batch of policies (or MDPs) is given.

    Raises:
        ModelError: shapes disagree or a size is not positive.

    Example:
        >>> T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]])     # one action, always to state 1
        >>> sample_trajectories(T, torch.tensor([0, 0]), 0, 2, 3, seed=0).states.tolist()
        [[0, 1, 1], [0, 1, 1]]
    """
    T = check_tensor("transition", transition)
    check_shape("transition", T, (None, None, None), "(..., A, S, S)")
    A, S = T.shape[-3], T.shape[-1]
    if T.shape[-2] != S:
        raise ModelError(f"expected transition of shape (..., A, S, S), got {tuple(T.shape)}")
    if num_trajectories < 1 or horizon < 1:
        raise ModelError(
            f"expected num_trajectories >= 1 and horizon >= 1, got {num_trajectories}, {horizon}"
        )
    pi = policy_matrix(policy, A, T.dtype)  # (..., S, A)
    if isinstance(start, int):
        if not 0 <= start < S:
            raise ModelError(f"expected start state in [0, {S}), got {start}")
        d0 = torch.nn.functional.one_hot(torch.tensor(start, device=T.device), S).to(T.dtype)
    else:
        d0 = check_tensor("start", start).to(T.dtype)
        check_shape("start", d0, (S,), f"(..., S={S})")
        check_probabilities("start", d0)
    batched = max(T.dim() - 3, pi.dim() - 2, d0.dim() - 1) > 0
    batch = broadcast_shapes(T.shape[:-3], pi.shape[:-2], d0.shape[:-1])
    if len(batch) > 1:
        raise ModelError(f"expected at most one batch dim, got batch shape {tuple(batch)}")
    B = batch[0] if batch else 1
    T = T.expand(B, A, S, S)
    pi = pi.expand(B, S, A)
    d0 = d0.expand(B, S)
    if generator is None:
        generator = torch.Generator(device=T.device)
        generator.manual_seed(0 if seed is None else seed)
    N, L = num_trajectories, horizon
    rows = torch.arange(B, device=T.device).unsqueeze(-1).expand(B, N)  # (B, N)
    states = torch.empty(B, N, L, dtype=torch.long, device=T.device)
    actions = torch.empty(B, N, L, dtype=torch.long, device=T.device)
    s = _sample_categorical(d0.unsqueeze(1).expand(B, N, S), generator)  # (B, N)
    # Sequential in time by nature (a Markov chain); vectorised over policies and samples.
    for t in range(L):
        a = _sample_categorical(pi[rows, s], generator)  # (B, N)
        states[..., t], actions[..., t] = s, a
        if t + 1 < L:
            s = _sample_categorical(T[rows, a, s], generator)
    lengths = torch.full((N,), L, dtype=torch.long, device=T.device)
    result = [Trajectories(states[b], actions[b], lengths) for b in range(B)]
    return result if batched else result[0]
