"""From a task and demonstrations to a learned, solved MOMDP: one call, the same for every task.

Paper (Nikolaidis et al., Fig. 1): demonstrations -> clustering into human types (mixture of
Markov chains, BIC picks ``k``) -> per-type human behaviour (the transition ``Tx``) -> a
reward per type by inverse reinforcement learning (Abbeel & Ng 2004) -> the MOMDP over
``(x, type)`` -> solved by SARSOP (Kurniawati et al. 2008; Ong et al. 2010). Every piece
that depends on the task is asked of the :class:`~torchhrc.tasks.interface.CollaborativeTask`
through its interface; the pipeline never looks at which task it holds.

* :func:`learn`: everything, ``learn(task, demos, seed=0) -> LearnedModel``;
* :func:`build_model`: the model from given clusters (chains and assignments), no solve;
* :func:`solve_model`: SARSOP on a built model.

A :class:`LearnedModel` is what a researcher inspects (clusters, rewards, behaviour, policy,
bounds) and is saved / loaded with :meth:`LearnedModel.save` / :meth:`LearnedModel.load`
(safetensors for the tensors, JSON for the rest, written atomically).

Example:
    >>> from torchhrc.tasks.place_and_drill import PlaceAndDrillTask
    >>> from torchhrc.tasks.place_and_drill.demos import simulate_study
    >>> demos = simulate_study(n_subjects=4, n_demos=2, seed=0)
    >>> model = learn(PlaceAndDrillTask(3), demos, k_max=3, restarts=2, solver_time=1.0)
    >>> model.num_types, model.momdp.num_observed
    (2, 27)
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import torch
import torch.nn.functional as F

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.tasks.divided_types import divided_states, split_divided
from torchhrc.tasks.human_model_choice import (
    HUMAN_MODELS,
    STATE_SMOOTHING_GRID,
    compare_human_models,
    state_smoothing_pair,
)
from torchhrc.tasks.interface import (
    CollaborativeTask,
    TaskSteps,
    TypeEvidence,
    check_task,
    offscript_lifts,
    reaction_weights,
)
from torchhrc.tasks.wrong_moves import price_wrong_moves

if TYPE_CHECKING:
    from torchhrc.mixture.selection import ClusterConfig, MixtureFit

__all__ = [
    "IRLConfig",
    "LearnedModel",
    "build_model",
    "cluster_options",
    "compare_human_models",
    "find_types",
    "learn",
    "learn_type_weights",
    "partner_moves",
    "solve_model",
    "solve_momdp",
    "split_divided_types",
    "task_momdp",
    "transition_from_behaviour",
]

_FORMAT = "torchhrc.learned_task_model"
_VERSION = 1

RewardRule = Literal["maxent", "dominant", "paper", "last"]
WrongMoves = Literal["symmetric", "learned"]

#: The values of ``IRLConfig.wrong_moves``.
WRONG_MOVES: tuple[str, ...] = ("symmetric", "learned")

#: The reward rules :func:`learn_type_weights` accepts.
REWARD_RULES: tuple[str, ...] = ("maxent", "dominant", "paper", "last")

#: The ridge penalty of the ``"maxent"`` rule (``IRLConfig.l2``'s default). Chosen on the task
#: suite over 10 seeds (docs/evaluation_history.md, "The MaxEnt ridge"): at
#: :func:`torchhrc.irl.maxent_irl`'s 1e-3 the rewards of near-deterministic partners grow to
#: +-20 (log-odds of their slips), every move a type's partner never made in a state the type
#: visits costs as much as any other, and the type-aware robot steered into states no
#: partner led to (behind the pooled robot on 3 of 90 suite runs); from 0.1 to 1 no run is
#: behind, 0.1 the smallest. The held-out tasks, not used to choose: behind on none of 90
#: (2 at 1e-3), ahead on 53 (40).
MAXENT_L2 = 0.1

#: The prior correlation of the types' rewards under the ``"maxent"`` rule (``IRLConfig.pooling``,
#: :func:`torchhrc.irl.maxent_irl_types`): with ``p > 0`` each type's reward is a part shared
#: by all types plus a part of its own, so that a state-action pair a type's demonstrations
#: never reach gets its reward from the types that reach it. 0 (each type alone) by default:
#: over the task suite and the held-out tasks pooling won some runs and lost as many
#: (docs/evaluation_history.md, "Pooling the types' rewards").
MAXENT_POOLING = 0.0

#: ``learn()``'s ``min_gain`` and ``strong_gain`` with the soft method, nats per transition
#: (``fit_mixture``'s own default, :data:`~torchhrc.mixture.selection.DEFAULT_MIN_GAIN`,
#: 0.015, stays for the paper's pipelines and ``torchhrc cluster``). Types whose difference is
#: one step of a long demonstration gain 0.010-0.014 a transition (the held-out tasks
#: ``press_block``: two steps in either order at one part of four; ``tool_rhythm``), a
#: sub-cluster of one type's people 0.002-0.006; over the suite and 30 held-out tasks,
#: 0.01 found the true k on 389 of 390 runs at 300 x 4 (379 at 0.015) and on one run fewer
#: at 30 x 4 (docs/clustering.md, "A smaller gain for learn()").
LEARN_MIN_GAIN = 0.01

#: ``learn()``'s ``heldout_gain`` as a share of its ``strong_gain``: a strong step is kept
#: where it also gains half its in-sample effect size on held-out subjects (``fit_mixture``'s
#: own :data:`~torchhrc.mixture.selection.DEFAULT_HELDOUT_GAIN`, 0.01, stays for the paper's
#: pipelines and ``torchhrc cluster``). Near that effect size a real type's held-out gain is a
#: median three quarters of its in-sample gain, a spurious cluster's a fifth; 0.01 held out
#: asked a step for its whole in-sample effect on subjects it never saw. Over the suite and 33
#: held-out tasks at 30 x 4, 0.005 found the true k on 392 of 420 runs (0.01: 387; 0.0025: 392,
#: one partition worse), at 300 x 4 on 410 as before (docs/clustering.md, "The held-out
#: gain").
LEARN_HELDOUT_SHARE = 0.5

#: ``learn()``'s EM restarts per k (``fit_mixture``'s ``restarts``): the paper's
#: numOfIterations, 20. Ten found the true k with ARI >= 0.9 on 382 of the 420 runs at 30 x 4
#: over the suite and 33 held-out tasks (seeds 0-9), twenty on 387, at about 1.5 times the
#: clustering time (docs/clustering.md, "Twenty restarts").
LEARN_RESTARTS = 20

#: The L-BFGS iteration cap of the ``"maxent"`` rule.
MAXENT_ITERATIONS = 300


@dataclass(frozen=True, kw_only=True)
class IRLConfig:
    """Settings of the reward learning per type (:func:`learn_type_weights`).

    Attributes:
        rule: ``"maxent"`` (default): maximum-entropy IRL (Ziebart), or which reward of Abbeel
            and Ng's iterations is kept: ``"dominant"``, ``"paper"`` or ``"last"``
            (:func:`learn_type_weights`). Why MaxEnt by default: with the per-``(a_r, x)``
            indicator features of a task without compact ones, the projection algorithm
            leaves the reward of every pair the type's ~40 demonstrations never show near 0
            (an idle loop in a state off their path is worth as much as finishing the task,
            and an action the type's partner never took is not penalised), whereas MaxEnt's
            gradient lowers the reward of every pair its soft policy takes and the expert
            does not (``docs/evaluation_history.md``, "The MaxEnt ridge").
        epsilon: the projection algorithm's stopping margin on the feature expectations
            (default 0.05; the projection rules only).
        iterations: cap on the IRL iterations (policies) per type (default 10; the
            projection rules only; ``"maxent"`` runs up to :data:`MAXENT_ITERATIONS` L-BFGS
            iterations).
        l2: the ridge of ``"maxent"`` on the reward weights (default :data:`MAXENT_L2`; the
            other rules ignore it).
        pooling: in [0, 1), the prior correlation of the types' rewards under ``"maxent"``
            (default :data:`MAXENT_POOLING`; 0: each type's reward learned from its own
            demonstrations alone; :func:`torchhrc.irl.maxent_irl_types`).
        wrong_moves: ``"symmetric"`` (default): where the types' partners made different
            moves, a move a type's partners never made costs it as much below a wait as its
            own move gains above it, or, for a type whose own move is the wait, as much as
            the move gains the types whose own move it is
            (:func:`~torchhrc.tasks.wrong_moves.price_wrong_moves`); ``"learned"``: the
            rewards as IRL gives them.

    Example:
        >>> IRLConfig(epsilon=0.01).rule
        'maxent'
    """

    rule: RewardRule = "maxent"
    epsilon: float = 0.05
    iterations: int = 10
    l2: float = MAXENT_L2
    pooling: float = MAXENT_POOLING
    wrong_moves: WrongMoves = "symmetric"

    def __post_init__(self) -> None:
        if self.rule not in REWARD_RULES:
            raise ValueError(f"expected rule 'maxent', 'dominant', 'paper' or 'last', "
                             f"got {self.rule!r}")  # fmt: skip
        if not self.epsilon > 0:
            raise ValueError(f"expected epsilon > 0, got {self.epsilon!r}")
        if (
            isinstance(self.iterations, bool)
            or not isinstance(self.iterations, int)
            or (self.iterations < 1)
        ):
            raise ValueError(f"expected iterations to be an int >= 1, got {self.iterations!r}")
        if isinstance(self.l2, bool) or not isinstance(self.l2, (int, float)) or self.l2 < 0:
            raise ValueError(f"expected l2 to be a number >= 0, got {self.l2!r}")
        pooling = self.pooling
        number = isinstance(pooling, (int, float)) and not isinstance(pooling, bool)
        if not number or not 0 <= pooling < 1:
            raise ValueError(f"expected pooling to be a number in [0, 1), got {pooling!r}")
        if self.wrong_moves not in WRONG_MOVES:
            raise ValueError(f"expected wrong_moves 'symmetric' or 'learned', got "
                             f"{self.wrong_moves!r}")  # fmt: skip
        if pooling > 0 and self.rule == "maxent" and self.l2 == 0:
            raise ValueError("pooling > 0 needs a ridge: expected l2 > 0 with pooling "
                             f"{pooling!r}, got l2 = 0")  # fmt: skip


@dataclass(frozen=True)
class LearnedModel:
    """A learned task model (``Y`` types, ``X`` states, ``A`` robot actions).

    Attributes:
        momdp: the MOMDP over ``(x, type)`` (static type).
        weights: ``(Y, F)`` IRL reward weights per type (empty ``(Y, 0)`` when the task gave
            its reward). ``momdp``'s reward is ``phi . w``, lowered where the price of a
            wrong move applies (``info["wrong_moves"]``).
        behaviour: ``(Y, A, X, H + 1)`` human behaviour ``P(a_h | x, a_r, y)`` (last column:
            no action).
        type_names: ``(Y,)`` names of the types.
        chains: ``(Y, V, V)`` the Markov chain of each type over ``vocabulary``.
        vocabulary: ``(V,)`` demonstration symbols.
        assignments: ``(N,)`` int64 type of each training demonstration.
        feature_names: ``(F,)``.
        human_actions: ``(H,)``.
        policy: the solved :class:`~torchhrc.solvers.AlphaVectorPolicy` (``None`` before
            :func:`solve_model`).
        lower, upper: the solver's bounds on the value of ``b0`` (NaN before solving).
        info: extra JSON-able facts (``k``, BIC, settings).
    """

    momdp: MOMDP
    weights: torch.Tensor
    behaviour: torch.Tensor
    type_names: tuple[str, ...]
    chains: torch.Tensor
    vocabulary: tuple[tuple[str, str], ...]
    assignments: torch.Tensor
    feature_names: tuple[str, ...]
    human_actions: tuple[str, ...]
    policy: Any = None
    lower: float = float("nan")
    upper: float = float("nan")
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def num_types(self) -> int:
        """``Y``."""
        return self.momdp.num_hidden

    def with_belief(self, b0: torch.Tensor) -> LearnedModel:
        """The same model with another initial type belief ``b0 (Y,)`` (policy kept)."""
        return replace(self, momdp=replace(self.momdp, b0=b0.to(self.momdp.Tx.dtype)))

    # ------------------------------------------------------------------ save / load
    def save(self, directory: str | os.PathLike[str]) -> Path:
        """Write ``model.safetensors`` and ``model.json`` into ``directory`` atomically.

        The directory is written under a temporary name next to it and renamed; an existing
        directory of that name is replaced.

        Example:
            >>> import tempfile, pathlib
            >>> from torchhrc.testing import random_momdp
            >>> m = random_momdp(3, 2, 2, 1, seed=0)
            >>> lm = LearnedModel(m, torch.zeros(2, 0), torch.zeros(2, 2, 3, 1), ("a", "b"),
            ...                   torch.zeros(2, 1, 1), (("human", "x"),), torch.zeros(0),
            ...                   (), ())
            >>> d = lm.save(pathlib.Path(tempfile.mkdtemp()) / "m")
            >>> LearnedModel.load(d).type_names
            ('a', 'b')
        """
        from safetensors.torch import save_file

        target = Path(directory)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
        m = self.momdp
        tensors: dict[str, torch.Tensor] = {
            "Tx": m.Tx,
            "Z": m.Z,
            "R": m.R,
            "b0": m.b0,
            "weights": self.weights,
            "behaviour": self.behaviour,
            "chains": self.chains,
            "assignments": self.assignments.long(),
        }
        if self.policy is not None:
            tensors["policy_alphas"] = self.policy.alphas
            tensors["policy_actions"] = self.policy.actions
            if self.policy.observed is not None:
                tensors["policy_observed"] = self.policy.observed
        meta = {
            "format": _FORMAT,
            "version": _VERSION,
            "x0": int(m.x0),
            "discount": float(m.discount),
            "observed_states": list(m.observed_states or ()),
            "hidden_states": list(self.type_names),
            "actions": list(m.actions or ()),
            "observations": list(m.observations or ()),
            "type_names": list(self.type_names),
            "vocabulary": [list(v) for v in self.vocabulary],
            "feature_names": list(self.feature_names),
            "human_actions": list(self.human_actions),
            "lower": None if self.lower != self.lower else float(self.lower),
            "upper": None if self.upper != self.upper else float(self.upper),
            "info": self.info,
        }
        try:
            save_file({k: v.detach().contiguous().cpu() for k, v in tensors.items()},
                      str(tmp / "model.safetensors"))  # fmt: skip
            (tmp / "model.json").write_text(json.dumps(meta, indent=2) + "\n")
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; a model is a plain file
            for f in tmp.iterdir():
                os.chmod(f, 0o666 & ~umask)
            if target.exists():
                old = target.with_name(f".{target.name}.old")
                shutil.rmtree(old, ignore_errors=True)
                target.rename(old)
                tmp.rename(target)
                shutil.rmtree(old, ignore_errors=True)
            else:
                tmp.rename(target)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return target

    @classmethod
    def load(cls, directory: str | os.PathLike[str]) -> LearnedModel:
        """Read a model written by :meth:`save`.

        Raises:
            ModelError: a file is missing or malformed (the message names the file and
                the field).
        """
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        from torchhrc.solvers.policy import AlphaVectorPolicy

        root = Path(directory)
        meta_path, tensor_path = root / "model.json", root / "model.safetensors"
        for p in (meta_path, tensor_path):
            if not p.is_file():
                raise ModelError(f"{p}: no such file (expected a directory written by save())")
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError as exc:
            raise ModelError(f"{meta_path}: line {exc.lineno}: {exc.msg}") from None
        if not isinstance(meta, dict) or meta.get("format") != _FORMAT:
            raise ModelError(f"{meta_path}: field 'format': expected {_FORMAT!r}")
        if meta.get("version") != _VERSION:
            raise ModelError(f"{meta_path}: field 'version': expected {_VERSION}, "
                             f"got {meta.get('version')!r}")  # fmt: skip
        try:
            t = load_file(str(tensor_path))
        except (SafetensorError, OSError) as exc:
            raise ModelError(f"{tensor_path}: {exc}") from None
        for key in ("Tx", "Z", "R", "b0", "weights", "behaviour", "chains", "assignments"):
            if key not in t:
                raise ModelError(f"{tensor_path}: tensor {key!r} is missing")
        try:
            momdp = MOMDP(
                Tx=t["Tx"], Ty=None, Z=t["Z"], R=t["R"], x0=int(meta["x0"]), b0=t["b0"],
                discount=float(meta["discount"]),
                observed_states=tuple(meta["observed_states"]) or None,
                hidden_states=tuple(meta["hidden_states"]) or None,
                actions=tuple(meta["actions"]) or None,
                observations=tuple(meta["observations"]) or None,
            )  # fmt: skip
            policy = None
            if "policy_alphas" in t:
                policy = AlphaVectorPolicy(t["policy_alphas"], t["policy_actions"],
                                           t.get("policy_observed"))  # fmt: skip
            return cls(
                momdp=momdp,
                weights=t["weights"],
                behaviour=t["behaviour"],
                type_names=tuple(meta["type_names"]),
                chains=t["chains"],
                vocabulary=tuple((str(a), str(b)) for a, b in meta["vocabulary"]),
                assignments=t["assignments"],
                feature_names=tuple(meta["feature_names"]),
                human_actions=tuple(meta["human_actions"]),
                policy=policy,
                lower=float("nan") if meta["lower"] is None else float(meta["lower"]),
                upper=float("nan") if meta["upper"] is None else float(meta["upper"]),
                info=dict(meta.get("info", {})),
            )
        except KeyError as exc:
            raise ModelError(f"{meta_path}: field {exc.args[0]!r} is missing") from None


# ---------------------------------------------------------------------------- pieces


def _check_types(name: str, value: torch.Tensor, dim: int, Y: int, shape: str) -> torch.Tensor:
    if not isinstance(value, torch.Tensor):
        raise TypeError(f"expected the task's {name} to be a tensor {shape}, got "
                        f"{type(value).__name__}")  # fmt: skip
    if value.dim() <= dim or value.shape[dim] != Y:
        raise ModelError(
            f"the task's {name} has {value.shape[dim] if value.dim() > dim else 'no'} types "
            f"(shape {tuple(value.shape)}), the clustering found Y={Y}; expected {shape}"
        )
    return value


def transition_from_behaviour(task: CollaborativeTask, behaviour: torch.Tensor) -> torch.Tensor:
    """``Tx (A, X, Y, X)`` from the human behaviour ``(Y, A, X, H + 1)`` and the dynamics.

    ``Tx[a, x, y, x'] = sum_h P(h | x, a, y) [human_effect[robot_effect[a, x], h] = x']``,
    with "no action" (the last column) going to ``robot_effect[a, x]``.
    """
    A, X = task.num_actions, task.num_states
    dev, dt = behaviour.device, behaviour.dtype
    mid = torch.as_tensor(task.robot_effect).to(dev)  # (A, X)
    dest = torch.as_tensor(task.human_effect).to(dev)[mid]  # (A, X, H)
    dest = torch.cat([dest, mid.unsqueeze(-1)], -1)  # (A, X, H + 1)
    probs = behaviour.permute(1, 2, 0, 3)  # (A, X, Y, H + 1)
    Y = probs.shape[2]
    index = dest.unsqueeze(2).expand(A, X, Y, dest.shape[-1])
    Tx = torch.zeros(A, X, Y, X, dtype=dt, device=dev)
    return Tx.scatter_add(-1, index, probs.contiguous())


#: A final IRL margin within this many sampling errors of the expert's feature expectations
#: is the demonstrations' noise floor (:func:`learn_type_weights` warns only above it).
IRL_NOISE_FLOOR = 2.0


def learn_type_weights(
    task: CollaborativeTask,
    Tx: torch.Tensor,
    steps: TaskSteps,
    assignments: torch.Tensor,
    *,
    rule: RewardRule = "dominant",
    epsilon: float = 0.05,
    max_iterations: int = 10,
    seed: int = 0,
    l2: float = MAXENT_L2,
    pooling: float = MAXENT_POOLING,
) -> torch.Tensor:
    """Reward weights per type by apprenticeship learning (Abbeel & Ng 2004; paper Sec. IRL).

    For type ``k`` the MDP is ``(X, A, Tx[:, :, k, :], phi, discount)`` and the expert's
    trajectories are the demonstrations of type ``k``. ``rule="maxent"``: maximum-entropy
    IRL of all types at once (:func:`torchhrc.irl.maxent_irl_types`, ridge ``l2``, the
    types' rewards with prior correlation ``pooling``) instead of the projection
    algorithm (``epsilon``, ``max_iterations`` unused; no warning). The projection
    algorithm's reward kept (``rule``):
    ``"dominant"`` (default): ``w^(i*)``, ``i* = argmax_{i >= 1} lambda_i``, the reward of
    the policy the expert's mixture relies on most; ``"paper"``: the mean of ``w^(i)`` over
    the second half of the iterations; ``"last"``: ``w^(M)``. Why not the paper's rule by
    default: with noisy demonstrations (each subject deviates at some steps) the expert's
    feature expectations are not those of any single policy, the margin stalls at the noise
    level and the late ``w^(i)`` point in noise directions. On the simulated place-and-drill
    study (seed 0, 9 subjects per type) the optimal policies of the second-half mean
    contradict the type's demonstrated rule in 7 (safe) and 13 (efficient) of the 19 states
    with a screw waiting, the dominant policy's reward in 0.

    Returns:
        ``(K, F)`` weights (zeros for a type without demonstrations).

    Warns:
        IRLConvergenceWarning: at most one per call, naming the types whose final margin
            stayed above both ``epsilon`` and the demonstrations' noise floor
            (:data:`IRL_NOISE_FLOOR` times the sampling error of their feature
            expectations), and what to do about it. A margin at the noise floor is what
            noisy demonstrations give; it is not reported.
    """
    import warnings

    from torchhrc.irl.maxent import maxent_irl_types
    from torchhrc.irl.projection import IRLConvergenceWarning, apprenticeship_learning
    from torchhrc.irl.trajectories import Trajectories

    if rule not in REWARD_RULES:
        raise ValueError(f"expected rule 'maxent', 'dominant', 'paper' or 'last', got {rule!r}")
    K = Tx.shape[-2]
    phi = task.features(dtype=Tx.dtype, device=Tx.device).permute(1, 0, 2)  # (X, A, F)
    weights = Tx.new_zeros(K, phi.shape[-1])
    stuck: list[tuple[int, float, float, bool]] = []  # (type, margin, sampling error, falling)
    lengths = steps.lengths
    assignments = assignments.to(steps.states.device)
    per_type: dict[int, Trajectories] = {}
    for k in range(K):  # a handful of types
        idx = torch.nonzero((assignments == k) & (lengths > 0)).flatten()
        if idx.numel():
            per_type[k] = Trajectories(steps.states[idx], steps.actions[idx], lengths[idx])
    if rule == "maxent":
        if per_type:
            ks = list(per_type)
            fit = maxent_irl_types(Tx.permute(2, 0, 1, 3)[ks], phi, list(per_type.values()),
                                   discount=task.discount, l2=l2, pooling=pooling,
                                   max_iterations=MAXENT_ITERATIONS)  # fmt: skip
            weights[ks] = fit.weights
        return weights
    for k, demos in per_type.items():
        result = apprenticeship_learning(
            Tx[:, :, k, :], phi, demos, discount=task.discount, epsilon=epsilon,
            max_iterations=max_iterations, seed=seed, rule=rule, warn=False,
        )  # fmt: skip
        weights[k] = result.weights  # the pick of `rule`
        floor = max(epsilon, IRL_NOISE_FLOOR * result.expert_standard_error)
        if not result.converged and result.margin > floor:
            margins = result.margins
            falling = len(margins) > 2 and float(margins[-1]) < 0.95 * float(margins[-3])
            stuck.append((k, result.margin, result.expert_standard_error, falling))
    if stuck:
        rows = ", ".join(
            f"type {k}: margin {m:.3g} (noise floor {IRL_NOISE_FLOOR:g} x {se:.3g})"
            for k, m, se, _ in stuck
        )
        if any(falling for *_, falling in stuck):
            hint = (
                f"the margin was still falling: allow more iterations (learn(..., "
                f"irl=IRLConfig(iterations={2 * max_iterations})) or irl_iterations=)"
            )
        else:
            hint = (
                "the margin had stopped falling: under the learned human behaviour no robot "
                "policy reproduces what these types' demonstrations do with these features; "
                "try the other human model (learn(..., human_model='chain' or 'state')) or "
                "features that describe the types' choices (CollaborativeTask.features)"
            )
        warnings.warn(
            f"reward learning (Abbeel-Ng IRL, rule={rule!r}, epsilon={epsilon:g}, "
            f"{max_iterations} iterations) did not match the demonstrations of "
            f"{len(stuck)} of {K} types beyond their noise floor: {rows}. Their rewards may "
            f"be poor; {hint}.",
            IRLConvergenceWarning,
            stacklevel=2,
        )
    return weights


def build_model(
    task: CollaborativeTask,
    demonstrations: Any,
    chains: torch.Tensor,
    assignments: torch.Tensor,
    *,
    b0: torch.Tensor | None = None,
    noise: float = 0.05,
    pause: float = 0.01,
    rule: RewardRule = "dominant",
    irl_epsilon: float = 0.05,
    irl_iterations: int = 10,
    seed: int = 0,
    info: dict[str, Any] | None = None,
    irl_l2: float = MAXENT_L2,
    human_model: str | None = None,
    irl_pooling: float = MAXENT_POOLING,
    state_smoothing: tuple[float, float] | str = "auto",
    wrong_moves: WrongMoves = "learned",
) -> LearnedModel:
    """Build the learned MOMDP from given types (no solve).

    Args:
        task: the task.
        demonstrations: the training :class:`~torchhrc.data.Demonstrations`.
        chains: ``(K, V, V)`` Markov chain of each type over the demonstrations' vocabulary.
        assignments: ``(N,)`` int64 type of each demonstration.
        b0: ``(K,)`` initial type belief (uniform by default).
        noise: weight of a random legal human action in the behaviour (:class:`TypeEvidence`).
        pause: probability of a skipped human turn.
        rule, irl_epsilon, irl_iterations, irl_l2, irl_pooling, seed: IRL settings
            (:func:`learn_type_weights`'s ``rule``, ``epsilon``, ``max_iterations``, ``l2``,
            ``pooling``).
        info: extra facts stored with the model.
        human_model: ``"chain"``, ``"state"`` or ``"auto"`` (:attr:`CollaborativeTask.human_model`
            of the default human policy); ``None``: the task's own ``human_model``. With
            ``"auto"`` the better of the two on held-out likelihood by subject is used
            (:func:`compare_human_models`); ``info["human_model"]`` records the choice and
            the held-out likelihoods, and with the state model each type's weight on its
            reaction to the robot's move (``"reaction"``,
            :func:`~torchhrc.tasks.interface.reaction_weights`) and how many more turns it
            lets pass after moves off its partners' script (``"offscript_lift"``,
            :func:`~torchhrc.tasks.interface.offscript_lifts`).
        state_smoothing: the state model's ``(habit_weight, prior_strength)``
            (:class:`~torchhrc.tasks.interface.TypeEvidence`), or ``"auto"``: the best of
            :data:`~torchhrc.tasks.human_model_choice.STATE_SMOOTHING_GRID` on held-out
            subjects, chosen with the human model (or alone when ``"state"`` is asked for);
            recorded in ``info["human_model"]["state_smoothing"]``.
        wrong_moves: ``"learned"`` (default here; the paper pipelines): the rewards as IRL
            gives them; ``"symmetric"`` (``learn()``'s default): priced in the contested
            states by :func:`~torchhrc.tasks.wrong_moves.price_wrong_moves`, the number of
            rewards lowered recorded as ``info["wrong_moves"]``. Only for learned rewards
            (a task's ``known_reward()`` is kept as given).

    Returns:
        :class:`LearnedModel` with ``policy=None``.

    Raises:
        ModelError: an inconsistent task (bad tables, a demonstration step the dynamics
            cannot produce, features of the wrong shape, a type-dependent piece with the
            wrong number of types) or inputs of the wrong shape.
    """
    check_task(task)
    Demonstrations.check(demonstrations)
    chains = chains.detach().to(torch.float64)
    if chains.dim() != 3 or chains.shape[1] != chains.shape[2]:
        raise ModelError(f"expected chains of shape (K, V, V), got {tuple(chains.shape)}")
    K = chains.shape[0]
    N = demonstrations.num_sequences
    if tuple(assignments.shape) != (N,):
        raise ModelError(f"expected assignments of shape (N={N},), got {tuple(assignments.shape)}")
    if N and (int(assignments.min()) < 0 or int(assignments.max()) >= K):
        raise ModelError(f"expected assignments in [0, {K}), got range "
                         f"[{int(assignments.min())}, {int(assignments.max())}]")  # fmt: skip
    A, X, H = task.num_actions, task.num_states, task.num_human_actions
    requested = getattr(task, "human_model", None) if human_model is None else human_model
    if requested not in (None, "auto", *HUMAN_MODELS):
        raise ValueError(f"expected human_model 'auto', 'chain' or 'state' (or None), "
                         f"got {requested!r}")  # fmt: skip
    if wrong_moves not in WRONG_MOVES:
        raise ValueError(f"expected wrong_moves 'symmetric' or 'learned', got {wrong_moves!r}")
    priced: dict[str, Any] = {"rule": "learned", "lowered": 0, "states": 0}
    given = state_smoothing_pair(state_smoothing)
    chosen: dict[str, Any] = {"requested": requested}
    if requested == "auto" or (requested == "state" and given is None):
        scored = HUMAN_MODELS if requested == "auto" else ("state",)
        chosen.update(compare_human_models(task, demonstrations, assignments, noise=noise,
                                           pause=pause, seed=seed, models=scored,
                                           state_smoothing=given))  # fmt: skip
        model_name = chosen["used"] if chosen["used"] in HUMAN_MODELS else None
    else:
        chosen["used"] = requested
        model_name = requested
    smoothing = chosen.get("state_smoothing")
    if smoothing is None:
        w, c = given if given is not None else STATE_SMOOTHING_GRID[0]
        smoothing = chosen["state_smoothing"] = {"habit_weight": w, "prior_strength": c}
    steps = task.read_steps(demonstrations)
    evidence = TypeEvidence(
        chains=chains,
        vocabulary=tuple(tuple(v) for v in demonstrations.vocabulary),  # type: ignore[misc]
        assignments=assignments.long(),
        steps=steps,
        noise=noise,
        pause=pause,
        human_model=model_name,
        **smoothing,
    )
    if model_name == "state" and steps is not None:
        chosen["reaction"] = reaction_weights(task, evidence).tolist()
        chosen["offscript_lift"] = offscript_lifts(task, evidence).tolist()
    behaviour = _check_types("human_policy()", task.human_policy(evidence), 0, K,
                             f"(Y={K}, A={A}, X={X}, H+1={H + 1})")  # fmt: skip
    if tuple(behaviour.shape) != (K, A, X, H + 1):
        raise ModelError(f"expected the task's human_policy() of shape (Y={K}, A={A}, X={X}, "
                         f"H+1={H + 1}), got {tuple(behaviour.shape)}")  # fmt: skip
    if (behaviour < 0).any() or not torch.allclose(
        behaviour.sum(-1), torch.ones((), dtype=behaviour.dtype), atol=1e-8
    ):
        raise ModelError("the task's human_policy() rows must be probabilities summing to 1")
    Tx = transition_from_behaviour(task, behaviour)
    R = task.known_reward(evidence)
    if R is None:
        if steps is None:
            raise ModelError(
                "the task reads no demonstration steps (read_steps() gave None) and gives no "
                "known_reward(): IRL needs the steps; implement one of the two"
            )
        weights = learn_type_weights(task, Tx, steps, evidence.assignments, rule=rule,
                                     epsilon=irl_epsilon, max_iterations=irl_iterations,
                                     seed=seed, l2=irl_l2, pooling=irl_pooling)  # fmt: skip
        phi = task.features(dtype=weights.dtype, device=weights.device)
        R = torch.einsum("axf,yf->axy", phi, weights)
        if wrong_moves == "symmetric":
            R, capped = price_wrong_moves(R, steps, evidence.assignments, task.robot_effect)
            priced = {"rule": wrong_moves, "lowered": int(capped.sum()),
                      "states": int(capped.any(0).any(-1).sum())}  # fmt: skip
    else:
        R = _check_types("known_reward()", R, 2, K, f"(A={A}, X={X}, Y={K})").to(Tx.dtype)
        if tuple(R.shape) != (A, X, K):
            raise ModelError(f"expected the task's known_reward() of shape (A={A}, X={X}, "
                             f"Y={K}), got {tuple(R.shape)}")  # fmt: skip
        weights = Tx.new_zeros(K, 0)
    if b0 is not None and tuple(b0.shape) != (K,):
        raise ModelError(f"expected b0 of shape (Y={K},), got {tuple(b0.shape)}")
    names = tuple(task.type_names(evidence))
    if len(names) != K:
        raise ModelError(f"the task's type_names() gave {len(names)} names for Y={K} types")
    momdp = task_momdp(task, Tx, R, b0, type_names=names)
    divided = _divided(task, steps, evidence.assignments, demonstrations, names, info)
    return LearnedModel(
        momdp=momdp,
        weights=weights,
        behaviour=behaviour,
        type_names=names,
        chains=chains,
        vocabulary=evidence.vocabulary,
        assignments=evidence.assignments,
        feature_names=tuple(task.feature_names) if R is not None and weights.numel() else (),
        human_actions=tuple(task.human_actions),
        info={
            **dict(info or {}),
            "human_model": chosen,
            "wrong_moves": priced,
            "divided": divided,
        },
    )


#: The most divided states ``info["divided"]["where"]`` lists (the count is of all).
DIVIDED_LISTED = 10


def partner_moves(
    task: CollaborativeTask, steps: TaskSteps, *, objects: str = "raw", separator: str = "_"
) -> tuple[TaskSteps, tuple[str, ...]]:
    """The robot's moves as a difference between types reads them.

    With ``objects="raw"`` every robot action is its own move. With ``"exchangeable"`` (the
    clustering's reading of the actions' objects as interchangeable names:
    ``docs/your_own_task.md``, "Action names carry objects") a robot action
    ``<verb><separator><object>`` is its verb: ``drill_A`` and ``drill_B`` are one move, as
    the clustering read them. Partners who drilled different screws in one state then do not
    divide a type: which screw follows the person's own placement order, her history, not
    her type.

    Args:
        task: the task.
        steps: its steps (:meth:`CollaborativeTask.read_steps`).
        objects: ``"raw"`` or ``"exchangeable"`` (``MixtureFit.objects``).
        separator: the separator between verb and object.

    Returns:
        The steps with ``actions`` as move ids and the moves' names (``(A',)``).

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> twp = make_task("screws_hands_off")  # robot actions: wait, drill_A, drill_B, drill_C
        >>> demos, _ = twp.demonstrations(subjects=3, per_subject=1, seed=0)
        >>> partner_moves(twp.task, twp.task.read_steps(demos), objects="exchangeable")[1]
        ('wait', 'drill')
    """
    names = tuple(task.robot_actions)
    if objects != "exchangeable":
        return steps, names
    verbs = [n.rsplit(separator, 1)[0] if separator in n else n for n in names]
    moves = tuple(dict.fromkeys(verbs))
    index = torch.tensor([moves.index(v) for v in verbs], device=steps.actions.device)
    actions = torch.where(steps.mask, index[steps.actions.clamp(0, len(names) - 1)], 0)
    return replace(steps, actions=actions), moves


def _objects_reading(info: dict[str, Any] | None) -> tuple[str, str]:
    """The clustering's reading of the objects and its separator, from learn()'s ``info``
    (which records the fit's separator; ``"_"``, ``fit_mixture``'s default, only for an
    ``info`` written by hand without one)."""
    info = info or {}
    separator = (info.get("cluster") or {}).get("object_separator") or "_"
    return str(info.get("objects") or "raw"), str(separator)


def _divided(task: CollaborativeTask, steps: TaskSteps | None, assignments: torch.Tensor,
             demonstrations: Demonstrations, names: tuple[str, ...],
             info: dict[str, Any] | None) -> dict[str, Any]:  # fmt: skip
    """``info["divided"]``: the states where a learned type's people had partners with
    different own moves (:func:`~torchhrc.tasks.divided_types.divided_states`, the moves
    read as the clustering read the objects: :func:`partner_moves`), the first
    :data:`DIVIDED_LISTED` of them by type and state, with the subjects per own move."""
    if steps is None:
        return {"states": 0, "where": []}
    objects, separator = _objects_reading(info)
    steps, moves = partner_moves(task, steps, objects=objects, separator=separator)
    divided, own = divided_states(steps, assignments, demonstrations.subject_index,
                                  num_types=len(names), num_states=task.num_states,
                                  num_actions=len(moves))  # fmt: skip
    where = []
    for y, x in divided.nonzero().tolist()[:DIVIDED_LISTED]:
        counts = {moves[a]: int(n) for a, n in enumerate(own[y, x].tolist()) if n}
        where.append({"type": names[y], "state": task.state_names[x], "subjects": counts})
    return {"states": int(divided.sum()), "where": where}


def split_divided_types(
    task: CollaborativeTask,
    demonstrations: Demonstrations,
    assignments: torch.Tensor,
    *,
    max_types: int,
    num_types: int | None = None,
    objects: str = "raw",
    separator: str = "_",
) -> tuple[torch.Tensor, list[dict[str, Any]]]:
    """A clustering's types, each divided type split by its partners' moves
    (:func:`~torchhrc.tasks.divided_types.split_divided` over the task's steps, the moves
    read as the clustering read the objects: :func:`partner_moves`), as ``learn()`` does
    after its clustering.

    Args:
        task: the task.
        demonstrations: the ``N`` demonstrations that were clustered.
        assignments: ``(N,)`` the type of each (``fit_mixture``'s ``assignments``).
        max_types: split no further than this many types.
        num_types: the clustering's number of types (default: the largest assigned + 1).
        objects: the clustering's reading of the objects (``MixtureFit.objects``):
            ``"exchangeable"`` compares the robot's moves by verb.
        separator: the separator between verb and object.

    Returns:
        ``(N,)`` int64 the new types (the split ones numbered after the clustering's) and one
        record per split, as ``split_divided``'s with the state and moves by name; no split
        where the task reads no steps.

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> twp = make_task("tool_handover")
        >>> demos, types = twp.demonstrations(subjects=12, per_subject=2, seed=0)
        >>> merged = torch.zeros_like(types)  # every person in one type
        >>> z, splits = split_divided_types(twp.task, demos, merged, max_types=6)
        >>> len(splits), int(z.max()) + 1  # split back into the task's two types
        (1, 2)
    """
    z = assignments.reshape(-1).long()
    steps = task.read_steps(demonstrations)
    if steps is None or z.numel() == 0:
        return z, []
    steps, moves = partner_moves(task, steps, objects=objects, separator=separator)
    K = int(z.max()) + 1 if num_types is None else num_types
    z, splits = split_divided(steps, z, demonstrations.subject_index, num_types=K,
                              num_states=task.num_states, num_actions=len(moves),
                              max_types=max_types)  # fmt: skip
    named = [{**r, "state": task.state_names[r["state"]], "move": moves[r["move"]],
              "kept_move": moves[r["kept_move"]]} for r in splits]  # fmt: skip
    return z, named


def find_types(
    task: CollaborativeTask,
    demonstrations: Demonstrations,
    options: dict[str, Any],
    *,
    seed: int | None = None,
    split: bool = True,
    max_types: int | None = None,
) -> tuple[MixtureFit, torch.Tensor, list[dict[str, Any]]]:
    """The human types of ``demonstrations`` as ``learn()`` finds them: the clustering
    (:func:`~torchhrc.mixture.fit_mixture` with ``options``), then, with ``split``, each
    divided type split by its partners' moves (:func:`split_divided_types`, the moves read
    as the clustering read the objects).

    Args:
        task: the task; demonstrations: its ``N`` demonstrations.
        options: ``fit_mixture``'s keyword arguments (:func:`cluster_options`).
        seed: the clustering's seed.
        split: split divided types (``learn()`` does unless it is given ``k``).
        max_types: split no further than this many types (default: the clustering's
            ``k_max``, the largest k it scored).

    Returns:
        The clustering's :class:`~torchhrc.mixture.MixtureFit`, ``(N,)`` int64 the types
        (the clustering's, then the split ones numbered after them) and one record per
        split (:func:`split_divided_types`); the number of types is ``fit.k`` plus the
        splits.

    Example:
        >>> from torchhrc.tasks.suite import make_task
        >>> twp = make_task("tool_handover")
        >>> demos, types = twp.demonstrations(subjects=12, per_subject=2, seed=0)
        >>> one = cluster_options(k=1)  # the clustering held at one type ...
        >>> fit, z, splits = find_types(twp.task, demos, one, seed=0, max_types=6)
        >>> int(fit.k), len(splits), int(z.max()) + 1  # ... and split into the task's two
        (1, 1, 2)
    """
    from torchhrc.mixture import fit_mixture

    fit = fit_mixture(demonstrations, seed=seed, **options)
    if not split:
        return fit, fit.assignments, []
    z, splits = split_divided_types(
        task, demonstrations, fit.assignments,
        max_types=max(fit.per_k) if max_types is None else max_types,
        num_types=int(fit.k), objects=fit.objects, separator=fit.model.object_separator,
    )  # fmt: skip
    return fit, z, splits


def task_momdp(
    task: CollaborativeTask,
    Tx: torch.Tensor,
    R: torch.Tensor,
    b0: torch.Tensor | None = None,
    *,
    type_names: tuple[str, ...] | list[str] | None = None,
    discount: float | None = None,
) -> MOMDP:
    """The task's MOMDP over ``(x, type)`` from a transition and a reward per type.

    What :func:`build_model` assembles from what it learned, for a ``Tx`` and ``R`` given
    otherwise (a hand-coded model): the type is static (``Ty = None``), ``R`` is zero in the
    task's terminal states, the start is the task's ``initial_state``, and the robot observes
    the human through ``x'`` alone (a trivial ``Z`` of ones, ``O = 1``) unless the task's
    :meth:`~torchhrc.tasks.interface.CollaborativeTask.observation` gives a ``Z``.

    Args:
        task: the task.
        Tx: ``(A, X, Y, X)`` ``P(x' | x, y, a_r)`` (:func:`transition_from_behaviour`).
        R: ``(A, X, Y)`` rewards.
        b0: ``(Y,)`` initial type belief (uniform by default).
        type_names: ``(Y,)`` names of the types (``None``: unnamed).
        discount: the discount factor (default: the task's ``discount``).

    Returns:
        A :class:`~torchhrc.pomdp.MOMDP` in ``Tx``'s dtype.

    Raises:
        ModelError: ``b0`` or the task's ``observation()`` of the wrong shape.

    Example:
        >>> from torchhrc.tasks.interface import behaviour_from_preferences
        >>> class Toggle(CollaborativeTask):  # press turns it on, the human flips it
        ...     state_names, robot_actions = ("off", "on"), ("wait", "press")
        ...     human_actions = ("flip",)
        ...     robot_effect = torch.tensor([[0, 1], [1, 1]])
        ...     human_effect = torch.tensor([[1], [0]])
        >>> task, flips = Toggle(), torch.ones(2, 2, 1, 1, dtype=torch.float64)  # (Y, A, X, H)
        >>> Tx = transition_from_behaviour(task, behaviour_from_preferences(task, flips))
        >>> m = task_momdp(task, Tx, torch.zeros(2, 2, 2, dtype=torch.float64))
        >>> m.b0.tolist(), m.num_observations, Tx[1, 0, 0].tolist()  # press at off: on, flipped
        ([0.5, 0.5], 1, [1.0, 0.0])
    """
    A, X = task.num_actions, task.num_states
    K = Tx.shape[-2]
    R = R.to(Tx.dtype).clone()
    R[:, torch.as_tensor(task.terminal).to(R.device), :] = 0.0
    if b0 is None:
        b0 = torch.full((K,), 1.0 / K, dtype=Tx.dtype, device=Tx.device)
    if tuple(b0.shape) != (K,):
        raise ModelError(f"expected b0 of shape (Y={K},), got {tuple(b0.shape)}")
    trivial = torch.ones(A, X, K, 1, dtype=Tx.dtype, device=Tx.device)
    common = dict(Tx=Tx, Ty=None, R=R, x0=task.initial_state, b0=b0.to(Tx.dtype),
                  discount=float(task.discount if discount is None else discount),
                  observed_states=tuple(task.state_names),
                  hidden_states=None if type_names is None else tuple(type_names),
                  actions=tuple(task.robot_actions))  # fmt: skip
    momdp = MOMDP(Z=trivial, observations=("none",), **common)  # type: ignore[arg-type]
    Z = task.observation(momdp)
    if Z is not None:
        Z = _check_types("observation()", Z, 2, K, f"(A={A}, X={X}, Y={K}, O)").to(Tx.dtype)
        if Z.dim() != 4 or tuple(Z.shape[:2]) != (A, X):
            raise ModelError(f"expected the task's observation() of shape (A={A}, X={X}, "
                             f"Y={K}, O), got {tuple(Z.shape)}")  # fmt: skip
        momdp = MOMDP(Z=Z, **common)  # type: ignore[arg-type]
    return momdp


def _sarsop_config(m: MOMDP, time_limit: float, precision: float, max_iterations: int | None,
                   seed: int, config: Any) -> Any:  # fmt: skip
    """The SARSOP settings of :func:`solve_model` (a config without ``lower_bound_init``
    gets the typed lower bound where the type is static, ``Ty`` None, and keeps SARSOP's own
    where it changes; ``precision`` relative to the reward span without one)."""
    from torchhrc.solvers.sarsop import SARSOPConfig
    from torchhrc.solvers.type_policies import type_policy_lower_bound

    typed = type_policy_lower_bound if m.Ty is None else None
    if config is None:
        span = float(m.R.max() - m.R.min()) or 1.0
        config = SARSOPConfig(
            time_limit=time_limit,
            precision=precision * span,
            max_iterations=max_iterations,
            seed=seed,
            lower_bound_init=typed,
        )
    elif not isinstance(config, SARSOPConfig):
        raise TypeError(f"expected config to be a SARSOPConfig, got {type(config).__name__}")
    elif config.lower_bound_init is None and typed is not None:
        config = replace(config, lower_bound_init=typed)
    return config


def solve_momdp(
    momdp: MOMDP,
    *,
    time_limit: float = 5.0,
    precision: float = 1e-3,
    max_iterations: int | None = None,
    seed: int = 0,
    config: Any = None,
) -> Any:
    """SARSOP on a task's MOMDP with :func:`solve_model`'s settings, for a MOMDP built
    otherwise (:func:`task_momdp`: a hand-coded baseline of the task).

    Args:
        momdp: the MOMDP.
        time_limit, precision, max_iterations, seed, config: as :func:`solve_model`'s
            (``precision`` relative to the reward span; a ``config`` as given, with the typed
            lower bound when it has no ``lower_bound_init`` and the type is static, ``Ty``
            None; a type that changes keeps SARSOP's own lower bound).

    Returns:
        The :class:`~torchhrc.solvers.solution.Solution`.
    """
    from torchhrc.solvers.sarsop import sarsop

    return sarsop(momdp, _sarsop_config(momdp, time_limit, precision, max_iterations, seed, config))


def solve_model(
    model: LearnedModel,
    *,
    time_limit: float = 5.0,
    precision: float = 1e-3,
    max_iterations: int | None = None,
    seed: int = 0,
    config: Any = None,
) -> LearnedModel:
    """Solve the model's MOMDP with SARSOP (typed lower bound: the best per-type policy).

    Args:
        model: a built model.
        time_limit: SARSOP time limit (s).
        precision: target gap, relative to the reward span ``max R - min R``.
        max_iterations: cap on SARSOP iterations (deterministic stop).
        seed: solver seed.
        config: a :class:`~torchhrc.solvers.sarsop.SARSOPConfig` used instead of the four
            settings above, as given (``precision`` absolute), except that a config without
            ``lower_bound_init`` gets the typed lower bound.

    Returns:
        The model with ``policy``, ``lower`` and ``upper`` set, and ``info["solver"]``: the
        settings used.
    """
    config = _sarsop_config(model.momdp, time_limit, precision, max_iterations, seed, config)
    solution = solve_momdp(model.momdp, config=config)
    used = {name: getattr(config, name) for name in ("time_limit", "precision",
            "max_iterations", "seed", "tie_break", "kappa", "prediction", "explore_within",
            "clock")}  # fmt: skip
    used["explore_after"] = solution.info.get("explore_after", config.explore_after)  # resolved
    used["lower_bound_init"] = getattr(config.lower_bound_init, "__name__", "custom")
    info = {**model.info, "solver": {"name": "sarsop", **used}}
    return replace(model, policy=solution.policy, lower=float(solution.lower),
                   upper=float(solution.upper), info=info)  # fmt: skip


def cluster_options(cluster: ClusterConfig | None = None, k: int | None = None) -> dict[str, Any]:
    """The keyword arguments :func:`learn` passes to :func:`~torchhrc.mixture.fit_mixture`.

    ``cluster``'s set fields over ``learn``'s defaults: ``k_min=1``, ``k_max=6``,
    ``restarts`` :data:`LEARN_RESTARTS`, ``parameters="support"``, ``initial=True``; with the
    soft method ``min_gain`` :data:`LEARN_MIN_GAIN`, ``strong_gain`` equal to ``min_gain``
    (one effect size for every step) and ``heldout_gain`` :data:`LEARN_HELDOUT_SHARE` times
    ``strong_gain``, and ``order="auto"`` unless ``k == 1`` (1 otherwise); ``k`` forces
    ``k_min = k_max = k``.

    Example:
        >>> from torchhrc.mixture import ClusterConfig
        >>> options = cluster_options(ClusterConfig(min_gain=0.02))
        >>> options["min_gain"], options["strong_gain"], options["heldout_gain"]
        (0.02, 0.02, 0.01)
        >>> options["order"]
        'auto'
        >>> cluster_options(k=1)["order"], cluster_options(k=1)["k_max"]
        (1, 1)
    """
    from torchhrc.mixture.selection import ClusterConfig

    options = {"k_min": 1, "k_max": 6, "restarts": LEARN_RESTARTS, "parameters": "support",
               "initial": True, **(cluster or ClusterConfig()).options()}  # fmt: skip
    soft = options.get("method", "soft") == "soft"
    if soft:  # one effect size for every step: strong_gain follows a given min_gain
        options.setdefault("min_gain", LEARN_MIN_GAIN)
        options.setdefault("strong_gain", options["min_gain"])
        options.setdefault("heldout_gain", LEARN_HELDOUT_SHARE * options["strong_gain"])
    # higher-order chains are compared with the soft method, where there are types to find
    pooled = k == 1 or not soft
    options.setdefault("order", 1 if pooled else "auto")
    if k is not None:
        options["k_min"] = options["k_max"] = k
    return options


def learn(
    task: CollaborativeTask,
    demonstrations: Any,
    *,
    k: int | None = None,
    cluster: Any = None,
    irl: IRLConfig | None = None,
    solver: Any = None,
    human_model: str | None = None,
    state_smoothing: tuple[float, float] | str = "auto",
    k_min: int | None = None,
    k_max: int | None = None,
    restarts: int | None = None,
    mixture_method: str | None = None,
    bic_parameters: str | None = None,
    criterion: str | None = None,
    objects: str | None = None,
    min_gain: float | None = None,
    order: int | str | None = None,
    noise: float = 0.05,
    pause: float = 0.01,
    irl_epsilon: float | None = None,
    irl_iterations: int | None = None,
    irl_l2: float | None = None,
    irl_pooling: float | None = None,
    irl_wrong_moves: str | None = None,
    solve: bool = True,
    solver_time: float = 5.0,
    solver_precision: float = 1e-3,
    solver_iterations: int | None = None,
    prior: str = "shares",
    split_divided: bool = True,
    seed: int = 0,
) -> LearnedModel:
    """Turn a task and its demonstrations into a learned, solved model (one call).

    Steps: cluster the demonstrations into types (:func:`torchhrc.mixture.fit_mixture`; its
    criterion picks ``k`` in ``[k_min, k_max]``, or exactly ``k``; ``k=1`` pools all
    demonstrations: a type-agnostic MDP), then :func:`build_model` (the human model, chosen
    on held-out likelihood by default; rewards by IRL) and :func:`solve_model`.

    Settings come as config objects (preferred) or as the keywords below them; a keyword
    given together with the config that holds it is an error (``ValueError``).

    Args:
        task: the task.
        demonstrations: :class:`~torchhrc.data.Demonstrations` over the task's actions.
        k: force the number of types (``k_min = k_max = k``; at most the number of
            demonstrations).
        cluster: a :class:`~torchhrc.mixture.ClusterConfig`; its unset fields take
            ``learn``'s defaults (:func:`cluster_options`; ``initial=True``: each type's
            first move is modelled; ``order="auto"``: chains of order 1, 2 and 3 each select
            a k, and the largest is kept, ``docs/clustering.md``, "Second-order chains",
            "Third-order chains") or
            :func:`~torchhrc.mixture.fit_mixture`'s (e.g. ``criterion``: ``"icl_or_gain"``
            for the soft method, BIC for ``"paper"``).
        irl: an :class:`IRLConfig` (rule, epsilon, iterations, l2, pooling, wrong_moves).
        solver: a :class:`~torchhrc.solvers.sarsop.SARSOPConfig`, used as given (its
            ``precision`` is absolute; without a ``lower_bound_init`` the typed lower bound
            of :func:`solve_model` is used).
        human_model: ``"auto"``, ``"chain"`` or ``"state"`` (:func:`build_model`); ``None``:
            the task's ``human_model`` (default ``"auto"``).
        state_smoothing: the state model's ``(habit_weight, prior_strength)``, or
            ``"auto"``: chosen on held-out subjects (:func:`build_model`).
        k_min: instead of ``cluster``: :func:`~torchhrc.mixture.fit_mixture`'s ``k_min``.
        k_max: instead of ``cluster``: ``fit_mixture``'s ``k_max``.
        restarts: instead of ``cluster``: ``fit_mixture``'s ``restarts``.
        mixture_method: instead of ``cluster``: ``fit_mixture``'s ``method``.
        bic_parameters: instead of ``cluster``: ``fit_mixture``'s ``parameters``.
        criterion: instead of ``cluster``: ``fit_mixture``'s ``criterion``.
        objects: instead of ``cluster``: ``fit_mixture``'s ``objects``.
        min_gain: instead of ``cluster``: ``fit_mixture``'s ``min_gain``.
        order: instead of ``cluster``: ``fit_mixture``'s ``order`` (1, 2, 3 or ``"auto"``).
        noise: human-behaviour setting (:class:`~torchhrc.tasks.interface.TypeEvidence`).
        pause: human-behaviour setting (:class:`~torchhrc.tasks.interface.TypeEvidence`).
        irl_epsilon: instead of ``irl``: its ``epsilon``.
        irl_iterations: instead of ``irl``: its ``iterations``.
        irl_l2: instead of ``irl``: its ``l2`` (the MaxEnt ridge).
        irl_pooling: instead of ``irl``: its ``pooling`` (the types' rewards' prior
            correlation).
        irl_wrong_moves: instead of ``irl``: its ``wrong_moves`` (``"symmetric"`` or
            ``"learned"``).
        solve: solve the MOMDP (SARSOP) too.
        solver_time: instead of ``solver``: :func:`solve_model`'s time limit (seconds).
        solver_precision: instead of ``solver``: :func:`solve_model`'s precision, relative
            to the reward span.
        solver_iterations: instead of ``solver``: :func:`solve_model`'s iteration cap.
        prior: the robot's initial belief over the learned types, ``b0``: ``"shares"``
            (default) each type's share of the demonstrations, the estimate of how common
            it is among the people the robot will meet (a new person is a draw from the
            population the demonstrators came from); ``"uniform"``: every type alike, as if
            each were equally common (the paper's studies, whose types are balanced).
            ``model.with_belief(b0)`` swaps it afterwards, keeping the policy solved for
            this one.
        split_divided: after the clustering (unless ``k`` is given), split each type whose
            people's demonstrating partners made different moves in one state
            (:func:`~torchhrc.tasks.divided_types.split_divided`, up to ``k_max`` types):
            the mixture keeps such types merged on small corpora (``docs/clustering.md``,
            "Splitting divided types").
        seed: the seed of everything.

    Returns:
        :class:`LearnedModel` (``b0`` by ``prior``) whose ``info`` records what decided it
        (JSON, saved with the model): ``k`` (after the splits), ``k_clustered`` (the
        clustering's), ``split`` (each split: the type, state, moves and subjects moved),
        ``criterion``, ``scores`` (every k's scores
        under every criterion: ``bic``, ``exact_icl``, ``log_likelihood``, ``gain``,
        ``heldout`` and ``heldout_se``; with ``order="auto"``, of the order kept),
        ``next_step`` (why the clustering stopped below one more type: the thresholds its
        step falls short of, :attr:`~torchhrc.mixture.MixtureFit.next_step`), ``objects``,
        ``order`` and ``order_comparison`` (each order's k, exact ICL and log-likelihood; on
        equal k each tied partition's exact ICL under each tied order),
        ``cluster`` (the settings used), ``irl``, ``solver``, ``human_model`` (requested,
        used, held-out likelihoods), ``prior`` (the rule and ``b0``) and ``seed``.

    Example:
        >>> from torchhrc.mixture import ClusterConfig
        >>> from torchhrc.tasks.suite import make_task
        >>> twp = make_task("tool_handover")
        >>> demos, _ = twp.demonstrations(subjects=6, per_subject=2, seed=0)
        >>> m = learn(twp.task, demos, cluster=ClusterConfig(criterion="bic", k_max=3,
        ...           restarts=2), irl=IRLConfig(iterations=2), solve=False)
        >>> m.info["criterion"], m.info["k"] in (1, 2, 3)
        ('bic', True)
    """
    from torchhrc.mixture import partition_chains
    from torchhrc.mixture.selection import (
        DEFAULT_HELDOUT_GAIN,
        DEFAULT_STRONG_GAIN,
        ClusterConfig,
    )

    check_task(task)
    Demonstrations.check(demonstrations)
    if prior not in ("shares", "uniform"):
        raise ValueError(f"expected prior 'shares' or 'uniform', got {prior!r}")
    state_smoothing_pair(state_smoothing)  # checked before the clustering
    keywords = dict(k_min=k_min, k_max=k_max, restarts=restarts, method=mixture_method,
                    parameters=bic_parameters, criterion=criterion, objects=objects,
                    min_gain=min_gain, order=order)  # fmt: skip
    given = {name: v for name, v in keywords.items() if v is not None}
    if cluster is None:
        cluster = ClusterConfig(**given)  # type: ignore[arg-type]
    elif not isinstance(cluster, ClusterConfig):
        raise TypeError(f"expected cluster to be a ClusterConfig, got {type(cluster).__name__}")
    elif given:
        raise ValueError(f"pass the clustering settings either in cluster= or as keywords, "
                         f"not both (got {', '.join(sorted(given))})")  # fmt: skip
    options = cluster_options(cluster, k)
    N = demonstrations.num_sequences
    if isinstance(options["k_min"], int) and options["k_min"] > N:
        name = "k" if k is not None else "k_min"
        raise ValueError(
            f"expected {name} <= the number of demonstrations ({N}), got "
            f"{name} = {options['k_min']}: a type needs demonstrations of its own"
        )
    irl_keywords = {"epsilon": irl_epsilon, "iterations": irl_iterations, "l2": irl_l2,
                    "pooling": irl_pooling, "wrong_moves": irl_wrong_moves}  # fmt: skip
    irl_given = {name: v for name, v in irl_keywords.items() if v is not None}
    if irl is None:
        irl = IRLConfig(**irl_given)  # type: ignore[arg-type]  # its defaults for the rest
    elif not isinstance(irl, IRLConfig):
        raise TypeError(f"expected irl to be an IRLConfig, got {type(irl).__name__}")
    elif irl_given:
        raise ValueError("pass the IRL settings either in irl= or as irl_epsilon/irl_iterations/"
                         "irl_l2/irl_pooling/irl_wrong_moves, not both")  # fmt: skip
    fit, assignments, splits = find_types(task, demonstrations, options, seed=seed,
                                          split=split_divided and k is None)  # fmt: skip
    K = int(fit.k) + len(splits)
    info: dict[str, Any] = {
        "k": K,
        "k_clustered": int(fit.k),
        "split": splits,
        "criterion": fit.criterion,
        "scores": {str(kk): dict(row) for kk, row in fit.per_k.items()},
        "next_step": fit.next_step,
        "bic": float(fit.bic),
        "log_likelihood": float(fit.log_likelihood),
        "objects": fit.objects,
        "object_comparison": fit.object_comparison,
        "order": fit.order,
        "order_comparison": fit.order_comparison,
        "cluster": _jsonable(
            {
                "method": fit.method,
                "min_gain": 0.0,  # the paper's hard EM: BIC alone
                "strong_gain": DEFAULT_STRONG_GAIN,
                "heldout_gain": DEFAULT_HELDOUT_GAIN,
                "se_factor": 1.0,
                "folds": 5,
                **options,
                "object_separator": fit.model.object_separator,  # the one the fit used
            }
        ),
        "irl": {
            "rule": irl.rule,
            "epsilon": irl.epsilon,
            "iterations": irl.iterations,
            "l2": irl.l2,
            "pooling": irl.pooling,
            "wrong_moves": irl.wrong_moves,
        },
        "seed": seed,
    }
    if splits:  # the chains of the split partition
        chains = partition_chains(demonstrations, F.one_hot(assignments, K).to(torch.float64))
    else:
        chains = fit.transition_over(demonstrations)  # over the recorded symbols (fit.objects)
    b0 = None  # build_model's uniform belief
    if prior == "shares":
        counts = torch.bincount(assignments.reshape(-1).long(), minlength=K)
        b0 = counts.to(torch.float64) / counts.sum()
    info["prior"] = {
        "rule": prior,
        "b0": [1.0 / K] * K if b0 is None else b0.tolist(),
    }
    model = build_model(task, demonstrations, chains, assignments, b0=b0, noise=noise,
                        pause=pause, rule=irl.rule, irl_epsilon=irl.epsilon,
                        irl_iterations=irl.iterations, irl_l2=irl.l2, irl_pooling=irl.pooling,
                        wrong_moves=irl.wrong_moves, seed=seed, info=info,
                        human_model=human_model, state_smoothing=state_smoothing)  # fmt: skip
    if solve:
        if solver is None:
            model = solve_model(model, time_limit=solver_time, precision=solver_precision,
                                max_iterations=solver_iterations, seed=seed)  # fmt: skip
        else:
            model = solve_model(model, config=solver)
    return model


def _jsonable(options: dict[str, Any]) -> dict[str, Any]:
    """Settings as JSON values (a dtype by name)."""
    return {k: (str(v) if isinstance(v, torch.dtype) else v) for k, v in options.items()}
