"""Batched execution of the place-and-drill task with a simulated human (paper Fig. 3).

Paper (section "Robustness of Computed Policy"): "we simulated the task execution for
increasing degrees of deviations from the demonstrated actions of the human ... by having a
simulated human perform a random placement action with a probability epsilon, or the actual
action taken by the testing human subject with probability 1 - epsilon".

One run, ``B`` runs at once as tensors (all runs of all epsilons of one subject)::

    x_0 = 0 (empty bench); for t = 0 .. horizon - 1:
        a_t   = robot(x_t)                           the controller's action, (B,)
        r_t   = score[a_t, x_t, true_type]           the run's reward
        m     = robot_effect[a_t, x_t]               drilling takes effect
        x_t+1 = m + human placement, if m has an empty position:
                with probability epsilon a uniformly random empty position, otherwise the
                subject's demonstrated next position (the first still-empty position of one
                of its demonstrated placement orders, drawn once per run)
        robot observes x_t+1 (MOMDP controllers update their type belief, paper Eq. 3)

Scoring (our choice, the paper scores all three policies on one scale): a run's score is the
undiscounted sum of the hand-coded expert reward of the subject's TRUE type over the horizon
(zero once every screw is drilled). The human's random numbers are drawn once per subject and
shared by every controller (common random numbers), so policy differences are not sampling
noise.

Example:
    >>> import torch
    >>> from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
    >>> task = PlaceAndDrillTask(2)
    >>> orders = torch.tensor([[0, 1]])
    >>> step_human(task, torch.tensor([0]), orders, torch.tensor([0.0]),
    ...            torch.tensor([0.5]), torch.rand(1, 2)).tolist()  # places A first
    [3]
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.belief import momdp_update
from torchhrc.tasks.place_and_drill.demos import placement_orders
from torchhrc.tasks.place_and_drill.model import EMPTY, PLACED, PlaceAndDrillTask

__all__ = [
    "CrossTrainingController",
    "ExecutionController",
    "ExecutionTrace",
    "MOMDPController",
    "demonstrated_orders",
    "run_executions",
    "step_human",
]


def demonstrated_orders(
    task: PlaceAndDrillTask, demonstrations: Demonstrations
) -> dict[str, torch.Tensor]:
    """Each subject's demonstrated placement orders as position indices.

    The order of a demonstration is the order of its ``human:place_<p>`` steps
    (:func:`~torchhrc.tasks.place_and_drill.demos.placement_orders`); a position placed twice
    counts once, positions it never places follow in index order.

    Returns:
        ``{subject: (M, n) int64}``, one row per demonstration of the subject.

    Example:
        >>> d = Demonstrations.from_lists([[("human", "place_B"), ("robot", "drill_B")]])
        >>> demonstrated_orders(PlaceAndDrillTask(2), d)["0"].tolist()
        [[1, 0]]
    """
    n = task.n_positions
    index = {p: i for i, p in enumerate(task.positions)}
    out: dict[str, torch.Tensor] = {}
    for subject, orders in placement_orders(demonstrations).items():
        rows = []
        for names in orders:
            order: list[int] = []
            for name in names:
                if name in index and index[name] not in order:
                    order.append(index[name])
            rows.append(order + [p for p in range(n) if p not in order])
        out[subject] = torch.tensor(rows, dtype=torch.long).view(len(rows), n)
    return out


def step_human(
    task: PlaceAndDrillTask,
    x_mid: torch.Tensor,
    order: torch.Tensor,
    epsilon: torch.Tensor,
    u_deviate: torch.Tensor,
    keys: torch.Tensor,
) -> torch.Tensor:
    """The simulated human's placement after the robot's action, batched.

    Args:
        task: the task.
        x_mid: ``(B,)`` int64 bench states after the robot's action.
        order: ``(B, n)`` int64 the run's demonstrated placement order.
        epsilon: ``(B,)`` probability of a random placement.
        u_deviate: ``(B,)`` uniforms; the human deviates where ``u_deviate < epsilon``.
        keys: ``(B, n)`` uniforms choosing the random empty position (largest key wins).

    Returns:
        ``(B,)`` int64 the bench after the placement (``x_mid`` when nothing is empty).
    """
    status = task.status.to(x_mid.device)[x_mid]  # (B, n)
    empty = status == EMPTY
    empty_in_order = empty.gather(-1, order)  # (B, n)
    first = empty_in_order.long().argmax(-1, keepdim=True)  # first empty in the order
    demonstrated = order.gather(-1, first).squeeze(-1)
    random_pos = torch.where(empty, keys, torch.full_like(keys, -1.0)).argmax(-1)
    position = torch.where(u_deviate < epsilon, random_pos, demonstrated)
    placed = task.place_effect.to(x_mid.device)[x_mid, position]
    return torch.where(empty.any(-1), placed, x_mid)


class ExecutionController(Protocol):
    """What :func:`run_executions` drives: the robot of ``B`` simulated runs, which acts on
    the bench state (ties broken by a given uniform draw, so every controller shares the
    runs' random numbers) and observes the next one.

    Implemented by :class:`MOMDPController` and :class:`CrossTrainingController`. Not to be
    confused with the public :class:`torchhrc.tasks.Controller`, a learned model's online
    controller (``reset``/``act``), which is one concrete controller; this is the protocol
    of the place-and-drill simulation loop (formerly named ``Controller`` here; that name
    still works, with a ``DeprecationWarning``, for one release).
    """

    def act(self, x: torch.Tensor, uniform: torch.Tensor) -> torch.Tensor:
        """``(B,)`` actions at bench states ``x (B,)``; ``uniform (B,)`` for tie-breaking."""
        ...

    def observe(self, x: torch.Tensor, action: torch.Tensor, x_next: torch.Tensor) -> None:
        """Take in the transition ``x -> x_next`` under ``action`` (all ``(B,)``)."""
        ...


class _VectorPolicy(Protocol):
    def action(self, x: torch.Tensor, belief_y: torch.Tensor) -> torch.Tensor: ...


class MOMDPController:
    """A MOMDP policy with an online type belief (paper Eq. 3, :func:`.belief.momdp_update`).

    Args:
        model: the MOMDP the belief is updated with (its ``Tx``; ``Z`` trivial).
        policy: an object with ``action(x (B,), belief_y (B, Y)) -> (B,)``, e.g. a MOMDP
            :class:`~torchhrc.solvers.policy.AlphaVectorPolicy`.
        belief: ``(B, Y)`` initial beliefs of the runs.
        record: keep every belief in :attr:`beliefs` (for traces).
    """

    def __init__(
        self, model: MOMDP, policy: _VectorPolicy, belief: torch.Tensor, *, record: bool = False
    ) -> None:
        if belief.dim() != 2 or belief.shape[-1] != model.num_hidden:
            raise ModelError(
                f"expected belief of shape (B, Y={model.num_hidden}), got {tuple(belief.shape)}"
            )
        self.model = model
        self.policy = policy
        self.belief = belief.to(model.Tx.dtype)
        self.beliefs: list[torch.Tensor] = [self.belief] if record else []
        self._record = record

    def act(self, x: torch.Tensor, uniform: torch.Tensor) -> torch.Tensor:
        return self.policy.action(x, self.belief).long()

    def observe(self, x: torch.Tensor, action: torch.Tensor, x_next: torch.Tensor) -> None:
        zero = torch.zeros_like(x)
        self.belief = momdp_update(self.model, x, self.belief, action, x_next, zero).belief
        if self._record:
            self.beliefs.append(self.belief)


class CrossTrainingController:
    """A cross-training policy (state lookup, random among tied best actions; no belief).

    Args:
        policy: a
            :class:`~torchhrc.tasks.place_and_drill.cross_training.CrossTrainingPolicy`-like
            object with ``action(subject, x, uniform)``.
        subject: int or ``(B,)`` int64 subject index of each run.
    """

    def __init__(self, policy: object, subject: torch.Tensor | int) -> None:
        self.policy = policy
        self.subject = subject

    def act(self, x: torch.Tensor, uniform: torch.Tensor) -> torch.Tensor:
        return self.policy.action(self.subject, x, uniform)  # type: ignore[attr-defined]

    def observe(self, x: torch.Tensor, action: torch.Tensor, x_next: torch.Tensor) -> None:
        return None


@dataclass(frozen=True)
class ExecutionTrace:
    """The result of :func:`run_executions` for each controller.

    Attributes:
        rewards: ``{name: (B,)}`` accumulated (undiscounted) score of each run.
        states: ``{name: (H + 1, B)}`` int64 bench states.
        actions: ``{name: (H, B)}`` int64 robot actions.
    """

    rewards: dict[str, torch.Tensor]
    states: dict[str, torch.Tensor]
    actions: dict[str, torch.Tensor]


def run_executions(
    task: PlaceAndDrillTask,
    controllers: Mapping[str, ExecutionController],
    *,
    orders: torch.Tensor,
    epsilon: torch.Tensor,
    score: torch.Tensor,
    horizon: int | None = None,
    generator: torch.Generator | None = None,
    human_chunk: torch.Tensor | None = None,
) -> ExecutionTrace:
    """Run ``B`` executions per controller, all at once, with shared human randomness.

    Args:
        task: the task.
        controllers: ``{name: controller}``; every controller runs the same ``B`` runs.
        orders: ``(B, n)`` int64 each run's demonstrated placement order.
        epsilon: ``(B,)`` each run's probability of a random placement.
        score: ``(A, X, B)`` or ``(A, X)`` the scoring reward of each run (the true type's).
        horizon: number of robot decisions (default ``4 n``: enough for any sensible policy,
            a policy that never finishes pays for it).
        generator: random generator (human deviations, random positions, tie-breaking).
        human_chunk: ``(B,)`` int64 in ``[1, n]`` or None. None (the paper's Fig. 3): the
            human places whenever a position is empty. Given: the human also follows the
            turn-taking rule of its type (the chunk rule of
            :mod:`~torchhrc.tasks.place_and_drill.demos`, ``n`` safe, ``1`` efficient): with
            ``P`` screws on the bench and ``Q`` placed but undrilled after the robot's
            action, it lets the turn pass (places nothing) when ``P mod g = 0`` and
            ``Q > 0`` (an efficient human waits for its screw to be drilled), unless it
            deviates (probability ``epsilon``: a random placement, as above). No random
            numbers are drawn for it, so the other draws are those of ``human_chunk=None``.

    Returns:
        :class:`ExecutionTrace`.
    """
    B = epsilon.shape[0]
    if orders.shape != (B, task.n_positions):
        raise ModelError(
            f"expected orders of shape (B={B}, n={task.n_positions}), got {tuple(orders.shape)}"
        )
    H = 4 * task.n_positions if horizon is None else int(horizon)
    if H < 1:
        raise ModelError(f"expected horizon >= 1, got {H}")
    dev = epsilon.device
    u_deviate = torch.rand(H, B, generator=generator, dtype=torch.float64).to(dev)
    keys = torch.rand(H, B, task.n_positions, generator=generator, dtype=torch.float64).to(dev)
    u_robot = torch.rand(H, B, generator=generator, dtype=torch.float64).to(dev)
    if score.dim() == 2:
        score = score.unsqueeze(-1).expand(*score.shape, B)
    runs = torch.arange(B, device=dev)
    effect = task.robot_effect.to(dev)
    status = task.status.to(dev)  # (X, n)
    if human_chunk is not None:
        human_chunk = human_chunk.to(dev)
        n = task.n_positions
        if human_chunk.shape != (B,) or ((human_chunk < 1) | (human_chunk > n)).any():
            raise ModelError(
                f"expected human_chunk of shape (B={B},) with values in [1, {n}], got "
                f"shape {tuple(human_chunk.shape)}"
            )
    rewards, states, actions = {}, {}, {}
    for name, controller in controllers.items():
        x = torch.full((B,), task.initial_state, dtype=torch.long, device=dev)
        total = torch.zeros(B, dtype=score.dtype, device=dev)
        xs, acts = [x], []
        for t in range(H):
            a = controller.act(x, u_robot[t])
            total = total + score[a, x, runs]
            x_mid = effect[a, x]
            x_next = step_human(task, x_mid, orders, epsilon, u_deviate[t], keys[t])
            if human_chunk is not None:
                on_bench = (status[x_mid] != EMPTY).sum(-1)  # P
                pending = (status[x_mid] == PLACED).any(-1)  # Q > 0
                waits = (on_bench % human_chunk == 0) & pending & (u_deviate[t] >= epsilon)
                x_next = torch.where(waits, x_mid, x_next)
            controller.observe(x, a, x_next)
            x = x_next
            xs.append(x)
            acts.append(a)
        rewards[name] = total
        states[name] = torch.stack(xs)
        actions[name] = torch.stack(acts)
    return ExecutionTrace(rewards=rewards, states=states, actions=actions)


def __getattr__(name: str) -> object:
    # Deprecated alias (one release): ``Controller`` clashed with torchhrc.tasks.Controller.
    if name == "Controller":
        import warnings

        warnings.warn(
            "torchhrc.tasks.place_and_drill.simulate.Controller is deprecated; use "
            "ExecutionController (torchhrc.tasks.Controller is the online controller)",
            DeprecationWarning,
            stacklevel=2,
        )
        return ExecutionController
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
