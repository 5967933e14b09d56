"""Human-robot separation of the place-and-drill policies, replayed in the SAPIEN workbench.

The paper scores policies by accumulated reward. The types differ in exactly what a physical
scene can measure: a "safe" person wants the robot to wait until every screw is placed (a
drill working next to a placing hand is a hazard), an "efficient" person accepts it. This
module samples simulated executions of each policy (learned, hand-coded, cross-training; in
the offline case and, when run, the online one) for subjects of each type, replays them in
:class:`~torchhrc.tasks.place_and_drill.workbench.PlaceAndDrillScene`
(:func:`~torchhrc.tasks.place_and_drill.replay.replay_execution`) and summarises, per case,
policy and true type, the per-step minimum separations: median, 5th percentile, the fraction of
steps below ``threshold`` and the robot-person contact points.

Sampling (:class:`TraceSampler`): in each sampled subject's simulation, the first ``runs``
executions at ``epsilon`` (their bench states and robot actions), for the first ``subjects``
subjects of each type, in subject order. Deterministic under the study's seed.

Example:
    >>> sampler = TraceSampler(runs=2, epsilon=0.0, subjects=1)
    >>> sampler.wants("S01", "safe"), sampler.wants("S02", "safe")
    (True, False)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch

__all__ = ["ReplayedExecution", "TraceSampler", "separation_study", "summarise"]


@dataclass(frozen=True)
class ReplayedExecution:
    """One sampled execution and, once replayed, its per-step measurements.

    Attributes:
        case: ``"offline"`` or ``"online"``.
        policy: ``"learned"``, ``"hand_coded"`` or ``"cross_training"``.
        true_type: the subject's type.
        subject: the subject.
        states: ``(H + 1,)`` int64 bench states; actions: ``(H,)`` int64 robot actions.
    """

    case: str
    policy: str
    true_type: str
    subject: str
    states: torch.Tensor
    actions: torch.Tensor


@dataclass
class TraceSampler:
    """Collects the executions to replay (see the module docstring).

    Attributes:
        runs: executions per (subject, policy, case).
        epsilon: the deviation probability of the sampled executions.
        subjects: subjects sampled per type.
    """

    runs: int = 2
    epsilon: float = 0.0
    subjects: int = 1
    executions: list[ReplayedExecution] = field(default_factory=list)
    _chosen: dict[str, list[str]] = field(default_factory=dict)

    def wants(self, subject: str, true_type: str) -> bool:
        """Whether ``subject`` (of ``true_type``) is sampled (the first few of each type)."""
        chosen = self._chosen.setdefault(true_type, [])
        if subject in chosen:
            return True
        if len(chosen) < self.subjects:
            chosen.append(subject)
            return True
        return False

    def hook(self, case: str, subject: str, true_type: str) -> Callable[[Any, Any], None] | None:
        """An ``on_trace`` callback for :func:`~torchhrc.experiments.robustness.
        simulate_subject`, or ``None`` when the subject is not sampled."""
        if not self.wants(subject, true_type):
            return None

        def take(trace: Any, eps: torch.Tensor) -> None:
            picked = torch.nonzero((eps - self.epsilon).abs() < 1e-9).flatten()[: self.runs]
            for name in trace.states:
                for b in picked.tolist():
                    self.executions.append(ReplayedExecution(
                        case, name, true_type, subject,
                        trace.states[name][:, b].clone(), trace.actions[name][:, b].clone(),
                    ))  # fmt: skip

        return take


def _quantile(values: torch.Tensor, q: float) -> float:
    return float(torch.quantile(values, q)) if values.numel() else math.nan


def summarise(
    rows: list[tuple[ReplayedExecution, Any]], threshold: float
) -> dict[str, dict[str, dict[str, dict[str, float | int]]]]:
    """``{case: {policy: {type: stats}}}``: ``median_m``, ``p5_m``, ``fraction_below``,
    ``contacts``, ``steps``, ``executions`` of the per-step minimum separations.

    Example:
        >>> import torch
        >>> from types import SimpleNamespace
        >>> e = ReplayedExecution("offline", "learned", "safe", "S01", torch.zeros(3),
        ...                       torch.zeros(2))
        >>> r = SimpleNamespace(separation=torch.tensor([0.05, 0.3]),
        ...                     contacts=torch.tensor([0, 2]))
        >>> summarise([(e, r)], 0.1)["offline"]["learned"]["safe"]["fraction_below"]
        0.5
    """
    groups: dict[tuple[str, str, str], list[Any]] = {}
    for execution, replay in rows:
        key = (execution.case, execution.policy, execution.true_type)
        groups.setdefault(key, []).append(replay)
    out: dict[str, dict[str, dict[str, dict[str, float | int]]]] = {}
    for (case, policy, label), replays in groups.items():
        seps = torch.cat([r.separation for r in replays])
        contacts = int(sum(int(r.contacts.sum()) for r in replays))
        out.setdefault(case, {}).setdefault(policy, {})[label] = {
            "median_m": round(_quantile(seps, 0.5), 4),
            "p5_m": round(_quantile(seps, 0.05), 4),
            "fraction_below": round(float((seps < threshold).double().mean()), 4)
            if seps.numel() else math.nan,
            "contacts": contacts,
            "steps": int(seps.numel()),
            "executions": len(replays),
        }  # fmt: skip
    return out


def separation_study(
    task: Any,
    executions: list[ReplayedExecution],
    *,
    threshold: float = 0.10,
    seed: int = 0,
    layout: Any | None = None,
) -> dict[str, Any]:
    """Replay ``executions`` in one workbench scene and summarise them.

    Returns:
        ``{"available": True, "threshold_m", "summary" (see :func:`summarise`),
        "per_step": [{case, policy, true_type, separation: [...], contacts: [...]}, ...],
        "time_s"}``; ``{"available": False, "note"}`` without SAPIEN.
    """
    try:
        import sapien  # noqa: F401
    except ImportError:
        note = "SAPIEN is not installed (pip install torchhrc[sim]); no replay"
        return {"available": False, "note": note}
    from torchhrc.tasks.place_and_drill.replay import execution_steps, replay_execution
    from torchhrc.tasks.place_and_drill.workbench import PlaceAndDrillScene, WorkbenchLayout

    start = time.perf_counter()
    scene = PlaceAndDrillScene(layout or WorkbenchLayout(n_positions=task.n_positions), seed=seed)
    rows = []
    for execution in executions:
        drill, place = execution_steps(task, execution.states, execution.actions)
        rows.append((execution, replay_execution(scene, drill, place)))
    return {
        "available": True,
        "threshold_m": threshold,
        "summary": summarise(rows, threshold),
        "per_step": [
            {
                "case": e.case,
                "policy": e.policy,
                "true_type": e.true_type,
                "subject": e.subject,
                "separation": [round(float(v), 4) for v in r.separation],
                "contacts": r.contacts.tolist(),
            }
            for e, r in rows
        ],
        "time_s": time.perf_counter() - start,
    }
