"""The task interface: what a user supplies about a collaborative task, and nothing more.

Paper (Nikolaidis et al., "MOMDP Formulation"): a collaborative task is a MOMDP whose
observed part ``x`` is the task state, whose hidden part ``y`` is the human type, and whose
one decision step is a robot action ``a_r`` followed by the human's response ``a_h``. What
differs between tasks is only the mechanics of ``x``; everything learned (the types, their
behaviour, their rewards) comes from demonstrations through :mod:`torchhrc.tasks.pipeline`.
A task is a :class:`CollaborativeTask`, tabulated (all tables are small tensors):

=====================  ==============================================================
``state_names``        ``(X,)`` names of the observed task states ``x``
``robot_actions``      ``(A,)`` names of the robot actions ``a_r``
``human_actions``      ``(H,)`` names of the human actions ``a_h``
``robot_effect``       ``(A, X)`` int64: ``x`` after robot action ``a`` (before the human)
``human_effect``       ``(X, H)`` int64: ``x`` after human action ``h`` (from the robot's result)
``human_legal``        ``(X, H)`` bool: ``h`` can happen in ``x`` (default: it changes ``x``)
``initial_state``      ``x0`` (default 0)
``terminal``           ``(X,)`` bool absorbing, zero-reward states (default none)
``features()``         ``(A, X, F)`` reward features ``phi(x, a_r)`` (default one-hot of
                       ``(x, a_r)``, :func:`tabular_features`, and one
                       :func:`wasted_move_feature` column)
``observation(model)`` how the robot observes the human: ``None`` (the human's action is
                       seen through ``x'``, as in place-and-drill) or ``Z (A, X, Y, O)``
                       (a noisy signal, as the hand positions of hand-finishing)
=====================  ==============================================================

One step is ``x' = human_effect[robot_effect[a_r, x], a_h]`` (:meth:`CollaborativeTask.step`);
the human may also let a turn pass (``x' = robot_effect[a_r, x]``). Demonstrations are
sequences of ``(actor, action)`` symbols (:class:`torchhrc.data.Demonstrations`); the default
reading (:meth:`CollaborativeTask.read_steps`) turns them into steps ``(x, a_r, a_h, x')``
and rejects a step the dynamics cannot produce.

The pieces a task may replace (each has a default that learns it from the demonstrations):
:meth:`~CollaborativeTask.human_policy` (per-type human behaviour),
:meth:`~CollaborativeTask.known_reward` (a reward given instead of learned by IRL),
:meth:`~CollaborativeTask.type_names`. The pipeline calls them the same way for every task.

Example:
    >>> class Toggle(CollaborativeTask):
    ...     state_names = ("off", "on")
    ...     robot_actions = ("wait", "press")
    ...     human_actions = ("flip",)
    ...     robot_effect = torch.tensor([[0, 1], [1, 1]])   # press turns it on
    ...     human_effect = torch.tensor([[1], [0]])         # flip toggles
    >>> task = Toggle()
    >>> task.step(torch.tensor(0), torch.tensor(0), torch.tensor(1)).item()  # press, flip
    0
    >>> task.features().shape
    torch.Size([2, 2, 5])
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import torch

from torchhrc._checks import check_index
from torchhrc.errors import ModelError

if TYPE_CHECKING:
    from torchhrc.data import Demonstrations
    from torchhrc.pomdp import MOMDP

__all__ = [
    "CollaborativeTask",
    "TaskSteps",
    "TaskWarning",
    "TypeEvidence",
    "behaviour_from_preferences",
    "chain_preferences",
    "check_state_smoothing",
    "check_task",
    "reachable_states",
    "tabular_features",
    "wasted_move_feature",
]

#: Human symbols read as "the human lets this turn pass" when not a task action.
IDLE_HUMAN_NAMES: tuple[str, ...] = ("wait", "idle", "none")


class TaskWarning(UserWarning):
    """A task that works but is probably not what its author meant (:func:`check_task`)."""


@dataclass(frozen=True)
class TaskSteps:
    """Demonstrations rewritten as task steps ``(x, a_r, a_h, x')`` (``N`` sequences,
    ``L`` steps at most, padded).

    Attributes:
        states: ``(N, L)`` int64 ``x`` before the robot's ``t``-th decision.
        actions: ``(N, L)`` int64 robot action ``a_r``.
        human: ``(N, L)`` int64 human action ``a_h`` (``-1``: the human let the turn pass).
        next_states: ``(N, L)`` int64 ``x'``.
        mask: ``(N, L)`` bool, True on real steps.
    """

    states: torch.Tensor
    actions: torch.Tensor
    human: torch.Tensor
    next_states: torch.Tensor
    mask: torch.Tensor

    @property
    def lengths(self) -> torch.Tensor:
        """``(N,)`` real steps per sequence."""
        return self.mask.sum(-1)

    def robot_moves(
        self, assignments: torch.Tensor, num_types: int, num_states: int, num_actions: int
    ) -> torch.Tensor:
        """``(K, X, A)`` float64: how often the (demonstrating) robot took each action in each
        state, per type, ``assignments (N,)`` giving each sequence's type.

        Example:
            >>> s = torch.tensor([[0, 1], [0, 0]])
            >>> steps = TaskSteps(s, torch.tensor([[1, 0], [2, 0]]), -torch.ones_like(s), s,
            ...                   torch.tensor([[True, True], [True, False]]))
            >>> steps.robot_moves(torch.tensor([0, 1]), 2, 2, 3)[:, 0].tolist()  # in state 0
            [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        """
        K, X, A = num_types, num_states, num_actions
        mask = self.mask
        y = assignments.to(mask.device).long()[:, None].expand_as(mask)[mask]
        index = (y * X + self.states[mask]) * A + self.actions[mask]
        return torch.bincount(index, minlength=K * X * A).reshape(K, X, A).to(torch.float64)


@dataclass(frozen=True)
class TypeEvidence:
    """What the pipeline knows about the types when it asks the task for a type-dependent
    piece (``K`` types, ``V`` demonstration symbols).

    Attributes:
        chains: ``(K, V, V)`` float64 Markov chain of each type over the symbols.
        vocabulary: ``(V,)`` symbols ``(actor, action)`` of the chains.
        assignments: ``(N,)`` int64 type of each demonstration.
        steps: the demonstrations as :class:`TaskSteps` (``None`` when the task does not
            read its demonstrations as steps).
        noise: weight of a uniformly random legal human action in the behaviour.
        pause: probability that the human lets a turn pass although an action is legal
            (the chain model's only "no action"; a floor under the state model's learned
            one, see :meth:`~CollaborativeTask.human_policy`).
        human_model: the human model the pipeline chose (``"chain"`` or ``"state"``: the
            task's :attr:`CollaborativeTask.human_model`, or ``"auto"`` resolved on held-out
            data), which the default :meth:`~CollaborativeTask.human_policy` follows;
            ``None``: the task's own setting (``"auto"`` then reads as ``"chain"``).
        habit_weight: the state model's weight ``w`` of the type's own habit in its prior
            (:func:`_state_counts`), in ``[0, 1]``; the pipeline chooses it on held-out
            subjects (:func:`~torchhrc.tasks.human_model_choice.compare_human_models`).
        prior_strength: the state model's Dirichlet strength ``c > 0``: how many
            demonstration steps the prior weighs as in each state (:func:`_state_counts`).
    """

    chains: torch.Tensor
    vocabulary: tuple[tuple[str, str], ...]
    assignments: torch.Tensor
    steps: TaskSteps | None
    noise: float = 0.05
    pause: float = 0.0
    human_model: str | None = None
    habit_weight: float = 0.75
    prior_strength: float = 1.0

    def __post_init__(self) -> None:
        check_state_smoothing(self.habit_weight, self.prior_strength)

    @property
    def num_types(self) -> int:
        """``K``."""
        return int(self.chains.shape[0])


def tabular_features(
    num_actions: int,
    num_states: int,
    terminal: torch.Tensor | None = None,
    *,
    dtype: torch.dtype = torch.float64,
) -> torch.Tensor:
    """The default reward features' tabular part: one indicator per ``(a_r, x)``, zero in
    terminal states (:meth:`CollaborativeTask.features` adds :func:`wasted_move_feature`).

    With these IRL can represent any reward ``R(x, a_r)``; a task with many states should
    supply a few meaningful features instead (fewer demonstrations needed).

    Returns:
        ``(A, X, A * X)`` float, ``phi[a, x, a * X + x] = 1``.

    Example:
        >>> tabular_features(2, 3)[1, 2].nonzero().flatten().tolist()
        [5]
    """
    phi = torch.eye(num_actions * num_states, dtype=dtype).view(num_actions, num_states, -1)
    if terminal is not None:
        phi = phi * (~terminal.to(torch.bool)).to(dtype).view(1, -1, 1)
    return phi


def wasted_move_feature(
    robot_effect: torch.Tensor,
    terminal: torch.Tensor | None = None,
    *,
    dtype: torch.dtype = torch.float64,
) -> torch.Tensor:
    """One shared reward feature: a robot move that is wasted where it is made.

    ``phi[a, x] = 1`` where robot action ``a`` leaves ``x`` unchanged
    (``robot_effect[a, x] == x``) although ``a`` changes some other state; zero for an
    action that changes no state at all (the task's wait), and zero in terminal states.

    Why: with only the per-``(x, a_r)`` indicators of :func:`tabular_features`, the reward
    of a pair no demonstration visits is unconstrained, and maximum-entropy IRL can leave a
    move that changes nothing with a positive reward off the demonstrated path; the robot
    then repeats it to the horizon rather than finish (the task's end is an absorbing
    zero-reward state). Seen on the held-out task ``shelf_kitting``
    (``benchmarks/heldout_tasks.py``): ``kit_C`` with ``C`` already mounted learned
    ``+1.44``, and the type-aware robot lost to the pooled one. One column shared by every
    state lets the ridge carry what the demonstrations show where partners were (they never
    waste a move) to the states they never visited. Part of the default
    :meth:`CollaborativeTask.features` (docs/evaluation_history.md, "The wasted-move
    column", has the figures that decided it).

    Args:
        robot_effect: ``(A, X)`` int64, ``x`` after robot action ``a``.
        terminal: ``(X,)`` bool (None: no terminal state).

    Returns:
        ``(A, X, 1)`` float.

    Example:
        >>> effect = torch.tensor([[0, 1, 2], [1, 1, 2]])  # wait; "press" 0 -> 1, else nothing
        >>> wasted_move_feature(effect, torch.tensor([False, False, True]))[..., 0].tolist()
        [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    """
    effect = torch.as_tensor(robot_effect)
    if effect.dim() != 2 or effect.dtype.is_floating_point or effect.dtype == torch.bool:
        raise ValueError(f"expected robot_effect of shape (A, X) with integer entries, got "
                         f"shape {tuple(effect.shape)} of {effect.dtype}")  # fmt: skip
    X = effect.shape[-1]
    if terminal is not None and tuple(torch.as_tensor(terminal).shape) != (X,):
        raise ValueError(f"expected terminal of shape (X,) = ({X},) like robot_effect's "
                         f"states, got {tuple(torch.as_tensor(terminal).shape)}")  # fmt: skip
    same = effect == torch.arange(X, device=effect.device)  # (A, X)
    moves = ~same.all(-1, keepdim=True)  # (A, 1): the action changes some state
    phi = (same & moves).to(dtype)
    if terminal is not None:
        phi = phi * (~torch.as_tensor(terminal).to(torch.bool)).to(dtype).view(1, -1)
    return phi.unsqueeze(-1)


def chain_preferences(
    chains: torch.Tensor,
    vocabulary: Sequence[tuple[str, str]],
    robot_actions: Sequence[str],
    human_actions: Sequence[str],
) -> torch.Tensor:
    """Per-type preferences ``p[k, a, h] = theta_k(human:h | robot:a)`` from Markov chains.

    Paper: "the transition matrix encodes information about how the human will act based on
    the previous robot action". Symbols missing from the vocabulary give zero preference.

    Args:
        chains: ``(..., K, V, V)`` ``chains[k, u, v] = P(next v | previous u)``.
        vocabulary: ``(V,)`` symbols.
        robot_actions: ``(A,)`` robot action names; human_actions: ``(H,)``.

    Returns:
        ``(..., K, A, H)`` preferences (rows not normalised).

    Example:
        >>> c = torch.tensor([[[0.0, 1.0], [1.0, 0.0]]])
        >>> chain_preferences(c, [("robot", "go"), ("human", "hi")], ["go"], ["hi"]).tolist()
        [[[1.0]]]
    """
    vocab = [tuple(v) for v in vocabulary]
    V = len(vocab)
    if chains.shape[-1] != V or chains.shape[-2] != V:
        raise ModelError(
            f"expected chains of shape (..., K, V={V}, V={V}), got {tuple(chains.shape)}"
        )
    lookup = {sym: i for i, sym in enumerate(vocab)}
    rows = torch.tensor([lookup.get(("robot", a), -1) for a in robot_actions])
    cols = torch.tensor([lookup.get(("human", h), -1) for h in human_actions])
    picked = chains[..., rows.clamp_min(0)[:, None], cols.clamp_min(0)[None, :]]
    ok = (rows[:, None] >= 0) & (cols[None, :] >= 0)
    return torch.where(ok.to(chains.device), picked, torch.zeros_like(picked))


def behaviour_from_preferences(
    task: CollaborativeTask,
    preferences: torch.Tensor,
    *,
    noise: float = 0.0,
    pause: float = 0.0,
) -> torch.Tensor:
    """Human behaviour ``P(a_h | x, a_r, y)`` from per-type preferences over the human actions.

    What :meth:`CollaborativeTask.human_policy` does with the preferences it reads from the
    chains, for preferences given otherwise (a hand-coded model: ``torch.ones`` is a human who
    picks uniformly among the legal actions). With ``q`` the preference restricted to the
    actions legal after the robot's move (``human_legal[robot_effect[a, x]]``) and
    renormalised (uniform where it has no mass), ``u`` the uniform legal action, ``e`` the
    noise and ``s`` the pause: ``P(h) = (1 - s) * ((1 - e) * q(h) + e * u(h))`` and
    ``P(none) = s`` (all of it where nothing is legal).

    Args:
        task: the task.
        preferences: ``(..., Y, A, X, H)`` non-negative, finite preferences ``p[y, a, x, h]``
            of human action ``h`` after robot action ``a`` in ``x`` (``X`` may be 1: the
            same for every state); unnormalised.
        noise: weight in ``[0, 1]`` of a uniformly random legal action.
        pause: probability in ``[0, 1)`` that the human lets a turn pass although an action
            is legal.

    Returns:
        ``(..., Y, A, X, H + 1)`` probabilities in ``preferences``' dtype and device, rows
        summing to 1 (last column: no action);
        :func:`torchhrc.tasks.pipeline.transition_from_behaviour` makes the task's ``Tx``.

    Example:
        >>> from torchhrc.tasks.place_and_drill import PlaceAndDrillTask
        >>> task = PlaceAndDrillTask(2)  # H = 2 placements; from the empty bench, wait
        >>> behaviour_from_preferences(task, torch.ones(1, 3, 1, 2))[0, 0, 0].tolist()
        [0.5, 0.5, 0.0]
    """
    A, X, H = task.num_actions, task.num_states, task.num_human_actions
    if not isinstance(preferences, torch.Tensor) or not preferences.is_floating_point():
        raise TypeError("expected preferences to be a floating torch.Tensor of shape "
                        "(..., Y, A, X, H)")  # fmt: skip
    shape = tuple(preferences.shape)
    if len(shape) < 4 or shape[-3] != A or shape[-2] not in (1, X) or shape[-1] != H:
        raise ModelError(f"expected preferences of shape (..., Y, A={A}, X={X} or 1, H={H}), "
                         f"actual shape = {shape}")  # fmt: skip
    if (preferences < 0).any() or not torch.isfinite(preferences).all():
        raise ModelError("expected preferences to be finite and non-negative")
    if not 0.0 <= noise <= 1.0:
        raise ModelError(f"expected noise in [0, 1], got {noise}")
    if not 0.0 <= pause < 1.0:
        raise ModelError(f"expected pause in [0, 1), got {pause}")
    legal = _legal_after_robot(task, preferences.device).to(preferences.dtype)
    return _behaviour(legal, preferences, noise, pause, None)


def _legal_after_robot(task: CollaborativeTask, device: torch.device) -> torch.Tensor:
    """``(A, X, H)`` bool: ``h`` is legal after robot action ``a`` in ``x``."""
    mid = torch.as_tensor(task.robot_effect).to(device)  # (A, X)
    return torch.as_tensor(task.human_legal).to(device)[mid]


def _behaviour(legal_f: torch.Tensor, p: torch.Tensor, noise: float, pause: float,
               none: torch.Tensor | None) -> torch.Tensor:  # fmt: skip
    """``(..., Y, A, X, H + 1)`` behaviour from ``legal_f (A, X, H)`` (0/1 in ``p``'s dtype),
    preferences ``p (..., Y, A, X or 1, H)`` and a learned "no action" ``none
    (..., Y, A, X, 1)`` or ``None`` (:meth:`CollaborativeTask.human_policy`)."""
    dt = p.dtype
    num_legal = legal_f.sum(-1, keepdim=True)
    uniform = legal_f / num_legal.clamp_min(1.0)
    masked = p * legal_f
    total = masked.sum(-1, keepdim=True)
    if none is not None:  # "no action" learned, only where the human had a choice
        none = none * (num_legal > 0).to(dt)
        total = total + none
    chain = torch.where(total > 0, masked / total.clamp_min(1e-300), uniform)
    probs = (1.0 - noise) * chain + noise * uniform
    probs = probs * (1.0 - pause)  # (Y, A, X, H)
    stay = torch.where(num_legal == 0, 1.0, pause).to(dt)  # (A, X, 1)
    stay = stay.expand(*probs.shape[:-1], 1)
    if none is not None:
        q_none = torch.where(total > 0, none / total.clamp_min(1e-300), 0.0)
        stay = stay + (1.0 - pause) * (1.0 - noise) * q_none
    return torch.cat([probs, stay], -1)


class CollaborativeTask:
    """Base class of a collaborative task (see the module docstring for the contract).

    Subclasses set (class attributes, properties or dataclass fields) ``state_names``,
    ``robot_actions``, ``human_actions``, ``robot_effect (A, X)`` and
    ``human_effect (X, H)``, and may override every other member.

    Attributes:
        human_model: how :meth:`human_policy` learns a type's behaviour by default:
            ``"chain"``: from the type's Markov chain, ``P(a_h | previous robot action)``
            (the paper's reading, place-and-drill); ``"state"``: from the type's
            demonstration steps, ``P(a_h | x after the robot's action)`` (counts with a
            Dirichlet pseudo-count), for tasks where the human's choice depends on the
            task state more than on the robot's last move; ``"auto"`` (default): the
            pipeline fits both and keeps the one with the larger held-out likelihood of the
            human's actions, held out by subject (:func:`torchhrc.tasks.pipeline.build_model`,
            recorded in ``LearnedModel.info["human_model"]``).
        discount: discount factor of the MOMDP and of the IRL.
    """

    state_names: Sequence[str]
    robot_actions: Sequence[str]
    human_actions: Sequence[str]
    robot_effect: torch.Tensor
    human_effect: torch.Tensor
    human_model: Literal["auto", "chain", "state"] = "auto"
    discount: float = 0.95

    # ------------------------------------------------------------------ sizes and defaults
    @property
    def num_states(self) -> int:
        """``X``."""
        return len(self.state_names)

    @property
    def num_actions(self) -> int:
        """``A``, robot actions."""
        return len(self.robot_actions)

    @property
    def num_human_actions(self) -> int:
        """``H``."""
        return len(self.human_actions)

    @property
    def initial_state(self) -> int:
        """``x0`` (default 0)."""
        return 0

    @property
    def idle_robot_action(self) -> int:
        """The robot action read before a human turn that follows no robot action
        (default: ``"wait"`` when there is one, else 0)."""
        names = list(self.robot_actions)
        return names.index("wait") if "wait" in names else 0

    @property
    def human_legal(self) -> torch.Tensor:
        """``(X, H)`` bool: human action ``h`` can happen in ``x`` (default: it changes ``x``)."""
        X = self.num_states
        return self.human_effect != torch.arange(X).view(X, 1)

    @property
    def terminal(self) -> torch.Tensor:
        """``(X,)`` bool absorbing zero-reward states (default: none)."""
        return torch.zeros(self.num_states, dtype=torch.bool)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """``(F,)`` names of :meth:`features` (default: ``"<action>@<state>"``, then
        ``"wasted_move"``)."""
        tabular = (f"{a}@{x}" for a in self.robot_actions for x in self.state_names)
        return (*tabular, "wasted_move")

    def features(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """Reward features ``(A, X, F)``, ``phi_f(x, a_r)``.

        Default: :func:`tabular_features` (``A * X`` columns) and one
        :func:`wasted_move_feature` column, ``F = A * X + 1``.
        """
        phi = tabular_features(self.num_actions, self.num_states, self.terminal, dtype=dtype)
        wasted = wasted_move_feature(self.robot_effect, self.terminal, dtype=dtype)
        return torch.cat([phi, wasted], -1).to(device)

    def observation(self, model: MOMDP) -> torch.Tensor | None:
        """How the robot observes the human, given the learned model without it.

        Args:
            model: the learned MOMDP with the trivial observation (``Z`` of ones, ``O = 1``).

        Returns:
            ``None``: the human's action is seen through ``x'`` alone (default); or
            ``Z (A, X, Y, O)`` = ``P(o | x', y', a_r)``, a noisy signal of the human.
        """
        return None

    # ------------------------------------------------------------------ dynamics
    def step(
        self, x: torch.Tensor | int, human_action: torch.Tensor | int,
        robot_action: torch.Tensor | int,
    ) -> torch.Tensor | int:  # fmt: skip
        """``x'`` after robot action ``a_r`` then human action ``a_h`` (``-1``: none), batched.

        Args:
            x, human_action, robot_action: int64 tensors that broadcast together, or ints
                (indices into :attr:`state_names`, :attr:`human_actions` (or ``-1``) and
                :attr:`robot_actions`).

        Returns:
            ``(...)`` int64 next states; an int when all three are ints.

        Raises:
            TypeError: an argument that is not an int or an integer tensor or array (an
                action's name: use its index, ``task.robot_actions.index(name)``).
            ModelError: an index out of range (the message names the argument and lists the
                actions).

        Example:
            >>> from torchhrc.tasks.suite import make_task
            >>> task = make_task("fetch_order").task
            >>> x0 = task.initial_state
            >>> task.step(x0, -1, 0) == int(task.robot_effect[0, x0])  # ints in, int out
            True
        """
        scalar = not any(isinstance(v, torch.Tensor) for v in (x, human_action, robot_action))
        effect = torch.as_tensor(self.robot_effect)
        human = torch.as_tensor(self.human_effect)
        xt = check_index("x", x, self.num_states, device=effect.device)
        ht = check_index("human_action", human_action, self.num_human_actions, low=-1,
                         device=effect.device, what=_listed(self.human_actions))  # fmt: skip
        at = check_index("robot_action", robot_action, self.num_actions,
                         device=effect.device, what=_listed(self.robot_actions))  # fmt: skip
        mid = effect[at, xt]
        after = human[mid, ht.clamp_min(0)]
        out = torch.where(ht >= 0, after, mid)
        return int(out) if scalar and out.dim() == 0 else out

    # ------------------------------------------------------------------ demonstrations
    def read_steps(self, demonstrations: Demonstrations) -> TaskSteps | None:
        """Rewrite ``(actor, action)`` demonstrations as task steps ``(x, a_r, a_h, x')``.

        A task whose demonstrations serve the clustering only (its reward given by
        :meth:`known_reward`, its behaviour not counted from steps) may return ``None``.

        Reading rules: a sequence starts at ``x0``; a robot symbol is one decision at the
        current ``x``; a human turn right after it belongs to the same step; a human turn
        that follows no robot action (the first one, or two human turns in a row) is
        preceded by :attr:`idle_robot_action`. A human symbol named ``wait`` (or ``idle``,
        ``none``) that is not a task action means "no human action".

        Raises:
            ModelError: a symbol that is not an action of the task, or a human action the
                dynamics cannot produce (``human_legal`` is False where it happens).
        """
        robot_index = {a: i for i, a in enumerate(self.robot_actions)}
        human_index = {h: i for i, h in enumerate(self.human_actions)}
        kinds: list[tuple[int, int]] = []  # (0 robot / 1 human / 2 other, index)
        for actor, action in demonstrations.vocabulary:
            if actor == "robot" and action in robot_index:
                kinds.append((0, robot_index[action]))
            elif actor == "human" and action in human_index:
                kinds.append((1, human_index[action]))
            elif actor == "human" and action in IDLE_HUMAN_NAMES:
                kinds.append((1, -1))
            else:
                kinds.append((2, -1))
        effect = torch.as_tensor(self.robot_effect).tolist()
        human = torch.as_tensor(self.human_effect).tolist()
        legal = torch.as_tensor(self.human_legal).tolist()
        idle = self.idle_robot_action
        names = list(self.state_names)
        subjects = getattr(demonstrations, "subjects", None)
        sequence_ids = getattr(demonstrations, "sequence_ids", None)

        def which(n: int) -> str:  # the subject and demonstration, as the user named them
            if subjects is None or sequence_ids is None:
                return f"demonstration {n}"
            return f"subject {subjects[n]!r} demonstration {sequence_ids[n]!r} (row {n})"

        seqs = demonstrations.sequences.cpu().tolist()
        lengths = demonstrations.lengths.cpu().tolist()
        rows: list[list[list[int]]] = []
        for n, (seq, length) in enumerate(zip(seqs, lengths)):
            x = self.initial_state
            steps: list[list[int]] = []
            open_step = False
            for t in range(length):
                kind, idx = kinds[seq[t]]
                if kind == 2:
                    actor, action = demonstrations.vocabulary[seq[t]]
                    raise ModelError(
                        f"{which(n)} step {t}: symbol {actor}:{action} is not an action "
                        f"of the task (robot: {', '.join(self.robot_actions)}; human: "
                        f"{', '.join(self.human_actions)})"
                    )
                if kind == 0:
                    mid = effect[idx][x]
                    steps.append([x, idx, -1, mid])
                    x = mid
                    open_step = True
                    continue
                if not open_step:
                    steps.append([x, idle, -1, effect[idle][x]])
                    x = effect[idle][x]
                if idx >= 0:
                    if not legal[x][idx]:
                        if self.human_actions[idx] in IDLE_HUMAN_NAMES:
                            raise ModelError(
                                f"{which(n)} step {t}: human action "
                                f"{self.human_actions[idx]!r} is listed in the task's "
                                "human_actions but does not change the state: leave it out of "
                                f"human_actions; a human {self.human_actions[idx]!r} in the "
                                "demonstrations then reads as no action (the human lets the "
                                "turn pass)"
                            )
                        raise ModelError(
                            f"{which(n)} step {t}: human action "
                            f"{self.human_actions[idx]!r} cannot happen in state {names[x]!r} "
                            f"(after robot action {self.robot_actions[steps[-1][1]]!r}); the "
                            "task's dynamics cannot produce this step"
                        )
                    x = human[x][idx]
                steps[-1][2] = idx
                steps[-1][3] = x
                open_step = False
            rows.append(steps)
        N = len(rows)
        H = max([len(s) for s in rows] + [1])
        out = torch.zeros(4, N, H, dtype=torch.long)
        mask = torch.zeros(N, H, dtype=torch.bool)
        out[2] = -1
        for n, steps in enumerate(rows):
            if steps:
                out[:, n, : len(steps)] = torch.tensor(steps, dtype=torch.long).T
                mask[n, : len(steps)] = True
        dev = demonstrations.device
        return TaskSteps(*(t.to(dev) for t in out), mask.to(dev))  # type: ignore[arg-type]

    # ------------------------------------------------------------------ type-dependent pieces
    def human_policy(self, evidence: TypeEvidence) -> torch.Tensor:
        """Per-type human behaviour ``P(a_h | x, a_r, y)``, the last column "no action".

        Default (:attr:`human_model`): preferences ``p[y, a, x, h]`` from the chains
        (:func:`chain_preferences`, the same for every ``x``; no mass on "no action") or from
        the type's demonstration steps (``"state"``: counts per ``(x after the robot, a_h)``,
        "no action" counted too, smoothed toward the type's habit before the robot's move
        and the population's behaviour in the state, see :func:`_state_counts`), restricted
        to the actions legal after the robot's move (and "no action"), renormalised
        (uniform where ``p`` has no mass), mixed with ``evidence.noise`` of a uniformly
        random legal action and scaled by
        ``1 - evidence.pause``; ``evidence.pause`` is added to "no action" (a floor: all of it
        where nothing is legal). With ``q`` the renormalised preference, ``u`` the uniform
        legal action, ``e`` the noise and ``s`` the pause:
        ``P(h) = (1 - s) * ((1 - e) * q(h) + e * u(h))`` and
        ``P(none) = (1 - s) * (1 - e) * q(none) + s``.

        Returns:
            ``(Y, A, X, H + 1)`` probabilities, rows summing to 1.

        Example:
            >>> from torchhrc.tasks.suite import make_task
            >>> task = make_task("tool_handover").task
            >>> task.human_model
            'auto'
        """
        chains = evidence.chains
        dt, dev = chains.dtype, chains.device
        legal = _legal_after_robot(self, dev)  # (A, X, H)
        # the pipeline's choice (the task's own setting, or "auto" resolved on held-out data)
        human_model = evidence.human_model or self.human_model
        if human_model == "auto":
            human_model = "chain"
        if human_model == "chain":
            p = chain_preferences(chains, evidence.vocabulary, self.robot_actions,
                                  self.human_actions)  # fmt: skip
            p = p.unsqueeze(-2)  # (Y, A, 1, H)
            none = None  # the chains give "no action" only the pause
        elif human_model == "state":
            if evidence.steps is None:
                raise ModelError("human_model='state' needs the demonstrations read as steps")
            p = _state_counts(self, evidence, dt, dev)  # (Y, A, X, H + 1)
            p, none = p[..., :-1], p[..., -1:]  # (Y, A, X, H), (Y, A, X, 1)
        else:
            raise ModelError(
                f"expected human_model 'auto', 'chain' or 'state', got {human_model!r}"
            )
        return _behaviour(legal.to(dt), p, evidence.noise, evidence.pause, none)

    def known_reward(self, evidence: TypeEvidence) -> torch.Tensor | None:
        """A reward ``(A, X, Y)`` the task knows, or ``None`` to learn one per type by IRL
        from the demonstrations (default)."""
        return None

    def type_names(self, evidence: TypeEvidence) -> tuple[str, ...]:
        """``(Y,)`` names of the learned types (default ``"type_0"``, ...)."""
        return tuple(f"type_{k}" for k in range(evidence.num_types))


#: Dirichlet strength of the type's habit toward its chain preference
#: (:func:`_state_counts`): the chain weighs as one demonstration step in each state.
HABIT_CHAIN_STRENGTH: float = 1.0

#: Strength of the shrinkage of a type's off-script lift toward the lift of all types, and of
#: that toward none (:func:`_offscript_lift`): two turns' worth.
OFFSCRIPT_STRENGTH: float = 2.0


def check_state_smoothing(habit_weight: float, prior_strength: float) -> None:
    """Raise a ValueError unless ``habit_weight`` is in ``[0, 1]`` and ``prior_strength``
    is a finite number above 0 (the state model's smoothing, :class:`TypeEvidence`).

    Example:
        >>> check_state_smoothing(0.75, 1.0)
        >>> check_state_smoothing(1.5, 1.0)
        Traceback (most recent call last):
        ...
        ValueError: expected habit_weight in [0, 1], got 1.5
    """
    if not 0.0 <= float(habit_weight) <= 1.0:
        raise ValueError(f"expected habit_weight in [0, 1], got {habit_weight}")
    if not 0.0 < float(prior_strength) < float("inf"):
        raise ValueError(f"expected prior_strength a finite number above 0, got {prior_strength}")


def _state_counts(
    task: CollaborativeTask,
    evidence: TypeEvidence,
    dtype: torch.dtype,
    device: torch.device,
    *,
    want_reaction: bool = False,
) -> torch.Tensor:
    """The state model's smoothed counts ``(K, A, X, H + 1)``, the last column "no action".

    ``counts[y, x, h]`` counts the steps of type ``y``'s demonstrations in which the human
    did ``h`` (``H``: let the turn pass) in ``x = robot_effect[a_r, x_before]``, over the
    steps where some human action was legal (where none is, "no action" is forced and says
    nothing of the type). A sequence's last step without a human turn is not counted: the
    recording ended before the human's turn, which is no evidence of waiting.

    Hierarchical Dirichlet smoothing: the posterior mean of ``P(h | x, a_r, y)`` under a
    Dirichlet prior of strength ``c`` (``evidence.prior_strength``),
    ``counts[y, x, h] + c * prior[y, a_r, x, h]``, whose centre mixes two parents with
    weight ``w`` (``evidence.habit_weight``):
    ``prior = w * habit[y, a_r, x_before] + (1 - w) * population[a_r, x_before]``.
    The pipeline chooses ``(w, c)`` per task on held-out subjects
    (:func:`~torchhrc.tasks.human_model_choice.compare_human_models`): how far a type's
    habit carries into situations its demonstrations rarely show is a property of the
    people, which the held-out subjects' turns after unusual partner moves measure.

    * ``habit``: what the type did in the state *before* the robot's move, whatever the move
      (counts by ``x_before``, restricted to what is possible after this move), itself
      smoothed (strength :data:`HABIT_CHAIN_STRENGTH`) toward the type's chain preference
      ``P(a_h | a_r = a)`` (:func:`chain_preferences`) restricted to the actions legal after
      the move and renormalised (uniform where it has no mass), scaled by ``1 - r_y``, with
      ``r_y = (waits_y + 0.5) / (choices_y + 1)`` on "no action".
      Mixed, per type, with the type's reaction to the robot's move: what it did after the
      same move in any state, with the weight ``rho_y`` that predicts the type's own steps
      best, each left out (:func:`_reaction`; 0 unless the type's turns after moves its
      partners rarely made follow the move rather than its habit).
      Its share of "no action" after a move is then raised, by how unusual the move was
      for the type's partners in that state (``u[y, a, x]`` of :func:`_unusual_moves`), by
      the type's *off-script lift* ``d_y`` (:func:`_offscript_lift`): how many more of its
      turns it let pass after its partners' unusual moves than its habit in the same
      states predicts: ``clamp(p + u d_y, 0, 1)`` for its share ``p``, its other actions
      rescaled to the rest.
    * ``population``: every type's counts in ``x`` (after the move), smoothed (strength
      ``c``) toward the types' habits weighted by their shares of the demonstrations.

    Why: a type-aware robot steers people into states that the type's demonstrations never
    visited (its partner there was a different robot). There the type's own counts are
    empty, and what the prior predicts is what the belief filter reads as evidence. The
    chain preference alone says "the person does what they did after this robot move
    elsewhere", which holds along each type's demonstrated path (the partner served that
    type) and is the same for every type when the partner's move decides the person's
    (``fetch_order``: every type assembles the part just fetched, so the belief never
    moves). The habit keeps what tells the types apart in a state they all visited (their
    own choice there). The population half keeps an unseen situation from carrying strong
    evidence: a person reacting in a way their type's demonstrations never show
    (``screws_hands_off``: ``hands_off`` pulls back after an early drill) costs that type at
    most about a factor ``1 / (1 - w)`` against a type seen there, instead of sending the
    belief to the wrong type with near-certainty. Where the type was seen often its counts
    dominate. The defaults ``w = 0.75``, ``c = 1`` (one step's worth) bound that factor at
    4; where the held-out subjects show that people keep their habit after moves their
    partners rarely made (``fetch_order``: each person assembles the next part of their own
    order whatever was fetched), the pipeline's choice trusts the habit more (a larger
    ``w`` and ``c``), so that one odd turn in a rare situation does not outweigh the type's
    habit and a first move the partners never made still tells the types apart. But a habit
    is the wrong guess for a person who answers the robot's move: a follower who does
    nothing while the robot waits (``lead_follow_phase``), a person who hands back a tool
    she did not ask for. Her few turns after such moves (the partners' slips) show it in
    every state where they happened, and the reaction carries them to the states where
    they did not (``rho_y``). And neither habit nor reaction knows how *often* a person
    acts at all after a move that breaks her routine: a person who needs a part and is
    handed another, or nothing, may fetch it herself or wait (``cabinet_glue``: 0.4 of such
    turns let pass), while after the handed part, the only turns her demonstrations show
    there, she acts at once. The habit then predicts that she acts at once after a robot
    wait (no action 0.02), so in the learned model a wait costs nothing and shows her type,
    and the type-aware robot waited where the person stood idle. The partners' own slips
    (the demonstrating robot's, at the noise rate) are where her turns after unusual moves
    are seen; how many more turns she let pass there than in the same states after the
    usual move, pooled over the states, carries to the states where none was (``d_y``).
    Measured against her habit, so that a person who lingers in some states whatever the
    robot does (``pace_split``'s careful types) is not read as stalling after every odd
    move (a pass share pooled over the odd moves, tried first, lost those tasks).

    ``want_reaction``: return ``(2, K)``, ``rho`` and ``d``, instead (:func:`reaction_weights`,
    :func:`offscript_lifts`).
    """
    steps = evidence.steps
    assert steps is not None
    K, X, H = evidence.num_types, task.num_states, task.num_human_actions
    sdev = steps.states.device
    effect = torch.as_tensor(task.robot_effect).to(sdev)  # (A, X)
    legal = torch.as_tensor(task.human_legal).to(sdev).bool()  # (X, H)
    mid = effect[steps.actions, steps.states]  # (N, L)
    choice = legal[mid].any(-1)  # (N, L) some human action was legal
    L = steps.mask.shape[-1]
    last = torch.arange(L, device=sdev) == (steps.lengths.view(-1, 1) - 1)  # (N, L)
    keep = steps.mask & choice & ~(last & (steps.human < 0))
    column = torch.where(steps.human < 0, H, steps.human)  # (N, L)
    y = evidence.assignments.to(sdev).view(-1, 1).expand_as(mid)[keep]
    # each kept step's robot move, state before it and human action: (n,) each
    a_k, s_k, h_k = steps.actions[keep], steps.states[keep], column[keep]
    counts = torch.zeros(K, X, H + 1, dtype=dtype, device=sdev)
    flat = (y * X + mid[keep]) * (H + 1) + h_k
    counts.view(-1).index_add_(0, flat, torch.ones_like(flat, dtype=dtype))
    # the prior: the type's chain preference after the same robot move, its pooled waiting
    pref = chain_preferences(evidence.chains.to(sdev, dtype), evidence.vocabulary,
                             task.robot_actions, task.human_actions)  # fmt: skip  # (K, A, H)
    legal_f = legal[effect].to(dtype)  # (A, X, H)
    pref = pref.unsqueeze(-2) * legal_f  # (K, A, X, H)
    mass = pref.sum(-1, keepdim=True)
    uniform = legal_f / legal_f.sum(-1, keepdim=True).clamp_min(1.0)
    pref = torch.where(mass > 0, pref / mass.clamp_min(1e-300), uniform)
    waits = counts[..., H].sum(-1)  # (K,)
    rate = ((waits + 0.5) / (counts.sum((-1, -2)) + 1.0)).view(K, 1, 1, 1)  # (K, 1, 1, 1)
    chain = torch.cat([(1.0 - rate) * pref, rate.expand(*pref.shape[:-1], 1)], -1)
    c = evidence.prior_strength
    # the type's habit: what it did in the same state before the robot's move, whatever
    # the move (counts by x_before), restricted to what is possible after this move, with
    # the chain preference as its own prior
    before = torch.zeros(K, X, H + 1, dtype=dtype, device=sdev)
    flat = (y * X + s_k) * (H + 1) + h_k
    before.view(-1).index_add_(0, flat, torch.ones_like(flat, dtype=dtype))
    possible = torch.cat([legal_f, legal_f.amax(-1, keepdim=True)], -1)  # (A, X, H + 1)
    habit = before.unsqueeze(1) * possible + HABIT_CHAIN_STRENGTH * chain  # (K, A, X, H + 1)
    habit = habit / habit.sum(-1, keepdim=True).clamp_min(1e-300)
    # ... mixed, per type, with what the type did after the same robot move anywhere
    u_k, unusual = _unusual_moves(before, effect.shape[0], a_k, s_k, y)
    one = torch.nn.functional.one_hot(h_k, H + 1).to(dtype)  # (n, H + 1) the step itself
    own = _left_out_habit(before, chain, possible, a_k, s_k, y, one)  # (n, H + 1)
    rho, react = _reaction(K, possible, a_k, s_k, y, h_k, one, own, u_k)
    d = _offscript_lift(u_k, y, one[:, H] - own[:, H], K)  # (K,)
    if want_reaction:
        return torch.stack([rho, d])  # (2, K)
    react = torch.where(react.sum(-1, keepdim=True) > 0, react, habit)  # (none possible)
    mixed = rho.view(K, 1, 1, 1) * unusual.unsqueeze(-1)  # (K, A, X, 1)
    habit = (1.0 - mixed) * habit + mixed * react
    # ... and its share of turns let pass raised by its lift, by how unusual the move was
    u = unusual.unsqueeze(-1)  # (K, A, X, 1)
    passed = habit[..., H:]
    acts = habit[..., :H]
    new_pass = (passed + u * d.view(K, 1, 1, 1)).clamp(0.0, 1.0)
    mended = torch.cat([acts * ((1.0 - new_pass) / (1.0 - passed).clamp_min(1e-300)), new_pass], -1)
    # where an action is possible (so is letting the turn pass)
    some = (possible[..., H:].unsqueeze(0) > 0) & (acts.sum(-1, keepdim=True) > 0)
    habit = torch.where(some, mended, habit)
    # the population: every type's counts in the state after the move, with the types'
    # habits (weighted by their sizes) as its prior
    size = torch.bincount(evidence.assignments.to(sdev), minlength=K).to(dtype)
    size = (size / size.sum().clamp_min(1.0)).view(K, 1, 1, 1)
    population = counts.sum(0)[effect] + c * (size * habit).sum(0)  # (A, X, H + 1)
    population = population / population.sum(-1, keepdim=True).clamp_min(1e-300)
    w = evidence.habit_weight
    prior = w * habit + (1.0 - w) * population  # (K, A, X, H + 1)
    return (counts[:, effect] + c * prior).to(device)  # (K, A, X, H + 1)


#: The grid of a type's weight on its reaction to the robot's move (:func:`_reaction`).
REACTION_GRID: tuple[float, ...] = tuple(i / 20 for i in range(21))


def _unusual_moves(
    before: torch.Tensor, A: int, a_k: torch.Tensor, s_k: torch.Tensor, y: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """How unusual each robot move was for a type's partners in a state.

    ``u[y, a, x]``: one less the share of type ``y``'s partners' moves in ``x`` that were
    ``a`` (1 where they never came). ``u_k``: the same for each kept step's own move, the
    step left out (its partners' other moves there; 1 for a state visited once).

    Args:
        before: ``(K, X, H + 1)`` the types' counts by the state before the robot's move;
            A: the robot's actions; a_k, s_k, y: ``(n,)`` the kept steps' robot moves,
            states before them and types (:func:`_state_counts`).

    Returns:
        ``u_k (n,)`` over the kept steps and ``u (K, A, X)``.
    """
    dtype, dev = before.dtype, before.device
    K, X = before.shape[:2]
    moves = torch.zeros(K, X, A, dtype=dtype, device=dev)
    moves.view(-1).index_add_(0, (y * X + s_k) * A + a_k, torch.ones_like(a_k, dtype=dtype))
    visits = before.sum(-1)  # (K, X) the same steps by their state before the move
    rest = (visits[y, s_k] - 1.0).clamp_min(0.0)
    u_k = torch.where(rest > 0, 1.0 - (moves[y, s_k, a_k] - 1.0) / rest.clamp_min(1.0), 1.0)
    share = moves.transpose(1, 2) / visits.unsqueeze(1).clamp_min(1.0)  # (K, A, X)
    unusual = torch.where(visits.unsqueeze(1) > 0, 1.0 - share, torch.ones_like(share))
    return u_k, unusual


def _left_out_habit(before: torch.Tensor, chain: torch.Tensor, possible: torch.Tensor,
                    a_k: torch.Tensor, s_k: torch.Tensor, y: torch.Tensor,
                    one: torch.Tensor) -> torch.Tensor:  # fmt: skip
    """``(n, H + 1)`` each kept step's habit with the step left out: what its type did in
    the step's state before the robot's move, over the actions possible after the move,
    with the chain prior (strength :data:`HABIT_CHAIN_STRENGTH`), normalised
    (:func:`_state_counts`; ``a_k``, ``s_k``, ``y``: the steps' robot moves, states and
    types; ``one`` ``(n, H + 1)``: their own actions)."""
    b = (before[y, s_k] - one) * possible[a_k, s_k] + HABIT_CHAIN_STRENGTH * chain[y, a_k, s_k]
    return b / b.sum(-1, keepdim=True).clamp_min(1e-300)


def _offscript_lift(u_k: torch.Tensor, y: torch.Tensor, excess: torch.Tensor,
                    K: int) -> torch.Tensor:  # fmt: skip
    """``d (K,)``: how many more turns each type let pass after moves off its partners'
    script than its habit predicts there.

    ``d_y = (sum_k u_k e_k + s d) / (sum_k u_k + s)`` over the type's kept steps ``k``,
    each weighted by how unusual its move was for the type's partners there (``u_k``,
    :func:`_unusual_moves`), where ``e_k`` is 1 for a turn let pass (else 0) less the
    type's habit's share of passes in the step's state, the step left out
    (:func:`_left_out_habit`); shrunk by ``s`` turns (:data:`OFFSCRIPT_STRENGTH`) toward
    the lift of all types ``d = sum e u / (sum u + s)`` over every kept step, itself
    shrunk toward 0. People who keep their pace after a slip have ``d`` near 0; people who
    stand and wait after a slip where they otherwise act, well above. Toward the pooled
    lift, not toward 0: the types' own slips are few, and lifts that differ by sampling
    alone make a pass after an odd move false evidence of the type (``pad_sides``: every
    type waits 3 turns in 5 for a part on the wrong pad; shrunk toward 0 its learned types
    lifted 0.21, 0.13 and 0.00, and the type-aware robot fell behind the pooled one).

    Args:
        u_k: ``(n,)`` the kept steps' unusualness; y: ``(n,)`` int64 their types;
            excess: ``(n,)`` ``e_k``; K: the number of types.

    Returns:
        ``(K,)`` lifts in ``[-1, 1]``.
    """
    dtype, dev = u_k.dtype, u_k.device
    num = torch.zeros(K, dtype=dtype, device=dev).index_add_(0, y, u_k * excess)
    den = torch.zeros(K, dtype=dtype, device=dev).index_add_(0, y, u_k)
    pooled = num.sum() / (den.sum() + OFFSCRIPT_STRENGTH)
    return (num + OFFSCRIPT_STRENGTH * pooled) / (den + OFFSCRIPT_STRENGTH)


def _reaction(
    K: int, possible: torch.Tensor, a_k: torch.Tensor, s_k: torch.Tensor, y: torch.Tensor,
    h_k: torch.Tensor, one: torch.Tensor, own: torch.Tensor, u_k: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """Each type's reaction to the robot's move and the weight its own steps give it.

    ``react[y, a, x]``: what type ``y`` did after robot move ``a``, in any state (counts by
    ``(y, a)`` with one pseudo-count spread over the actions possible after the move,
    restricted to them). ``rho_y``: the weight on the grid :data:`REACTION_GRID` of
    ``u rho react + (1 - u rho) habit`` that predicts type ``y``'s own steps best, each
    step left out of the counts, under a Beta(1, 2) prior (the habit unless the steps say
    otherwise). ``u[y, a, x]`` is how unusual move ``a`` was for type ``y``'s partners in
    ``x`` (:func:`_unusual_moves`; ``u_k`` for each step's own move, the step left out):
    the habit is what the type did after its partners' usual move, and the reaction is
    what it did after the same move elsewhere, so only the steps after a move its partners
    rarely made can tell them apart, and only there does the reaction enter. A person who
    keeps to her own next step after such a move (``fetch_order``: she assembles her next
    part whatever was fetched) keeps ``rho`` at 0; one who answers it (hands back a tool she
    did not want, does nothing while the robot waits) raises it.

    Args:
        K: the number of types.
        possible: ``(A, X, H + 1)`` the actions possible after each move (the last column:
            "no action", possible where any action is).
        a_k, s_k, y: ``(n,)`` the kept steps' robot moves, states before them and types
            (:func:`_state_counts`); h_k: ``(n,)`` their human actions' columns, one
            ``(n, H + 1)`` the same one-hot; own: ``(n, H + 1)`` their habits, each left out
            (:func:`_left_out_habit`); u_k: ``(n,)`` their unusualness
            (:func:`_unusual_moves`).

    Returns:
        ``rho (K,)`` and ``react (K, A, X, H + 1)`` (rows over the possible actions, each
        summing to 1; all zero where no action is possible).
    """
    dtype, dev = own.dtype, own.device
    A, H1 = possible.shape[0], own.shape[-1]
    counts = torch.zeros(K, A, H1, dtype=dtype, device=dev)
    counts.view(-1).index_add_(0, (y * A + a_k) * H1 + h_k, torch.ones_like(h_k, dtype=dtype))
    poss = possible[a_k, s_k]  # (n, H + 1)
    spread = poss / poss.sum(-1, keepdim=True).clamp_min(1.0)
    # each step under each part, left out of its counts
    r = (counts[y, a_k] - one) * poss + spread
    p_react = (r * one).sum(-1) / r.sum(-1).clamp_min(1e-300)
    p_habit = (own * one).sum(-1)
    grid = torch.tensor(REACTION_GRID, dtype=dtype, device=dev)
    mix = (grid.view(-1, 1) * u_k) * p_react + (1.0 - grid.view(-1, 1) * u_k) * p_habit
    score = torch.zeros(grid.numel(), K, dtype=dtype, device=dev)
    score.index_add_(1, y, mix.clamp_min(1e-300).log())
    score = score + (1.0 - grid).clamp_min(1e-300).log().view(-1, 1)  # the Beta(1, 2) prior
    rho = grid[score.argmax(0)]  # (K,): the first best, the smallest weight on ties
    spread_all = possible / possible.sum(-1, keepdim=True).clamp_min(1.0)  # (A, X, H + 1)
    react = counts[:, :, None, :] * possible + spread_all  # (K, A, X, H + 1)
    react = react / react.sum(-1, keepdim=True).clamp_min(1e-300)
    return rho, react


def reaction_weights(task: CollaborativeTask, evidence: TypeEvidence) -> torch.Tensor:
    """``(K,)`` each type's weight on its reaction to the robot's move in the state model's
    back-off (:func:`_reaction`; ``info["human_model"]["reaction"]`` records it).

    Args:
        task: the task; evidence: its :class:`TypeEvidence` with ``steps``.

    Returns:
        ``(K,)`` float64 weights in ``[0, 1]``, from :data:`REACTION_GRID`.
    """
    return _back_off_weights(task, evidence)[0]


def offscript_lifts(task: CollaborativeTask, evidence: TypeEvidence) -> torch.Tensor:
    """``(K,)`` each type's off-script lift: how many more of its turns it let pass after its
    partners' unusual moves than its habit predicts in the same states, which the state
    model's back-off adds to its "no action" after a move the type's partners rarely made
    (:func:`_offscript_lift`; ``info["human_model"]["offscript_lift"]`` records it).

    Args:
        task: the task; evidence: its :class:`TypeEvidence` with ``steps``.

    Returns:
        ``(K,)`` float64 lifts in ``[-1, 1]``.

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> from torchhrc.tasks.pipeline import learn
        >>> world = make_task("pace")
        >>> demos, _ = world.demonstrations(subjects=9, per_subject=2, seed=0)
        >>> lifts = learn(world.task, demos, k=3, solver_time=0.2, seed=0).info[
        ...     "human_model"]["offscript_lift"]
        >>> len(lifts), all(-1.0 <= d <= 1.0 for d in lifts)
        (3, True)
    """
    return _back_off_weights(task, evidence)[1]


def _back_off_weights(task: CollaborativeTask, evidence: TypeEvidence) -> torch.Tensor:
    if evidence.steps is None:
        raise ValueError("expected evidence.steps (the demonstrations as task steps), got None")
    return _state_counts(task, evidence, torch.float64, torch.device("cpu"), want_reaction=True)


def _listed(names: Sequence[str]) -> str:
    """``"0: wait, 1: fetch_A, ..."``: the indices of an action list, for an error."""
    return ", ".join(f"{i}: {n}" for i, n in enumerate(names))


def _table(name: str, value: Any, shape: tuple[int, ...], kind: str) -> torch.Tensor:
    try:
        t = torch.as_tensor(value)
    except Exception as exc:
        raise TypeError(f"expected {name} to be a tensor of shape {shape}, got {value!r}") from exc
    if tuple(t.shape) != shape:
        raise ModelError(f"expected {name} of shape {shape}, got {tuple(t.shape)}")
    if kind == "index" and (t.is_floating_point() or t.dtype == torch.bool):
        raise TypeError(f"expected {name} to have an integer dtype, got {t.dtype}")
    if kind == "bool" and t.dtype != torch.bool:
        raise TypeError(f"expected {name} to have dtype torch.bool, got {t.dtype}")
    return t


def reachable_states(task: CollaborativeTask) -> torch.Tensor:
    """``(X,)`` bool: the states reachable from ``x0`` under every robot action and every
    human response legal after it (or none).

    Example:
        >>> class Line(CollaborativeTask):
        ...     state_names, robot_actions, human_actions = ("a", "b", "c"), ("go",), ("back",)
        ...     robot_effect = torch.tensor([[1, 1, 2]])        # go: a -> b
        ...     human_effect = torch.tensor([[0], [0], [2]])    # back: b -> a
        >>> reachable_states(Line()).tolist()
        [True, True, False]
    """
    robot = torch.as_tensor(task.robot_effect).to(torch.long).cpu()  # (A, X)
    human = torch.as_tensor(task.human_effect).to(torch.long).cpu()  # (X, H)
    legal = torch.as_tensor(task.human_legal).to(torch.bool).cpu()  # (X, H)
    X = task.num_states
    seen = torch.zeros(X, dtype=torch.bool)
    seen[task.initial_state] = True
    while True:  # at most X rounds of one tensor step each
        mid = torch.zeros(X, dtype=torch.bool)
        mid[robot[:, seen].flatten()] = True
        rows = mid.nonzero().flatten()
        grown = seen | mid
        grown[human[rows][legal[rows]]] = True
        if torch.equal(grown, seen):
            return seen
        seen = grown


def check_task(task: CollaborativeTask) -> None:
    """Validate a task's tables; raise a clear error naming the bad piece.

    Checks: names are non-empty; ``robot_effect (A, X)`` and ``human_effect (X, H)`` are
    integer tables of states in ``[0, X)``; ``human_legal (X, H)`` and ``terminal (X,)``
    bool; ``x0`` in range; ``features()`` of shape ``(A, X, F)``, finite, with
    ``len(feature_names) == F``. Then the task's reach from ``x0``
    (:func:`reachable_states`): a human action that can happen nowhere (a human ``"wait"``
    listed among the actions), a task where no action changes any reachable state, and
    terminal states none of which is reachable are errors; unreachable states are a
    :class:`TaskWarning` naming them (they are solved for nothing).

    Raises:
        ModelError: a table has the wrong shape or an out-of-range entry, a human action is
            never legal, nothing changes the state, or no terminal state is reachable.
        TypeError: a table has the wrong kind.

    Warns:
        TaskWarning: states that cannot be reached from ``x0`` (once per task object).

    Example:
        >>> class Bad(CollaborativeTask):
        ...     state_names, robot_actions, human_actions = ("s",), ("wait",), ("go",)
        ...     robot_effect = torch.tensor([[0]])
        ...     human_effect = torch.tensor([[1]])
        >>> check_task(Bad())
        Traceback (most recent call last):
        ...
        torchhrc.errors.ModelError: human_effect[0, 0] = 1 is not a state index in [0, 1)
    """
    for name in ("state_names", "robot_actions", "human_actions"):
        names = getattr(task, name, None)
        if names is None or len(names) == 0:
            raise ModelError(f"expected the task's {name} to be a non-empty sequence of names")
    X, A, H = task.num_states, task.num_actions, task.num_human_actions
    for name, shape in (("robot_effect", (A, X)), ("human_effect", (X, H))):
        t = _table(name, getattr(task, name), shape, "index")
        bad = (t < 0) | (t >= X)
        if bad.any():
            i = tuple(torch.nonzero(bad)[0].tolist())
            raise ModelError(
                f"{name}[{', '.join(map(str, i))}] = {int(t[i])} is not a state index in [0, {X})"
            )
    _table("human_legal", task.human_legal, (X, H), "bool")
    _table("terminal", task.terminal, (X,), "bool")
    x0 = task.initial_state
    if not isinstance(x0, int) or not 0 <= x0 < X:
        raise ModelError(f"expected initial_state in [0, {X}), got {x0!r}")
    phi = task.features()
    if not isinstance(phi, torch.Tensor) or phi.dim() != 3 or tuple(phi.shape[:2]) != (A, X):
        shape = tuple(phi.shape) if isinstance(phi, torch.Tensor) else type(phi).__name__
        raise ModelError(f"expected features() of shape (A={A}, X={X}, F), got {shape}")
    if not phi.is_floating_point() or not torch.isfinite(phi).all():
        raise ModelError("expected features() to be finite floating-point values")
    if len(task.feature_names) != phi.shape[-1]:
        raise ModelError(
            f"expected {phi.shape[-1]} feature_names (F of features()), "
            f"got {len(task.feature_names)}"
        )
    if not 0.0 < float(task.discount) < 1.0:
        raise ModelError(f"expected discount in (0, 1), got {task.discount}")
    _check_reach(task)


#: id(task) -> weak reference, for the tasks whose unreachable states were reported (the
#: pipeline checks a task more than once per learn() call; one warning is enough).
_REPORTED: dict[int, Any] = {}


def _first_report(task: CollaborativeTask) -> bool:
    import weakref

    key = id(task)
    ref = _REPORTED.get(key)
    if ref is not None and ref() is task:
        return False
    try:
        _REPORTED[key] = weakref.ref(task, lambda _, key=key: _REPORTED.pop(key, None))
    except TypeError:  # not weakly referenceable: report every time
        pass
    return True


def _check_reach(task: CollaborativeTask) -> None:
    import warnings

    legal = torch.as_tensor(task.human_legal).cpu()
    never = (~legal.any(0)).nonzero().flatten().tolist()
    if never:
        name = task.human_actions[never[0]]
        hint = (
            f"leave it out of human_actions: a human {name!r} in the demonstrations reads as "
            "no action (the human lets the turn pass)"
            if name in IDLE_HUMAN_NAMES
            else "fix human_effect (or human_legal), or leave the action out"
        )
        raise ModelError(
            f"human action {name!r} can happen in no state (human_legal is False everywhere: "
            f"it changes no state); {hint}"
        )
    reach = reachable_states(task)
    X = task.num_states
    robot = torch.as_tensor(task.robot_effect).cpu()
    human = torch.as_tensor(task.human_effect).cpu()
    moves = (robot[:, reach] != torch.arange(X)[reach]).any() or (
        (human[reach] != torch.arange(X)[reach].view(-1, 1)) & legal[reach]
    ).any()
    if not moves:
        raise ModelError(
            "no robot or human action changes any state reachable from initial_state "
            f"{task.state_names[task.initial_state]!r}: the task cannot progress; check "
            "robot_effect and human_effect (x' = human_effect[robot_effect[a, x], h])"
        )
    terminal = torch.as_tensor(task.terminal).cpu()
    if terminal.any() and not (terminal & reach).any():
        raise ModelError(
            "no terminal state is reachable from initial_state "
            f"{task.state_names[task.initial_state]!r} (terminal: "
            f"{', '.join(task.state_names[i] for i in terminal.nonzero().flatten()[:5].tolist())}"
            "): episodes never end; check robot_effect, human_effect and terminal"
        )
    if not reach.all() and _first_report(task):
        lost = (~reach).nonzero().flatten().tolist()
        shown = ", ".join(repr(task.state_names[i]) for i in lost[:5])
        more = f" and {len(lost) - 5} more" if len(lost) > 5 else ""
        warnings.warn(
            f"{len(lost)} of {X} states cannot be reached from initial_state "
            f"{task.state_names[task.initial_state]!r} under any robot action and legal "
            f"human action: {shown}{more}. They cost solver time for nothing: leave them out "
            "of state_names (or check robot_effect and human_effect if they should be "
            "reachable); torchhrc.tasks.reachable_states(task) lists them",
            TaskWarning,
            stacklevel=3,
        )
