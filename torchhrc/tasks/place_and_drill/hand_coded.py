"""The hand-coded expert MOMDP of the place-and-drill task, read from a readable JSON file.

Paper (section "Quality of Learned Model"): "we had a domain expert manually partition the
data and empirically hand-craft a reward function"; the policy of that MOMDP is the
reference the learned model is compared with (Fig. 3). The shipped file
``models/place_and_drill_expert.json`` states, per human type, a reward for each situation
of the task (the reward features of :mod:`torchhrc.tasks.place_and_drill.model`), the
expert's model of the human's placements (uniform over the empty positions) and how sure the
expert's label of a subject makes the robot at the start. Its reward of a subject's true type
is also the scale on which every policy is scored (:mod:`torchhrc.tasks.place_and_drill.simulate`).

File format (JSON object)::

    format: "torchhrc.expert_momdp", version: 1, task: "place-and-drill"
    positions: int >= 1            number of screw positions n
    discount: float in (0, 1]
    human: {placement: "uniform",
            waits_while_pending: {type name: float in [0, 1], ... every type} (optional)}
    initial_belief: {labelled_type_probability: float in [1/Y, 1]}
    types: {name: {description: str, reward: {feature name: float, ... every feature}}}

Example:
    >>> expert = load_expert_model()
    >>> expert.type_names, expert.weights.shape
    (('safe', 'efficient'), torch.Size([2, 6]))
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.pomdp import MOMDP
from torchhrc.resources import shipped_path
from torchhrc.tasks.interface import behaviour_from_preferences
from torchhrc.tasks.pipeline import task_momdp, transition_from_behaviour
from torchhrc.tasks.place_and_drill.model import FEATURE_NAMES, PlaceAndDrillTask

__all__ = [
    "DEFAULT_EXPERT_PATH",
    "ExpertModel",
    "build_expert_momdp",
    "expert_initial_belief",
    "load_expert_model",
    "parse_expert_model",
]

_FORMAT = "torchhrc.expert_momdp"
_VERSION = 1

#: The shipped expert model, ``models/place_and_drill_expert.json`` (found by
#: :func:`torchhrc.resources.shipped_path` in a checkout, an editable install or a wheel).
DEFAULT_EXPERT_PATH: Path = shipped_path("models", "place_and_drill_expert.json")


@dataclass(frozen=True)
class ExpertModel:
    """A hand-coded expert model of the place-and-drill task.

    Attributes:
        type_names: ``(Y,)`` the expert's human types, in file order.
        weights: ``(Y, F)`` float64 reward per situation (feature) and type.
        n_positions: number of screw positions.
        discount: discount factor of the MOMDP.
        labelled_probability: initial belief on the expert's label of a subject.
        descriptions: ``(Y,)`` the expert's description of each type.
        path: where the model was read from.
        waits_while_pending: ``(Y,)`` the expert's probability that a human of each type
            lets its turn pass while a placed screw waits for drilling (the online study's
            turn taking, :mod:`torchhrc.experiments.online`), or None when the file states
            none.
    """

    type_names: tuple[str, ...]
    weights: torch.Tensor
    n_positions: int
    discount: float
    labelled_probability: float
    descriptions: tuple[str, ...]
    path: str = "<dict>"
    waits_while_pending: tuple[float, ...] | None = None

    @property
    def task(self) -> PlaceAndDrillTask:
        """The task the model is written for."""
        return PlaceAndDrillTask(self.n_positions)

    def reward(self) -> torch.Tensor:
        """``(A, X, Y)`` the expert's reward ``R[a, x, y] = sum_f weights[y, f] phi_f(x, a)``."""
        return self.task.reward(self.weights)


def _field_error(path: str, where: str, reason: str) -> ModelError:
    return ModelError(f"{path}: field {where!r}: {reason}")


