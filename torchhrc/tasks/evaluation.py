"""Robots against a task's simulated people, scored by the people's true rewards.

:func:`evaluate_task` runs robots (online controllers) against the simulated people of a
:class:`~torchhrc.tasks.people.TaskWithPeople` of known (true) types, and scores every
episode by the TRUE reward of the person's type, ``true_reward[a_r, x, y_true]``, not by the
reward the robot learned:

* the type-aware robot: the learned model's :class:`~torchhrc.tasks.controller.Controller`
  (a belief over the learned types, updated online, paper Eq. 3);
* the type-agnostic robot: the model learned with ``k = 1`` (``learn(task, demos, k=1)``,
  all demonstrations pooled into one type, as the paper's comparison);
* any robots given (anything with ``reset(*, batch=B)`` and ``act(observation)``, as a
  :class:`~torchhrc.tasks.controller.Controller`).

Per robot and true type it reports the mean discounted return ``sum_t gamma^t r_t`` over the
episodes and its 95% confidence half-width ``1.96 s / sqrt(E)``. For the type-aware robot it
also reports how well the online belief identifies the person: the learned type each true
type maps to (by the majority of the training demonstrations' assignments, or else by the
belief's posterior mass), and after ``n`` steps the accuracy (``argmax b == mapped type``)
and the mean largest posterior. A type that the belief cannot tell apart from another in
``n`` steps (its largest posterior stays below ``split_threshold``) is reported ``"split"``,
and one the learning merged with another (two true types on one learned type) ``"merged"``,
instead of a low accuracy counted as a failure.

Episodes are stepped together as tensors: ``E`` episodes per true type, ``B = E * Y_true``
at once; the people draw from one seeded generator per robot (the same seed for every
robot), so that two robots are compared on the same people and draws: the paired difference
of :meth:`TaskEvaluation.difference` and :meth:`TaskEvaluation.compare`.

Example:
    >>> import torchhrc
    >>> from torchhrc.tasks.suite import make_task
    >>> world = make_task("pace")
    >>> demos, _ = world.demonstrations(subjects=6, per_subject=2, seed=0)
    >>> model = torchhrc.learn(world.task, demos, k=3, solver_time=0.5, seed=0)
    >>> result = evaluate_task(world, model, demonstrations=demos, episodes=20,
    ...                        agnostic=False)
    >>> result.mean.shape, result.robots
    (torch.Size([1, 3]), ('type-aware',))
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol

import torch

from torchhrc.errors import ModelError
from torchhrc.tasks.people import population_shares

if TYPE_CHECKING:
    from torchhrc.data import Demonstrations
    from torchhrc.tasks.controller import Controller
    from torchhrc.tasks.people import TaskWithPeople
    from torchhrc.tasks.pipeline import LearnedModel

__all__ = ["Robot", "TaskEvaluation", "evaluate_task", "told_type_controller"]

#: 97.5% quantile of the standard normal: the 95% confidence half-width is ``Z95 s / sqrt(E)``.
Z95 = 1.959963984540054

#: The name of the robot ``told_type=True`` adds: the learned model's optimal robot for the
#: person's type, told it (:func:`told_type_controller`).
TOLD = "told the type"

#: The name of the robot ``true_model=True`` adds: a robot planning on the world's true
#: people, rewards and shares, finding the type online
#: (:func:`~torchhrc.tasks.true_model.true_model_controller`).
TRUE_MODEL = "true model"

#: The names of the robots ``true_parts=True`` adds: the learned model with the people's true
#: behaviour (:func:`~torchhrc.tasks.true_model.true_behaviour_controller`), and with the
#: true rewards (:func:`~torchhrc.tasks.true_model.true_reward_controller`).
TRUE_BEHAVIOUR, TRUE_REWARDS = "true behaviour", "true rewards"


class Robot(Protocol):
    """What :func:`evaluate_task` needs of a robot (a
    :class:`~torchhrc.tasks.controller.Controller` is one)."""

    def reset(self, prior: Any = None, *, batch: int | None = None) -> None:
        """Start ``batch`` episodes."""
        ...

    def act(self, observation: Any) -> Any:
        """``x (B,)`` or ``(x, o)`` -> robot actions ``(B,)`` int64."""
        ...


@dataclass(frozen=True)
class TaskEvaluation:
    """The result of :func:`evaluate_task` (``R`` robots, ``Y`` true types, ``E`` episodes
    per type, ``S`` belief checkpoints, ``K`` learned types).

    Attributes:
        robots: ``(R,)`` robot names (``"type-aware"``, ``"type-agnostic"``, then the given).
        type_names: ``(Y,)`` true type names.
        returns: ``(R, Y, E)`` float64 discounted return of every episode under the true
            reward of its person's type.
        mean: ``(R, Y)`` mean return.
        ci: ``(R, Y)`` 95% confidence half-width of the mean (``1.96 s / sqrt(E)``).
        overall_mean: ``(R,)`` mean return over a population of people: the per-type means
            weighted by ``shares`` (equal shares: the mean of all ``Y * E`` episodes).
        overall_ci: ``(R,)`` its 95% confidence half-width, treating the episodes as people
            drawn from that population (the spread between the types counts:
            ``1.96 sqrt(N / (N - 1) sum_y w_y mean_e (r - m)^2 / N)``, ``N = Y E``; with
            equal shares the plain standard error of the ``N`` returns). To compare two
            robots use :meth:`difference` and :meth:`compare`: their interval is the paired
            one, without the spread between the types or the draws the robots share.
        steps: ``(R, Y)`` mean episode length (steps until a terminal state or the horizon).
        belief_steps: ``(S,)`` the ``n`` at which the type-aware belief is checked.
        type_map: ``(Y,)`` the learned type each true type maps to.
        map_source: ``"assignments"`` (majority of the training demonstrations) or
            ``"posterior"`` (the belief's mean posterior at the last checkpoint).
        belief_accuracy: ``(Y, S)`` fraction of episodes whose ``argmax`` belief after
            ``n`` steps is the mapped learned type (a tie of ``m`` types counts ``1 / m``).
        belief_max: ``(Y, S)`` mean largest posterior after ``n`` steps.
        belief_status: ``(Y,)`` per true type at the last checkpoint: ``"identified"``
            (accuracy >= 0.5), ``"split"`` (mean largest posterior below
            ``split_threshold``: the actions seen do not tell this type apart; not a
            failure of the filter), ``"merged"`` (another true type maps to the same learned
            type: the learning did not separate them), or ``"wrong"``.
        split_threshold: the threshold of ``"split"``.
        episodes, noise, seed, discount, horizon: the settings.
        shares: ``(Y,)`` the population's share of each true type, summing to 1, that the
            overall figures weigh by (``None``: equal shares).
    """

    robots: tuple[str, ...]
    type_names: tuple[str, ...]
    returns: torch.Tensor
    mean: torch.Tensor
    ci: torch.Tensor
    overall_mean: torch.Tensor
    overall_ci: torch.Tensor
    steps: torch.Tensor
    belief_steps: tuple[int, ...]
    type_map: torch.Tensor
    map_source: str
    belief_accuracy: torch.Tensor
    belief_max: torch.Tensor
    belief_status: tuple[str, ...]
    split_threshold: float
    episodes: int
    noise: float
    seed: int
    discount: float
    horizon: int
    shares: torch.Tensor | None = None

    def index(self, robot: str) -> int:
        """The row of ``robot`` (raises ``ValueError`` naming the robots)."""
        if robot not in self.robots:
            raise ValueError(f"expected robot in {self.robots}, got {robot!r}")
        return self.robots.index(robot)

    def difference(self, robot: str, other: str, *, overall: bool = False,
                   ) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """The mean return of ``robot`` less that of ``other`` and its 95% half-width:
        ``(Y,)`` each per true type, ``()`` each with ``overall`` (the population, the types
        weighed by :attr:`shares`).

        Paired: every robot meets the same people with the same random draws (one seed,
        episode ``e`` of a type the same person for every robot), so the interval is that of
        the episodes' differences, ``1.96 sd(r_robot - r_other) / sqrt(E)`` per type, and
        over the population ``1.96 sqrt(sum_y w_y^2 var_y / E)``: the ``E`` episodes of each
        type are fixed by the design (stratified), so the spread between the types' returns
        is not sampling noise here (it is in :attr:`overall_ci`, which treats the episodes
        as people drawn from the population). The half-width is at least ``1e-9`` times the
        largest absolute return (at least 1), so that two robots whose returns differ only
        in the last bits are level.

        Example:
            >>> import torch
            >>> returns = torch.tensor([[[1.0, 3.0, 5.0]], [[0.9, 2.9, 4.9]]])  # (R, Y, E)
            >>> r = TaskEvaluation(
            ...     robots=("a", "b"), type_names=("t",), returns=returns,
            ...     mean=returns.mean(-1), ci=torch.full((2, 1), 2.26),
            ...     overall_mean=returns.mean((-1, -2)), overall_ci=torch.full((2,), 2.26),
            ...     steps=torch.zeros(2, 1), belief_steps=(), type_map=torch.tensor([0]),
            ...     map_source="assignments", belief_accuracy=torch.zeros(1, 0),
            ...     belief_max=torch.zeros(1, 0), belief_status=(), split_threshold=0.8,
            ...     episodes=3, noise=0.0, seed=0, discount=0.95, horizon=10)
            >>> mean, half = r.difference("a", "b", overall=True)
            >>> round(float(mean), 6), float(half) < 1e-6  # the same 0.1 in every episode
            (0.1, True)
            >>> int(r.compare("a", "b", overall=True))  # the intervals overlap; the pairs do not
            1
        """
        i, j = self.index(robot), self.index(other)
        d = (self.returns[i] - self.returns[j]).double()  # (Y, E)
        Y, E = d.shape
        mean = d.mean(-1)  # (Y,)
        if E > 1:
            var = d.var(-1, correction=1) / E  # (Y,) the variance of each type's mean
        else:
            var = torch.full_like(mean, math.inf)
        floor = 1e-9 * max(1.0, float(self.returns[[i, j]].abs().max()))
        if not overall:
            return mean, (Z95 * var.sqrt()).clamp_min(floor)
        w = (torch.full((Y,), 1.0 / Y, dtype=torch.float64) if self.shares is None
             else self.shares.to(torch.float64))  # fmt: skip
        return (w * mean).sum(), (Z95 * ((w**2) * var).sum().sqrt()).clamp_min(floor)

    def compare(self, robot: str, other: str, *, overall: bool = False) -> torch.Tensor:
        """``(Y,)`` int (``()`` with ``overall``): ``+1`` where ``robot`` beats ``other``
        beyond the 95% interval of their paired difference (:meth:`difference`: its mean
        above its half-width), ``-1`` where it is worse beyond it, else 0.

        Per type, a robot that always serves one type can beat the type-aware robot on that
        type (it never pays for a misread person); ``overall`` compares the population."""
        mean, half = self.difference(robot, other, overall=overall)
        return (mean > half).long() - (mean < -half).long()

    def summary(self, robot: str = "type-aware", other: str = "type-agnostic") -> str:
        """The result in words, over the population (the types in :attr:`shares`).

        One line per finding:

        * ``robot`` against ``other``: ahead, level or behind, by the 95% interval of
          their paired difference over the population (:meth:`difference` and
          :meth:`compare` with ``overall=True``);
        * with ``"told the type"`` among the robots (``told_type=True``): whether knowing
          the type pays (*told the type* against ``other``). Where it does not, ``robot``
          level with ``other`` is the expected result: no robot gains from finding a type
          that changes nothing (docs/evaluation_history.md, "Over ten seeds"). Where
          it does, the share of the gain that ``robot`` keeps,
          ``(robot - other) / (told - other)``;
        * with ``"true model"`` among the robots (``true_model=True``): whether finding the
          type online pays (*true model* against ``other``): a robot with the people's true
          behaviour, rewards and shares, not told the type. Where it does not, the types
          cannot be told apart before the robot has to act, and ``robot`` level with
          ``other`` is the expected result. Where it does, the share of that gain that
          ``robot`` keeps, ``(robot - other) / (true model - other)``: what is missing was
          lost to learning (the clustering, the human model or the rewards);
        * with ``"true model"``, ``"true behaviour"`` and ``"true rewards"`` among the robots
          (``true_model=True, true_parts=True``): what learning lost (*true model* against
          ``robot``, where beyond the intervals) and the share of it that each part, given
          its true value, wins back: ``(part - robot) / (true model - robot)``;
        * the true types the belief did not identify after the last checkpoint, by status
          (``split``: their actions do not tell them apart in ``n`` steps, a property of the
          people; ``merged``: the learning joined them; ``wrong``), with ``robot`` the
          type-aware one.

        Example:
            >>> import torch
            >>> returns = torch.tensor([2.0, 1.0, 3.0]).view(3, 1, 1).expand(3, 2, 2)
            >>> r = TaskEvaluation(
            ...     robots=("type-aware", "type-agnostic", "told the type"),
            ...     type_names=("a", "b"), returns=returns,
            ...     mean=torch.zeros(3, 2), ci=torch.zeros(3, 2),
            ...     overall_mean=torch.tensor([2.0, 1.0, 3.0]),
            ...     overall_ci=torch.tensor([0.1, 0.1, 0.1]), steps=torch.zeros(3, 2),
            ...     belief_steps=(5,), type_map=torch.tensor([0, 1]),
            ...     map_source="assignments", belief_accuracy=torch.ones(2, 1),
            ...     belief_max=torch.ones(2, 1), belief_status=("identified", "split"),
            ...     split_threshold=0.8, episodes=2, noise=0.05, seed=0, discount=0.95,
            ...     horizon=10)
            >>> print(r.summary())  # doctest: +ELLIPSIS
            type-aware 2.00 ± 0.10 against type-agnostic 1.00 ± 0.10: ahead by 1.00 ± 0.00 ...
            knowing the type pays: told the type 3.00 ± 0.10, ahead of ...; type-aware keeps 50% ...
            not identified after 5 steps: b (split: its actions do not tell it apart yet)
        """
        i = self.index(robot)
        m, c = self.overall_mean, self.overall_ci

        def value(k: int) -> str:
            return f"{self.robots[k]} {float(m[k]):.2f} ± {float(c[k]):.2f}"

        if other == "type-agnostic" and other not in self.robots:
            # evaluated without demonstrations= or agnostic=: nothing to compare with
            lines = [f"{value(i)}; no type-agnostic robot to compare with (evaluate_task "
                     "learns one from demonstrations=, or takes agnostic=)"]  # fmt: skip
            return "\n".join(lines + (self._belief_lines() if robot == "type-aware" else []))
        j = self.index(other)
        word = {1: "ahead by", 0: "level:", -1: "behind by"}
        sign = int(self.compare(robot, other, overall=True))
        gap, half = (float(v) for v in self.difference(robot, other, overall=True))
        lines = [
            f"{value(i)} against {value(j)}: {word[sign]} {abs(gap) if sign else gap:.2f} "
            f"± {half:.2f} (the paired difference, 95%)"
        ]
        references = (
            (TOLD, "knowing the type", "no robot gains from finding the type here"),
            (TRUE_MODEL, "finding the type online", "even with the people's true behaviour "
             "and rewards a robot that must find the type from their actions gains nothing "
             "here"),
        )  # fmt: skip
        for name, what, none in references:
            if name not in self.robots or robot == name:
                continue
            t = self.index(name)
            pays = int(self.compare(name, other, overall=True))
            if pays > 0:
                share = float((m[i] - m[j]) / (m[t] - m[j]))
                lines.append(f"{what} pays: {value(t)}, ahead of {other}; {robot} keeps "
                             f"{100 * share:.0f}% of that gain")  # fmt: skip
            else:
                lines.append(f"{what} does not pay: {value(t)}, "
                             f"{'level with' if pays == 0 else 'behind'} {other}; {none}, and "
                             f"{robot} level with {other} is the expected result")  # fmt: skip
        parts = (TRUE_MODEL, TRUE_BEHAVIOUR, TRUE_REWARDS)
        if all(p in self.robots for p in parts) and robot not in parts:
            t, b, r = (self.index(p) for p in parts)
            if int(self.compare(TRUE_MODEL, robot, overall=True)) > 0:
                lost = float(m[t] - m[i])
                back = [float(m[k] - m[i]) / lost for k in (b, r)]
                verdict = (
                    "the behaviour (the human model) matters most" if back[0] >= 0.5 > back[1]
                    else "the rewards (their features) matter most" if back[1] >= 0.5 > back[0]
                    else "either part alone wins back half or more" if min(back) >= 0.5
                    else "neither part alone wins back half: both are off"
                )  # fmt: skip
                lines.append(f"learning lost {lost:.2f} ({robot} against {TRUE_MODEL}): "
                             f"{value(b)} wins back {100 * back[0]:.0f}% of it, {value(r)} "
                             f"{100 * back[1]:.0f}%; {verdict}")  # fmt: skip
            else:
                lines.append(f"learning lost nothing beyond the 95% interval: {value(t)} is "
                             f"not ahead of {robot}")  # fmt: skip
        if robot == "type-aware":
            lines += self._belief_lines()
        return "\n".join(lines)

    def _belief_lines(self) -> list[str]:
        """The true types the type-aware robot's belief did not identify, as summary lines."""
        if not self.belief_steps:
            return []
        why = {
            "split": "its actions do not tell it apart yet",
            "merged": "the learning joined it with another type",
            "wrong": "the belief settles on another type",
        }
        missed = [f"{name} ({status}: {why[status]})"
                  for name, status in zip(self.type_names, self.belief_status)
                  if status in why]  # fmt: skip
        if not missed:
            return []
        return [f"not identified after {self.belief_steps[-1]} steps: " + ", ".join(missed)]

    def table(self, *, digits: int = 2) -> str:
        """A Markdown table: one row per true type, ``mean ± ci`` per robot, then the
        belief's accuracy and largest posterior at the last checkpoint and its status."""
        n = self.belief_steps[-1] if self.belief_steps else 0
        head = ["true type", *self.robots, f"belief acc. @{n}", f"max post. @{n}", "belief"]
        rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for y, name in enumerate(self.type_names):
            cells = [name] + [
                f"{float(m):.{digits}f} ± {float(c):.{digits}f}"
                for m, c in zip(self.mean[:, y], self.ci[:, y])
            ]
            if self.belief_steps:
                accuracy, top = float(self.belief_accuracy[y, -1]), float(self.belief_max[y, -1])
                cells += [f"{accuracy:.2f}", f"{top:.2f}", self.belief_status[y]]
            else:
                cells += ["", "", ""]
            rows.append("| " + " | ".join(cells) + " |")
        cells = ["all types"] + [
            f"{float(m):.{digits}f} ± {float(c):.{digits}f}"
            for m, c in zip(self.overall_mean, self.overall_ci)
        ]
        rows.append("| " + " | ".join([*cells, "", "", ""]) + " |")
        return "\n".join(rows)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (no per-episode returns)."""
        return {
            "robots": list(self.robots),
            "type_names": list(self.type_names),
            "mean": self.mean.tolist(),
            "ci": self.ci.tolist(),
            "overall_mean": self.overall_mean.tolist(),
            "overall_ci": self.overall_ci.tolist(),
            "steps": self.steps.tolist(),
            "belief_steps": list(self.belief_steps),
            "type_map": self.type_map.tolist(),
            "map_source": self.map_source,
            "belief_accuracy": self.belief_accuracy.tolist(),
            "belief_max": self.belief_max.tolist(),
            "belief_status": list(self.belief_status),
            "split_threshold": self.split_threshold,
            "episodes": self.episodes,
            "noise": self.noise,
            "seed": self.seed,
            "shares": None if self.shares is None else self.shares.tolist(),
        }


def _population(returns: torch.Tensor, weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(R,)`` the population's mean return and its 95% half-width from ``returns
    (R, Y, E)`` and type weights ``(Y,)``: the per-type means weighted, and the standard
    error of ``N = Y E`` people drawn from the population (the weighted second moment about
    the mean, with ``N / (N - 1)``); with equal weights, the plain mean and standard error
    of the ``N`` returns."""
    R, Y, E = returns.shape
    N = Y * E
    mean = (returns.mean(-1) * weights).sum(-1)  # (R,)
    second = (((returns - mean.view(R, 1, 1)) ** 2).mean(-1) * weights).sum(-1)  # (R,)
    ci = Z95 * torch.sqrt(second * N / (N - 1) / N)
    return mean, ci


def _simulate(
    world: TaskWithPeople,
    robot: Any,
    types: torch.Tensor,
    *,
    noise: float,
    seed: int,
    horizon: int,
    record_belief: bool,
    prior: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
    """``B`` episodes of ``robot`` against the people of ``types (B,)``: returns
    ``(return (B,), length (B,), beliefs)``, ``beliefs[t]`` the robot's belief ``(B, K)``
    after ``t`` updates (``t = 0..horizon``) when ``record_belief``."""
    task = world.task
    robot_effect = torch.as_tensor(task.robot_effect).to(torch.long)
    human_effect = torch.as_tensor(task.human_effect).to(torch.long)
    terminal = torch.as_tensor(task.terminal).to(torch.bool)
    reward = world.true_reward  # (A, X, Y)
    z = world.true_observation if world.observed else None
    gamma = float(task.discount)
    g = torch.Generator().manual_seed(int(seed))
    B = int(types.shape[0])
    x = torch.full((B,), int(task.initial_state), dtype=torch.long)
    memory = world.people.initial_memory(types, g)
    done = terminal[x].clone()
    total = torch.zeros(B, dtype=torch.float64)
    length = torch.zeros(B, dtype=torch.long)
    o = torch.zeros(B, dtype=torch.long)
    if prior is None:
        robot.reset(batch=B)
    else:
        robot.reset(prior)  # (B, K): one belief per episode
    beliefs: list[torch.Tensor] = []
    for t in range(horizon + 1):
        a = robot.act((x, o) if z is not None else x)
        a = torch.as_tensor(a, dtype=torch.long).expand(B)
        if record_belief:
            beliefs.append(torch.as_tensor(robot.belief).detach().double().expand(B, -1).clone())
        if t == horizon or bool(done.all()):
            break
        live = ~done
        if bool(((a < 0) | (a >= task.num_actions)).any()):
            raise ModelError(f"robot {robot!r} returned an action outside [0, {task.num_actions})")
        total = total + torch.where(live, reward[a, x, types] * gamma**t, 0.0)
        length = length + live.long()
        mid = robot_effect[a, x]
        h, new_memory = world.people.act(types, mid, a, memory, g, noise=noise)
        nxt = torch.where(h >= 0, human_effect[mid, h.clamp_min(0)], mid)
        if z is not None:
            o = torch.multinomial(z[a, nxt, types], 1, generator=g).squeeze(-1)
        x = torch.where(live, nxt, x)
        memory = torch.where(live.unsqueeze(-1), new_memory, memory)
        done = done | terminal[x]
    while record_belief and len(beliefs) < horizon + 1:  # all ended: the belief stays
        beliefs.append(beliefs[-1])
    return total, length, beliefs


def _true_type_ids(world: TaskWithPeople, demonstrations: Demonstrations) -> torch.Tensor | None:
    labels = getattr(demonstrations, "types", None)
    if labels is None:
        return None
    names = {n: i for i, n in enumerate(world.type_names)}
    if any(label not in names for label in labels):
        return None
    return torch.tensor([names[label] for label in labels], dtype=torch.long)


def _type_map(
    world: TaskWithPeople,
    model: LearnedModel,
    demonstrations: Demonstrations | None,
    belief: torch.Tensor,
    Y: int,
    episodes: int,
) -> tuple[torch.Tensor, str]:
    """``(Y,)`` the learned type of each true type: the majority of its training
    demonstrations' assignments, or the largest mean posterior of ``belief (B, K)``; and
    ``(K,)`` the true type of each learned type, read the other way from the same table (the
    true type with most of its demonstrations, or of its posterior mass)."""
    K = model.num_types
    truth = None if demonstrations is None else _true_type_ids(world, demonstrations)
    if truth is not None and truth.shape[0] == model.assignments.shape[0]:
        counts = torch.zeros(Y, K, dtype=torch.long)
        counts.index_put_((truth, model.assignments.long().cpu()), torch.ones_like(truth),
                          accumulate=True)  # fmt: skip
        return counts.argmax(-1), "assignments", counts.argmax(0)
    mass = belief.view(Y, episodes, K).mean(1)  # (Y, K)
    return mass.argmax(-1), "posterior", mass.argmax(0)


def told_type_controller(model: LearnedModel) -> Controller:
    """The robot of ``evaluate_task(told_type=True)``: the learned model's controller whose
    policy is optimal once the type is known (start it with all its belief on one type:
    ``reset(prior)``).

    With the type known and static (``momdp.Ty`` is None, as ``learn()`` builds it) and the
    task state observed, the MOMDP is one MDP per type, whose optimal action values are
    QMDP's vectors ``Q(x, y, a)`` (Littman, Cassandra and Kaelbling 1995): at a one-hot
    belief QMDP's action is the MDP's optimal one, and the belief stays on that type. The
    model's own policy is not used: solved from the initial belief ``b0`` (uniform over the
    types), its search need not reach a one-hot belief, and there its vectors can act far
    from optimally (``lead_follow_phase``, benchmarks/heldout_tasks.py, seed 1: 3.01 against
    5.22 over the population). Where the type may change (``Ty`` given), the model's own
    policy.

    Raises:
        ModelError: a model whose type may change and that has no policy (not solved); a
            static-type model needs none.

    Example:
        >>> import warnings, torchhrc
        >>> from torchhrc.tasks.suite import make_task
        >>> world = make_task("pace")
        >>> demos, _ = world.demonstrations(subjects=6, per_subject=2, seed=0)
        >>> with warnings.catch_warnings():
        ...     warnings.simplefilter("ignore")
        ...     model = torchhrc.learn(world.task, demos, k=2, solver_time=1.0)
        >>> robot = told_type_controller(model)
        >>> robot.reset(torch.tensor([1.0, 0.0], dtype=torch.float64))
        >>> robot.act(world.task.initial_state) in range(world.task.num_actions)
        True
    """
    from torchhrc.solvers import qmdp
    from torchhrc.tasks.controller import Controller

    momdp = model.momdp
    if momdp.Ty is not None:
        return Controller.from_model(model)
    return Controller.from_momdp(momdp, qmdp(momdp).policy)


def evaluate_task(
    world: TaskWithPeople,
    model: LearnedModel | None,
    *,
    demonstrations: Demonstrations | None = None,
    agnostic: LearnedModel | Literal[False] | None = None,
    robots: Mapping[str, Robot] | None = None,
    episodes: int = 200,
    noise: float = 0.05,
    belief_steps: int | Sequence[int] = (1, 3, 5),
    split_threshold: float = 0.8,
    told_type: bool = False,
    true_model: bool = False,
    true_parts: bool = False,
    horizon: int | None = None,
    seed: int = 0,
    shares: Sequence[float] | torch.Tensor | None = None,
) -> TaskEvaluation:
    """Compare robots against a task's simulated people under the people's true rewards.

    Args:
        world: the task with its simulated people and true reward per true type
            (:class:`~torchhrc.tasks.people.TaskWithPeople`; a suite task or your own).
        model: the solved type-aware :class:`~torchhrc.tasks.pipeline.LearnedModel`
            (``torchhrc.learn(task, demos)``), or ``None`` to score the given robots only.
        demonstrations: the training demonstrations of ``model``. With ``types`` naming the
            true types they map the learned types to the true ones (the majority of each
            true type's assignments); and the type-agnostic robot is learned from them.
        agnostic: the type-agnostic model (``k = 1``); ``None``: learned by
            ``torchhrc.learn(world.task, demonstrations, k=1, seed=seed)`` when
            demonstrations are given; ``False``: no type-agnostic robot.
        robots: more robots by name (``reset(*, batch=B)``, ``act(x)`` or ``act((x, o))``
            for an observed task, returning ``(B,)`` actions).
        episodes: ``E`` episodes per true type (``>= 2``).
        noise: the people's epsilon (a uniformly random legal action with this probability;
            default 0.05, the demonstrations' default).
        belief_steps: the ``n`` (belief updates) at which the type-aware belief is checked.
        split_threshold: a type whose mean largest posterior stays below this is ``"split"``.
        told_type: add the robot ``"told the type"``: a robot that knows from the start
            which learned type the person's true type maps to, and acts optimally for it
            under the learned model (:func:`told_type_controller`). It separates the two
            ways a type-aware robot can fail: if it also loses, the learned behaviour or
            reward of the type is wrong; if only the type-aware one loses, the belief does
            not find the type in time.
        true_model: add the robot ``"true model"``: a robot that plans on the world's own
            people, true rewards and ``shares`` (its prior), and finds the person's type
            from their actions as the type-aware robot does
            (:func:`~torchhrc.tasks.true_model.true_model_controller`, solved for the
            model's solver time limit, else 5 s). Against the type-agnostic robot it says
            what finding the type online can gain at all; the gap between it and the
            type-aware robot is what learning lost. Needs people that give their tables
            (:class:`~torchhrc.tasks.people.TabularPeople`).
        true_parts: add the robots ``"true behaviour"`` and ``"true rewards"``: the learned
            model with one part replaced by the truth, through the type map. *true
            behaviour* plans on the people's true behaviour (the true model) for the
            learned rewards, each true type wanting what its learned type learned
            (:func:`~torchhrc.tasks.true_model.true_behaviour_controller`); *true rewards*
            keeps the learned behaviour and gives each learned type the true reward of the
            true type it maps to (:func:`~torchhrc.tasks.true_model.true_reward_controller`).
            With ``true_model=True``, :meth:`TaskEvaluation.summary` says how much of what
            learning lost each recovers: which part to work on (the human model, or the
            features of the rewards). Needs a model and people that give their tables.
        horizon: steps per episode (default ``world.horizon``).
        seed: the seed of the people's generator (the same for every robot).
        shares: ``(Y,)`` the share of each true type in the population the overall figures
            describe (non-negative, any positive sum; normalised). ``None``: the world's
            :attr:`~torchhrc.tasks.people.TaskWithPeople.shares`, equal shares where it has
            none. Where your types are not equally common, give the shares (here or on the
            world): a robot that serves the common types at the cost of a rare one is then
            judged as your people would meet it. Every type is still simulated ``episodes``
            times, and the per-type figures do not depend on it.

    Returns:
        :class:`TaskEvaluation`.

    Raises:
        ModelError: the model is not solved, does not fit the task, or a robot returns an
            action out of range.
        ValueError: a bad setting (named).
        TypeError: a robot without ``reset`` or ``act``.

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> world = make_task("pace")
        >>> class Wait:
        ...     def reset(self, prior=None, *, batch=None): self.batch = batch
        ...     def act(self, x): return torch.zeros(self.batch, dtype=torch.long)
        >>> r = evaluate_task(world, None, robots={"wait": Wait()}, episodes=5)
        >>> r.robots, tuple(r.mean.shape)
        (('wait',), (1, 3))
    """
    from torchhrc.tasks.controller import Controller

    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 2:
        raise ValueError(f"expected episodes to be an int >= 2, got {episodes!r}")
    if not 0.0 <= float(noise) <= 1.0:
        raise ValueError(f"expected noise in [0, 1], got {noise!r}")
    if not 0.0 < float(split_threshold) <= 1.0:
        raise ValueError(f"expected split_threshold in (0, 1], got {split_threshold!r}")
    T = int(world.horizon if horizon is None else horizon)
    if T < 1:
        raise ValueError(f"expected horizon >= 1, got {horizon!r}")
    checks = (belief_steps,) if isinstance(belief_steps, int) else tuple(belief_steps)
    checks = tuple(sorted({int(n) for n in checks}))
    if any(n < 0 or n > T for n in checks):
        raise ValueError(f"expected belief_steps in [0, horizon={T}], got {belief_steps!r}")
    Y = world.num_types
    if shares is None:
        shares = world.shares
    weights = population_shares(shares, Y)
    A, X = world.task.num_actions, world.task.num_states
    if told_type and model is None:
        raise ValueError("told_type=True needs a model")
    if true_parts and model is None:
        raise ValueError("true_parts=True needs a model")
    # every robot this call solves gets the model's solver time (5 s without a model)
    solver = dict(model.info.get("solver", {})) if model is not None else {}
    time_limit = float(solver.get("time_limit", 5.0) or 5.0)
    entries: list[tuple[str, Any]] = []
    if model is not None:
        if model.momdp.num_actions != A or model.momdp.num_observed != X:
            raise ModelError(
                f"the model has A={model.momdp.num_actions}, X={model.momdp.num_observed}; "
                f"the task has A={A}, X={X}"
            )
        z = world.true_observation
        if world.observed and z is not None and model.momdp.num_observations != z.shape[-1]:
            raise ModelError(
                f"the model observes O={model.momdp.num_observations} signals, the world's "
                f"true_observation gives O={z.shape[-1]}"
            )
        entries.append(("type-aware", Controller.from_model(model)))
    if agnostic is None and demonstrations is not None and model is not None:
        from torchhrc.tasks.pipeline import learn

        agnostic = learn(world.task, demonstrations, k=1, seed=seed, solver_time=time_limit)
    if agnostic is not None and agnostic is not False:
        entries.append(("type-agnostic", Controller.from_model(agnostic)))
    for name, robot in (robots or {}).items():
        if name in dict(entries):
            raise ValueError(f"robot name {name!r} is taken; use another")
        missing = [m for m in ("reset", "act") if not callable(getattr(robot, m, None))]
        if missing:
            raise TypeError(f"robots[{name!r}] ({type(robot).__name__}) has no "
                            f"{' or '.join(f'{m}()' for m in missing)}: a robot needs "
                            "reset(*, batch=B) and act(x) -> (B,) actions")  # fmt: skip
        entries.append((str(name), robot))
    if true_model:
        from torchhrc.tasks.true_model import true_model_controller

        if TRUE_MODEL in dict(entries):
            raise ValueError(f"robot name {TRUE_MODEL!r} is taken by robots=; rename it or "
                             "leave out true_model=True")  # fmt: skip
        entries.append((TRUE_MODEL, true_model_controller(
            world, noise=float(noise), shares=weights, time_limit=time_limit,
            seed=seed)))  # fmt: skip
    if not entries:
        raise ValueError("nothing to evaluate: give a model or robots")

    types = torch.arange(Y).repeat_interleave(episodes)  # (B,) episodes grouped by type
    R = len(entries) + int(told_type) + 2 * int(true_parts)
    returns = torch.zeros(R, Y, episodes, dtype=torch.float64)
    steps = torch.zeros(R, Y, dtype=torch.float64)
    beliefs: list[torch.Tensor] = []
    type_map = torch.full((Y,), -1, dtype=torch.long)
    truth_of = torch.zeros(0, dtype=torch.long)
    source = "none"
    for r, (_name, robot) in enumerate(entries):
        aware = model is not None and r == 0
        total, length, seen = _simulate(world, robot, types, noise=float(noise), seed=seed,
                                        horizon=T, record_belief=aware)  # fmt: skip
        returns[r] = total.view(Y, episodes)
        steps[r] = length.double().view(Y, episodes).mean(-1)
        if aware:
            assert model is not None
            beliefs = seen
            at = checks[-1] if checks else T
            type_map, source, truth_of = _type_map(world, model, demonstrations, seen[at], Y,
                                                   episodes)  # fmt: skip
    if told_type:
        assert model is not None
        prior = torch.nn.functional.one_hot(type_map[types], model.num_types)
        total, length, _ = _simulate(world, told_type_controller(model), types,
                                     noise=float(noise), seed=seed, horizon=T,
                                     record_belief=False,
                                     prior=prior.to(model.momdp.b0.dtype))  # fmt: skip
        returns[len(entries)] = total.view(Y, episodes)
        steps[len(entries)] = length.double().view(Y, episodes).mean(-1)
        entries.append((TOLD, None))
    if true_parts:
        from torchhrc.tasks.true_model import true_behaviour_controller, true_reward_controller

        assert model is not None
        parts = (
            (TRUE_BEHAVIOUR, true_behaviour_controller(world, model, type_map, noise=float(noise),
                                                       shares=weights, time_limit=time_limit,
                                                       seed=seed)),
            (TRUE_REWARDS, true_reward_controller(world, model, truth_of, time_limit=time_limit,
                                                  seed=seed)),
        )  # fmt: skip
        for name, robot in parts:
            total, length, _ = _simulate(world, robot, types, noise=float(noise), seed=seed,
                                         horizon=T, record_belief=False)  # fmt: skip
            returns[len(entries)] = total.view(Y, episodes)
            steps[len(entries)] = length.double().view(Y, episodes).mean(-1)
            entries.append((name, None))
    mean = returns.mean(-1)
    ci = Z95 * returns.std(-1, correction=1) / math.sqrt(episodes)
    overall_mean, overall_ci = _population(returns, weights)

    S = len(checks) if beliefs else 0
    accuracy = torch.zeros(Y, S, dtype=torch.float64)
    top = torch.zeros(Y, S, dtype=torch.float64)
    status: tuple[str, ...] = ()
    if beliefs:
        assert model is not None
        K = model.num_types
        for s, n in enumerate(checks):
            b = beliefs[n].view(Y, episodes, K)
            # ties share the credit: a uniform belief is not "right" by index order
            best = b >= b.max(-1, keepdim=True).values - 1e-12  # (Y, E, K)
            mine = best.gather(-1, type_map.view(Y, 1, 1).expand(Y, episodes, 1)).squeeze(-1)
            accuracy[:, s] = (mine.double() / best.sum(-1).double()).mean(-1)
            top[:, s] = b.max(-1).values.mean(-1)
        shared = torch.bincount(type_map, minlength=K)[type_map] > 1
        labels = []
        for y in range(Y):
            if S and bool(shared[y]):
                labels.append("merged")
            elif S and float(top[y, -1]) < split_threshold:
                labels.append("split")
            elif S and float(accuracy[y, -1]) >= 0.5:
                labels.append("identified")
            else:
                labels.append("wrong" if S else "")
        status = tuple(labels)
    return TaskEvaluation(
        robots=tuple(name for name, _ in entries),
        type_names=world.type_names,
        returns=returns,
        mean=mean,
        ci=ci,
        overall_mean=overall_mean,
        overall_ci=overall_ci,
        steps=steps,
        belief_steps=checks if beliefs else (),
        type_map=type_map,
        map_source=source,
        belief_accuracy=accuracy,
        belief_max=top,
        belief_status=status,
        split_threshold=float(split_threshold),
        episodes=episodes,
        noise=float(noise),
        seed=int(seed),
        discount=float(world.task.discount),
        horizon=T,
        shares=None if shares is None else weights,
    )
