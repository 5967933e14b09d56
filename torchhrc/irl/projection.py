"""Apprenticeship learning by inverse reinforcement learning (Abbeel & Ng 2004), as in the paper.

The paper's IRL section (Nikolaidis et al., Sec. "Inverse Reinforcement Learning"), for one
human type with expert feature expectations ``mu_hat`` (S states, A actions, F features)::

    1. pick a random policy pi^(0); mu^(0) = mu(pi^(0)); i = 1
    2. t^(i), w^(i) from mu^(0..i-1):
         "qp"         (paper Eq. quadraticProg):
                      mu = argmin_{mu in conv(mu^(0..i-1))} ||mu_hat - mu||
         "projection" (Abbeel & Ng 2004, Sec. 3.1): mu_bar^(i-1) = mu_bar^(i-2) projected
                      towards mu^(i-1) along the segment; mu = mu_bar^(i-1)
       t^(i) = ||mu_hat - mu||_2,  w^(i) = (mu_hat - mu) / t^(i)
    3. if t^(i) <= epsilon: stop
    4. pi^(i) = optimal policy of R = w^(i) . phi (value iteration)
    5. mu^(i) = mu(pi^(i)) (exact, or Monte Carlo as in the paper); i = i + 1; go to 2

Output: the policies pi^(0..M), their mixture weights lambda and feature expectations
mu^(0..M), the margins t^(1..M+1), why the loop stopped, and one reward, chosen by ``rule``
among the ``w^(1..M)`` (M is the number of policies computed by reinforcement learning,
``<= max_iterations``):

* ``"closest"`` (default): ``w^(i*)``, ``i* = argmin_{i >= 1} ||mu_hat - mu^(i)||``, the
  reward whose optimal policy's feature expectations are nearest the expert's. Abbeel & Ng
  (2004, Sec. 3) end with a set of policies from which one is *picked* ("we can then ...
  pick the policy from the set", by inspection, or a mixture); with no expert at hand the
  nearest ``mu`` is the pick: by their Eq. 2 argument its true value is within
  ``||w*|| ||mu_hat - mu^(i*)||`` of the expert's.
* ``"dominant"``: the ``w^(i)`` with the largest mixture weight ``lambda_i``.
* ``"paper"``: the mean of ``w^(i)`` over the second half of the iterations
  (``w^(M//2 + 1 .. M)``, the paper's rule: "we ignore the first half ... as the initial
  policies and associated weights ... are of lesser quality").
* ``"last"``: ``w^(M)``.

Why not the paper's rule by default. The margin only reaches ``epsilon`` when ``mu_hat`` is
in the hull of the policies' feature expectations. The empirical ``mu_hat`` is not: it
carries the sampling error of n demonstrations (``expert_standard_error``, 0.15 to 0.45
in feature units for 100 trajectories of 40 steps on the random 10x10 colour worlds of
:class:`~torchhrc.tasks.gridworld.ColourGridworld`), and a finite demonstration length with
``horizon=None`` leaves it short of any policy's total discounted mass
(``(1 - gamma^L) / (1 - gamma)`` against ``1 / (1 - gamma)`` for features that sum to 1; on
those worlds a margin floor of 0.060 = 0.148 / sqrt(6)). The loop then runs to
``max_iterations`` with the late ``w^(i)`` pointing at noise directions, and their mean is a
direction no policy was checked against: on 20 such worlds (seeds 200-219) the paper's
rule scored below 0.95 on 6 and as low as -0.48 (fraction of the expert's value above a
random policy's), the ``"closest"`` rule 0.978 or more (``docs/irl.md``;
``tests/irl/test_projection.py``).

Stopping: ``converged`` when the margin is ``<= epsilon`` (``stop_reason="margin"``);
``"stalled"`` when, with exact feature expectations, the RL step returns a policy the
margin cannot use (projection: the last policy again; QP: a policy already in the set), so
that every later iteration would repeat it; ``"max_iterations"`` otherwise. The last two
emit an :class:`IRLConvergenceWarning` giving the margin and the expert's sampling error.

Several problems (one per human type) run as one batch: value iteration and feature
expectations are batched tensor programs over the problems still running.

Example:
    >>> import torch
    >>> from torchhrc.irl.trajectories import Trajectories
    >>> T = torch.tensor([[[1.0, 0.0], [1.0, 0.0]], [[0.0, 1.0], [0.0, 1.0]]],
    ...                  dtype=torch.float64)          # action a moves to state a
    >>> demos = Trajectories.from_pairs([[(0, 1), (1, 1), (1, 1), (1, 1)]])
    >>> result = apprenticeship_learning(T, torch.eye(2, dtype=torch.float64), demos,
    ...     discount=0.5, horizon=4, epsilon=1e-6, initial_policy=torch.tensor([0, 0]))
    >>> result.num_iterations, result.converged, result.policies[-1].tolist()
    (1, True, [1, 1])
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch

from torchhrc._checks import check_probabilities, check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.irl.features import (
    check_features,
    empirical_feature_expectations,
    feature_expectations,
    monte_carlo_feature_expectations,
    reward_from_weights,
    start_distribution,
)
from torchhrc.irl.qp import solve_simplex_qp
from torchhrc.irl.trajectories import Trajectories, check_trajectories
from torchhrc.solvers.value_iteration import value_iteration

__all__ = [
    "REWARD_RULES",
    "ApprenticeshipResult",
    "IRLConvergenceWarning",
    "apprenticeship_learning",
]

Method = Literal["projection", "qp"]
RewardRule = Literal["closest", "dominant", "paper", "last"]

#: The rules that pick the reported reward among ``w^(1..M)`` (module docstring).
REWARD_RULES: tuple[str, ...] = ("closest", "dominant", "paper", "last")


class IRLConvergenceWarning(UserWarning):
    """Abbeel-Ng's loop stopped before its margin reached ``epsilon`` (the message says why)."""