def _number(path: str, where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _field_error(path, where, f"expected a number, got {value!r}")
    if not math.isfinite(float(value)):
        raise _field_error(path, where, f"expected a finite number, got {value!r}")
    return float(value)


def _mapping(path: str, where: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise _field_error(path, where, f"expected an object, got {type(value).__name__}")
    return value


def parse_expert_model(data: Mapping[str, Any], *, path: str = "<dict>") -> ExpertModel:
    """Validate a decoded expert JSON object and build an :class:`ExpertModel`.

    Raises:
        ModelError: a field is missing or invalid; the message names the file and field.

    Example:
        >>> import json
        >>> data = json.loads(DEFAULT_EXPERT_PATH.read_text())
        >>> parse_expert_model(data).labelled_probability
        0.95
    """
    data = _mapping(path, "<root>", data)
    for key in (
        "format",
        "version",
        "task",
        "positions",
        "discount",
        "human",
        "initial_belief",
        "types",
    ):
        if key not in data:
            raise _field_error(path, key, "missing")
    if data["format"] != _FORMAT:
        raise _field_error(path, "format", f"expected {_FORMAT!r}, got {data['format']!r}")
    if data["version"] != _VERSION:
        raise _field_error(path, "version", f"expected {_VERSION}, got {data['version']!r}")
    if data["task"] != "place-and-drill":
        raise _field_error(path, "task", f"expected 'place-and-drill', got {data['task']!r}")
    n = data["positions"]
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 8:
        raise _field_error(path, "positions", f"expected an int in [1, 8], got {n!r}")
    discount = _number(path, "discount", data["discount"])
    if not 0.0 < discount <= 1.0:
        raise _field_error(path, "discount", f"expected a value in (0, 1], got {discount}")
    human = _mapping(path, "human", data["human"])
    if human.get("placement") != "uniform":
        raise _field_error(
            path, "human.placement", f"expected 'uniform', got {human.get('placement')!r}"
        )
    types = _mapping(path, "types", data["types"])
    if len(types) < 2:
        raise _field_error(path, "types", f"expected at least 2 types, got {len(types)}")
    names: list[str] = []
    rows: list[list[float]] = []
    descriptions: list[str] = []
    for name, spec in types.items():
        spec = _mapping(path, f"types.{name}", spec)
        reward = _mapping(path, f"types.{name}.reward", spec.get("reward"))
        unknown = sorted(set(reward) - set(FEATURE_NAMES))
        if unknown:
            raise _field_error(
                path,
                f"types.{name}.reward.{unknown[0]}",
                f"unknown situation; expected one of {', '.join(FEATURE_NAMES)}",
            )
        row = []
        for feature in FEATURE_NAMES:
            where = f"types.{name}.reward.{feature}"
            if feature not in reward:
                raise _field_error(path, where, "missing")
            row.append(_number(path, where, reward[feature]))
        description = spec.get("description", "")
        if not isinstance(description, str):
            raise _field_error(path, f"types.{name}.description", "expected a string")
        names.append(str(name))
        rows.append(row)
        descriptions.append(description)
    belief = _mapping(path, "initial_belief", data["initial_belief"])
    if "labelled_type_probability" not in belief:
        raise _field_error(path, "initial_belief.labelled_type_probability", "missing")
    p = _number(
        path, "initial_belief.labelled_type_probability", belief["labelled_type_probability"]
    )
    if not 1.0 / len(names) <= p <= 1.0:
        raise _field_error(
            path,
            "initial_belief.labelled_type_probability",
            f"expected a value in [1/{len(names)}, 1], got {p}",
        )
    waits: tuple[float, ...] | None = None
    if "waits_while_pending" in human:
        table = _mapping(path, "human.waits_while_pending", human["waits_while_pending"])
        values = []
        for name in names:
            where = f"human.waits_while_pending.{name}"
            if name not in table:
                raise _field_error(path, where, "missing")
            value = _number(path, where, table[name])
            if not 0.0 <= value <= 1.0:
                raise _field_error(path, where, f"expected a probability in [0, 1], got {value}")
            values.append(value)
        extra = sorted(set(table) - set(names))
        if extra:
            raise _field_error(
                path, f"human.waits_while_pending.{extra[0]}", "not one of the types"
            )
        waits = tuple(values)
    return ExpertModel(
        waits_while_pending=waits,
        type_names=tuple(names),
        weights=torch.tensor(rows, dtype=torch.float64),
        n_positions=n,
        discount=discount,
        labelled_probability=p,
        descriptions=tuple(descriptions),
        path=path,
    )


def load_expert_model(path: str | os.PathLike[str] | None = None) -> ExpertModel:
    """Read and validate an expert model file (default: the shipped one).

    Raises:
        FileNotFoundError: the file does not exist.
        ParseError: the file is not valid JSON (file, line and column in the message).
        ModelError: a field is missing or invalid (file and field in the message).

    Example:
        >>> load_expert_model().n_positions
        3
    """
    target = Path(DEFAULT_EXPERT_PATH if path is None else path)
    text = target.read_text(encoding="utf-8")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ParseError(
            error.msg, path=str(target), line=error.lineno, column=error.colno
        ) from None
    return parse_expert_model(data, path=str(target))


def expert_initial_belief(
    expert: ExpertModel, labels: Sequence[str], *, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """The expert's initial type belief for subjects with the given labels.

    ``b0[s, y] = p`` for the labelled type and ``(1 - p) / (Y - 1)`` for the others
    (``p = labelled_probability``).

    Args:
        expert: the expert model.
        labels: ``(S,)`` the expert's label of each subject (one of ``type_names``).

    Returns:
        ``(S, Y)`` beliefs.

    Raises:
        ModelError: a label is not one of the expert's types.

    Example:
        >>> expert_initial_belief(load_expert_model(), ["efficient"])
        tensor([[0.0500, 0.9500]], dtype=torch.float64)
    """
    Y = len(expert.type_names)
    lookup = {n: i for i, n in enumerate(expert.type_names)}
    for s, label in enumerate(labels):
        if label not in lookup:
            raise ModelError(
                f"labels[{s}] = {label!r} is not a type of the expert model "
                f"{expert.path} (expected one of {', '.join(expert.type_names)})"
            )
    p = expert.labelled_probability
    other = (1.0 - p) / (Y - 1)
    b0 = torch.full((len(labels), Y), other, dtype=dtype)
    idx = torch.tensor([lookup[label] for label in labels], dtype=torch.long)
    b0[torch.arange(len(labels)), idx] = p
    return b0


def build_expert_momdp(expert: ExpertModel, b0: torch.Tensor | None = None) -> MOMDP:
    """The expert's MOMDP: uniform placements for every type, the expert's rewards.

    Args:
        expert: the expert model.
        b0: ``(Y,)`` initial belief (uniform by default); per-subject beliefs are
            passed to the policy at execution time, the solution does not depend on ``b0``
            beyond the solver's sampling.

    Returns:
        :class:`~torchhrc.pomdp.MOMDP` with ``Y = len(type_names)``.

    Example:
        >>> build_expert_momdp(load_expert_model()).R.shape
        torch.Size([4, 27, 2])
    """
    task = expert.task
    Y = len(expert.type_names)
    uniform = torch.ones(Y, task.num_actions, 1, task.n_positions, dtype=torch.float64)
    Tx = transition_from_behaviour(task, behaviour_from_preferences(task, uniform))
    return task_momdp(task, Tx, expert.reward(), b0, discount=expert.discount,
                      type_names=expert.type_names)  # fmt: skip
