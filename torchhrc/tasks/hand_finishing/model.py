"""The hand-finishing task MOMDP (paper, "Online estimation of human type").

A robot holds a box for a person who refinishes its two side surfaces by hand. The person is
of one of two preference types, working the left (``+y``) side first or the right (``-y``)
side first; the robot cannot see the type, only the person's hand position in the
horizontal plane, observed through a discretized 2D Gaussian
(:class:`~torchhrc.observation.DiscretizedGaussianObservation`).

Observed state ``x = (c, p)``: ``c`` indexes the box configurations kept by the kinematic
checks (:func:`torchhrc.kinematics.feasible_box_configurations`: reachable by the robot and
comfortable for the person; a configuration is a horizontal position x vertical position x
tilt of :class:`~torchhrc.kinematics.BoxGeometry`), ``p`` the task progress in
``0 .. P - 1`` (``P = 2 W + 1``: ``W`` work units per side, the last value "done", absorbing).
``x = c * P + p``; ``X = C * P``. With the default geometry (75 of 100 configurations kept)
and ``W = 6``, ``X = 975`` and ``X * Y = 1950`` states, the paper's "about 2000".

Hidden ``y``: the type values, one per cluster found in the demonstrations; each has a first
side (``first_sides[y]``). The side the person works on next is
``side(y, p) = first_sides[y]`` if ``p < W`` else the other side.

Robot actions (moves to neighbouring configurations, so ``Tx`` stays local and the robot's
path to a presentation passes through intermediate poses):
``wait``, ``h-``, ``h+``, ``v-``, ``v+``, ``tilt-``, ``tilt+``. A move whose target is not a kept
configuration (off the grid, unreachable or uncomfortable) leaves the box where it is.

The box *presents* side ``s`` when the configuration is comfortable for working on ``s``
but not on the other side (the surface is turned towards the person), and the box centre is
not displaced towards the other side (``sign(s) * horizontal >= 0``). After the robot's
action, if the box presents ``side(y, p)`` the person completes a work unit with probability
``work_probability`` (``p -> p + 1``); otherwise the progress stays.

Rewards ``R[a, x, y]`` (expected over the next state):

* ``+work_reward * work_probability`` when the box presents ``side(y, p)`` after the action;
* ``-move_cost`` for every move;
* ``-unwanted_cost`` for a move the person did not want: one that does not shorten the
  number of moves to the nearest configuration presenting ``side(y, p)`` (including blocked
  moves and moves away from a presentation the person is using);
* nothing once the task is done.

The robot's waiting is therefore not written anywhere: with an uncertain type every move
risks ``unwanted_cost``, and the solved policy waits for hand observations until the belief
makes a move worth it.

Example:
    >>> import torch
    >>> geometry = BoxGeometry(horizontal=(0.0,), vertical=(0.2, 0.4), tilt=(-0.5, 0.0, 0.5))
    >>> task = HandFinishingTask.build(feasible=torch.ones(1, 2, 3, 2, dtype=torch.bool),
    ...                                geometry=geometry, work_units=2)
    >>> task.num_observed, task.num_states, task.momdp().num_actions  # 6 configs x 5 progress
    (30, 60, 7)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchhrc._checks import check_tensor
from torchhrc.errors import ModelError
from torchhrc.kinematics import BoxGeometry
from torchhrc.observation import DiscretizedGaussianObservation, ObservationGrid
from torchhrc.pomdp import MOMDP

__all__ = [
    "ACTIONS",
    "SIDES",
    "HandFinishingTask",
    "RewardSettings",
    "count_states",
]

#: Robot actions: index -> name. ``wait`` is 0.
ACTIONS: tuple[str, ...] = ("wait", "h-", "h+", "v-", "v+", "tilt-", "tilt+")
#: Sides of the box: index 0 ``left`` (+y), 1 ``right`` (-y).
SIDES: tuple[str, ...] = ("left", "right")
# (axis, step) of each action; wait has step 0.
_MOVES: tuple[tuple[int, int], ...] = ((0, 0), (0, -1), (0, 1), (1, -1), (1, 1), (2, -1), (2, 1))


def count_states(num_configurations: int, work_units: int, num_types: int = 2) -> int:
    """Number of MOMDP states ``C * (2 W + 1) * Y``.

    Example:
        >>> count_states(75, 6)
        1950
    """
    for name, v in (("num_configurations", num_configurations), ("work_units", work_units),
                    ("num_types", num_types)):  # fmt: skip
        if not isinstance(v, int) or v < 1:
            raise ModelError(f"expected {name} to be a positive int, got {v!r}")
    return num_configurations * (2 * work_units + 1) * num_types


@dataclass(frozen=True, kw_only=True)
class RewardSettings:
    """Reward and dynamics constants of the task (see the module docstring).

    Attributes:
        work_reward: reward of one completed work unit.
        work_probability: chance the person completes a unit on a presented side per step.
        move_cost: cost of any move (robot effort).
        unwanted_cost: cost of a move the person did not want.
        discount: discount factor.
    """

    work_reward: float = 1.0
    work_probability: float = 0.8
    move_cost: float = 0.05
    unwanted_cost: float = 2.0
    discount: float = 0.95

    def __post_init__(self) -> None:
        if not 0.0 < self.work_probability <= 1.0:
            raise ModelError(f"expected work_probability in (0, 1], got {self.work_probability}")
        if not 0.0 < self.discount < 1.0:
            raise ModelError(f"expected discount in (0, 1), got {self.discount}")
        for name in ("work_reward", "move_cost", "unwanted_cost"):
            if getattr(self, name) < 0:
                raise ModelError(f"expected {name} >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class HandFinishingTask:
    """The task's structure: kept configurations, progress, types, and the tensors built
    from them. Build with :meth:`build`; get the MOMDP with :meth:`momdp`.

    Attributes:
        geometry: the configuration grid.
        kept: ``(C, 3)`` int64 ``(h, v, t)`` grid indices of the kept configurations.
        comfortable: ``(C, 2)`` bool, comfortable for working on ``[left, right]``.
        presents: ``(C, 2)`` bool, the configuration presents ``[left, right]``.
        distance: ``(C, 2)`` moves to the nearest configuration presenting each side
            (``C`` when none can be reached).
        neighbour: ``(A, C)`` int64 configuration after each action.
        work_units: ``W``.
        first_sides: ``(Y,)`` first side of each type value (``"left"`` / ``"right"``).
        start: index of the start configuration in ``kept``.
        rewards: the :class:`RewardSettings`.
    """

    geometry: BoxGeometry
    kept: torch.Tensor
    comfortable: torch.Tensor
    presents: torch.Tensor
    distance: torch.Tensor
    neighbour: torch.Tensor
    work_units: int
    first_sides: tuple[str, ...]
    start: int
    rewards: RewardSettings

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(
        cls,
        *,
        feasible: torch.Tensor | None = None,
        reachable: torch.Tensor | None = None,
        geometry: BoxGeometry | None = None,
        work_units: int = 6,
        first_sides: tuple[str, ...] = ("left", "right"),
        start: tuple[int, int, int] | None = None,
        rewards: RewardSettings | None = None,
        seed: int = 0,
    ) -> HandFinishingTask:
        """Build the task from the kinematic feasibility of each box configuration.

        Args:
            feasible: ``(H, V, T, 2)`` bool, comfortable for the person on ``[left, right]``
                (and reachable, combined with ``reachable``); default: computed with
                :func:`torchhrc.kinematics.feasible_box_configurations` (pytorch-kinematics,
                tens of seconds).
            reachable: ``(H, V, T)`` bool robot reachability (default all True when
                ``feasible`` is given).
            geometry: the configuration grid (default :class:`BoxGeometry`).
            work_units: ``W``, work units per side.
            first_sides: first side of each type value.
            start: ``(h, v, t)`` start configuration (default: the kept configuration
                closest to the grid's centre, preferring one that presents neither side).
            rewards: reward settings.
            seed: seed of the kinematic checks.

        Raises:
            ModelError: bad shapes, no kept configuration, an unknown side.
        """
        geometry = BoxGeometry() if geometry is None else geometry
        rewards = RewardSettings() if rewards is None else rewards
        H, V, T = geometry.shape
        if feasible is None:
            from torchhrc.kinematics import feasible_box_configurations

            f = feasible_box_configurations(geometry, seed=seed)
            feasible, reachable = f.comfortable, f.reachable
        feasible = check_tensor("feasible", feasible, floating=False)
        if tuple(feasible.shape) != (H, V, T, 2) or feasible.dtype != torch.bool:
            raise ModelError(
                f"expected feasible to be bool of shape (H, V, T, 2) = {(H, V, T, 2)}, "
                f"got {feasible.dtype} {tuple(feasible.shape)}"
            )
        if reachable is None:
            reachable = torch.ones(H, V, T, dtype=torch.bool)
        if tuple(reachable.shape) != (H, V, T):
            raise ModelError(
                f"expected reachable to have shape (H, V, T) = {(H, V, T)}, "
                f"got {tuple(reachable.shape)}"
            )
        if not isinstance(work_units, int) or work_units < 1:
            raise ModelError(f"expected work_units to be a positive int, got {work_units!r}")
        for s in first_sides:
            if s not in SIDES:
                raise ModelError(f"expected first_sides in {SIDES}, got {first_sides!r}")
        if not first_sides:
            raise ModelError("expected at least one type in first_sides")
        comfortable_grid = feasible & reachable.unsqueeze(-1)
        mask = comfortable_grid.any(-1)  # (H, V, T)
        if not mask.any():
            raise ModelError("no box configuration is both reachable and comfortable")
        kept = torch.nonzero(mask)  # (C, 3) in row-major order
        C = kept.shape[0]
        comfortable = comfortable_grid[kept[:, 0], kept[:, 1], kept[:, 2]]  # (C, 2)
        horizontal = torch.tensor(geometry.horizontal, dtype=torch.float64)[kept[:, 0]]
        sign = torch.tensor([1.0, -1.0], dtype=torch.float64)
        presents = (
            comfortable & ~comfortable.flip(-1) & (sign * horizontal.unsqueeze(-1) >= -1e-12)
        )  # (C, 2)
        # grid index -> kept index (-1 when not kept)
        lookup = torch.full((H, V, T), -1, dtype=torch.long)
        lookup[kept[:, 0], kept[:, 1], kept[:, 2]] = torch.arange(C)
        sizes = torch.tensor([H, V, T])
        step = torch.zeros(len(ACTIONS), 3, dtype=torch.long)
        for a, (axis, d) in enumerate(_MOVES):
            step[a, axis] = d
        target = kept.unsqueeze(0) + step.unsqueeze(1)  # (A, C, 3)
        inside = ((target >= 0) & (target < sizes)).all(-1)
        clamped = torch.minimum(target.clamp(min=0), sizes - 1)
        idx = lookup[clamped[..., 0], clamped[..., 1], clamped[..., 2]]
        neighbour = torch.where(inside & (idx >= 0), idx, torch.arange(C).expand_as(idx))
        # Moves to the nearest presenting configuration: Bellman-Ford relaxation on the
        # move graph, batched over configurations and sides.
        inf = C
        distance = torch.where(presents, 0, inf)  # (C, 2)
        for _ in range(C):
            relaxed = torch.minimum(distance, distance[neighbour].amin(0) + 1)
            if torch.equal(relaxed, distance):
                break
            distance = relaxed
        if start is None:
            centre = (sizes.double() - 1) / 2
            dist = ((kept.double() - centre) ** 2).sum(-1) + 1e3 * presents.any(-1).double()
            start_index = int(dist.argmin())
        else:
            g = lookup[start]
            if int(g) < 0:
                raise ModelError(f"start configuration {start} is not a kept configuration")
            start_index = int(g)
        return cls(
            geometry=geometry,
            kept=kept,
            comfortable=comfortable,
            presents=presents,
            distance=distance,
            neighbour=neighbour,
            work_units=work_units,
            first_sides=tuple(first_sides),
            start=start_index,
            rewards=rewards,
        )

    # ------------------------------------------------------------------ sizes
    @property
    def num_configurations(self) -> int:
        """``C``, kept box configurations."""
        return int(self.kept.shape[0])

    @property
    def num_progress(self) -> int:
        """``P = 2 W + 1``."""
        return 2 * self.work_units + 1

    @property
    def num_observed(self) -> int:
        """``X = C * P``."""
        return self.num_configurations * self.num_progress

    @property
    def num_types(self) -> int:
        """``Y``."""
        return len(self.first_sides)

    @property
    def num_states(self) -> int:
        """``X * Y``."""
        return self.num_observed * self.num_types

    @property
    def x0(self) -> int:
        """The start state: start configuration, no progress."""
        return self.start * self.num_progress

    def decode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x (...)`` -> ``(configuration (...), progress (...))``."""
        x = torch.as_tensor(x)
        return x // self.num_progress, x % self.num_progress

    def side_next(self, progress: torch.Tensor) -> torch.Tensor:
        """``(..., Y)`` int64 side (0 left, 1 right) each type works on at ``progress (...)``."""
        first = torch.tensor([SIDES.index(s) for s in self.first_sides], device=progress.device)
        second = progress.unsqueeze(-1) >= self.work_units
        return torch.where(second, 1 - first, first)

    # ------------------------------------------------------------------ tensors
    def _tensors(self, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
        A, C, P, Y = len(ACTIONS), self.num_configurations, self.num_progress, self.num_types
        X = C * P
        rw = self.rewards
        c = torch.arange(C).view(C, 1).expand(C, P).reshape(X)  # (X,)
        p = torch.arange(P).view(1, P).expand(C, P).reshape(X)  # (X,)
        done = p == P - 1  # (X,)
        side = self.side_next(p)  # (X, Y)
        c2 = self.neighbour[:, c]  # (A, X)
        presented = self.presents[c2.unsqueeze(-1), side.unsqueeze(0)]  # (A, X, Y)
        work = presented & ~done.view(1, X, 1)
        prob = rw.work_probability * work.to(dtype)  # (A, X, Y)
        x_stay = (c2 * P + p).unsqueeze(-1).expand(A, X, Y)  # (A, X, Y)
        x_work = torch.where(work, x_stay + 1, x_stay)
        Tx = torch.zeros(A, X, Y, X, dtype=dtype)
        Tx.scatter_add_(-1, x_stay.unsqueeze(-1), (1.0 - prob).unsqueeze(-1))
        Tx.scatter_add_(-1, x_work.unsqueeze(-1), prob.unsqueeze(-1))
        # rewards
        is_move = torch.tensor([d != 0 for _, d in _MOVES]).view(A, 1, 1)
        d_before = self.distance[c.unsqueeze(-1), side]  # (X, Y)
        d_after = self.distance[c2.unsqueeze(-1), side.unsqueeze(0)]  # (A, X, Y)
        unwanted = is_move & (d_after >= d_before.unsqueeze(0))
        R = rw.work_reward * prob
        R = R - rw.move_cost * is_move.to(dtype) - rw.unwanted_cost * unwanted.to(dtype)
        R = torch.where(done.view(1, X, 1), torch.zeros_like(R), R)
        return Tx, R

    def hand_offset(self, *, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """``(X, Y, 2)`` the centre of the surface each type works on next, projected on the
        horizontal plane ``(x_base, y_base)``: the geometric part of the hand's mean."""
        C, P = self.num_configurations, self.num_progress
        pts = torch.stack(
            [self.geometry.work_points(s, dtype=dtype) for s in SIDES], dim=-2
        )  # (H, V, T, 2, 3)
        pts = pts[self.kept[:, 0], self.kept[:, 1], self.kept[:, 2]][..., :2]  # (C, 2, 2)
        p = torch.arange(P)
        side = self.side_next(p)  # (P, Y)
        out = pts[:, side]  # (C, P, Y, 2)
        return out.reshape(C * P, self.num_types, 2)

    def observation_model(
        self,
        grid: ObservationGrid,
        *,
        loc: torch.Tensor,
        scale: torch.Tensor,
        dtype: torch.dtype = torch.float64,
    ) -> DiscretizedGaussianObservation:
        """The hand-position observation model: ``N(hand_offset[x, y] + loc[y], diag(scale)^2)``.

        Args:
            grid: the grid over the horizontal plane (robot base ``x`` by ``y``).
            loc: ``(Y, 2)`` or ``(2,)`` hand position relative to the surface's centre.
            scale: ``(Y, 2)`` or ``(2,)`` standard deviations (m).
            dtype: floating dtype.
        """
        loc = torch.as_tensor(loc, dtype=dtype)
        if loc.dim() == 2:
            loc = loc.unsqueeze(0)  # (1, Y, 2)
        scale = torch.as_tensor(scale, dtype=dtype)
        if scale.dim() == 2:
            scale = scale.unsqueeze(0)
        return DiscretizedGaussianObservation(
            grid.to(dtype=dtype),
            loc,
            scale,
            num_observed=self.num_observed,
            num_hidden=self.num_types,
            offset=self.hand_offset(dtype=dtype),
            num_actions=len(ACTIONS),
        )

    def momdp(
        self,
        observation: torch.Tensor | DiscretizedGaussianObservation | None = None,
        *,
        b0: torch.Tensor | None = None,
        dtype: torch.dtype = torch.float64,
    ) -> MOMDP:
        """The task MOMDP.

        Args:
            observation: ``Z: (A, X, Y, O)`` or an observation module (its output is
                detached); default a single uninformative observation (``O = 1``).
            b0: ``(Y,)`` initial type belief (default uniform).
            dtype: floating dtype.

        Returns:
            :class:`~torchhrc.pomdp.MOMDP` with a static type (``Ty = None``).
        """
        Tx, R = self._tensors(dtype)
        A, X, Y = R.shape
        if observation is None:
            Z = Tx.new_ones(1, 1, 1, 1).expand(A, X, Y, 1)
        elif isinstance(observation, DiscretizedGaussianObservation):
            Z = observation().detach().to(dtype)
        else:
            Z = check_tensor("observation", observation).to(dtype)
        if Z.shape[:3] != (A, X, Y):
            raise ModelError(
                f"expected observation of shape (A, X, Y, O) = ({A}, {X}, {Y}, O), "
                f"actual shape = {tuple(Z.shape)}"
            )
        if b0 is None:
            b0 = Tx.new_full((Y,), 1.0 / Y)
        P = self.num_progress
        names = tuple(
            f"c{int(c)}(h{h},v{v},t{t})/p{p}"
            for c, (h, v, t) in enumerate(self.kept.tolist())
            for p in range(P)
        )
        return MOMDP(
            Tx=Tx,
            Ty=None,
            Z=Z,
            R=R,
            x0=self.x0,
            b0=b0.to(dtype),
            discount=self.rewards.discount,
            observed_states=names,
            hidden_states=tuple(f"{s}-first" for s in self.first_sides),
            actions=ACTIONS,
        )
