"""The builder behind every suite task: a task written as plain Python rules, tabulated.

A suite task is described by a :class:`TaskSpec`: the states as hashable Python values
(tuples), the robot's and the human's moves as functions, which states end the task, and per
true type the person's behaviour (``P(a_h | memory, x_mid, a_r)``), how its memory changes and
the true reward of the robot's actions. :func:`build` enumerates the states reachable from the
initial one (so no state is unreachable), tabulates the rules into a
:class:`SuiteTask` (a :class:`~torchhrc.tasks.CollaborativeTask`) and a
:class:`~torchhrc.tasks.people.TabularPeople`, and returns the
:class:`~torchhrc.tasks.people.TaskWithPeople`. Tabulating costs one Python call per table
cell (a few thousand); it happens once per task.

Observed tasks (``intent_accuracy`` set) give the robot a noisy "reach" signal after each
step: the human action the person is about to take next (or none), read correctly with
probability ``intent_accuracy`` and uniformly otherwise, ``O = H + 1`` observations. The true
signal comes from the people's own behaviour; the learned model's (``observation(model)``)
from the learned behaviour, i.e. from ``Tx`` under the robot's idle action.

Example:
    >>> from torchhrc.tasks.suite import make_task
    >>> twp = make_task("screws_hands_off")
    >>> twp.task.num_states, twp.num_types
    (27, 3)
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.interface import CollaborativeTask
from torchhrc.tasks.people import TabularPeople, TaskWithPeople

if TYPE_CHECKING:
    from torchhrc.pomdp import MOMDP

__all__ = ["SuiteTask", "TaskSpec", "build", "intent_signal"]

State = Hashable
#: ``behaviour(y, m, s_mid, a_r) -> {a_h: probability}`` (``a_h = -1``: no action).
Behaviour = Callable[[int, int, Any, int], Mapping[int, float]]


@dataclass(frozen=True)
class TaskSpec:
    """A suite task written as rules over Python states (see the module docstring).

    Attributes:
        name: the suite name.
        description: one line on what distinguishes the types.
        initial: the initial state.
        robot_actions, human_actions: names (``A``, ``H``); ``robot_actions[0]`` is the idle
            robot action ("wait") and must change nothing.
        robot_step: ``(s, a_r) -> s'`` (every robot action is possible; a no-op where it
            makes no sense).
        human_step: ``(s, a_h) -> s'``, or None where ``a_h`` cannot happen.
        terminal: ``s -> bool``.
        state_name: ``s -> str`` (distinct names).
        type_names: ``(Y,)`` readable names of the true types.
        behaviour: ``(y, m, s_mid, a_r) -> {a_h: p}``, legal actions only.
        reward: ``(y, s, a_r) -> float`` the true reward of the robot's action.
        horizon: episode length cap.
        memory_size: ``M`` (1: behaviour depends on the state only).
        memory_update: ``(y, m, s_mid, a_r, a_h) -> m'`` (default: stays 0).
        demo_robot: ``(y, s) -> {a_r: p}`` the demonstrating partner's action (default: the
            type's best actions by ``reward``).
        intent_accuracy: set for an observed task (see the module docstring).
        features: ``(s, a_r) -> {feature name: value}`` compact reward features (default:
            one indicator per ``(a_r, x)`` and the wasted-move column).
    """

    name: str
    description: str
    initial: State
    robot_actions: tuple[str, ...]
    human_actions: tuple[str, ...]
    robot_step: Callable[[Any, int], Any]
    human_step: Callable[[Any, int], Any]
    terminal: Callable[[Any], bool]
    state_name: Callable[[Any], str]
    type_names: tuple[str, ...]
    behaviour: Behaviour
    reward: Callable[[int, Any, int], float]
    horizon: int
    memory_size: int = 1
    memory_update: Callable[[int, int, Any, int, int], int] | None = None
    demo_robot: Callable[[int, Any], Mapping[int, float]] | None = None
    intent_accuracy: float | None = None
    features: Callable[[Any, int], Mapping[str, float]] | None = None


class SuiteTask(CollaborativeTask):
    """A tabulated task of the suite (built by :func:`build`; tables as in
    :class:`~torchhrc.tasks.CollaborativeTask`, with explicit ``human_legal`` and ``terminal``).

    Attributes:
        name: the suite name.
        intent_accuracy: probability that the reach signal is read correctly (None: the task
            has no observation of the human).
    """

    def __init__(
        self,
        *,
        name: str,
        state_names: Sequence[str],
        robot_actions: Sequence[str],
        human_actions: Sequence[str],
        robot_effect: torch.Tensor,
        human_effect: torch.Tensor,
        legal: torch.Tensor,
        terminal: torch.Tensor,
        intent_accuracy: float | None = None,
        features: torch.Tensor | None = None,
        feature_names: Sequence[str] | None = None,
    ) -> None:
        self.name = name
        self.state_names = tuple(state_names)
        self.robot_actions = tuple(robot_actions)
        self.human_actions = tuple(human_actions)
        self.robot_effect = robot_effect
        self.human_effect = human_effect
        self._legal = legal
        self._terminal = terminal
        self.intent_accuracy = intent_accuracy
        self._features = features
        self._feature_names = None if feature_names is None else tuple(feature_names)

    def __repr__(self) -> str:
        return (f"SuiteTask({self.name!r}, X={self.num_states}, A={self.num_actions}, "
                f"H={self.num_human_actions})")  # fmt: skip

    @property
    def human_legal(self) -> torch.Tensor:
        """``(X, H)`` bool."""
        return self._legal

    @property
    def terminal(self) -> torch.Tensor:
        """``(X,)`` bool."""
        return self._terminal

    @property
    def feature_names(self) -> tuple[str, ...]:
        """``(F,)``."""
        if self._feature_names is None:
            return super().feature_names
        return self._feature_names

    def features(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """``(A, X, F)`` the task's compact features, or the default
        (:meth:`CollaborativeTask.features`)."""
        if self._features is None:
            return super().features(dtype=dtype, device=device)
        return self._features.to(dtype=dtype, device=device)

    def observation(self, model: MOMDP) -> torch.Tensor | None:
        """The reach signal's ``Z (A, X, Y, H + 1)`` from the learned behaviour (``Tx`` under
        the idle robot action), or None for a task without observation."""
        if self.intent_accuracy is None:
            return None
        Tx = model.Tx  # (A, X, Y, X)
        idle = self.idle_robot_action
        mid = torch.as_tensor(self.robot_effect)[idle].to(Tx.device)  # (X,)
        after = torch.as_tensor(self.human_effect).to(Tx.device)[mid]  # (X, H)
        legal = self._legal.to(Tx.device)[mid]  # (X, H)
        row = Tx[idle]  # (X, Y, X')
        X, Y = row.shape[0], row.shape[1]
        p_h = row.gather(-1, after.unsqueeze(1).expand(X, Y, -1)) * legal.unsqueeze(1)
        p_none = row.gather(-1, mid.view(X, 1, 1).expand(X, Y, 1))
        intent = torch.cat([p_h, p_none], -1)  # (X, Y, H + 1)
        return intent_signal(intent, self.intent_accuracy, self.num_actions)


def intent_signal(intent: torch.Tensor, accuracy: float, num_actions: int) -> torch.Tensor:
    """``Z (A, X, Y, O)`` of a reach signal: the intended next human move read correctly with
    probability ``accuracy``, uniformly otherwise.

    Args:
        intent: ``(X, Y, O)`` non-negative weights of the next move in ``x'`` (normalised here;
            uniform where all are 0).
        accuracy: in ``[0, 1]``.
        num_actions: ``A`` (the signal does not depend on the robot's action).

    Example:
        >>> z = intent_signal(torch.tensor([[[1.0, 0.0]]]), 0.8, 1)
        >>> [round(v, 6) for v in z[0, 0, 0].tolist()]
        [0.9, 0.1]
    """
    O = intent.shape[-1]
    total = intent.sum(-1, keepdim=True)
    p = torch.where(total > 0, intent / total.clamp_min(1e-300), torch.full_like(intent, 1.0 / O))
    z = accuracy * p + (1.0 - accuracy) / O
    return z.unsqueeze(0).expand(num_actions, *z.shape).contiguous()


def _reachable(spec: TaskSpec) -> list[Any]:
    order, seen = [spec.initial], {spec.initial}
    i = 0
    while i < len(order):
        s = order[i]
        i += 1
        if spec.terminal(s):
            continue
        for a in range(len(spec.robot_actions)):
            mid = spec.robot_step(s, a)
            nxt = [mid] + [spec.human_step(mid, h) for h in range(len(spec.human_actions))]
            for t in nxt:
                if t is not None and t not in seen:
                    seen.add(t)
                    order.append(t)
    return order


def _normalise(weights: Mapping[int, float], what: str) -> dict[int, float]:
    total = float(sum(weights.values()))
    if total <= 0 or any(v < 0 for v in weights.values()):
        raise ModelError(f"{what}: expected non-negative weights with a positive sum, got "
                         f"{dict(weights)}")  # fmt: skip
    return {k: float(v) / total for k, v in weights.items()}


def build(spec: TaskSpec) -> TaskWithPeople:
    """Tabulate a :class:`TaskSpec` into a :class:`~torchhrc.tasks.people.TaskWithPeople`.

    Raises:
        ModelError: the rules are inconsistent (a behaviour with mass on an illegal action, a
            robot idle action that changes the state, a memory state out of range).
    """
    states = _reachable(spec)
    index = {s: i for i, s in enumerate(states)}
    X, A, H = len(states), len(spec.robot_actions), len(spec.human_actions)
    Y, M = len(spec.type_names), spec.memory_size
    # numpy while filling cell by cell (a torch element write costs ~100x more), then torch
    is_end = [bool(spec.terminal(s)) for s in states]
    robot_effect = np.empty((A, X), dtype=np.int64)
    human_effect = np.empty((X, H), dtype=np.int64)
    legal = np.zeros((X, H), dtype=bool)
    mids: list[list[Any]] = []
    for x, s in enumerate(states):
        mids.append([s if is_end[x] else spec.robot_step(s, a) for a in range(A)])
        for a in range(A):
            robot_effect[a, x] = index[mids[x][a]]
        for h in range(H):
            t = None if is_end[x] else spec.human_step(s, h)
            human_effect[x, h] = x if t is None else index[t]
            legal[x, h] = t is not None and t != s
    if not (robot_effect[0] == np.arange(X)).all():
        raise ModelError(f"{spec.name}: robot action {spec.robot_actions[0]!r} must change nothing")
    policy = np.zeros((Y, M, X, A, H + 1))
    update = np.zeros((Y, M, X, A, H + 1), dtype=np.int64)
    reward = np.zeros((A, X, Y))
    demo = np.zeros((Y, X, A)) if spec.demo_robot is not None else None
    for x, s in enumerate(states):
        for y in range(Y):
            if is_end[x]:
                policy[y, :, x, :, H] = 1.0
                update[y, :, x] = np.arange(M).reshape(M, 1, 1)
                if demo is not None:
                    demo[y, x, 0] = 1.0
                continue
            for a in range(A):
                reward[a, x, y] = float(spec.reward(y, s, a))
            if demo is not None and spec.demo_robot is not None:
                for a, p in _normalise(spec.demo_robot(y, s), f"demo_robot({y}, {s})").items():
                    demo[y, x, a] = p
        if is_end[x]:
            continue
        for a in range(A):  # x is the state after the robot's move a (the person's turn)
            for y in range(Y):
                for m in range(M):
                    rule = spec.behaviour(y, m, s, a)
                    for h, p in _normalise(rule, f"behaviour({y}, {m}, {s}, {a})").items():
                        if h >= 0 and not legal[x, h]:
                            raise ModelError(
                                f"{spec.name}: type {spec.type_names[y]!r} (memory {m}) takes "
                                f"{spec.human_actions[h]!r} in state {spec.state_name(s)!r}, "
                                "where it cannot happen"
                            )
                        policy[y, m, x, a, h if h >= 0 else H] = p
                    for h in range(-1, H):
                        if h >= 0 and not legal[x, h]:
                            update[y, m, x, a, h] = m
                            continue
                        nm = 0 if spec.memory_update is None else spec.memory_update(y, m, s, a, h)
                        if not 0 <= nm < M:
                            raise ModelError(f"{spec.name}: memory {nm} out of [0, {M})")
                        update[y, m, x, a, h if h >= 0 else H] = nm
    features = names = None
    if spec.features is not None:
        table: dict[str, np.ndarray] = {}
        for x, s in enumerate(states):
            if is_end[x]:
                continue
            for a in range(A):
                for f, v in spec.features(s, a).items():
                    table.setdefault(f, np.zeros((A, X)))[a, x] = float(v)
        names = tuple(table)
        features = torch.from_numpy(np.stack([table[f] for f in names], -1))
    legal_t = torch.from_numpy(legal)
    task = SuiteTask(
        name=spec.name,
        state_names=[spec.state_name(s) for s in states],
        robot_actions=spec.robot_actions,
        human_actions=spec.human_actions,
        robot_effect=torch.from_numpy(robot_effect),
        human_effect=torch.from_numpy(human_effect),
        legal=legal_t,
        terminal=torch.tensor(is_end, dtype=torch.bool),
        intent_accuracy=spec.intent_accuracy,
        features=features,
        feature_names=names,
    )
    policy_t = torch.from_numpy(policy)
    people = TabularPeople(spec.type_names, policy_t, legal_t, update=torch.from_numpy(update))
    true_observation = None
    if spec.intent_accuracy is not None:
        if M != 1:
            raise ModelError(f"{spec.name}: an observed task needs memory-free people (M = 1)")
        intent = policy_t[:, 0, :, 0, :].permute(1, 0, 2)  # (X, Y, H + 1), robot idle
        true_observation = intent_signal(intent, spec.intent_accuracy, A)
    return TaskWithPeople(
        task=task,
        people=people,
        true_reward=torch.from_numpy(reward),
        horizon=spec.horizon,
        observed=spec.intent_accuracy is not None,
        demo_robot=None if demo is None else torch.from_numpy(demo),
        true_observation=true_observation,
        description=spec.description,
    )
