"""An n x n gridworld MDP with a goal, hazards and slippery moves (the IRL test bed).

States are cells numbered ``s = row * n + col`` (S = n * n); actions ``up, down, left,
right, stay`` (A = 5). A move goes the intended way with probability ``1 - slip`` and, with
probability ``slip``, in a uniformly random one of the four directions; a move into a wall
stays put. The goal is absorbing. The reward depends on the state only::

    R(a, s) = goal_reward  if s is the goal
              hazard_reward if s is a hazard
              step_reward  otherwise

Tensors (shared/DESIGN.md): ``T: (A, S, S)``, ``R: (A, S)``, features ``(S, F)``.

Example:
    >>> from torchhrc.tasks.gridworld import Gridworld
    >>> world = Gridworld(size=4, goal=(3, 3), hazards=((1, 1),))
    >>> world.transition.shape, world.features("semantic").shape
    (torch.Size([5, 16, 16]), torch.Size([16, 3]))
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

from torchhrc.errors import ModelError
from torchhrc.irl.trajectories import Trajectories, sample_trajectories
from torchhrc.solvers.value_iteration import MDPSolution, value_iteration

__all__ = ["ACTIONS", "SEMANTIC_FEATURES", "ColourGridworld", "Gridworld", "grid_transition"]

ACTIONS: tuple[str, ...] = ("up", "down", "left", "right", "stay")
"""Action names, in index order."""

SEMANTIC_FEATURES: tuple[str, ...] = ("goal", "hazard", "goal_distance")
"""Names of the ``"semantic"`` features: goal and hazard indicators and the Manhattan
distance to the goal divided by ``2 (n - 1)``. There is no "free cell" feature: a constant
shift of the reward changes no policy, so ``step_reward`` is the reference level."""

_MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1), (0, 0))


def grid_transition(size: int, slip: float, *, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """``(A=5, S, S)`` moves on an n x n grid (no absorbing cell): the intended move with
    probability ``1 - slip``, a uniformly random one of the four directions with ``slip``; a
    move into a wall stays put.

    Example:
        >>> grid_transition(3, 0.0)[3, 0].nonzero().flatten().tolist()   # right from (0, 0)
        [1]
    """
    n, S = size, size * size
    rows = torch.arange(S) // n
    cols = torch.arange(S) % n
    moves = torch.tensor(_MOVES)  # (A, 2)
    # target[a, s] = the cell reached by moving a from s (walls keep the agent in place)
    r2 = (rows.unsqueeze(0) + moves[:, :1]).clamp(0, n - 1)
    c2 = (cols.unsqueeze(0) + moves[:, 1:]).clamp(0, n - 1)
    target = r2 * n + c2  # (A, S)
    deterministic = torch.nn.functional.one_hot(target, S).to(dtype)  # (A, S, S)
    slipped = deterministic[:4].mean(0)  # (S, S), a uniformly random direction
    return (1.0 - slip) * deterministic + slip * slipped


def _check_slip_and_discount(slip: float, discount: float) -> None:
    """The options both gridworlds share: ``slip`` in ``[0, 1]``, ``discount`` in ``(0, 1)``."""
    if not 0.0 <= slip <= 1.0:
        raise ModelError(f"expected slip in [0, 1], got {slip}")
    if not 0.0 < discount < 1.0:
        raise ModelError(f"expected discount in (0, 1), got {discount}")


@dataclass(frozen=True)
class Gridworld:
    """An n x n gridworld (see the module docstring for the dynamics and the reward).

    Args:
        size: n, the side of the grid (S = n * n states).
        goal: ``(row, col)`` of the absorbing goal cell.
        hazards: ``(row, col)`` of each hazard cell.
        slip: probability that a move goes in a uniformly random direction instead.
        discount: discount factor in (0, 1).
        goal_reward, hazard_reward, step_reward: the true reward of each kind of cell.
        dtype: floating dtype of every tensor.

    Raises:
        ModelError: a cell is outside the grid, the goal is a hazard, or a parameter is out
            of range.
    """

    size: int = 8
    goal: tuple[int, int] = (7, 7)
    hazards: tuple[tuple[int, int], ...] = ()
    slip: float = 0.1
    discount: float = 0.9
    goal_reward: float = 1.0
    hazard_reward: float = -1.0
    step_reward: float = 0.0
    dtype: torch.dtype = torch.float64

    def __post_init__(self) -> None:
        n = self.size
        if not isinstance(n, int) or n < 2:
            raise ModelError(f"expected size to be an int >= 2, got {n!r}")
        object.__setattr__(self, "goal", tuple(int(v) for v in self.goal))
        object.__setattr__(self, "hazards", tuple(tuple(int(v) for v in h) for h in self.hazards))
        for name, cell in [("goal", self.goal)] + [("hazards", h) for h in self.hazards]:
            if len(cell) != 2 or not all(0 <= v < n for v in cell):
                raise ModelError(
                    f"expected {name} cell (row, col) inside the {n}x{n} grid, got {cell}"
                )
        if self.goal in self.hazards:
            raise ModelError(f"the goal {self.goal} must not be a hazard")
        _check_slip_and_discount(self.slip, self.discount)

    @classmethod
    def random(
        cls,
        size: int = 8,
        num_hazards: int = 6,
        *,
        seed: int = 0,
        **kwargs: object,
    ) -> Gridworld:
        """A gridworld with the goal and ``num_hazards`` hazards at random distinct cells.

        Example:
            >>> len(Gridworld.random(5, 3, seed=1).hazards)
            3
        """
        if not 0 <= num_hazards < size * size - 1:
            raise ModelError(f"expected num_hazards in [0, {size * size - 1}), got {num_hazards}")
        generator = torch.Generator().manual_seed(seed)
        cells = torch.randperm(size * size, generator=generator)[: num_hazards + 1].tolist()
        goal = divmod(cells[0], size)
        hazards = tuple(divmod(c, size) for c in cells[1:])
        return cls(size=size, goal=goal, hazards=hazards, **kwargs)  # type: ignore[arg-type]

    @property
    def num_states(self) -> int:
        """S = n * n."""
        return self.size * self.size

    @property
    def num_actions(self) -> int:
        """A = 5."""
        return len(ACTIONS)

    def state(self, row: int, col: int) -> int:
        """The state index ``row * n + col`` of a cell."""
        return row * self.size + col

    @property
    def cell_kind(self) -> torch.Tensor:
        """``(S,)`` int64: 0 goal, 1 hazard, 2 free."""
        kind = torch.full((self.num_states,), 2, dtype=torch.long)
        for h in self.hazards:
            kind[self.state(*h)] = 1
        kind[self.state(*self.goal)] = 0
        return kind

    @property
    def transition(self) -> torch.Tensor:
        """``(A, S, S)`` transition probabilities ``T[a, s, s2] = P(s2 | s, a)``."""
        T = grid_transition(self.size, self.slip, dtype=self.dtype)
        goal = self.state(*self.goal)
        T[:, goal, :] = 0.0
        T[:, goal, goal] = 1.0
        return T

    @property
    def reward(self) -> torch.Tensor:
        """``(A, S)`` true rewards."""
        values = torch.tensor(
            [self.goal_reward, self.hazard_reward, self.step_reward], dtype=self.dtype
        )
        return values[self.cell_kind].expand(self.num_actions, self.num_states).clone()

    def features(self, kind: Literal["semantic", "indicator"] = "semantic") -> torch.Tensor:
        """Reward features over states.

        Args:
            kind: ``"semantic"`` for ``(S, 3)`` features named :data:`SEMANTIC_FEATURES`
                (the true reward is ``true_weights("semantic") . phi + step_reward``);
                ``"indicator"`` for ``(S, S)`` one-hot features (a tabular reward).

        Returns:
            ``(S, F)`` features.
        """
        S = self.num_states
        if kind == "indicator":
            return torch.eye(S, dtype=self.dtype)
        if kind != "semantic":
            raise ValueError(f"expected kind 'semantic' or 'indicator', got {kind!r}")
        onehot = torch.nn.functional.one_hot(self.cell_kind, 3)[:, :2].to(self.dtype)  # (S, 2)
        rows = torch.arange(S) // self.size
        cols = torch.arange(S) % self.size
        distance = (rows - self.goal[0]).abs() + (cols - self.goal[1]).abs()
        scaled = distance.to(self.dtype) / (2 * (self.size - 1))
        return torch.cat([onehot, scaled.unsqueeze(-1)], dim=-1)

    def true_weights(self, kind: Literal["semantic", "indicator"] = "semantic") -> torch.Tensor:
        """``(F,)`` weights: ``true reward = features(kind) @ weights`` (``+ step_reward``
        for ``"semantic"``, a constant that changes no policy)."""
        if kind == "indicator":
            return self.reward[0].clone()
        if kind != "semantic":
            raise ValueError(f"expected kind 'semantic' or 'indicator', got {kind!r}")
        return torch.tensor(
            [self.goal_reward - self.step_reward, self.hazard_reward - self.step_reward, 0.0],
            dtype=self.dtype,
        )

    def solve(self, reward: torch.Tensor | None = None, *, tol: float = 1e-8) -> MDPSolution:
        """Value iteration for ``reward (..., A, S)`` (default: the true reward)."""
        R = self.reward if reward is None else reward
        return value_iteration(self.transition, R, self.discount, tol=tol)

    def expert_policy(self) -> torch.Tensor:
        """``(S,)`` int64, an optimal policy for the true reward."""
        return self.solve().policy

    def uniform_start(self) -> torch.Tensor:
        """``(S,)`` uniform distribution over the non-goal cells."""
        d0 = torch.ones(self.num_states, dtype=self.dtype)
        d0[self.state(*self.goal)] = 0.0
        return d0 / d0.sum()

    def demonstrations(
        self,
        num_trajectories: int,
        horizon: int,
        *,
        start: int | torch.Tensor | None = None,
        min_length: int | None = None,
        seed: int = 0,
    ) -> Trajectories:
        """Sample expert trajectories (the optimal policy for the true reward), seeded.

        Args:
            num_trajectories: N.
            horizon: L, the longest length.
            start: a start state or a ``(S,)`` distribution (default :meth:`uniform_start`).
            min_length: if given, each trajectory is cut at a length drawn uniformly from
                ``[min_length, horizon]`` (unequal lengths).
            seed: seed of the sampler.

        Returns:
            :class:`~torchhrc.irl.trajectories.Trajectories` of N trajectories.

        Example:
            >>> Gridworld(size=3, goal=(2, 2)).demonstrations(2, 5, seed=0).states.shape
            torch.Size([2, 5])
        """
        generator = torch.Generator().manual_seed(seed)
        d0 = self.uniform_start() if start is None else start
        demos = sample_trajectories(
            self.transition,
            self.expert_policy(),
            d0,
            num_trajectories,
            horizon,
            generator=generator,
        )
        assert isinstance(demos, Trajectories)
        if min_length is None:
            return demos
        if not 1 <= min_length <= horizon:
            raise ModelError(f"expected min_length in [1, {horizon}], got {min_length}")
        lengths = torch.randint(min_length, horizon + 1, (num_trajectories,), generator=generator)
        mask = torch.arange(horizon) < lengths.unsqueeze(-1)
        return Trajectories(demos.states * mask, demos.actions * mask, lengths)


@dataclass(frozen=True)
class ColourGridworld:
    """An n x n grid of coloured cells whose reward is a linear function of the colour.

    The IRL setting of Abbeel & Ng (2004, Sec. 4.1: a grid whose reward is a weighted sum of
    region indicators): moves as :func:`grid_transition` (no absorbing cell), features the
    one-hot colour of a cell ``phi: (S, C)``, true reward ``R(a, s) = w* . phi(s)`` with
    ``w*`` non-zero on a few colours. Used by ``tests/irl/test_projection.py`` and
    ``docs/irl.md`` to score the reward Abbeel-Ng's loop reports.

    Args:
        size: n (S = n * n).
        colours: ``(S,)`` int64 colour of each cell, in ``[0, C)``.
        weights: ``(C,)`` true reward weight of each colour.
        slip: probability that a move goes in a uniformly random direction.
        discount: discount factor in (0, 1).

    Example:
        >>> w = ColourGridworld.random(4, num_colours=3, num_rewarded=1, seed=0)
        >>> w.features().shape, int((w.weights != 0).sum())
        (torch.Size([16, 3]), 1)
    """

    size: int
    colours: torch.Tensor
    weights: torch.Tensor
    slip: float = 0.1
    discount: float = 0.9

    def __post_init__(self) -> None:
        n = self.size
        if not isinstance(n, int) or n < 2:
            raise ModelError(f"expected size to be an int >= 2, got {n!r}")
        if self.colours.shape != (n * n,) or self.colours.is_floating_point():
            raise ModelError(
                f"expected colours to be int64 of shape (S={n * n},), got "
                f"{self.colours.dtype} {tuple(self.colours.shape)}"
            )
        C = self.weights.shape[-1]
        if self.weights.dim() != 1 or int(self.colours.min()) < 0 or int(self.colours.max()) >= C:
            raise ModelError(f"expected weights (C,) and colours in [0, C={C})")
        _check_slip_and_discount(self.slip, self.discount)

    @classmethod
    def random(
        cls,
        size: int = 10,
        *,
        num_colours: int = 6,
        num_rewarded: int = 3,
        slip: float = 0.1,
        discount: float = 0.9,
        seed: int = 0,
    ) -> ColourGridworld:
        """Uniformly random colours; ``num_rewarded`` colours get weights ``U[0, 1)``.

        Example:
            >>> ColourGridworld.random(3, seed=1).colours.shape
            torch.Size([9])
        """
        if not 1 <= num_rewarded <= num_colours:
            raise ModelError(f"expected 1 <= num_rewarded <= num_colours, got {num_rewarded}")
        g = torch.Generator().manual_seed(int(seed))
        colours = torch.randint(num_colours, (size * size,), generator=g)
        weights = torch.zeros(num_colours, dtype=torch.float64)
        rewarded = torch.randperm(num_colours, generator=g)[:num_rewarded]
        weights[rewarded] = torch.rand(num_rewarded, generator=g, dtype=torch.float64)
        return cls(size=size, colours=colours, weights=weights, slip=slip, discount=discount)

    @property
    def num_states(self) -> int:
        """S = n * n."""
        return self.size * self.size

    @property
    def num_actions(self) -> int:
        """A = 5."""
        return len(ACTIONS)

    @property
    def transition(self) -> torch.Tensor:
        """``(A, S, S)``."""
        return grid_transition(self.size, self.slip, dtype=self.weights.dtype)

    def features(self) -> torch.Tensor:
        """``(S, C)`` one-hot colours."""
        C = self.weights.shape[-1]
        return torch.nn.functional.one_hot(self.colours, C).to(self.weights.dtype)

    @property
    def reward(self) -> torch.Tensor:
        """``(A, S)`` true rewards ``w* . phi(s)``."""
        return (self.features() @ self.weights).expand(self.num_actions, -1).clone()

    def solve(self, reward: torch.Tensor | None = None, *, tol: float = 1e-8) -> MDPSolution:
        """Value iteration for ``reward (..., A, S)`` (default: the true reward)."""
        R = self.reward if reward is None else reward
        return value_iteration(self.transition, R, self.discount, tol=tol)

    def uniform_start(self) -> torch.Tensor:
        """``(S,)`` uniform over all cells."""
        return torch.full((self.num_states,), 1.0 / self.num_states, dtype=self.weights.dtype)

    def demonstrations(self, num_trajectories: int, horizon: int, *, seed: int = 0) -> Trajectories:
        """Trajectories of the optimal policy from uniform starts, seeded.

        Example:
            >>> ColourGridworld.random(3, seed=0).demonstrations(2, 4).states.shape
            torch.Size([2, 4])
        """
        demos = sample_trajectories(
            self.transition,
            self.solve().policy,
            self.uniform_start(),
            num_trajectories,
            horizon,
            generator=torch.Generator().manual_seed(int(seed)),
        )
        assert isinstance(demos, Trajectories)
        return demos
