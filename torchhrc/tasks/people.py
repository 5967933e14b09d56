"""Simulated people of known types: the ground truth a task suite and an evaluation need.

A :class:`SimulatedPeople` is the human side of a :class:`~torchhrc.tasks.CollaborativeTask`
with known (true) types, batched over ``B`` episodes: after the robot's move it picks the
human's response from the type, the state and a per-episode memory (so behaviour may depend
on history: a person who lags every other turn, who mirrors the robot's previous move, ...).
A :class:`TaskWithPeople` bundles a task, its people, the true reward of the robot's actions
per type and the episode horizon; it generates demonstrations (joint human/robot sequences
with the true type of each) and is what an evaluation scores robots against.

:class:`TabularPeople` is the general table-driven implementation: per type ``y`` and
memory state ``m`` a policy ``P(a_h | m, x_mid, a_r, y)`` and a memory update
``m' = update[y, m, x_mid, a_r, a_h]`` (``M`` memory states, one memory column).

Example:
    >>> import torch
    >>> legal = torch.tensor([[True, True], [True, False]])       # (X=2, H=2)
    >>> policy = torch.zeros(1, 1, 2, 1, 3)                        # (Y, M, X, A, H + 1)
    >>> policy[..., 1] = 1.0                                       # always h = 1 ...
    >>> policy[0, 0, 1, 0] = torch.tensor([1.0, 0.0, 0.0])         # ... but h = 0 in x = 1
    >>> people = TabularPeople(("solo",), policy, legal)
    >>> g = torch.Generator().manual_seed(0)
    >>> types = torch.zeros(2, dtype=torch.long)
    >>> h, m = people.act(types, torch.tensor([0, 1]), torch.tensor([0, 0]),
    ...                   people.initial_memory(types, g), g)
    >>> h.tolist()
    [1, 0]
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import torch

from torchhrc.errors import ModelError

if TYPE_CHECKING:
    from torchhrc.data import Demonstrations
    from torchhrc.tasks.interface import CollaborativeTask

__all__ = ["SimulatedPeople", "TabularPeople", "TaskWithPeople", "sample_legal"]


@runtime_checkable
class SimulatedPeople(Protocol):
    """Simulated people of known (true) types for one CollaborativeTask, batched over ``B``
    episodes.

    Behaviour may depend on the state and on history: per-episode memory is an int64 tensor.
    People that can also give their turn as tables (``turn_tables(noise)``, as
    :class:`TabularPeople`) can be written down as a MOMDP
    (:func:`~torchhrc.tasks.true_model.true_momdp`), the reference of
    ``evaluate_task(true_model=True)``.

    Attributes:
        num_types: ``Y_true``.
        type_names: ``(Y_true,)`` human-readable names of the types.
    """

    num_types: int
    type_names: tuple[str, ...]

    def initial_memory(self, types: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """``types (B,)`` int64 in ``[0, Y_true)`` -> memory ``(B, M)`` int64 (``M >= 0``
        columns, may be 0)."""
        ...

    def act(
        self,
        types: torch.Tensor,
        x_mid: torch.Tensor,
        robot_action: torch.Tensor,
        memory: torch.Tensor,
        generator: torch.Generator,
        *,
        noise: float = 0.0,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One human turn after the robot's move, batched.

        Args:
            types: ``(B,)`` true types.
            x_mid: ``(B,)`` the state after the robot's action (``task.robot_effect[a_r, x]``).
            robot_action: ``(B,)`` the robot's action.
            memory: ``(B, M)``.
            generator: the random stream.
            noise: with this probability the person takes a uniformly random legal action
                instead (the paper's epsilon).

        Returns:
            ``(human_action (B,)`` int64 in ``[0, H)`` or ``-1`` for no action, ``new memory
            (B, M))``; only actions legal in ``x_mid``.
        """
        ...


