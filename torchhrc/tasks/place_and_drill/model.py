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
from typing import Any

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.tasks.interface import CollaborativeTask, TypeEvidence

__all__ = [
    "DRILLED",
    "EMPTY",
    "FEATURE_NAMES",
    "PLACED",
    "PlaceAndDrillTask",
    "interpret_clusters",
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


# ---------------------------------------------------------------------------- deprecated
# The task's own copy of the pipeline (issue 32): the MOMDP of this task is built by
# torchhrc.tasks.pipeline (build_model, learn) like any task's. The old names stay one
# release: the same objects under their new names, or thin forwards where the call differs.

_RENAMED: dict[str, tuple[str, str, str]] = {  # old name: (module, new name, what to use)
    "learn_type_weights": (
        "torchhrc.tasks.pipeline",
        "learn_type_weights",
        "torchhrc.tasks.pipeline.learn_type_weights (the discount is the task's)",
    ),
    "DemonstrationSteps": (
        "torchhrc.tasks.interface",
        "TaskSteps",
        "torchhrc.tasks.interface.TaskSteps",
    ),
    "demonstration_steps": (
        "torchhrc.tasks.interface",
        "CollaborativeTask.read_steps",
        "task.read_steps(demonstrations)",
    ),
    "LearnedTaskModel": (
        "torchhrc.tasks.pipeline",
        "LearnedModel",
        "torchhrc.tasks.pipeline.LearnedModel",
    ),
    "build_momdp": ("torchhrc.tasks.pipeline", "task_momdp", "torchhrc.tasks.pipeline.task_momdp"),
    "placement_probabilities": (
        __name__,
        "_placement_probabilities",
        "torchhrc.tasks.interface.chain_preferences(transition, "
        "vocabulary, task.robot_actions, task.human_actions)",
    ),
    "placement_transition": (
        __name__,
        "_placement_transition",
        "torchhrc.tasks.pipeline.transition_from_behaviour(task, "
        "behaviour_from_preferences(task, placement.unsqueeze(-2), "
        "noise=..., pause=...))",
    ),
    "build_learned_model": (
        __name__,
        "_build_learned_model",
        "torchhrc.tasks.pipeline.build_model(task, demonstrations, chains, assignments, ...)",
    ),
}


def __getattr__(name: str) -> object:
    if name not in _RENAMED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    import warnings

    module, new, use = _RENAMED[name]
    warnings.warn(f"{__name__}.{name} is deprecated; use {use}", DeprecationWarning,
                  stacklevel=2)  # fmt: skip
    found: Any = importlib.import_module(module)
    for part in new.split("."):
        found = getattr(found, part)
    return found


def _placement_probabilities(
    task: PlaceAndDrillTask, transition: torch.Tensor, vocabulary: Sequence[tuple[str, str]]
) -> torch.Tensor:
    """Deprecated ``placement_probabilities``: ``(..., K, A, n)`` from chains ``(..., K, V, V)``."""
    from torchhrc.tasks.interface import chain_preferences

    return chain_preferences(transition, vocabulary, task.robot_actions, task.human_actions)


def _placement_transition(
    task: PlaceAndDrillTask, placement: torch.Tensor, *, noise: float = 0.05, pause: float = 0.0
) -> torch.Tensor:
    """Deprecated ``placement_transition``: ``Tx (..., A, X, Y, X)`` from ``(..., Y, A, n)``."""
    from torchhrc.tasks.interface import behaviour_from_preferences
    from torchhrc.tasks.pipeline import transition_from_behaviour

    if not isinstance(placement, torch.Tensor) or placement.dim() < 3:
        raise ModelError("expected placement to be a torch.Tensor of shape (..., Y, A, n)")
    behaviour = behaviour_from_preferences(task, placement.unsqueeze(-2), noise=noise, pause=pause)
    batch, Y = behaviour.shape[:-4], behaviour.shape[-4]
    Tx = transition_from_behaviour(task, behaviour.reshape(-1, *behaviour.shape[-3:]))
    Tx = Tx.reshape(*Tx.shape[:2], -1, Y, Tx.shape[-1])  # (A, X, B, Y, X)
    return Tx.movedim(2, 0).reshape(*batch, *Tx.shape[:2], Y, Tx.shape[-1])


def _build_learned_model(
    task: PlaceAndDrillTask,
    mixture: Any,
    demonstrations: Demonstrations,
    assignments: torch.Tensor,
    *,
    discount: float = 0.95,
    **options: Any,
) -> Any:
    """Deprecated ``build_learned_model``: :func:`torchhrc.tasks.pipeline.build_model`."""
    from torchhrc.tasks.pipeline import build_model

    transition = mixture if isinstance(mixture, torch.Tensor) else mixture.transition
    if task.discount != discount:
        task = PlaceAndDrillTask(task.n_positions, discount=discount)
    return build_model(task, demonstrations, transition, assignments, **options)
