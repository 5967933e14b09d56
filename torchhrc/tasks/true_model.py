"""The world's own people as a MOMDP: what a robot could do online with the true model.

:func:`evaluate_task`'s ``"told the type"`` robot says whether knowing the type pays when the
robot is told it before the first move. A robot that must find the type from the person's
actions can gain less: where the types act alike until the robot has committed, nothing it
sees can tell them apart in time. :func:`true_momdp` writes the simulated people of a
:class:`~torchhrc.tasks.people.TaskWithPeople` down as the MOMDP they are, and
:func:`true_model_controller` solves it: a robot that knows the people's true behaviour,
their true rewards and how common each type is, but not which type the person in front of it
is. It is a reference, not a learner: its return is what finding the type online can gain
(up to the solver's gap), so a type-aware robot level with the type-agnostic one where this
robot is level too has lost nothing to learning. Where it loses,
:func:`true_behaviour_controller` and :func:`true_reward_controller` give the learned model one
part of the truth each (the people's behaviour, or their rewards), to say which part lost it
(``evaluate_task(true_parts=True)``).

The hidden value is ``h = y * M + m``: the person's true type ``y`` (static) and the people's
memory ``m`` (``M`` memory states, :class:`~torchhrc.tasks.people.TabularPeople`; ``M = 1``
for people whose behaviour depends on the state only, and then the type is static and
``Ty`` is ``None``). With the robot's move ``a`` from ``x``, ``x_mid = robot_effect[a, x]``,
the person's turn ``c`` (a human action, or "no action", the last column) drawn from
``P(c | y, m, x_mid, a)`` (the people's ``noise`` mixed in: a uniformly random legal action
with that probability, as :meth:`~torchhrc.tasks.people.TabularPeople.act`), then::

    x2 = human_effect[x_mid, c]  (x_mid for no action),  m2 = update[y, m, x_mid, a, c]
    P(x2, h2 | x, h, a) = sum_c P(c | y, m, x_mid, a) [x2, m2 as above, y2 = y]
    Tx[a, x, h, x2] = sum_h2 P(x2, h2 | ...),  Ty[a, x, h, x2, h2] = P(x2, h2 | ...) / Tx
        (h2 = h where Tx = 0: never reached)
    R[a, x, h] = true_reward[a, x, y] (0 in terminal states, which every action keeps)
    Z[a, x2, h2, o] = true_observation[a, x2, y2, o] (observed worlds; else O = 1)
    b0[h] = shares[y] * initial[y, m]

Example:
    >>> from torchhrc.tasks.suite import make_task
    >>> world = make_task("pace")
    >>> m = true_momdp(world)
    >>> (m.num_observed, m.num_hidden) == (world.task.num_states, 3 * world.people.num_memory)
    True
    >>> round(float(m.b0.sum()), 6)
    1.0
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.people import population_shares

if TYPE_CHECKING:
    from torchhrc.pomdp import MOMDP
    from torchhrc.tasks.controller import Controller
    from torchhrc.tasks.people import TaskWithPeople
    from torchhrc.tasks.pipeline import LearnedModel

__all__ = [
    "true_behaviour_controller",
    "true_model_controller",
    "true_momdp",
    "true_reward_controller",
]


def true_momdp(
    world: TaskWithPeople,
    *,
    noise: float = 0.05,
    shares: Sequence[float] | torch.Tensor | None = None,
    reward: torch.Tensor | None = None,
) -> MOMDP:
    """The MOMDP of a world's simulated people, true rewards and population (module doc).

    Args:
        world: a :class:`~torchhrc.tasks.people.TaskWithPeople` whose people give their
            tables (``people.turn_tables(noise)``, as
            :class:`~torchhrc.tasks.people.TabularPeople` does).
        noise: the people's epsilon (as :func:`~torchhrc.tasks.evaluate_task`'s).
        shares: ``(Y,)`` how common each true type is (``None``: the world's, else equal).
        reward: ``(A, X, Y)`` a reward per true type to plan for instead of the world's
            ``true_reward`` (the people's true behaviour with other rewards:
            :func:`true_behaviour_controller`).

    Returns:
        A float64 :class:`~torchhrc.pomdp.MOMDP` with ``X`` the task's states and
        ``Y * M`` hidden values named ``type`` (``M = 1``) or ``type/m<m>``.

    Raises:
        ModelError: the people give no tables.
        ValueError: ``noise`` outside ``[0, 1]`` or ``shares`` of the wrong shape or sign.
        TypeError: ``shares`` not numbers.
    """
    from torchhrc.pomdp import MOMDP

    if not 0.0 <= float(noise) <= 1.0:
        raise ValueError(f"expected noise in [0, 1], got {noise!r}")
    tables = getattr(world.people, "turn_tables", None)
    if not callable(tables):
        raise ModelError(
            f"the world's people ({type(world.people).__name__}) give no turn_tables(noise): "
            "the true model needs P(human turn | type, memory, state, robot action) and the "
            "memory update as tables (torchhrc.tasks.TabularPeople gives them)"
        )
    probs, update, initial = tables(float(noise))  # (Y, M, X, A, C), same, (Y, M); C = H + 1
    task = world.task
    Y, M, X, A, C = probs.shape
    N = Y * M
    w = population_shares(world.shares if shares is None else shares, Y)
    mid = torch.as_tensor(task.robot_effect).to(torch.long)  # (A, X)
    dest = torch.as_tensor(task.human_effect).to(torch.long)[mid]  # (A, X, H)
    dest = torch.cat([dest, mid.unsqueeze(-1)], -1)  # (A, X, C): x2 of each turn
    terminal = torch.as_tensor(task.terminal).to(torch.bool)  # (X,)
    # P(c | y, m, x_mid(a, x), a) as (A, X, Y, M, C) and the memory after it
    a_idx = torch.arange(A).view(A, 1)
    p = probs.permute(3, 2, 0, 1, 4)[a_idx, mid]  # (A, X, Y, M, C)
    m2 = update.permute(3, 2, 0, 1, 4)[a_idx, mid]  # (A, X, Y, M, C)
    y_idx = torch.arange(Y).view(1, 1, Y, 1, 1)
    h2 = y_idx * M + m2  # (A, X, Y, M, C)
    x2 = dest.view(A, X, 1, 1, C).expand(A, X, Y, M, C)
    # a terminal state keeps its x whatever the people would do (the episode is over)
    stay_x = torch.arange(X).view(1, X, 1, 1, 1).expand(A, X, Y, M, C)
    x2 = torch.where(terminal.view(1, X, 1, 1, 1), stay_x, x2)
    joint = torch.zeros(A, X, N, X * N, dtype=torch.float64)
    joint.view(A, X, Y, M, X * N).scatter_add_(-1, x2 * N + h2, p)
    joint = joint.view(A, X, N, X, N)
    Tx = joint.sum(-1)  # (A, X, N, X)
    Ty = None
    if M > 1:
        reached = Tx > 0
        keep = torch.eye(N, dtype=joint.dtype).view(1, 1, N, 1, N)  # where x2 is never reached
        Ty = torch.where(reached.unsqueeze(-1),
                         joint / torch.where(reached, Tx, torch.ones_like(Tx)).unsqueeze(-1),
                         keep)  # fmt: skip
    if reward is None:
        reward = world.true_reward
    reward = torch.as_tensor(reward, dtype=torch.float64)
    if tuple(reward.shape) != (A, X, Y):
        raise ValueError(f"expected reward of shape (A={A}, X={X}, Y={Y}), got "
                         f"{tuple(reward.shape)}")  # fmt: skip
    R = reward.repeat_interleave(M, -1).clone()  # (A, X, N)
    R[:, terminal, :] = 0.0
    if world.observed and world.true_observation is not None:
        Z = world.true_observation.repeat_interleave(M, -2)  # (A, X, N, O)
        observations = None
    else:
        Z = torch.ones(A, X, N, 1, dtype=torch.float64)
        observations = ("none",)
    b0 = (w.view(Y, 1) * initial).reshape(N)
    names = world.type_names
    hidden = names if M == 1 else tuple(f"{n}/m{m}" for n in names for m in range(M))
    return MOMDP(Tx=Tx, Ty=Ty, Z=Z, R=R, x0=int(task.initial_state), b0=b0,
                 discount=float(task.discount), observed_states=tuple(task.state_names),
                 hidden_states=hidden, actions=tuple(task.robot_actions),
                 observations=observations)  # fmt: skip


def true_model_controller(
    world: TaskWithPeople,
    *,
    noise: float = 0.05,
    shares: Sequence[float] | torch.Tensor | None = None,
    time_limit: float = 5.0,
    seed: int = 0,
) -> Controller:
    """A robot that plans on the world's true model (:func:`true_momdp`) and finds the
    person's type online: SARSOP on it, with :func:`~torchhrc.tasks.pipeline.solve_model`'s
    settings (precision 1e-3 of the reward span; the per-type lower bound where the hidden
    value is the static type, SARSOP's own where the people's memory changes it).

    Args:
        world, noise, shares: as :func:`true_momdp`.
        time_limit: SARSOP's time limit (s).
        seed: the solver's seed.

    Returns:
        A :class:`~torchhrc.tasks.controller.Controller` (its belief is over ``(type,
        memory)``).

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> world = make_task("pace")
        >>> robot = true_model_controller(world, time_limit=1.0)
        >>> robot.act(world.task.initial_state) in range(world.task.num_actions)
        True
    """
    return _solved(true_momdp(world, noise=noise, shares=shares), time_limit, seed)


def true_behaviour_controller(
    world: TaskWithPeople,
    model: LearnedModel,
    type_map: torch.Tensor,
    *,
    noise: float = 0.05,
    shares: Sequence[float] | torch.Tensor | None = None,
    time_limit: float = 5.0,
    seed: int = 0,
) -> Controller:
    """The learned model with its behaviour replaced by the people's true one: the true
    model (:func:`true_momdp`) planning for the learned rewards, true type ``y`` wanting what
    its learned type ``type_map[y]`` learned (``R[a, x, y] = model R[a, x, type_map[y]]``).

    Against the type-aware robot it says how much of what learning lost was the behaviour
    (``evaluate_task(true_parts=True)``).

    Args:
        world, noise, shares: as :func:`true_momdp`.
        model: the learned model.
        type_map: ``(Y,)`` the learned type of each true type.
        time_limit, seed: as :func:`true_model_controller`.

    Example:
        >>> import warnings, torchhrc
        >>> from torchhrc.tasks.suite import make_task
        >>> world = make_task("pace")
        >>> demos, _ = world.demonstrations(subjects=6, per_subject=2, seed=0)
        >>> with warnings.catch_warnings():
        ...     warnings.simplefilter("ignore")
        ...     model = torchhrc.learn(world.task, demos, k=3, solve=False)
        >>> robot = true_behaviour_controller(world, model, torch.tensor([0, 1, 2]),
        ...                                   time_limit=0.5)
        >>> robot.act(world.task.initial_state) in range(world.task.num_actions)
        True
    """
    index = _map("type_map", type_map, world.num_types, model.num_types)
    reward = model.momdp.R.to(torch.float64)[..., index]  # (A, X, Y)
    return _solved(true_momdp(world, noise=noise, shares=shares, reward=reward), time_limit,
                   seed)  # fmt: skip


def true_reward_controller(
    world: TaskWithPeople,
    model: LearnedModel,
    truth_of: torch.Tensor,
    *,
    time_limit: float = 5.0,
    seed: int = 0,
) -> Controller:
    """The learned model with its rewards replaced by the true ones: learned type ``k`` gets
    the true reward of the true type ``truth_of[k]`` (0 in terminal states), its learned
    behaviour and first belief kept.

    Against the type-aware robot it says how much of what learning lost was the rewards
    (``evaluate_task(true_parts=True)``).

    Args:
        world: the task with its people and true rewards.
        model: the learned model.
        truth_of: ``(K,)`` the true type of each learned type.
        time_limit, seed: as :func:`true_model_controller`.

    Example:
        >>> import warnings, torchhrc
        >>> from torchhrc.tasks.suite import make_task
        >>> world = make_task("pace")
        >>> demos, _ = world.demonstrations(subjects=6, per_subject=2, seed=0)
        >>> with warnings.catch_warnings():
        ...     warnings.simplefilter("ignore")
        ...     model = torchhrc.learn(world.task, demos, k=3, solve=False)
        >>> robot = true_reward_controller(world, model, torch.tensor([0, 1, 2]),
        ...                                time_limit=0.5)
        >>> robot.act(world.task.initial_state) in range(world.task.num_actions)
        True
    """
    index = _map("truth_of", truth_of, model.num_types, world.num_types)
    R = world.true_reward.to(model.momdp.R.dtype)[..., index].clone()  # (A, X, K)
    R[:, torch.as_tensor(world.task.terminal).to(torch.bool), :] = 0.0
    return _solved(dataclasses.replace(model.momdp, R=R), time_limit, seed)


def _map(name: str, value: torch.Tensor, size: int, into: int) -> torch.Tensor:
    """``value`` as a ``(size,)`` int64 index into ``[0, into)``, or a ValueError naming it."""
    index = torch.as_tensor(value)
    if (
        index.is_floating_point()
        or tuple(index.shape) != (size,)
        or bool(((index < 0) | (index >= into)).any())
    ):
        raise ValueError(f"expected {name} of shape ({size},), integers in [0, {into}), got "
                         f"{index.tolist()}")  # fmt: skip
    return index.to(torch.long)


def _solved(momdp: MOMDP, time_limit: float, seed: int) -> Controller:
    """SARSOP on ``momdp`` with solve_model's settings, as a controller."""
    from torchhrc.tasks.controller import Controller
    from torchhrc.tasks.pipeline import solve_momdp

    solution = solve_momdp(momdp, time_limit=float(time_limit), seed=seed)
    return Controller.from_momdp(momdp, solution.policy)
