"""The place-and-drill task as a MOMDP over (workbench configuration, human type).

Paper (Nikolaidis et al., section "Evaluation"): the human places screws in one of ``n``
positions, the robot drills each placed screw; "the observable state variable ``x`` is the
workbench configuration", "the actions ``a_r`` are the drilling actions, as well as the
no-op action", "the human placing actions are encoded implicitly in the transition and
observation matrices", and the hidden ``y`` is the human type (one value per cluster).

State, actions and one decision step (our reading, documented here once)::

    status: (X, n) int64   status[x, i] in {0: empty, 1: placed, 2: drilled}
                           x = sum_i status[x, i] * 3 ** (n - 1 - i), X = 3 ** n
                           (position 0, "A", is the most significant digit)
    actions (A = n + 1):   0 = "wait" (the no-op), 1 + i = "drill_<position i>"

No turn or phase bit is needed: one MOMDP step is one robot action followed by one human
placement. At ``x`` the robot acts (drilling a placed screw makes it drilled; drilling an
empty or drilled position, and waiting, change nothing); then, if a position is still
empty, the human places one screw. The episode starts with an empty bench (``x0 = 0``; the
robot's first decision is made before the first placement) and ends in the all-drilled state,
which is absorbing with zero reward. ``Tx[a, x, y, x2]`` is the probability of the human's
placement given the robot action and the human type ``y``: the learned Markov chain of type
``y`` gives ``P(place_i | previous symbol = robot action a)``, restricted to the empty
positions and renormalised, mixed with a floor ``noise`` of a uniformly random legal
placement (so no placement is ever impossible under any type and the belief update never
divides by zero). The type is static (``Ty`` is ``None``). The robot observes the human's
action through ``x2`` alone, so ``Z`` is trivial (one observation, probability 1): the type
information comes from ``Tx``.

Reward features ``phi(x, a)`` (the basis of the IRL reward of each type and of the
hand-coded expert reward; zero in the terminal state)::

    features: (A, X, F)   features[a, x, f] in {0, 1}, exactly one f is 1 per non-terminal (a, x)

    0 drill_ready    drill a placed screw when no position is empty any more
    1 drill_early    drill a placed screw while some position is still empty
    2 wait_early     wait while a placed screw waits for drilling and some position is empty
    3 wait_late      wait while a placed screw waits for drilling and none is empty (idle)
    4 wait_idle      wait with nothing to drill
    5 drill_invalid  drill an empty or an already drilled position

A "safe" human (the robot waits until every screw is placed) shows ``wait_early`` and
``drill_ready``; an "efficient" one (place and drill alternately) shows ``drill_early``.

Example:
    >>> task = PlaceAndDrillTask(3)
    >>> task.num_states, task.actions
    (27, ('wait', 'drill_A', 'drill_B', 'drill_C'))
    >>> task.state_names[task.encode(torch.tensor([1, 0, 2]))]
    'PED'
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Literal

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.tasks.interface import CollaborativeTask, TypeEvidence

__all__ = [
    "DRILLED",
    "EMPTY",
    "FEATURE_NAMES",
    "PLACED",
    "DemonstrationSteps",
    "LearnedTaskModel",
    "PlaceAndDrillTask",
    "build_learned_model",
    "build_momdp",
    "demonstration_steps",
    "interpret_clusters",
    "learn_type_weights",
    "placement_probabilities",
    "placement_transition",
]

#: Status of an empty position (``status[x, i]``, see the module docstring).
EMPTY = 0
#: Status of a placed, undrilled screw.
PLACED = 1
#: Status of a drilled screw.
DRILLED = 2
_STATUS_LETTERS = ("E", "P", "D")

#: Names of the reward features ``phi(x, a)``, in feature order (see the module docstring).
FEATURE_NAMES: tuple[str, ...] = (
    "drill_ready",
    "drill_early",
    "wait_early",
    "wait_late",
    "wait_idle",
    "drill_invalid",
)


@dataclass(frozen=True)
class PlaceAndDrillTask(CollaborativeTask):
    """The task's mechanics: states, actions, effects and reward features.

    A :class:`~torchhrc.tasks.interface.CollaborativeTask`: robot actions :attr:`actions`,
    human actions ``place_<p>``, ``robot_effect (A, X)``, ``human_effect = place_effect
    (X, n)``, the features of the module docstring, the human's placements seen through
    ``x`` (no observation model), the types learned from the chains and named "safe" /
    "efficient" (:func:`interpret_clusters`); :func:`torchhrc.tasks.pipeline.learn` turns
    it and demonstrations into a solved model.

    Args:
        n_positions: number of screw positions ``n`` (1 to 8); ``X = 3 ** n``.
        discount: discount factor of the MOMDP and the IRL.

    Example:
        >>> PlaceAndDrillTask(2).robot_effect[1].tolist()[:4]  # drill_A from EE, EP, ED, PE
        [0, 1, 2, 6]
    """

    n_positions: int = 3
    discount: float = 0.95
    #: the paper's reading of the human: each type's chain, ``P(a_h | previous robot action)``
    #: (not a dataclass field; the pipeline's "auto" comparison is not run for this task)
    human_model = "chain"

    def __post_init__(self) -> None:
        if not 0.0 < float(self.discount) < 1.0:
            raise ModelError(f"expected discount in (0, 1), got {self.discount}")
        n = self.n_positions
        if not isinstance(n, int) or isinstance(n, bool):
            raise TypeError(f"expected n_positions to be an int, got {type(n).__name__}")
        if not 1 <= n <= 8:
            raise ModelError(f"expected n_positions in [1, 8], got {n}")

    # ------------------------------------------------------------------ names
    @property
    def positions(self) -> tuple[str, ...]:
        """Position names ``("A", "B", ...)``."""
        return tuple(chr(ord("A") + i) for i in range(self.n_positions))

    @property
    def actions(self) -> tuple[str, ...]:
        """Robot actions ``("wait", "drill_A", ...)``; ``A = n + 1``."""
        return ("wait", *(f"drill_{p}" for p in self.positions))

    @property
    def robot_actions(self) -> tuple[str, ...]:
        """The task interface's name of :attr:`actions`."""
        return self.actions

    @property
    def human_actions(self) -> tuple[str, ...]:
        """Human actions ``("place_A", ...)``."""
        return tuple(f"place_{p}" for p in self.positions)

    @property
    def feature_names(self) -> tuple[str, ...]:
        """:data:`FEATURE_NAMES`."""
        return FEATURE_NAMES

    @property
    def terminal(self) -> torch.Tensor:
        """``(X,)`` bool, True in the all-drilled state."""
        return torch.arange(self.num_states) == self.terminal_state

    @property
    def human_effect(self) -> torch.Tensor:
        """:attr:`place_effect` (the task interface's name)."""
        return self.place_effect

    @property
    def human_legal(self) -> torch.Tensor:
        """:attr:`legal_placements` (the task interface's name)."""
        return self.legal_placements

    def type_names(self, evidence: TypeEvidence) -> tuple[str, ...]:
        """ "safe" / "efficient" from the chains (:func:`interpret_clusters`)."""
        return interpret_clusters(self, evidence.chains, evidence.vocabulary)

    @property
    def num_states(self) -> int:
        """``X = 3 ** n``."""
        return 3**self.n_positions

    @property
    def num_actions(self) -> int:
        """``A = n + 1``."""
        return self.n_positions + 1

    @property
    def initial_state(self) -> int:
        """The empty bench, ``x0 = 0``."""
        return 0

    @property
    def terminal_state(self) -> int:
        """The all-drilled state ``X - 1``."""
        return self.num_states - 1

    @cached_property
    def state_names(self) -> tuple[str, ...]:
        """``(X,)`` names such as ``"PED"`` (E empty, P placed, D drilled per position)."""
        return tuple("".join(_STATUS_LETTERS[s] for s in row) for row in self.status.tolist())

    # ------------------------------------------------------------------ tables
    @cached_property
    def status(self) -> torch.Tensor:
        """``(X, n)`` int64, ``status[x, i]`` in {0 empty, 1 placed, 2 drilled}."""
        n = self.n_positions
        x = torch.arange(self.num_states)
        powers = 3 ** torch.arange(n - 1, -1, -1)
        return (x[:, None] // powers) % 3

    def encode(self, status: torch.Tensor) -> torch.Tensor:
        """State index of ``status (..., n)`` (int64 in {0, 1, 2}) -> ``(...)`` int64."""
        n = self.n_positions
        powers = 3 ** torch.arange(n - 1, -1, -1, device=status.device)
        return (status.long() * powers).sum(-1)

    @cached_property
    def robot_effect(self) -> torch.Tensor:
        """``(A, X)`` int64: the state after robot action ``a`` in ``x`` (before the human)."""
        n, X = self.n_positions, self.num_states
        status = self.status
        out = torch.arange(X).expand(n + 1, X).clone()
        powers = 3 ** torch.arange(n - 1, -1, -1)
        placed = status == PLACED  # (X, n)
        # drilling position i adds 3 ** (n-1-i) (placed -> drilled) where it is placed
        out[1:] = out[1:] + (placed * powers).T
        return out

    @cached_property
    def legal_placements(self) -> torch.Tensor:
        """``(X, n)`` bool: position ``i`` is empty in ``x``."""
        return self.status == EMPTY

    @cached_property
    def place_effect(self) -> torch.Tensor:
        """``(X, n)`` int64: the state after placing ``i`` in ``x`` (``x`` when not empty)."""
        n = self.n_positions
        powers = 3 ** torch.arange(n - 1, -1, -1)
        return torch.arange(self.num_states)[:, None] + self.legal_placements * powers

    @cached_property
    def drill_legal(self) -> torch.Tensor:
        """``(A, X)`` bool: action ``a`` drills a placed screw in ``x`` (False for wait)."""
        placed = self.status == PLACED  # (X, n)
        return torch.cat([torch.zeros(1, self.num_states, dtype=torch.bool), placed.T], 0)

    @cached_property
    def _features(self) -> torch.Tensor:
        status = self.status
        any_empty = (status == EMPTY).any(-1)  # (X,)
        pending = (status == PLACED).any(-1)  # (X,)
        terminal = torch.arange(self.num_states) == self.terminal_state
        F = len(FEATURE_NAMES)
        phi = torch.zeros(self.num_actions, self.num_states, F, dtype=torch.float64)
        drill_ok = self.drill_legal[1:]  # (n, X)
        phi[1:, :, 0] = (drill_ok & ~any_empty).double()
        phi[1:, :, 1] = (drill_ok & any_empty).double()
        phi[0, :, 2] = (pending & any_empty).double()
        phi[0, :, 3] = (pending & ~any_empty).double()
        phi[0, :, 4] = (~pending).double()
        phi[1:, :, 5] = (~drill_ok).double()
        phi[:, terminal] = 0.0
        return phi

    def features(
        self, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """Reward features ``(A, X, F)``, ``features[a, x, f] = phi_f(x, a)`` (module docstring).

        Example:
            >>> PlaceAndDrillTask(1).features()[:, 1].tolist()  # state "P": wait, drill_A
            [[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]]
        """
        return self._features.to(device=device, dtype=dtype)

    def reward(self, weights: torch.Tensor) -> torch.Tensor:
        """Linear reward ``R[..., a, x, y] = sum_f weights[..., y, f] * phi_f(x, a)``.

        Args:
            weights: ``(..., Y, F)`` feature weights per type.

        Returns:
            ``(..., A, X, Y)`` rewards in ``weights``' dtype and device.
        """
        F = len(FEATURE_NAMES)
        if not isinstance(weights, torch.Tensor) or weights.dim() < 2 or weights.shape[-1] != F:
            shape = tuple(weights.shape) if isinstance(weights, torch.Tensor) else weights
            raise ModelError(f"expected weights of shape (..., Y, F={F}), got {shape}")
        phi = self.features(dtype=weights.dtype, device=weights.device)
        return torch.einsum("axf,...yf->...axy", phi, weights)


# ---------------------------------------------------------------------------- transitions


def placement_transition(
    task: PlaceAndDrillTask,
    placement: torch.Tensor,
    *,
    noise: float = 0.05,
    pause: float = 0.0,
) -> torch.Tensor:
    """The observed-part transition ``Tx`` from per-type placement preferences.

    ``Tx[..., a, x, y, x2] = P(x2 | x, y, a)``: the robot's action moves ``x`` to
    ``m = robot_effect[a, x]``; if ``m`` has an empty position the human places screw ``i``
    with probability ``(1 - noise) * p[y, a, i] / sum_{j empty} p[y, a, j] + noise / #empty``
    over the empty positions ``i`` (uniform when ``p`` puts no mass on them), all scaled by
    ``1 - pause``; with probability ``pause`` the human lets a turn pass (``x2 = m``, as the
    noisy demonstrations sometimes show); when nothing is empty ``x2 = m``. ``pause`` is
    the same for every type, so it never moves the type belief.

    Args:
        task: the task.
        placement: ``(..., Y, A, n)`` non-negative preferences ``p[y, a, i]`` of placing
            position ``i`` right after robot action ``a`` (unnormalised).
        noise: weight in ``[0, 1]`` of a uniformly random legal placement.
        pause: probability in ``[0, 1)`` that the human skips a turn although a position
            is empty.

    Returns:
        ``(..., A, X, Y, X)`` transition probabilities in ``placement``'s dtype/device.

    Example:
        >>> task = PlaceAndDrillTask(2)
        >>> Tx = placement_transition(task, torch.ones(1, 3, 2, dtype=torch.float64))
        >>> Tx[0, 0, 0].nonzero().flatten().tolist(), Tx[0, 0, 0, 3].item()  # EE -> PE or EP
        ([1, 3], 0.5)
    """
    n, A, X = task.n_positions, task.num_actions, task.num_states
    if not isinstance(placement, torch.Tensor) or not placement.is_floating_point():
        raise TypeError("expected placement to be a floating torch.Tensor of shape (..., Y, A, n)")
    if placement.dim() < 3 or placement.shape[-2:] != (A, n):
        raise ModelError(
            f"expected placement to have shape (..., Y, A={A}, n={n}), "
            f"actual shape = {tuple(placement.shape)}"
        )
    if (placement < 0).any() or not torch.isfinite(placement).all():
        raise ModelError("placement preferences must be finite and non-negative")
    if not 0.0 <= noise <= 1.0:
        raise ModelError(f"expected noise in [0, 1], got {noise}")
    if not 0.0 <= pause < 1.0:
        raise ModelError(f"expected pause in [0, 1), got {pause}")
    dev, dt = placement.device, placement.dtype
    mid = task.robot_effect.to(dev)  # (A, X)
    legal = task.legal_placements.to(dev)[mid]  # (A, X, n)
    dest = task.place_effect.to(dev)[mid]  # (A, X, n)
    p = placement.movedim(-3, -2).unsqueeze(-3)  # (..., A, 1, Y, n)
    legal_f = legal.unsqueeze(-2).to(dt)  # (A, X, 1, n)
    num_legal = legal_f.sum(-1, keepdim=True)  # (A, X, 1, 1)
    uniform = legal_f / num_legal.clamp_min(1.0)
    masked = p * legal_f  # (..., A, X, Y, n)
    total = masked.sum(-1, keepdim=True)
    chain = torch.where(total > 0, masked / total.clamp_min(1e-300), uniform)
    probs = (1.0 - noise) * chain + noise * uniform  # (..., A, X, Y, n); 0 where no legal
    probs = probs * (1.0 - pause)
    batch = probs.shape[:-4]
    Y = probs.shape[-2]
    Tx = torch.zeros(*batch, A, X, Y, X, dtype=dt, device=dev)
    index = dest.unsqueeze(-2).expand(A, X, Y, n).expand(*batch, A, X, Y, n)
    Tx = Tx.scatter_add(-1, index, probs)
    nothing = num_legal.squeeze(-1) == 0  # (A, X, 1): nothing to place
    stay = torch.where(nothing, 1.0, pause).to(dt)
    Tx = Tx.scatter_add(
        -1,
        mid.view(A, X, 1, 1).expand(*batch, A, X, Y, 1),
        stay.unsqueeze(-1).expand(*batch, A, X, Y, 1).contiguous(),
    )
    return Tx


def placement_probabilities(
    task: PlaceAndDrillTask,
    transition: torch.Tensor,
    vocabulary: Sequence[tuple[str, str]],
) -> torch.Tensor:
    """Per-type placement preferences from learned Markov chains over demonstration symbols.

    ``p[k, a, i] = theta_k(human:place_i | robot:a)``, the chain's probability that the human
    places screw ``i`` right after the robot's action ``a`` (paper: "the transition matrix
    encodes information about how the human will act based on the previous robot action").
    Symbols missing from the vocabulary give zero preference (uniform after restriction).

    Args:
        task: the task.
        transition: ``(..., K, V, V)`` chains, ``transition[k, u, v] = P(next v | previous u)``.
        vocabulary: ``(V,)`` symbols ``(actor, action)`` of the chains.

    Returns:
        ``(..., K, A, n)`` preferences (rows not normalised).
    """
    vocab = [tuple(v) for v in vocabulary]
    V = len(vocab)
    if transition.shape[-1] != V or transition.shape[-2] != V:
        raise ModelError(
            f"expected transition of shape (..., K, V={V}, V={V}), got {tuple(transition.shape)}"
        )
    lookup = {sym: i for i, sym in enumerate(vocab)}
    rows = [lookup.get(("robot", a), -1) for a in task.actions]
    cols = [lookup.get(("human", h), -1) for h in task.human_actions]
    out = transition.new_zeros(*transition.shape[:-2], task.num_actions, task.n_positions)
    for ai, r in enumerate(rows):
        for i, c in enumerate(cols):
            if r >= 0 and c >= 0:
                out[..., ai, i] = transition[..., r, c]
    return out


# ---------------------------------------------------------------------------- demonstrations


@dataclass(frozen=True)
class DemonstrationSteps:
    """Demonstrations rewritten as MOMDP steps ``(x, a, x2)``.

    Attributes:
        states: ``(N, H)`` int64, ``x`` before the robot's ``t``-th decision.
        actions: ``(N, H)`` int64, the robot action taken (0 = wait, 1 + i = drill_i).
        next_states: ``(N, H)`` int64, ``x2`` after the action and the human's placement.
        mask: ``(N, H)`` bool, True on real steps (padding beyond).
    """

    states: torch.Tensor
    actions: torch.Tensor
    next_states: torch.Tensor
    mask: torch.Tensor

    @property
    def lengths(self) -> torch.Tensor:
        """``(N,)`` number of real steps of each sequence."""
        return self.mask.sum(-1)


def demonstration_steps(
    task: PlaceAndDrillTask, demonstrations: Demonstrations
) -> DemonstrationSteps:
    """Rewrite joint-action demonstrations as the MOMDP's ``(x, a, x2)`` steps.

    Reading rules: the bench starts empty; a robot symbol is one decision at the current
    ``x``; a human turn right after it (a placement, or ``human:wait``: no placement) belongs
    to the same step (the human's move that ``Tx`` models); a human turn that does not follow
    a robot action (the first one, or two human turns in a row) is preceded by an implicit
    robot ``wait``. Placing an occupied position leaves the bench unchanged. Symbols of other
    tasks raise ``ModelError``.

    Args:
        task: the task.
        demonstrations: sequences over ``human:place_<p>``, ``robot:drill_<p>``, ``robot:wait``.

    Returns:
        :class:`DemonstrationSteps` with tensors on the demonstrations' device.

    Example:
        >>> demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "drill_A")]])
        >>> s = demonstration_steps(PlaceAndDrillTask(1), demos)
        >>> s.states.tolist(), s.actions.tolist(), s.next_states.tolist()
        ([[0, 1]], [[0, 1]], [[1, 2]])
    """
    robot_index = {a: i for i, a in enumerate(task.actions)}
    human_index = {h: i for i, h in enumerate(task.human_actions)}
    kinds: list[tuple[str, int]] = []
    for actor, action in demonstrations.vocabulary:
        if actor == "robot" and action in robot_index:
            kinds.append(("robot", robot_index[action]))
        elif actor == "human" and action in human_index:
            kinds.append(("human", human_index[action]))
        elif actor == "human" and action == "wait":
            kinds.append(("human", -1))
        else:
            kinds.append(("other", -1))
    effect = task.robot_effect.tolist()
    place = task.place_effect.tolist()
    seqs = demonstrations.sequences.cpu().tolist()
    lengths = demonstrations.lengths.cpu().tolist()
    all_steps: list[list[tuple[int, int, int]]] = []
    for n, (seq, length) in enumerate(zip(seqs, lengths)):
        x = task.initial_state
        steps: list[list[int]] = []
        open_step = False  # the last step is a robot action not yet followed by a placement
        for t in range(length):
            kind, idx = kinds[seq[t]]
            if kind == "other":
                actor, action = demonstrations.vocabulary[seq[t]]
                raise ModelError(
                    f"demonstration {n} step {t}: symbol {actor}:{action} is not a "
                    f"place-and-drill action for {task.n_positions} positions"
                )
            if kind == "robot":
                x_mid = effect[idx][x]
                steps.append([x, idx, x_mid])
                x = x_mid
                open_step = True
            else:
                if not open_step:
                    steps.append([x, 0, x])  # implicit robot wait before this human turn
                if idx >= 0:
                    x = place[x][idx]
                steps[-1][2] = x
                open_step = False
        all_steps.append([tuple(s) for s in steps])  # type: ignore[misc]
    H = max((len(s) for s in all_steps), default=0)
    N = len(all_steps)
    out = torch.zeros(3, N, max(H, 1), dtype=torch.long)
    mask = torch.zeros(N, max(H, 1), dtype=torch.bool)
    for n, steps in enumerate(all_steps):
        if steps:
            out[:, n, : len(steps)] = torch.tensor(steps, dtype=torch.long).T
            mask[n, : len(steps)] = True
    dev = demonstrations.device
    return DemonstrationSteps(out[0].to(dev), out[1].to(dev), out[2].to(dev), mask.to(dev))


# ---------------------------------------------------------------------------- IRL

RewardRule = Literal["dominant", "paper", "last"]


def learn_type_weights(
    task: PlaceAndDrillTask,
    Tx: torch.Tensor,
    steps: DemonstrationSteps,
    assignments: torch.Tensor,
    *,
    discount: float = 0.95,
    rule: RewardRule = "dominant",
    epsilon: float = 0.05,
    max_iterations: int = 10,
    seed: int = 0,
) -> torch.Tensor:
    """Reward weights per type by apprenticeship learning (Abbeel & Ng 2004; paper Sec. IRL).

    For type ``k`` the MDP is ``(X, A, Tx[:, :, k, :], phi, discount)`` and the expert's
    trajectories are the demonstrations assigned to cluster ``k``;
    :func:`torchhrc.irl.projection.apprenticeship_learning` returns the policies
    ``pi^(1..M)`` found by RL, their reward directions ``w^(1..M)`` and the mixture weights
    ``lambda`` whose feature expectations are closest to the expert's. The reward kept:

    * ``"dominant"`` (default): ``w^(i*)`` with ``i* = argmax_{i >= 1} lambda_i``, the reward
      of the policy the expert's mixture relies on most;
    * ``"paper"``: the mean of ``w^(i)`` over the second half of the iterations;
    * ``"last"``: ``w^(M)``.

    Why not the paper's rule by default: with noisy demonstrations (each subject deviates at
    some steps) the expert's feature expectations are not those of any single policy, the
    margin stalls at the noise level and the late ``w^(i)`` point in noise directions. On the
    simulated study (seed 0, 9 subjects per type) the optimal policies of the second-half
    mean contradict the type's demonstrated rule in 7 (safe) and 13 (efficient) of the 19
    states with a screw waiting, the dominant policy's reward in 0.

    Args:
        task: the task.
        Tx: ``(A, X, K, X)`` the model's transitions per type.
        steps: the demonstrations as MOMDP steps (:func:`demonstration_steps`).
        assignments: ``(N,)`` int64 cluster of each demonstration.
        discount: discount of the feature expectations.
        rule: which reward to keep (above).
        epsilon: stopping margin of the IRL loop (feature-expectation units).
        max_iterations: cap on the RL policies per type.
        seed: seed of the random initial policy.

    Returns:
        ``(K, F)`` float64 weights (unit norm; zeros for a cluster without demonstrations).
    """
    from torchhrc.irl.projection import apprenticeship_learning
    from torchhrc.irl.trajectories import Trajectories

    if rule not in ("dominant", "paper", "last"):
        raise ValueError(f"expected rule 'dominant', 'paper' or 'last', got {rule!r}")
    K = Tx.shape[-2]
    phi = task.features(dtype=Tx.dtype, device=Tx.device).permute(1, 0, 2)  # (X, A, F)
    weights = Tx.new_zeros(K, len(FEATURE_NAMES))
    lengths = steps.lengths
    assignments = assignments.to(steps.states.device)
    for k in range(K):
        idx = torch.nonzero((assignments == k) & (lengths > 0)).flatten()
        if idx.numel() == 0:
            continue
        demos = Trajectories(steps.states[idx], steps.actions[idx], lengths[idx])
        result = apprenticeship_learning(
            Tx[:, :, k, :],
            phi,
            demos,
            discount=discount,
            epsilon=epsilon,
            max_iterations=max_iterations,
            seed=seed,
        )
        if rule == "paper" or result.num_iterations == 0:
            weights[k] = result.paper_weights
        elif rule == "last":
            weights[k] = result.last_weights
        else:
            dominant = int(result.mixture_weights[1:].argmax())
            weights[k] = result.weight_history[dominant]
    return weights


# ---------------------------------------------------------------------------- MOMDP


def build_momdp(
    task: PlaceAndDrillTask,
    Tx: torch.Tensor,
    R: torch.Tensor,
    b0: torch.Tensor,
    *,
    discount: float = 0.95,
    type_names: Sequence[str] | None = None,
) -> MOMDP:
    """Assemble the task MOMDP (static type, trivial observation).

    Args:
        task: the task.
        Tx: ``(..., A, X, Y, X)`` from :func:`placement_transition`.
        R: ``(..., A, X, Y)`` rewards (zero in the terminal state is enforced).
        b0: ``(..., Y)`` initial belief over the type.
        discount: discount factor.
        type_names: ``(Y,)`` names of the hidden values.

    Returns:
        A :class:`~torchhrc.pomdp.MOMDP` with ``Ty=None``, ``Z`` of ones ``(A, X, Y, 1)``.
    """
    A, X = task.num_actions, task.num_states
    Y = Tx.shape[-2]
    R = R.clone()
    R[..., :, task.terminal_state, :] = 0.0
    Z = torch.ones(A, X, Y, 1, dtype=Tx.dtype, device=Tx.device)
    return MOMDP(
        Tx=Tx,
        Ty=None,
        Z=Z,
        R=R,
        x0=task.initial_state,
        b0=b0.to(Tx.dtype),
        discount=discount,
        observed_states=task.state_names,
        hidden_states=None if type_names is None else tuple(type_names),
        actions=task.actions,
        observations=("placement",),
    )


def interpret_clusters(
    task: PlaceAndDrillTask,
    transition: torch.Tensor,
    vocabulary: Sequence[tuple[str, str]],
) -> tuple[str, ...]:
    """Name learned clusters "safe" or "efficient" from their Markov chains.

    A cluster is "efficient" when, right after a human placement, its chain puts more
    probability on a robot drill than on a robot wait (place and drill alternately), and
    "safe" otherwise. Repeated names get a suffix (``"safe_2"``).

    Args:
        task: the task.
        transition: ``(K, V, V)`` chains, ``transition[k, u, v] = P(v | u)``.
        vocabulary: ``(V,)`` symbols.

    Returns:
        ``(K,)`` names.
    """
    lookup = {tuple(sym): i for i, sym in enumerate(vocabulary)}
    places = [lookup[("human", h)] for h in task.human_actions if ("human", h) in lookup]
    drills = [lookup[("robot", a)] for a in task.actions[1:] if ("robot", a) in lookup]
    wait = lookup.get(("robot", "wait"))
    names: list[str] = []
    for k in range(transition.shape[-3]):
        rows = transition[k][places] if places else transition.new_zeros(1, len(vocabulary))
        p_drill = rows[:, drills].sum(-1).mean().item() if drills else 0.0
        p_wait = rows[:, wait].mean().item() if wait is not None else 0.0
        base = "efficient" if p_drill > p_wait else "safe"
        count = sum(1 for m in names if m.split("_")[0] == base)
        names.append(base if count == 0 else f"{base}_{count + 1}")
    return tuple(names)


@dataclass(frozen=True)
class LearnedTaskModel:
    """A learned place-and-drill model: the MOMDP and what it was built from.

    Attributes:
        momdp: the MOMDP over ``(x, type)`` (``b0`` uniform unless given).
        weights: ``(Y, F)`` reward feature weights per type (IRL).
        placement: ``(Y, A, n)`` placement preferences per type (from the chains).
        type_names: ``(Y,)`` cluster interpretations.
    """

    momdp: MOMDP
    weights: torch.Tensor
    placement: torch.Tensor
    type_names: tuple[str, ...]


def build_learned_model(
    task: PlaceAndDrillTask,
    mixture: Any,
    demonstrations: Demonstrations,
    assignments: torch.Tensor,
    *,
    b0: torch.Tensor | None = None,
    noise: float = 0.05,
    pause: float = 0.01,
    discount: float = 0.95,
    rule: RewardRule = "dominant",
    irl_epsilon: float = 0.05,
    irl_iterations: int = 10,
    seed: int = 0,
) -> LearnedTaskModel:
    """Build the learned MOMDP: cluster chains -> ``Tx``, IRL per cluster -> ``R``.

    A thin wrapper of :func:`torchhrc.tasks.pipeline.build_model` (the task-independent
    pipeline) that keeps the place-and-drill names (``placement``).

    Paper (sections "MOMDP Formulation" and "Inverse Reinforcement Learning"): each cluster
    is a value of the hidden type; its Markov chain gives the human's placements
    (:func:`placement_probabilities`, :func:`placement_transition`), IRL on the cluster's
    demonstrations gives its reward (:func:`learn_type_weights`).

    Args:
        task: the task.
        mixture: a fitted :class:`~torchhrc.mixture.MarkovChainMixture` (or anything with a
            ``transition (K, V, V)`` attribute), or the ``(K, V, V)`` chains themselves.
        demonstrations: the training demonstrations (vocabulary of the chains).
        assignments: ``(N,)`` int64 cluster of each training demonstration.
        b0: ``(K,)`` initial type belief (uniform by default).
        noise: random-placement floor of ``Tx`` (see :func:`placement_transition`).
        pause: probability of a skipped human turn in ``Tx``.
        discount: discount factor of the MOMDP and of the IRL.
        rule, irl_epsilon, irl_iterations, seed: IRL settings (:func:`learn_type_weights`).

    Returns:
        :class:`LearnedTaskModel`.

    Example:
        >>> from torchhrc.tasks.place_and_drill.demos import simulate_study
        >>> demos = simulate_study(n_subjects=4, n_demos=2, noise=0.0, seed=0)
        >>> labels = torch.tensor([t == "efficient" for t in demos.types]).long()
        >>> counts = torch.stack([demos.subset(labels == k).transition_counts() + 0.1
        ...                       for k in range(2)])
        >>> chains = counts / counts.sum(-1, keepdim=True)
        >>> build_learned_model(PlaceAndDrillTask(3), chains, demos, labels).type_names
        ('safe', 'efficient')
    """
    from torchhrc.tasks.pipeline import build_model

    transition = mixture if isinstance(mixture, torch.Tensor) else mixture.transition
    transition = transition.detach().to(torch.float64)
    if transition.dim() != 3:
        raise ModelError(
            f"expected the mixture's transition of shape (K, V, V), got {tuple(transition.shape)}"
        )
    if task.discount != discount:
        task = PlaceAndDrillTask(task.n_positions, discount=discount)
    learned = build_model(
        task,
        demonstrations,
        transition,
        assignments,
        b0=b0,
        noise=noise,
        pause=pause,
        rule=rule,
        irl_epsilon=irl_epsilon,
        irl_iterations=irl_iterations,
        seed=seed,
    )
    placement = placement_probabilities(task, transition, demonstrations.vocabulary)
    return LearnedTaskModel(
        momdp=learned.momdp, weights=learned.weights, placement=placement,
        type_names=learned.type_names,
    )  # fmt: skip
