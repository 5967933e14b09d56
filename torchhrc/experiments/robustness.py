"""Robustness of the robot's policy to deviations of the human (paper Fig. 3).

Paper (section "Robustness of Computed Policy"): for each held-out subject, the human's
placements are replaced by random ones with probability ``epsilon``; "for each subject, we
ran 100 simulated iterations of task execution" and plotted the mean accumulated reward of
(a) the learned MOMDP policy, (b) the hand-coded MOMDP policy and (c) human-robot
cross-training against ``epsilon``. Here every run of every ``epsilon`` of one subject is one
batch (:func:`~torchhrc.tasks.place_and_drill.simulate.run_executions`); the three policies
see the same human randomness.

Shapes::

    rewards[name]: (E, S, R)   accumulated reward of run r of subject s at epsilon e

Confidence intervals: ``reward_ci95`` is the normal-approximation half-width
``1.96 * sd / sqrt(S * R)`` over all runs of an epsilon; :meth:`RobustnessResult.ci95` with
``over="subjects"`` gives the Student-t half-width over the ``S`` per-subject means, which
also counts the between-subject spread.

Example:
    >>> import torch
    >>> mean, half = mean_ci95(torch.tensor([[1.0, 3.0], [2.0, 2.0]]))
    >>> mean.tolist(), half[1].item()
    ([2.0, 2.0], 0.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
from torchhrc.tasks.place_and_drill.simulate import (
    CrossTrainingController,
    ExecutionController,
    ExecutionTrace,
    MOMDPController,
    run_executions,
)

__all__ = [
    "EPSILONS",
    "POLICY_NAMES",
    "MOMDPPolicy",
    "RobustnessResult",
    "mean_ci95",
    "simulate_subject",
    "student_t_quantile",
]

#: The paper's deviation probabilities 0, 0.1, ..., 1.0.
EPSILONS: tuple[float, ...] = tuple(round(0.1 * i, 1) for i in range(11))
#: The three policies of Fig. 3, in plotting order.
POLICY_NAMES: tuple[str, ...] = ("learned", "hand_coded", "cross_training")


def student_t_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of Student's t with ``dof`` degrees of freedom (bisection on the CDF).

    Example:
        >>> round(student_t_quantile(0.975, 17), 3)
        2.11
    """
    if dof < 1:
        raise ValueError(f"expected dof >= 1, got {dof}")

    def cdf(t: float) -> float:
        # regularized incomplete beta via the continued fraction is overkill here: integrate
        # the density with Simpson's rule on [0, t] (t <= 20 in practice).
        n = 2000
        h = t / n
        c = math.exp(math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2)) / math.sqrt(dof * math.pi)

        def f(u: float) -> float:
            return c * (1 + u * u / dof) ** (-(dof + 1) / 2)

        total = f(0.0) + f(t) + sum((4 if i % 2 else 2) * f(i * h) for i in range(1, n))
        return 0.5 + total * h / 3

    lo, hi = 0.0, 50.0
    for _ in range(60):
        mid = (lo + hi) / 2
        if cdf(mid) < p:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def mean_ci95(
    values: torch.Tensor, *, over: Literal["runs", "subjects"] = "runs"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and 95% confidence half-width over the last dim.

    Args:
        values: ``(..., N)`` samples.
        over: ``"runs"`` uses the normal quantile 1.96 (many runs); ``"subjects"`` uses the
            Student-t quantile with ``N - 1`` degrees of freedom.

    Returns:
        ``(mean (...), half_width (...))``; the half-width is 0 when ``N = 1``.
    """
    n = values.shape[-1]
    mean = values.mean(-1)
    if n < 2:
        return mean, torch.zeros_like(mean)
    sd = values.std(-1, unbiased=True)
    q = 1.959963984540054 if over == "runs" else student_t_quantile(0.975, n - 1)
    return mean, q * sd / math.sqrt(n)


@dataclass(frozen=True)
class MOMDPPolicy:
    """A solved MOMDP ready to run: the model (for belief updates), its policy, a start belief.

    Attributes:
        model: the MOMDP.
        policy: an object with ``action(x (B,), belief_y (B, Y)) -> (B,)``.
        b0: ``(Y,)`` the initial type belief of the runs.
    """

    model: MOMDP
    policy: object
    b0: torch.Tensor


@dataclass(frozen=True)
class RobustnessResult:
    """Accumulated rewards of every policy, epsilon, subject and run.

    Attributes:
        epsilon: ``(E,)`` deviation probabilities.
        subjects: ``(S,)`` subject ids.
        rewards: ``{policy name: (E, S, R)}`` float64 accumulated rewards.
    """

    epsilon: tuple[float, ...]
    subjects: tuple[str, ...]
    rewards: dict[str, torch.Tensor]

    @property
    def runs_per_subject(self) -> int:
        """R."""
        return next(iter(self.rewards.values())).shape[-1]

    def mean(self, name: str) -> torch.Tensor:
        """``(E,)`` mean reward over all subjects and runs."""
        return self.rewards[name].flatten(1).mean(-1)

    def ci95(self, name: str, *, over: Literal["runs", "subjects"] = "runs") -> torch.Tensor:
        """``(E,)`` 95% half-width, over all runs or over the per-subject means."""
        r = self.rewards[name]
        values = r.flatten(1) if over == "runs" else r.mean(-1)
        return mean_ci95(values, over=over)[1]

    def subject_means(self, name: str) -> torch.Tensor:
        """``(E, S)`` mean reward of each subject."""
        return self.rewards[name].mean(-1)


def simulate_subject(
    task: PlaceAndDrillTask,
    *,
    momdp_policies: Mapping[str, MOMDPPolicy],
    cross_training: object | None,
    subject_index: int,
    orders: torch.Tensor,
    score: torch.Tensor,
    epsilons: Sequence[float] = EPSILONS,
    runs: int = 100,
    horizon: int | None = None,
    generator: torch.Generator | None = None,
    human_chunk: int | None = None,
    on_trace: Callable[[ExecutionTrace, torch.Tensor], None] | None = None,
) -> dict[str, torch.Tensor]:
    """Run every policy on one subject: ``runs`` executions per epsilon, all in one batch.

    Args:
        task: the task.
        momdp_policies: ``{name: MOMDPPolicy}`` (the learned and the hand-coded MOMDP).
        cross_training: a
            :class:`~torchhrc.tasks.place_and_drill.cross_training.CrossTrainingPolicy`
            (its subject ``subject_index`` is used) or None.
        subject_index: the subject's index in the cross-training policy.
        orders: ``(M, n)`` int64 the subject's demonstrated placement orders; each run
            replays one of them, drawn uniformly.
        score: ``(A, X)`` the scoring reward (the subject's true type's expert reward).
        epsilons: ``(E,)`` deviation probabilities.
        runs: executions per epsilon, ``R``.
        horizon: robot decisions per run (default ``4 n``).
        generator: random source (order draws, the human's deviations, tie-breaking).
        human_chunk: None (Fig. 3: the human places whenever it can) or the chunk size of
            the subject's type, whose turn-taking rule the human then follows
            (:func:`~torchhrc.tasks.place_and_drill.simulate.run_executions`).
        on_trace: called with the runs' :class:`ExecutionTrace` and their ``epsilon (B,)``
            (e.g. to replay some runs in the SAPIEN workbench).

    Returns:
        ``{name: (E, R)}`` accumulated rewards (``"cross_training"`` included when given).
    """
    if runs < 1:
        raise ModelError(f"expected runs >= 1, got {runs}")
    E = len(epsilons)
    B = E * runs
    eps = torch.tensor(list(epsilons), dtype=torch.float64).repeat_interleave(runs)  # (B,)
    pick = torch.randint(orders.shape[0], (B,), generator=generator)
    run_orders = orders[pick]  # (B, n)
    controllers: dict[str, ExecutionController] = {}
    for name, p in momdp_policies.items():
        belief = p.b0.to(p.model.Tx.dtype).expand(B, -1).clone()
        controllers[name] = MOMDPController(p.model, p.policy, belief)  # type: ignore[arg-type]
    if cross_training is not None:
        controllers["cross_training"] = CrossTrainingController(cross_training, subject_index)
    trace = run_executions(
        task,
        controllers,
        orders=run_orders,
        epsilon=eps,
        score=score,
        horizon=horizon,
        generator=generator,
        human_chunk=None if human_chunk is None else torch.full((B,), int(human_chunk)),
    )
    if on_trace is not None:
        on_trace(trace, eps)
    return {name: r.view(E, runs) for name, r in trace.rewards.items()}
