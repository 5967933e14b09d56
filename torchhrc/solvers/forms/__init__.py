"""Model forms of the point-based solvers and the adapter that picks one: :func:`as_solver_model`.

SARSOP and PBVI are written once against :class:`~torchhrc.solvers.forms.base.SolverModel`;
each representation of a model implements it in its own module:

* :class:`~torchhrc.solvers.forms.dense.DenseForm`: a flat :class:`~torchhrc.pomdp.POMDP`;
* :class:`~torchhrc.solvers.forms.momdp.MOMDPForm`: a :class:`~torchhrc.pomdp.MOMDP`,
  factored over observed and hidden values (Ong et al. 2010);
* :class:`~torchhrc.solvers.forms.sparse.SparseForm`: a :class:`~torchhrc.pomdp.SparsePOMDP`
  (or a prepared :class:`~torchhrc.solvers.sparse_model.SparseFlatModel`), ``T`` sparse;
* :class:`~torchhrc.solvers.forms.sparse_momdp.SparseMOMDPForm`: a
  :class:`~torchhrc.pomdp.SparseMOMDP`, factored like a MOMDP with ``Tx Ty`` sparse.

A new form (a device backend, a sparse MOMDP) is one new module with one class, registered
here with :func:`register_form`.

Example:
    >>> from torchhrc.tasks.classic import rock_sample
    >>> type(as_solver_model(rock_sample(4, 4, form="momdp"))).__name__
    'MOMDPForm'
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP, SparseMOMDP, SparsePOMDP
from torchhrc.solvers.forms.base import Children, SolverModel
from torchhrc.solvers.forms.dense import DenseForm
from torchhrc.solvers.forms.momdp import MOMDPForm
from torchhrc.solvers.forms.sparse import SparseForm
from torchhrc.solvers.forms.sparse_momdp import SparseMOMDPForm
from torchhrc.solvers.sparse_model import SparseFlatModel

__all__ = [
    "Children",
    "DenseForm",
    "MOMDPForm",
    "SolverModel",
    "SparseForm",
    "SparseMOMDPForm",
    "as_solver_model",
    "has_form",
    "register_form",
]

FormBuilder = Callable[[Any, torch.dtype | None], SolverModel]


def _floats_are(model: POMDP | MOMDP, dtype: torch.dtype) -> bool:
    """Whether every floating tensor of ``model`` already has ``dtype`` (no copy needed)."""
    tensors = [getattr(model, f) for f in ("T", "Tx", "Ty", "Z", "R", "b0") if hasattr(model, f)]
    return all(t.dtype == dtype for t in tensors if isinstance(t, torch.Tensor))


def _tensor_model(form: type[DenseForm] | type[MOMDPForm]) -> FormBuilder:
    def build(model: Any, dtype: torch.dtype | None) -> SolverModel:
        if len(model.batch_shape) > 0:
            raise ModelError(
                f"expected an unbatched model, got batch_shape = {tuple(model.batch_shape)}; "
                "solve each problem of the batch separately"
            )
        dt = dtype or model.R.dtype
        work = model if _floats_are(model, dt) else model.to(dtype=dt)
        return form(work, model)

    return build


def _sparse_model(model: Any, dtype: torch.dtype | None) -> SolverModel:
    # a prepared SparseFlatModel already in the dtype is used as it is
    return SparseForm(SparseFlatModel.from_model(model, dtype=dtype or model.R.dtype), model)


def _as_is(model: SolverModel, dtype: torch.dtype | None) -> SolverModel:
    return model


_FORMS: dict[type, FormBuilder] = {
    POMDP: _tensor_model(DenseForm),
    MOMDP: _tensor_model(MOMDPForm),
    SparsePOMDP: _sparse_model,
    SparseFlatModel: _sparse_model,
    SparseMOMDP: lambda model, dtype: SparseMOMDPForm(model, dtype),
    SolverModel: _as_is,  # an adapted model (any form's class derives from it)
}


def register_form(model_type: type, build: FormBuilder) -> None:
    """Make :func:`as_solver_model` hold models of ``model_type`` as ``build(model, dtype)``.

    Example:
        >>> register_form(SparseFlatModel, _sparse_model)  # already registered: replaced
    """
    if not isinstance(model_type, type):
        raise TypeError(f"expected model_type to be a type, got {type(model_type).__name__}")
    _FORMS[model_type] = build


def has_form(model: Any) -> bool:
    """Whether :func:`as_solver_model` accepts ``model``: a :class:`SolverModel`, or an
    instance of a type with a form (built in or added by :func:`register_form`).

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> has_form(tiger()), has_form("tiger")
        (True, False)
    """
    return any(cls in _FORMS for cls in type(model).__mro__)


def as_solver_model(model: Any, *, dtype: torch.dtype | None = None) -> SolverModel:
    """The solver interface of ``model``, chosen once by its type (the only place that asks:
    the first of its classes, in method resolution order, with a registered builder).

    Args:
        model: an unbatched :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.MOMDP`,
            a :class:`~torchhrc.pomdp.SparsePOMDP`, a
            :class:`~torchhrc.solvers.sparse_model.SparseFlatModel`, or an already adapted
            :class:`SolverModel` (returned as is), or a registered type.
        dtype: floating dtype of the solve (default: the model's own).

    Returns:
        The form: :class:`DenseForm`, :class:`MOMDPForm` or :class:`SparseForm`.

    Raises:
        TypeError: ``model`` of no known form.
        ModelError: a batched model.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> form = as_solver_model(tiger())
        >>> form.num_observed, form.num_hidden, form.state_shape
        (1, 2, (2,))
    """
    for cls in type(model).__mro__:
        if cls in _FORMS:
            return _FORMS[cls](model, dtype)
    raise TypeError(f"expected a POMDP, MOMDP or SparsePOMDP, got {type(model).__name__}")
