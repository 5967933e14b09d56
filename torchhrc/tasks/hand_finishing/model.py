"""The hand-finishing task MOMDP (paper, "Online estimation of human type").

A robot holds a box for a person who refinishes its two side surfaces by hand. The person is
of one of two preference types, working the left (``+y``) side first or the right (``-y``)
side first; the robot cannot see the type, only the person's hand position in the
horizontal plane, observed through a discretized 2D Gaussian
(:class:`~torchhrc.pomdp.observation.DiscretizedGaussianObservation`).

Observed state ``x = (c, p)``: ``c`` indexes the box configurations kept by the kinematic
checks (:func:`~torchhrc.tasks.hand_finishing.geometry.feasible_box_configurations`:
reachable by the robot and comfortable for the person; a configuration is a horizontal
position x vertical position x tilt of
:class:`~torchhrc.tasks.hand_finishing.geometry.BoxGeometry`), ``p`` the task progress in
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
makes a move worth it. The price of an unwanted move is a requirement, not a tuning knob: by
default it is set from the probability of a wrong move the user accepts
(``RewardSettings.risk_tolerance``, 0.02) as the cost at which moving at belief ``b`` beats
waiting one step only when ``1 - b <= risk_tolerance``, the type counted as known after that
step (:func:`unwanted_cost_for_risk`, :meth:`HandFinishingTask.unwanted_cost_for_risk`); it
can also be set directly (``RewardSettings(unwanted_cost=...)``).

Example:
    >>> import torch
    >>> geometry = BoxGeometry(horizontal=(0.0,), vertical=(0.2, 0.4), tilt=(-0.5, 0.0, 0.5))
    >>> task = HandFinishingTask.build(feasible=torch.ones(1, 2, 3, 2, dtype=torch.bool),
    ...                                geometry=geometry, work_units=2)
    >>> task.num_observed, task.num_states, task.momdp().num_actions  # 6 configs x 5 progress
    (30, 60, 7)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import torch

from torchhrc._checks import check_tensor
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.observation import DiscretizedGaussianObservation, ObservationGrid
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry

__all__ = [
    "ACTIONS",
    "SIDES",
    "HandFinishingTask",
    "RewardSettings",
    "count_states",
    "unwanted_cost_for_risk",
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
        unwanted_cost: cost of a move the person did not want; ``None`` (the default): priced
            from ``risk_tolerance`` when the task is built
            (:meth:`HandFinishingTask.unwanted_cost_for_risk`). A number is used as given and
            ``risk_tolerance`` is then ignored.
        risk_tolerance: the probability of a wrong first move the user accepts (default
            0.02: the robot should act on the person's type only when it is at least 98%
            sure). It sets ``unwanted_cost`` when that is ``None``.
        discount: discount factor.

    Example:
        >>> RewardSettings().unwanted_cost is None, RewardSettings(unwanted_cost=2.0).unwanted_cost
        (True, 2.0)
    """

    work_reward: float = 1.0
    work_probability: float = 0.8
    move_cost: float = 0.05
    unwanted_cost: float | None = None
    risk_tolerance: float = 0.02
    discount: float = 0.95

    def __post_init__(self) -> None:
        if not 0.0 < self.work_probability <= 1.0:
            raise ModelError(f"expected work_probability in (0, 1], got {self.work_probability}")
        if not 0.0 < self.discount < 1.0:
            raise ModelError(f"expected discount in (0, 1), got {self.discount}")
        if not 0.0 < self.risk_tolerance < 1.0:
            raise ModelError(f"expected risk_tolerance in (0, 1), got {self.risk_tolerance}")
        for name in ("work_reward", "move_cost", "unwanted_cost"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise ModelError(f"expected {name} >= 0, got {value}")


def unwanted_cost_for_risk(gain: float, loss: float, risk_tolerance: float) -> float:
    """The cost of an unwanted move at which a risky move breaks even at ``1 - b = tolerance``.

    One step, move against wait, the value of what follows taken as if the type were then
    known (the QMDP comparison, Littman et al. 1995): a move that is right for type ``y``
    and unwanted for ``y'`` gains ``gain = Q_y(move) - Q_y(wait)`` over waiting if the type is
    ``y`` and loses ``loss + U = Q_y'(wait) - Q_y'(move)`` if it is ``y'`` (``loss`` without the
    unwanted cost ``U``: the move back and the delay). At belief ``b`` on ``y`` the move is
    worth it when ``b gain >= (1 - b)(loss + U)``, i.e. when
    ``1 - b <= gain / (gain + loss + U)``. Setting that bound to ``tolerance``:

        ``U = gain (1 - tolerance) / tolerance - loss``  (clamped at 0)

    Args:
        gain: ``Q_y(move) - Q_y(wait)`` (> 0: the move is worth making for its type).
        loss: ``Q_y'(wait) - Q_y'(move)`` without the unwanted cost.
        risk_tolerance: the accepted probability of a wrong move, in (0, 1).

    Returns:
        ``U >= 0``.

    Example:
        >>> round(unwanted_cost_for_risk(0.1, 0.2, 0.02), 6)  # 0.1 * 49 - 0.2
        4.7
    """
    if not 0.0 < risk_tolerance < 1.0:
        raise ModelError(f"expected risk_tolerance in (0, 1), got {risk_tolerance}")
    if not (math.isfinite(gain) and math.isfinite(loss)):
        raise ModelError(f"expected finite gain and loss, got {gain}, {loss}")
    return max(0.0, gain * (1.0 - risk_tolerance) / risk_tolerance - loss)


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
        rewards: the :class:`RewardSettings` (as given; the unwanted-move cost in effect is
            :attr:`unwanted_cost`).
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
                :func:`~torchhrc.tasks.hand_finishing.geometry.feasible_box_configurations`
                (pytorch-kinematics, tens of seconds).
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
            from torchhrc.tasks.hand_finishing.geometry import feasible_box_configurations

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

    @cached_property
    def unwanted_cost(self) -> float:
        """The cost of an unwanted move in effect: ``rewards.unwanted_cost`` when set, else
        priced from ``rewards.risk_tolerance`` for this task's types
        (:meth:`unwanted_cost_for_risk`; a task derived with other ``first_sides`` is priced
        again)."""
        if self.rewards.unwanted_cost is not None:
            return float(self.rewards.unwanted_cost)
        return self.unwanted_cost_for_risk(self.rewards.risk_tolerance)

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
    def _parts(
        self, dtype: torch.dtype
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The task's dynamics and rewards in parts, all ``(A, X, Y)``: ``x_stay`` (the state
        after the robot's action, no work), ``x_work`` (after a completed unit), ``prob``
        (the chance of a unit), ``reward`` without the unwanted cost, ``unwanted`` (float
        0/1, the move is unwanted; 0 once the task is done)."""
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
        is_move = torch.tensor([d != 0 for _, d in _MOVES]).view(A, 1, 1)
        d_before = self.distance[c.unsqueeze(-1), side]  # (X, Y)
        d_after = self.distance[c2.unsqueeze(-1), side.unsqueeze(0)]  # (A, X, Y)
        live = ~done.view(1, X, 1)
        unwanted = (is_move & (d_after >= d_before.unsqueeze(0)) & live).to(dtype)
        reward = rw.work_reward * prob - rw.move_cost * (is_move & live).to(dtype)
        return x_stay, x_work, prob, reward, unwanted

    def _tensors(self, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
        x_stay, x_work, prob, reward, unwanted = self._parts(dtype)
        A, X, Y = prob.shape
        Tx = torch.zeros(A, X, Y, X, dtype=dtype)
        Tx.scatter_add_(-1, x_stay.unsqueeze(-1), (1.0 - prob).unsqueeze(-1))
        Tx.scatter_add_(-1, x_work.unsqueeze(-1), prob.unsqueeze(-1))
        return Tx, reward - self.unwanted_cost * unwanted

    def known_type_q_values(
        self, unwanted_cost: float, *, dtype: torch.dtype = torch.float64, tol: float = 1e-12
    ) -> torch.Tensor:
        """``(A, X, Y)`` action values when the type is known (the MDP of each type), with
        ``unwanted_cost`` for an unwanted move; value iteration on the task's two-successor
        dynamics, to a residual below ``tol``.

        Example:
            >>> geometry = BoxGeometry(horizontal=(0.0,), vertical=(0.2,), tilt=(-0.5, 0.0, 0.5))
            >>> f = torch.ones(1, 1, 3, 2, dtype=torch.bool)
            >>> f[..., 0, 0] = False; f[..., 2, 1] = False  # tilt -: right only, +: left only
            >>> task = HandFinishingTask.build(feasible=f, geometry=geometry, work_units=1,
            ...                                rewards=RewardSettings(unwanted_cost=1.0))
            >>> task.known_type_q_values(1.0).shape
            torch.Size([7, 9, 2])
        """
        x_stay, x_work, prob, reward, unwanted = self._parts(dtype)
        R = reward - unwanted_cost * unwanted
        g = self.rewards.discount
        Y = prob.shape[-1]
        ys = torch.arange(Y)
        V = R.new_zeros(R.shape[1], Y)  # (X, Y)
        for _ in range(100_000):  # a fixed point: iterations, not a loop over states
            Q = R + g * ((1.0 - prob) * V[x_stay, ys] + prob * V[x_work, ys])
            V_new = Q.amax(0)
            if (V_new - V).abs().max() <= tol * (1.0 - g):
                V = V_new
                break
            V = V_new
        return R + g * ((1.0 - prob) * V[x_stay, ys] + prob * V[x_work, ys])

    def unwanted_cost_for_risk(self, risk_tolerance: float) -> float:
        """The unwanted-move cost that a risk tolerance sets (:func:`unwanted_cost_for_risk`).

        At the start state, where the robot chooses its first move without knowing the
        type, for each type ``y`` take its best move ``a_y`` (the known-type values
        :meth:`known_type_q_values`) and each type ``y'`` for which ``a_y`` is unwanted; the
        cost makes the one-step comparison of ``a_y`` against waiting break even at a
        belief ``1 - risk_tolerance`` on ``y`` (and ``risk_tolerance`` on ``y'``), the
        strictest pair deciding. The known-type values do not depend on the cost when a
        robot that knows the type never needs an unwanted move; when they do, the rule is
        iterated to its fixed point (the values at the cost they set).

        Returns:
            ``U >= 0`` (0 when no first move is right for one type and unwanted for another).

        Raises:
            ModelError: ``risk_tolerance`` not in (0, 1), or the iteration does not settle.
        """
        if not 0.0 < risk_tolerance < 1.0:
            raise ModelError(f"expected risk_tolerance in (0, 1), got {risk_tolerance}")
        x0 = self.x0
        unwanted = self._parts(torch.float64)[4][:, x0]  # (A, Y)
        moves = torch.tensor([d != 0 for _, d in _MOVES])
        cost = 0.0
        for _ in range(50):
            Q = self.known_type_q_values(cost)[:, x0]  # (A, Y)
            Q_free = Q + cost * unwanted  # without the unwanted cost
            required = 0.0
            Y = Q.shape[-1]
            for y in range(Y):  # types and pairs: a handful, not states
                wanted = moves & (unwanted[:, y] == 0)
                if not wanted.any():
                    continue
                a = int(torch.where(wanted, Q[:, y], -math.inf).argmax())
                gain = float(Q[a, y] - Q[0, y])
                if gain <= 0:
                    continue
                for y2 in range(Y):
                    if y2 != y and unwanted[a, y2] > 0:
                        loss = float(Q[0, y2] - Q_free[a, y2])
                        required = max(required, unwanted_cost_for_risk(gain, loss, risk_tolerance))
            if abs(required - cost) <= 1e-9 * (1.0 + required):
                return required
            cost = required
        raise ModelError("the unwanted cost of a risk tolerance did not settle in 50 iterations")

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
