"""The probabilistic models: POMDP and MOMDP containers, belief updates, observation models.

One package for every form of a model and what reads it (issue 32):

* :mod:`~torchhrc.pomdp.dense`: :class:`POMDP` and :class:`MOMDP`, batched dense tensors;
* :mod:`~torchhrc.pomdp.base`: :class:`MOMDPBase`, what every MOMDP form shares (the fields
  after the transition, their checks, the random start);
* :mod:`~torchhrc.pomdp.sparse`: :class:`SparsePOMDP`, a flat POMDP as coordinate lists;
* :mod:`~torchhrc.pomdp.sparse_momdp`: :class:`SparseMOMDP`, a MOMDP whose joint transition
  is a coordinate list;
* :mod:`~torchhrc.pomdp.belief`: the belief updates (pure, batched, log space);
* :mod:`~torchhrc.pomdp.observation`: the discretized 2D Gaussian observation model and its
  grid; :mod:`~torchhrc.pomdp.observation_fit`: hand tracks, their likelihood through the
  belief filter, and learning the model from them;
  :mod:`~torchhrc.pomdp.approach_observation`: a hand that approaches its target.

The solvers' own lowered form of a flat model, ``SparseFlatModel``, stays in
:mod:`torchhrc.solvers.sparse_model` (docs/architecture.md says why). Shapes and letters
(``S``, ``A``, ``O``, ``X``, ``Y``) are in :mod:`torchhrc.pomdp.dense`.

Example:
    >>> from torchhrc.pomdp import SparsePOMDP
    >>> from torchhrc.tasks.classic import tiger
    >>> SparsePOMDP.from_dense(tiger()).to_dense().num_states
    2
"""

from __future__ import annotations

from torchhrc.pomdp.base import (
    MOMDPBase,
    check_initial,
    initial_joint,
    split_initial,
    start_from,
)
from torchhrc.pomdp.dense import MOMDP, POMDP
from torchhrc.pomdp.sparse import SparsePOMDP
from torchhrc.pomdp.sparse_momdp import SparseMOMDP

__all__ = [
    "MOMDP",
    "POMDP",
    "MOMDPBase",
    "SparseMOMDP",
    "SparsePOMDP",
    "check_initial",
    "initial_joint",
    "split_initial",
    "start_from",
]