def sample_legal(legal: torch.Tensor, x: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """A uniformly random legal human action per episode, ``-1`` where none is legal.

    Args:
        legal: ``(X, H)`` bool ``human_legal``.
        x: ``(B,)`` states.
        generator: the random stream (one draw per episode, whatever the states).

    Returns:
        ``(B,)`` int64.

    Example:
        >>> legal = torch.tensor([[False, True], [False, False]])
        >>> sample_legal(legal, torch.tensor([0, 1]), torch.Generator()).tolist()
        [1, -1]
    """
    rows = legal[x].to(torch.float64)  # (B, H)
    none = rows.sum(-1, keepdim=True) == 0
    weights = torch.cat([rows, none.to(rows.dtype)], -1)  # (B, H + 1), last: nothing legal
    pick = torch.multinomial(weights, 1, generator=generator).squeeze(-1)
    return torch.where(pick == legal.shape[-1], -1, pick)


class TabularPeople:
    """People given by tables: a policy and a memory update per type and memory state.

    ``P(a_h | m, x_mid, a_r, y) = policy[y, m, x_mid, a_r, a_h]`` (last column of ``a_h``:
    no action), then ``m' = update[y, m, x_mid, a_r, a_h]`` (``a_h = -1`` reads the last
    column). The memory is one int64 column in ``[0, M)`` drawn at the start of an episode
    from ``initial[y]``. With ``M = 1`` the behaviour depends on the state only.

    Args:
        type_names: ``(Y,)`` names.
        policy: ``(Y, M, X, A, H + 1)`` probabilities, rows summing to 1, no mass on human
            actions illegal in ``x_mid`` (``legal``).
        legal: ``(X, H)`` bool, the task's ``human_legal``.
        update: ``(Y, M, X, A, H + 1)`` int64 next memory state (default: all 0).
        initial: ``(Y, M)`` probabilities of the first memory state (default: state 0).
        task: the :class:`~torchhrc.tasks.CollaborativeTask` the tables belong to (optional):
            its ``state_names``, ``robot_actions`` and ``human_actions`` name the entry in an
            error (without it, the error gives indices).

    Raises:
        ModelError: shapes disagree, rows do not sum to 1, mass on an illegal action, or a
            memory state out of range.

    Example:
        >>> legal = torch.tensor([[True]])
        >>> p = TabularPeople(("a", "b"), torch.tensor([1.0, 0.0]).expand(2, 1, 1, 1, 2), legal)
        >>> p.num_types, p.num_memory
        (2, 1)
    """

    def __init__(
        self,
        type_names: Sequence[str],
        policy: torch.Tensor,
        legal: torch.Tensor,
        *,
        update: torch.Tensor | None = None,
        initial: torch.Tensor | None = None,
        task: CollaborativeTask | None = None,
    ) -> None:
        policy = torch.as_tensor(policy, dtype=torch.float64)
        legal = torch.as_tensor(legal)
        if policy.dim() != 5:
            raise ModelError(
                f"expected policy of shape (Y, M, X, A, H + 1), got {tuple(policy.shape)}"
            )
        Y, M, X, A, H1 = policy.shape
        names = tuple(str(n) for n in type_names)
        if len(names) != Y:
            raise ModelError(f"expected {Y} type_names (Y of policy), got {len(names)}")
        if legal.dim() == 2 and tuple(legal.shape) == (X, H1):
            raise ModelError(
                f"expected policy of shape (Y, M, X, A, H + 1) = (..., {H1 + 1}) for legal's "
                f"H = {H1} human actions: the last column is 'no action'; got "
                f"{tuple(policy.shape)}"
            )
        if legal.dtype != torch.bool or tuple(legal.shape) != (X, H1 - 1):
            raise ModelError(
                f"expected legal of shape (X={X}, H={H1 - 1}) bool, got "
                f"{tuple(legal.shape)} {legal.dtype}"
            )
        if (policy < 0).any() or not torch.allclose(
            policy.sum(-1), torch.ones((), dtype=policy.dtype), atol=1e-9
        ):
            raise ModelError("expected policy rows (last dim) of non-negative values summing to 1")
        illegal = (policy[..., :-1] > 0) & ~legal.view(1, 1, X, 1, H1 - 1)
        if illegal.any():
            y, m, x, a, h = torch.nonzero(illegal)[0].tolist()
            where = ""
            if task is not None:  # the task's names for the indices
                where = (f" (human action {task.human_actions[h]!r} in state "
                         f"{task.state_names[x]!r}, after robot action "
                         f"{task.robot_actions[a]!r})")  # fmt: skip
            raise ModelError(
                f"policy[{y}, {m}, {x}, {a}, {h}] > 0 (type {names[y]!r}) but human action "
                f"{h} is illegal in state {x} (legal[{x}, {h}] is False){where}; policy's x "
                "is the state after the robot's move, x_mid = robot_effect[a_r, x]: give that "
                "action no mass there, or make it legal in the task's human_legal"
            )
        if update is None:
            update = torch.zeros(Y, M, X, A, H1, dtype=torch.long)
        update = torch.as_tensor(update)
        if tuple(update.shape) != (Y, M, X, A, H1) or update.is_floating_point():
            raise ModelError(
                f"expected update of shape {(Y, M, X, A, H1)} int64, got {tuple(update.shape)}"
            )
        if ((update < 0) | (update >= M)).any():
            raise ModelError(f"expected update entries in [0, M={M})")
        if initial is None:
            initial = torch.zeros(Y, M, dtype=torch.float64)
            initial[:, 0] = 1.0
        initial = torch.as_tensor(initial, dtype=torch.float64)
        if tuple(initial.shape) != (Y, M) or (initial < 0).any():
            raise ModelError(f"expected initial of shape (Y={Y}, M={M}), non-negative")
        if not torch.allclose(initial.sum(-1), torch.ones((), dtype=initial.dtype), atol=1e-9):
            raise ModelError("expected initial rows summing to 1")
        self.type_names: tuple[str, ...] = names
        self.num_types: int = Y
        self.policy = policy
        self.legal = legal
        self.update = update.to(torch.long)
        self.initial = initial

    @property
    def num_memory(self) -> int:
        """``M``, memory states."""
        return int(self.policy.shape[1])

    def turn_tables(self, noise: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The people's turn as tables, with their ``noise`` mixed in: what
        :func:`~torchhrc.tasks.true_model.true_momdp` reads.

        Returns:
            ``(probs, update, initial)``: ``probs (Y, M, X, A, H + 1)`` the probability of
            each turn (last column: no action), ``(1 - noise) policy + noise u``, ``u``
            uniform over the human actions legal in ``x_mid`` (no action where none is
            legal), as :meth:`act` draws; ``update`` and ``initial`` as given.

        Example:
            >>> legal = torch.tensor([[True, False]])
            >>> people = TabularPeople(("idle",), torch.tensor([[[[[0.0, 0.0, 1.0]]]]]), legal)
            >>> people.turn_tables(0.1)[0][0, 0, 0, 0].tolist()
            [0.1, 0.0, 0.9]
        """
        if not 0.0 <= noise <= 1.0:
            raise ValueError(f"expected noise in [0, 1], got {noise}")
        rows = self.legal.to(torch.float64)  # (X, H)
        none = (rows.sum(-1, keepdim=True) == 0).to(rows.dtype)
        uniform = torch.cat([rows, none], -1)
        uniform = uniform / uniform.sum(-1, keepdim=True)  # (X, H + 1)
        probs = (1.0 - noise) * self.policy + noise * uniform.view(1, 1, *uniform.shape[:1], 1, -1)
        return probs, self.update, self.initial

    def initial_memory(self, types: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """``(B, 1)`` int64 memory drawn from ``initial[types]`` (one draw per episode)."""
        rows = self.initial[types.to(torch.long)]  # (B, M)
        return torch.multinomial(rows, 1, generator=generator)

    def act(
        self,
        types: torch.Tensor,
        x_mid: torch.Tensor,
        robot_action: torch.Tensor,
        memory: torch.Tensor,
        generator: torch.Generator,
        *,
        noise: float = 0.0,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One human turn (see :class:`SimulatedPeople`); the same number of random draws
        whatever ``noise``, so runs at different noise share their streams."""
        if not 0.0 <= noise <= 1.0:
            raise ValueError(f"expected noise in [0, 1], got {noise}")
        m = memory[:, 0]
        rows = self.policy[types, m, x_mid, robot_action]  # (B, H + 1)
        H = rows.shape[-1] - 1
        chosen = torch.multinomial(rows, 1, generator=generator).squeeze(-1)
        chosen = torch.where(chosen == H, -1, chosen)
        random = sample_legal(self.legal, x_mid, generator)
        slip = torch.rand(x_mid.shape, generator=generator, dtype=torch.float64) < noise
        human = torch.where(slip, random, chosen)
        column = torch.where(human < 0, H, human)
        new_m = self.update[types, m, x_mid, robot_action, column]
        return human, new_m.unsqueeze(-1)


def population_shares(shares: Sequence[float] | torch.Tensor | None, Y: int) -> torch.Tensor:
    """``(Y,)`` float64 population weights summing to 1 (equal when ``shares`` is None): how
    :func:`~torchhrc.tasks.evaluate_task` and :func:`~torchhrc.tasks.true_model.true_momdp`
    read a ``shares`` argument.

    Raises:
        TypeError: ``shares`` not numbers.
        ValueError: not ``Y`` of them, or negative, not finite or all zero.

    Example:
        >>> population_shares([3, 1], 2).tolist()
        [0.75, 0.25]
    """
    if shares is None:
        return torch.full((Y,), 1.0 / Y, dtype=torch.float64)
    try:
        w = torch.as_tensor(shares, dtype=torch.float64).detach().cpu()
    except (TypeError, ValueError) as err:
        raise TypeError(f"expected shares to be a sequence of {Y} numbers, got {shares!r}") from err
    if tuple(w.shape) != (Y,):
        raise ValueError(f"expected shares of shape (Y={Y},) (one per true type), "
                         f"got shape {tuple(w.shape)}")  # fmt: skip
    if not bool(torch.isfinite(w).all()) or bool((w < 0).any()) or float(w.sum()) <= 0:
        raise ValueError(f"expected shares to be finite, non-negative and not all zero, "
                         f"got {w.tolist()}")  # fmt: skip
    return w / w.sum()


def _split(subjects: int, shares: Sequence[float]) -> list[int]:
    """Subjects per type in proportion to ``shares``: the floors of ``subjects * share``
    (at least one for a positive share), then one more to the largest remainders until
    there are ``subjects`` (or, where the ones given to small shares made too many, one less
    from the largest counts).

    Example:
        >>> _split(30, (0.35, 0.25, 0.20, 0.12, 0.08))
        [11, 7, 6, 4, 2]
        >>> _split(3, (0.9, 0.05, 0.05))
        [1, 1, 1]
    """
    positive = sum(1 for s in shares if s > 0)
    if subjects < positive:
        raise ValueError(f"expected subjects >= {positive} (one per type with a positive "
                         f"share), got {subjects}")  # fmt: skip
    raw = [subjects * s / sum(shares) for s in shares]
    counts = [max(1, math.floor(r)) if s > 0 else 0 for r, s in zip(raw, shares)]
    order = sorted(range(len(raw)), key=lambda y: raw[y] - math.floor(raw[y]), reverse=True)
    for y in order:
        if sum(counts) < subjects and shares[y] > 0:
            counts[y] += 1
    while sum(counts) > subjects:
        counts[max(range(len(counts)), key=lambda y: counts[y])] -= 1
    return counts


@dataclass(frozen=True, eq=False)
class TaskWithPeople:
    """A task with simulated people of known types: what a suite entry returns (a user can
    build one for their own task).

    Attributes:
        task: the :class:`~torchhrc.tasks.CollaborativeTask`.
        people: its :class:`SimulatedPeople` (``Y_true`` types).
        true_reward: ``(A, X, Y_true)`` float64, the reward of robot action ``a`` in state
            ``x`` for a person of true type ``y``.
        horizon: episode length cap (steps) for evaluation and demonstrations.
        observed: True when the task has noisy observations of the human
            (``task.observation`` is not None).
        demo_robot: ``(Y_true, X, A)`` probabilities of the robot's action in the
            demonstrations per true type (the partner demonstrates the type's preferred
            complementary action); default: the type's best action by ``true_reward`` of
            that step alone, ``argmax_a true_reward[a, x, y]`` (myopic; the first one on
            ties).
        true_observation: ``(A, X, Y_true, O)`` ``P(o | x', y, a_r)`` of the true people when
            ``observed`` (the signal the robot receives after the step), else None.
        description: one line on what distinguishes the types.
        shares: ``(Y_true,)`` how common each true type is among the people (non-negative,
            any positive sum; ``None``: equally common). :meth:`demonstrations` splits its
            subjects by them, and :func:`~torchhrc.tasks.evaluate_task` weighs the types by
            them over the population.

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> twp = make_task("fetch_order")
        >>> demos, y = twp.demonstrations(subjects=4, per_subject=2, seed=0)
        >>> len(demos), y.shape
        (8, torch.Size([8]))
    """

    task: CollaborativeTask
    people: SimulatedPeople
    true_reward: torch.Tensor
    horizon: int
    observed: bool
    demo_robot: torch.Tensor | None = None
    true_observation: torch.Tensor | None = None
    description: str = ""
    shares: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        A, X, Y = self.task.num_actions, self.task.num_states, self.people.num_types
        r = torch.as_tensor(self.true_reward, dtype=torch.float64)
        if tuple(r.shape) != (A, X, Y):
            raise ModelError(f"expected true_reward of shape (A={A}, X={X}, Y={Y}), got "
                             f"{tuple(r.shape)}")  # fmt: skip
        object.__setattr__(self, "true_reward", r)
        if len(self.people.type_names) != Y:
            raise ModelError(f"expected {Y} people.type_names, got {len(self.people.type_names)}")
        if int(self.horizon) < 2:
            raise ModelError(f"expected horizon >= 2, got {self.horizon}")
        if self.demo_robot is not None:
            d = torch.as_tensor(self.demo_robot, dtype=torch.float64)
            if tuple(d.shape) != (Y, X, A) or (d < 0).any():
                raise ModelError(f"expected demo_robot of shape (Y={Y}, X={X}, A={A}), >= 0")
            if not torch.allclose(d.sum(-1), torch.ones((), dtype=d.dtype), atol=1e-9):
                raise ModelError("expected demo_robot rows summing to 1")
            object.__setattr__(self, "demo_robot", d)
        if self.true_observation is not None:
            z = torch.as_tensor(self.true_observation, dtype=torch.float64)
            if z.dim() != 4 or tuple(z.shape[:3]) != (A, X, Y):
                raise ModelError(f"expected true_observation of shape (A={A}, X={X}, Y={Y}, O), "
                                 f"got {tuple(z.shape)}")  # fmt: skip
            object.__setattr__(self, "true_observation", z)
        if self.observed and self.true_observation is None:
            raise ModelError("an observed task needs true_observation (A, X, Y_true, O)")
        if self.shares is not None:
            try:  # the check evaluate_task makes, as this container's ModelError
                population_shares(self.shares, Y)
            except (TypeError, ValueError) as err:
                raise ModelError(str(err)) from err
            object.__setattr__(self, "shares", tuple(float(v) for v in self.shares))

    @property
    def num_types(self) -> int:
        """``Y_true``."""
        return int(self.people.num_types)

    @property
    def type_names(self) -> tuple[str, ...]:
        """``(Y_true,)``."""
        return tuple(self.people.type_names)

    def robot_demo_policy(self) -> torch.Tensor:
        """``(Y_true, X, A)`` the robot's action probabilities in demonstrations."""
        if self.demo_robot is not None:
            return self.demo_robot
        r = self.true_reward.permute(2, 1, 0)  # (Y, X, A)
        # the first best action: ties broken by index, so every partner of a type acts
        # alike (random tie-breaking adds orders a first-order chain reads as extra types)
        best = r.argmax(-1)  # (Y, X)
        return torch.nn.functional.one_hot(best, r.shape[-1]).to(torch.float64)

    def rollout(
        self,
        types: torch.Tensor,
        *,
        noise: float = 0.05,
        generator: torch.Generator,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Batched demonstration episodes (robot by :meth:`robot_demo_policy`, slipping to a
        uniformly random action with probability ``noise``; people with ``noise``).

        Args:
            types: ``(B,)`` true types.

        Returns:
            ``states (B, T + 1)``, ``robot (B, T)``, ``human (B, T)`` int64 (``T = horizon``;
            after a terminal state ``robot = -2`` and ``human = -2`` mark unused steps).
        """
        task = self.task
        robot_effect = torch.as_tensor(task.robot_effect).to(torch.long)
        human_effect = torch.as_tensor(task.human_effect).to(torch.long)
        terminal = torch.as_tensor(task.terminal).to(torch.bool)
        demo = self.robot_demo_policy()
        B, T, A = types.shape[0], int(self.horizon), task.num_actions
        x = torch.full((B,), task.initial_state, dtype=torch.long)
        memory = self.people.initial_memory(types, generator)
        states = torch.full((B, T + 1), -2, dtype=torch.long)
        robot = torch.full((B, T), -2, dtype=torch.long)
        human = torch.full((B, T), -2, dtype=torch.long)
        states[:, 0] = x
        done = terminal[x]
        for t in range(T):  # steps are sequential; the batch is one tensor program
            wanted = torch.multinomial(demo[types, x], 1, generator=generator).squeeze(-1)
            other = torch.randint(A, (B,), generator=generator)
            slip = torch.rand(B, generator=generator, dtype=torch.float64) < noise
            a = torch.where(slip, other, wanted)
            mid = robot_effect[a, x]
            h, new_memory = self.people.act(types, mid, a, memory, generator, noise=noise)
            nxt = torch.where(h >= 0, human_effect[mid, h.clamp_min(0)], mid)
            live = ~done
            robot[:, t] = torch.where(live, a, -2)
            human[:, t] = torch.where(live, h, -2)
            x = torch.where(live, nxt, x)
            memory = torch.where(live.unsqueeze(-1), new_memory, memory)
            states[:, t + 1] = torch.where(live, x, -2)
            done = done | terminal[x]
        return states, robot, human

    def demonstrations(
        self,
        *,
        subjects: int = 30,
        per_subject: int = 4,
        noise: float = 0.05,
        seed: int = 0,
    ) -> tuple[Demonstrations, torch.Tensor]:
        """Demonstrations of ``subjects x per_subject`` sequences and their true types.

        Subject ``s`` (named ``"s000"``, ...) has true type ``s mod Y_true`` (types balanced).
        With :attr:`shares`, type ``y`` has about ``subjects * shares[y]`` subjects (largest
        remainders; at least one for every type with a positive share), the subjects of one
        type in a row. A subject's sequences are named ``"0"``, ``"1"``, .... Each sequence
        alternates the robot's action and the human's response (none when the person lets
        the turn pass) until a terminal state or ``horizon`` steps. Deterministic under
        ``seed``.

        Args:
            subjects: number of subjects (>= 1).
            per_subject: sequences per subject (>= 1).
            noise: the people's epsilon and the demonstrating robot's slip rate.
            seed: seed of the :class:`torch.Generator`.

        Returns:
            ``(demonstrations, types (N,) int64)``: the true type of each of the
            ``N = subjects * per_subject`` sequences (one per demonstration, not per subject;
            a subject's sequences share it, and ``demonstrations.subject_index`` maps each
            sequence to its subject); ``demonstrations.types`` holds the true type names.

        Raises:
            ValueError: a bad size or noise, or fewer subjects than types (than types with
                a positive share, where the world has ``shares``).
        """
        from torchhrc.data import Demonstrations

        if subjects < 1 or per_subject < 1:
            raise ValueError(f"expected subjects, per_subject >= 1, got {subjects}, {per_subject}")
        if not 0.0 <= noise <= 1.0:
            raise ValueError(f"expected noise in [0, 1], got {noise}")
        generator = torch.Generator().manual_seed(int(seed))
        Y = self.num_types
        if self.shares is None:
            if subjects < Y:
                raise ValueError(f"expected subjects >= {Y} (one per type, or a type has no "
                                 f"demonstrations), got {subjects}")  # fmt: skip
            subject_types = torch.arange(subjects) % Y
        else:
            counts = _split(subjects, self.shares)
            subject_types = torch.tensor([y for y, c in enumerate(counts) for _ in range(c)])
        types = subject_types.repeat_interleave(per_subject)  # (N,)
        _, robot, human = self.rollout(types, noise=noise, generator=generator)
        robot_names, human_names = list(self.task.robot_actions), list(self.task.human_actions)
        seqs: list[list[tuple[str, str]]] = []
        for r_row, h_row in zip(robot.tolist(), human.tolist()):
            seq: list[tuple[str, str]] = []
            for a, h in zip(r_row, h_row):
                if a == -2:
                    break
                seq.append(("robot", robot_names[a]))
                if h >= 0:
                    seq.append(("human", human_names[h]))
            if len(seq) < 2:
                raise ModelError(
                    f"a demonstration of {len(seq)} symbol(s) (the task ended after one robot "
                    "action with no human turn); a demonstration needs at least 2"
                )
            seqs.append(seq)
        width = len(str(subjects - 1))
        names = [f"s{s:0{max(width, 3)}d}" for s in range(subjects)]
        subject_ids = [names[s] for s in range(subjects) for _ in range(per_subject)]
        sequence_ids = [str(i) for _ in range(subjects) for i in range(per_subject)]
        labels = [self.type_names[int(y)] for y in types]
        vocab = [("human", h) for h in human_names] + [("robot", a) for a in robot_names]
        demos = Demonstrations.from_lists(
            seqs, subjects=subject_ids, sequence_ids=sequence_ids, types=labels,
            vocabulary=sorted(vocab),
        )  # fmt: skip
        return demos, types
