"""``solve()`` accepts whatever ``as_solver_model`` accepts (issue 33): a form added with
``register_form``, a prepared ``SparseFlatModel``, a ``SolverModel``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from torchhrc.pomdp import POMDP
from torchhrc.solvers import PBVIConfig, QMDPConfig, SARSOPConfig, SparseFlatModel, solve
from torchhrc.solvers.forms import as_solver_model, has_form, register_form
from torchhrc.tasks.classic import tiger

# Tiger, discount 0.95: V*(b0) = 19.3714 (tests/solvers/sarsop/test_sarsop.py).
TIGER_OPTIMUM = 19.3714
CONFIG = SARSOPConfig(time_limit=60.0, precision=1e-3, max_iterations=300)


@dataclass(frozen=True)
class ArrayPOMDP:
    """A minimal new model type: a flat POMDP held as numpy arrays, T[a, s, s2], Z[a, s2, o]."""

    T: np.ndarray
    Z: np.ndarray
    R: np.ndarray
    b0: np.ndarray
    discount: float


def _array_form(model: ArrayPOMDP, dtype: torch.dtype | None):  # type: ignore[no-untyped-def]
    pomdp = POMDP(
        T=torch.as_tensor(model.T),
        Z=torch.as_tensor(model.Z),
        R=torch.as_tensor(model.R),
        b0=torch.as_tensor(model.b0),
        discount=model.discount,
    )
    return as_solver_model(pomdp, dtype=dtype)


def _tiger_arrays() -> ArrayPOMDP:
    m = tiger()
    return ArrayPOMDP(m.T.numpy(), m.Z.numpy(), m.R.numpy(), m.b0.numpy(), m.discount)


def test_solve_takes_a_form_added_with_register_form() -> None:
    model = _tiger_arrays()
    assert not has_form(model)
    with pytest.raises(TypeError, match="ArrayPOMDP"):
        solve(model, CONFIG)
    register_form(ArrayPOMDP, _array_form)
    assert has_form(model)
    sol = solve(model, CONFIG)
    assert sol.lower - 1e-6 <= TIGER_OPTIMUM + 1e-3 and TIGER_OPTIMUM - 1e-3 <= sol.upper + 1e-6
    assert sol.upper - sol.lower <= 1e-3 + 1e-9
    ref = solve(tiger(), CONFIG)
    assert sol.lower == pytest.approx(ref.lower, abs=1e-9)
    assert sol.upper == pytest.approx(ref.upper, abs=1e-9)
    # the other built-in solvers go through the same form: QMDP's upper bound on Tiger is 189
    # (solvers/__init__.py's example), PBVI's lower bound stays below the optimum.
    assert solve(model, QMDPConfig()).upper == pytest.approx(189.0, abs=1e-6)
    assert solve(model, PBVIConfig()).lower <= TIGER_OPTIMUM + 1e-3


def test_solve_takes_a_sparse_flat_model_and_a_solver_model() -> None:
    m = tiger()
    ref = solve(m, CONFIG)
    for model in (SparseFlatModel.from_model(m), as_solver_model(m)):
        assert has_form(model)
        sol = solve(model, CONFIG)
        assert sol.lower == pytest.approx(ref.lower, abs=1e-6)
        assert sol.upper == pytest.approx(ref.upper, abs=1e-6)


def test_solve_still_refuses_a_model_of_no_form() -> None:
    with pytest.raises(TypeError, match="register_form"):
        solve("tiger", CONFIG)
    assert not has_form(object())