@dataclass(frozen=True)
class ApprenticeshipResult:
    """The result of :func:`apprenticeship_learning` (M policies found by RL).

    Attributes:
        weights: ``(F,)`` the reward weights picked by ``rule`` (default ``"closest"``: the
            ``w^(i)`` whose policy's feature expectations are nearest ``mu_hat``; see the
            module docstring). ``paper_weights``, ``closest_weights``, ``dominant_weights``
            and ``last_weights`` give every rule's pick.
        last_weights: ``(F,)`` ``w^(M)``, the weights of the last policy.
        weight_history: ``(M, F)`` ``w^(1..M)``; row ``i - 1`` generated ``policies[i]``.
            Each row is a unit vector (paper step 2).
        policies: ``(M + 1, S)`` int64, ``pi^(0..M)`` (row 0 the random start policy).
        mixture_weights: ``(M + 1,)`` ``lambda``, the final mixture whose feature
            expectations are closest to the expert's.
        feature_expectations: ``(M + 1, F)`` ``mu^(0..M)``.
        expert_feature_expectations: ``(F,)`` ``mu_hat``.
        margins: ``(M + 1,)`` ``t^(1..M+1)``; ``margins[i - 1]`` is the distance from
            ``mu_hat`` to the mixture of ``pi^(0..i-1)``; the last one is the final margin.
        converged: whether the final margin is ``<= epsilon``.
        method: ``"projection"`` or ``"qp"``.
        rule: the rule that picked ``weights``.
        stop_reason: ``"margin"`` (converged), ``"stalled"`` (the RL step repeated a policy,
            so the margin could not decrease any more) or ``"max_iterations"``.
        expert_standard_error: ``||std(mu_hat)||_2``, the sampling error of the expert's
            empirical feature expectations (per-trajectory spread over ``sqrt(n)``; 0 for one
            demonstration). A final margin of that order is the noise floor, not a failure.
    """

    weights: torch.Tensor
    last_weights: torch.Tensor
    weight_history: torch.Tensor
    policies: torch.Tensor
    mixture_weights: torch.Tensor
    feature_expectations: torch.Tensor
    expert_feature_expectations: torch.Tensor
    margins: torch.Tensor
    converged: bool
    method: str
    rule: str = "closest"
    stop_reason: str = "margin"
    expert_standard_error: float = 0.0

    @property
    def num_iterations(self) -> int:
        """M, the number of policies computed by reinforcement learning."""
        return self.weight_history.shape[0]

    @property
    def dominant_weights(self) -> torch.Tensor:
        """``(F,)`` ``w^(i*)`` with ``i* = argmax_{i >= 1} lambda_i``: the reward of the RL
        policy the final mixture relies on most (``weights`` when ``M = 0``).

        Beyond the paper: with noisy demonstrations the margin stalls at the noise level and
        the late ``w^(i)`` (hence the second-half mean) can point in noise directions.
        """
        if self.num_iterations == 0:
            return self.last_weights
        return self.weight_history[int(self.mixture_weights[1:].argmax())]

    @property
    def paper_weights(self) -> torch.Tensor:
        """``(F,)`` the paper's rule: the mean of ``w^(i)`` over the second half of the
        iterations, ``weight_history[M // 2:].mean(0)`` (``w^(1)``'s direction when M = 0).

        Fails when the margin stalls above ``epsilon`` (module docstring)."""
        if self.num_iterations == 0:
            return self.last_weights
        return self.weight_history[self.num_iterations // 2 :].mean(0)

    @property
    def closest_weights(self) -> torch.Tensor:
        """``(F,)`` ``w^(i*)`` with ``i* = argmin_{i >= 1} ||mu_hat - mu^(i)||``: the reward
        whose optimal policy's feature expectations are nearest the expert's (the default).
        """
        if self.num_iterations == 0:
            return self.last_weights
        gaps = torch.linalg.vector_norm(
            self.feature_expectations[1:] - self.expert_feature_expectations, dim=-1
        )
        return self.weight_history[int(gaps.argmin())]

    @property
    def margin(self) -> float:
        """The final margin ``t^(M+1)``."""
        return float(self.margins[-1])

    def reward(self, features: torch.Tensor, num_actions: int) -> torch.Tensor:
        """The learned reward ``R[a, s] = weights . phi(s[, a])``, shape ``(A, S)``."""
        return reward_from_weights(features, self.weights, num_actions)


def _check_transition(transition: object) -> torch.Tensor:
    T = check_tensor("transition", transition)
    check_shape("transition", T, (None, None, None), "(..., A, S, S)")
    if T.shape[-2] != T.shape[-1]:
        raise ModelError(
            f"expected transition of shape (..., A, S, S), actual shape = {tuple(T.shape)}"
        )
    check_probabilities("transition", T.detach())
    return T


def _unit(residual: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(t, w)``: norms ``(...)`` and unit directions ``(..., F)`` (0 where t = 0)."""
    t = torch.linalg.vector_norm(residual, dim=-1)
    w = residual / t.clamp_min(torch.finfo(residual.dtype).tiny).unsqueeze(-1)
    return t, torch.where((t > 0).unsqueeze(-1), w, torch.zeros_like(w))


def _default_rollout_horizon(discount: float, tolerance: float = 1e-4) -> int:
    """Steps after which ``discount^H <= tolerance`` (truncation of a Monte Carlo rollout)."""
    return max(1, math.ceil(math.log(tolerance) / math.log(discount))) if discount < 1 else 1000


def _run_batched(
    T: torch.Tensor,
    phi: torch.Tensor,
    mu_hat: torch.Tensor,
    d0: torch.Tensor,
    *,
    discount: float,
    method: Method,
    epsilon: float,
    max_iterations: int,
    horizon: int | None,
    monte_carlo: int | None,
    initial_policy: torch.Tensor | None,
    generator: torch.Generator,
    vi_tol: float,
    qp_solver: str,
    qp_options: dict[str, Any] | None,
    standard_error: torch.Tensor | None = None,
    rule: str = "closest",
    warn: bool = True,
) -> list[ApprenticeshipResult]:
    """The algorithm on B problems at once: ``T (B, A, S, S)``, ``mu_hat (B, F)``, ``d0 (B, S)``.

    ``standard_error (B,)``: the sampling error of each ``mu_hat`` (reported only).
    ``warn``: one :class:`IRLConvergenceWarning` for all the problems that did not converge."""
    if standard_error is None:
        standard_error = mu_hat.new_zeros(mu_hat.shape[0])
    B, A, S = T.shape[0], T.shape[-3], T.shape[-1]
    F = mu_hat.shape[-1]
    dtype, device = T.dtype, T.device
    K = max_iterations + 1
    policies = torch.zeros(B, K, S, dtype=torch.long, device=device)
    mus = torch.zeros(B, K, F, dtype=dtype, device=device)
    ws = torch.zeros(B, max_iterations, F, dtype=dtype, device=device)
    margins = torch.zeros(B, K, dtype=dtype, device=device)
    lam = torch.zeros(B, K, dtype=dtype, device=device)
    count = torch.zeros(B, dtype=torch.long, device=device)  # policies so far per problem
    active = torch.ones(B, dtype=torch.bool, device=device)
    stalled = torch.zeros(B, dtype=torch.bool, device=device)
    rollout = horizon if horizon is not None else _default_rollout_horizon(discount)

    def evaluate(index: torch.Tensor, pi: torch.Tensor) -> torch.Tensor:
        if monte_carlo is None:
            return feature_expectations(T[index], pi, phi, discount, d0[index], horizon=horizon)
        return monte_carlo_feature_expectations(
            T[index],
            pi,
            phi,
            discount,
            d0[index],
            num_trajectories=monte_carlo,
            horizon=rollout,
            generator=generator,
        )

    # Step 1: a random deterministic policy per problem (or the one given).
    everyone = torch.arange(B, device=device)
    if initial_policy is None:
        pi0 = torch.randint(A, (B, S), generator=generator, device=generator.device).to(device)
    else:
        pi0 = initial_policy.to(device).long().expand(B, S)
    policies[:, 0] = pi0
    mus[:, 0] = evaluate(everyone, pi0)
    count[:] = 1
    mu_bar = mus[:, 0].clone()  # projection method: the current mixture's mu
    lam[:, 0] = 1.0

    for i in range(1, max_iterations + 2):
        idx = torch.nonzero(active).squeeze(-1)
        # Step 2: the margin and direction from the policies pi^(0..i-1).
        if method == "projection":
            if i > 1:
                new = mus[idx, i - 1]
                d = new - mu_bar[idx]
                dd = (d * d).sum(-1)
                beta = (d * (mu_hat[idx] - mu_bar[idx])).sum(-1) / dd.clamp_min(1e-300)
                beta = torch.where(dd > 0, beta.clamp(0.0, 1.0), torch.zeros_like(beta))
                mu_bar[idx] = mu_bar[idx] + beta.unsqueeze(-1) * d
                lam[idx] = lam[idx] * (1.0 - beta).unsqueeze(-1)
                lam[idx, i - 1] = beta
            mixture = mu_bar[idx]
        else:
            rows = []
            for b in idx.tolist():
                weights = solve_simplex_qp(
                    mus[b, :i], mu_hat[b], solver=qp_solver, solver_options=qp_options
                )
                lam[b, :i] = weights
                rows.append(weights @ mus[b, :i])
            mixture = torch.stack(rows)
        t, w = _unit(mu_hat[idx] - mixture)
        margins[idx, i - 1] = t
        # Step 3: stop the problems whose margin is small enough, or at max_iterations.
        running = t > epsilon
        if i > max_iterations:
            break
        done = idx[~running]
        active[done] = False
        idx, w = idx[running], w[running]
        if idx.numel() == 0:
            break
        ws[idx, i - 1] = w
        # Step 4: reinforcement learning for R = w . phi, all running problems at once.
        R = reward_from_weights(phi, w, A)  # (b, A, S)
        pi = value_iteration(T[idx], R, discount, tol=vi_tol).policy  # (b, S)
        if monte_carlo is None:
            # A policy the margin cannot use: the same w, hence the same policy, for ever.
            if method == "projection":
                repeat = (pi == policies[idx, i - 1]).all(-1)
            else:
                repeat = (pi.unsqueeze(1) == policies[idx, :i]).all(-1).any(-1)
            if repeat.any():
                stalled[idx[repeat]] = True
                active[idx[repeat]] = False
                idx, pi = idx[~repeat], pi[~repeat]
                if idx.numel() == 0:
                    break
        policies[idx, i] = pi
        # Step 5: feature expectations of the new policies.
        mus[idx, i] = evaluate(idx, pi)
        count[idx] = i + 1

    results = []
    unconverged: list[str] = []
    for b in range(B):
        n = int(count[b])
        M = n - 1
        history = ws[b, :M]
        # converged on the random policy: the only direction there is is w^(1)
        last = history[-1] if M > 0 else _unit(mu_hat[b] - mus[b, 0])[1]
        final_margin = margins[b, M]
        converged = bool(final_margin <= epsilon)
        reason = "margin" if converged else ("stalled" if stalled[b] else "max_iterations")
        result = ApprenticeshipResult(
            weights=last,
            last_weights=last,
            weight_history=history,
            policies=policies[b, :n],
            mixture_weights=lam[b, :n],
            feature_expectations=mus[b, :n],
            expert_feature_expectations=mu_hat[b],
            margins=margins[b, :n],
            converged=converged,
            method=method,
            rule=rule,
            stop_reason=reason,
            expert_standard_error=float(standard_error[b]),
        )
        chosen = {
            "closest": result.closest_weights,
            "dominant": result.dominant_weights,
            "paper": result.paper_weights,
            "last": last,
        }[rule]
        results.append(dataclasses.replace(result, weights=chosen))
        if not converged:
            why = (
                "the RL step returned a policy already used, so the margin cannot decrease"
                if reason == "stalled"
                else f"max_iterations = {max_iterations} reached"
            )
            unconverged.append(
                f"{'' if B == 1 else f'problem {b}: '}after {M} iterations ({why}), "
                f"final margin {float(final_margin):.4g}, sampling error of the expert's "
                f"feature expectations {float(standard_error[b]):.4g}"
            )
    if warn and unconverged:
        warnings.warn(
            f"apprenticeship learning ended without reaching epsilon = {epsilon:.3g}: "
            f"{'; '.join(unconverged)} (a margin of the order of the sampling error is the "
            "demonstrations' noise floor; the horizon= of finite demonstrations also "
            f"matters). The reward is picked by rule={rule!r}.",
            IRLConvergenceWarning,
            stacklevel=3,
        )
    return results


def _standard_errors(
    features: torch.Tensor, demonstrations: Sequence[Trajectories], discount: float
) -> torch.Tensor:
    """``(B,)`` ``||std(mu_hat)||_2``: the spread of the per-trajectory discounted feature
    sums over ``sqrt(n)``, one per set of (validated) demonstrations; 0 when ``n = 1``."""
    out = []
    for demos in demonstrations:
        per = empirical_feature_expectations(features, demos.to(features.device), discount,
                                             reduction="none")  # fmt: skip
        n = per.shape[0]
        var = per.var(0, correction=1).sum() if n > 1 else per.new_zeros(())
        out.append((var / n).sqrt())
    return torch.stack(out)


def _check_rule(rule: object) -> str:
    if rule not in REWARD_RULES:
        raise ValueError(f"expected rule in {REWARD_RULES}, got {rule!r}")
    return str(rule)


def _prepare(
    transition: torch.Tensor,
    features: torch.Tensor,
    demonstrations: Sequence[Trajectories],
    *,
    discount: float,
    start: torch.Tensor | None,
    method: str,
    epsilon: float,
    max_iterations: int,
    horizon: int | None,
    monte_carlo: int | None,
    initial_policy: torch.Tensor | None,
    names: Sequence[str],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Validate everything; return ``T (B, A, S, S)``, ``phi``, ``mu_hat (B, F)``, ``d0 (B, S)``."""
    if method not in ("projection", "qp"):
        raise ValueError(f"expected method 'projection' or 'qp', got {method!r}")
    if isinstance(discount, bool) or not isinstance(discount, (int, float)):
        raise TypeError(f"expected discount to be a float, got {type(discount).__name__}")
    if not 0.0 < discount < 1.0 and horizon is None:
        raise ModelError(f"expected discount in (0, 1) (or a finite horizon), got {discount}")
    if not 0.0 < discount <= 1.0:
        raise ModelError(f"expected discount in (0, 1], got {discount}")
    if not epsilon >= 0.0:
        raise ValueError(f"expected epsilon >= 0, got {epsilon}")
    if (
        isinstance(max_iterations, bool)
        or not isinstance(max_iterations, int)
        or max_iterations < 1
    ):
        raise ValueError(f"expected max_iterations to be an int >= 1, got {max_iterations!r}")
    if horizon is not None and (not isinstance(horizon, int) or horizon < 1):
        raise ValueError(f"expected horizon to be an int >= 1 or None, got {horizon!r}")
    if monte_carlo is not None and (not isinstance(monte_carlo, int) or monte_carlo < 1):
        raise ValueError(f"expected monte_carlo to be an int >= 1 or None, got {monte_carlo!r}")
    T = _check_transition(transition)
    if not T.is_floating_point() or T.dtype not in (torch.float32, torch.float64):
        T = T.to(torch.float64)
    B, A, S = T.shape[0], T.shape[-3], T.shape[-1]
    phi = check_features(features, S, A).to(T.dtype)
    if len(demonstrations) != B:
        raise ModelError(
            f"expected {B} sets of demonstrations (one per MDP), got {len(demonstrations)}"
        )
    mu_hats, starts = [], []
    for b, (demos, name) in enumerate(zip(demonstrations, names)):
        if not isinstance(demos, Trajectories):
            raise TypeError(f"expected {name} to be Trajectories, got {type(demos).__name__}")
        if demos.num_trajectories == 0:
            raise ModelError(f"{name} is empty: IRL needs at least one demonstration")
        demos = demos.to(T.device)
        check_trajectories(demos, T[b], name=name)
        mu_hats.append(empirical_feature_expectations(phi, demos, discount))
        starts.append(start_distribution(demos, S, dtype=T.dtype).to(T.device))
    mu_hat = torch.stack(mu_hats)
    if start is None:
        d0 = torch.stack(starts)
    else:
        d0 = check_tensor("start", start).to(T.dtype)
        check_shape("start", d0, (S,), f"(S={S},) or (B={B}, S={S})")
        check_probabilities("start", d0)
        d0 = d0.expand(B, S)
    if initial_policy is not None:
        initial_policy = check_tensor("initial_policy", initial_policy, floating=False)
        if initial_policy.is_floating_point():
            raise TypeError("expected initial_policy to be an int64 tensor of actions (S,)")
        check_shape("initial_policy", initial_policy, (S,), f"(S={S},)")
        if initial_policy.min() < 0 or initial_policy.max() >= A:
            raise ModelError(f"expected initial_policy actions in [0, {A})")
    return T, phi, mu_hat, d0, initial_policy


def apprenticeship_learning(
    transition: torch.Tensor,
    features: torch.Tensor,
    demonstrations: Trajectories,
    *,
    discount: float,
    method: Method = "projection",
    rule: RewardRule = "closest",
    epsilon: float = 1e-2,
    max_iterations: int = 50,
    start: torch.Tensor | None = None,
    horizon: int | None = None,
    monte_carlo: int | None = None,
    initial_policy: torch.Tensor | None = None,
    seed: int = 0,
    generator: torch.Generator | None = None,
    vi_tol: float = 1e-8,
    qp_solver: str = "CLARABEL",
    qp_options: dict[str, Any] | None = None,
    warn: bool = True,
) -> ApprenticeshipResult:
    """Learn reward weights from demonstrations by Abbeel & Ng's algorithm (the paper's IRL).

    Args:
        transition: ``(A, S, S)`` transition probabilities of the (known) MDP.
        features: ``(S, F)`` state or ``(S, A, F)`` state-action features ``phi``.
        demonstrations: the expert's trajectories (unequal lengths allowed).
        discount: discount factor ``gamma`` of the feature expectations.
        method: ``"projection"`` (Abbeel & Ng 2004, Sec. 3.1) or ``"qp"`` (the paper's
            quadratic program, solved with cvxpy).
        rule: which ``w^(i)`` becomes ``weights``: ``"closest"`` (default; the one whose
            policy's feature expectations are nearest the expert's), ``"dominant"``,
            ``"paper"`` (the paper's mean over the second half of the iterations, poor when
            the margin stalls: see the module docstring) or ``"last"``.
        epsilon: stop when the margin ``t = ||mu_hat - mu(mixture)||_2 <= epsilon``
            (in feature-expectation units).
        max_iterations: at most this many policies are computed by RL.
        start: ``(S,)`` initial state distribution D of ``mu(pi)``; default the empirical
            distribution of the demonstrations' first states.
        horizon: feature expectations over H steps (use the demonstrations' length when
            every demonstration ends at the task's end); None = infinite horizon.
        monte_carlo: estimate ``mu(pi)`` from this many sampled trajectories (the paper's
            "approximate via Monte-Carlo"); None = exact (one batched linear solve).
        initial_policy: ``(S,)`` int64 ``pi^(0)``; default uniformly random actions.
        seed: seed of the random start policy and Monte Carlo sampling.
        generator: a ``torch.Generator`` used instead of ``seed``.
        vi_tol: accuracy of the value iteration in step 4.
        qp_solver: cvxpy solver of the QP (``method="qp"``).
        qp_options: extra keyword arguments of ``cvxpy.Problem.solve``.
        warn: emit the :class:`IRLConvergenceWarning` below (``False``: the caller reads
            ``converged``, ``stop_reason``, ``margins`` and ``expert_standard_error``).

    Returns:
        :class:`ApprenticeshipResult` (reward weights, policies, lambda, mu, margins,
        ``converged`` and ``stop_reason``).

    Warns:
        IRLConvergenceWarning: the margin did not reach ``epsilon`` (the loop stalled or hit
            ``max_iterations``); the message gives the margin and the expert's sampling
            error.

    Raises:
        ModelError: features and MDP of different sizes, empty demonstrations, a
            demonstration that visits an impossible transition (``T = 0``), bad arguments.
        QPError: the QP solver reports a status other than optimal (solver and status named).

    Example:
        >>> from torchhrc.tasks.gridworld import Gridworld
        >>> world = Gridworld(size=4, goal=(3, 3), hazards=((1, 2),), slip=0.0)
        >>> res = apprenticeship_learning(world.transition, world.features(),
        ...     world.demonstrations(20, 30, seed=0), discount=0.9, horizon=30, epsilon=0.05)
        >>> res.converged
        True
    """
    transition = check_tensor("transition", transition)
    if transition.dim() != 3:
        raise ModelError(
            "expected transition of shape (A, S, S) (use learn_type_rewards for a batch), "
            f"actual shape = {tuple(transition.shape)}"
        )
    rule = _check_rule(rule)  # type: ignore[assignment]
    T, phi, mu_hat, d0, pi0 = _prepare(
        transition.unsqueeze(0),
        features,
        [demonstrations],
        discount=discount,
        start=start,
        method=method,
        epsilon=epsilon,
        max_iterations=max_iterations,
        horizon=horizon,
        monte_carlo=monte_carlo,
        initial_policy=initial_policy,
        names=["demonstrations"],
    )
    if generator is None:
        generator = torch.Generator(device=T.device).manual_seed(seed)
    return _run_batched(
        T,
        phi,
        mu_hat,
        d0,
        discount=discount,
        method=method,
        epsilon=epsilon,
        max_iterations=max_iterations,
        horizon=horizon,
        monte_carlo=monte_carlo,
        initial_policy=pi0,
        generator=generator,
        vi_tol=vi_tol,
        qp_solver=qp_solver,
        qp_options=qp_options,
        standard_error=_standard_errors(phi, [demonstrations], discount),
        rule=rule,
        warn=warn,
    )[0]
