"""FIB's fixed point by policy iteration (torchhrc.solvers.fib_exact): a value worked by hand,
the plain iteration of the FIB operator far past its tolerance as the reference, the bound's
direction, and the dense form handing it to SARSOP."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc.solvers import SARSOPConfig, sarsop
from torchhrc.solvers.clock import NEVER
from torchhrc.solvers.fib import fib_backup
from torchhrc.solvers.fib_exact import fib_exact_pays, fib_fixed_point
from torchhrc.solvers.forms import as_solver_model
from torchhrc.solvers.qmdp import qmdp_vectors
from torchhrc.tasks.classic import tiger
from torchhrc.testing import random_pomdp


def _fib_star(model) -> torch.Tensor:  # type: ignore[no-untyped-def]
    """The FIB fixed point by the library's torch operator (fib_backup), iterated from QMDP
    until nothing changes (an independent path: torch, no policy, no linear solve)."""
    alpha = qmdp_vectors(model, tol=1e-14)
    for _ in range(200_000):
        new = torch.minimum(fib_backup(model, alpha), alpha)
        if float((alpha - new).abs().max()) < 1e-15:
            return new
        alpha = new
    raise AssertionError("no fixed point")


def test_one_state_two_actions_worked_by_hand() -> None:
    # one state that stays, one observation: alpha*[a] = R[a] + gamma max R / (1 - gamma)
    # (R = (1, 3), gamma = 0.5: the value 3 / 0.5 = 6, so alpha* = (1 + 3, 3 + 3) = (4, 6));
    # from R the greedy choice is already the best action: one solve
    T = np.ones((2, 1, 1))
    Z = np.ones((2, 1, 1))
    R = np.array([[1.0], [3.0]])
    out = fib_fixed_point(T, Z, R, 0.5)
    assert out is not None and out.iterations == 1
    np.testing.assert_allclose(out.vectors, [[4.0], [6.0]], rtol=0, atol=1e-12)
    # an upper start whose greedy choice is the worse action: the first policy's values are
    # (2, 4) (alpha[0] = 1 + 0.5 alpha[0]), and the improvement step must change the choice
    out = fib_fixed_point(T, Z, R, 0.5, start=np.array([[10.0], [7.0]]))
    assert out is not None and out.iterations == 2
    np.testing.assert_allclose(out.vectors, [[4.0], [6.0]], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "build",
    [tiger,
     lambda: random_pomdp(6, 3, 3, discount=0.95, seed=1),
     lambda: random_pomdp(12, 4, 5, discount=0.99, seed=2),
     lambda: random_pomdp(20, 5, 2, discount=0.9, sparsity=0.8, seed=3),
     lambda: random_pomdp(9, 2, 6, discount=0.995, seed=7)],
)  # fmt: skip
def test_fixed_point_matches_the_iterated_operator_and_bounds_it(build) -> None:  # type: ignore[no-untyped-def]
    model = build()
    T, Z, R = (t.double().numpy() for t in (model.T, model.Z, model.R))
    start = qmdp_vectors(model, tol=1e-12).double().numpy()
    out = fib_fixed_point(T, Z, R, model.discount, start=start)
    assert out is not None
    want = _fib_star(model).numpy()
    scale = max(1.0, float(np.abs(want).max()))
    # within round-off of F*, and never below it: an upper bound of the optimal value
    assert float(np.abs(out.vectors - want).max()) <= 1e-9 * scale
    assert float((out.vectors - want).min()) >= -1e-12 * scale
    assert (out.vectors <= start + 1e-12 * scale).all()  # never above the QMDP start
    assert 1 <= out.iterations <= 10


def test_bad_arguments_and_the_rule() -> None:
    T, Z, R = np.ones((1, 2, 2)) / 2, np.ones((1, 2, 1)), np.zeros((1, 2))
    with pytest.raises(ValueError, match="gamma"):
        fib_fixed_point(T, Z, R, 1.0)
    with pytest.raises(ValueError, match="T to have shape"):
        fib_fixed_point(np.ones((1, 2, 3)), Z, R, 0.9)
    with pytest.raises(ValueError, match="Z to have shape"):
        fib_fixed_point(T, np.ones((1, 3, 1)), R, 0.9)
    with pytest.raises(ValueError, match="R to have shape"):
        fib_fixed_point(T, Z, np.zeros((2, 2)), 0.9)
    with pytest.raises(ValueError, match="start to have shape"):
        fib_fixed_point(T, Z, R, 0.9, start=np.zeros(2))
    # rows that sum above 1 leave no bracket: the caller iterates instead
    assert fib_fixed_point(T * 2.2, Z, R, 0.9) is None
    # the unknowns A S, against the cap and 48 steps' worth of observations
    assert fib_exact_pays(3, 2, 2) and fib_exact_pays(5, 60, 21)
    assert not fib_exact_pays(5, 61, 21)  # 305 unknowns: above the cap
    assert not fib_exact_pays(50, 4, 2)  # 200 unknowns: a solve costs more than 16 steps
    assert not fib_exact_pays(1, 300, 1000)  # T Z would hold 9e7 floats (720 MB)


def test_the_dense_form_and_sarsop_use_it_on_a_few_states() -> None:
    model = tiger()
    form = as_solver_model(model)
    info: dict = {}
    start, step = form.fib_start(1e-5, NEVER, info)
    assert step is None and info == {"iterations": 1, "method": "policy iteration"}
    torch.testing.assert_close(start, _fib_star(model), rtol=0, atol=1e-9)
    sol = sarsop(model, SARSOPConfig(time_limit=30.0, precision=1e-3))
    assert sol.info["init"]["upper_method"] == "policy iteration"
    assert sol.info["init"]["upper_iterations"] == 1
    # the optimum of Tiger (discount 0.95) lies within the bounds: 19.37 (pomdp.org)
    assert sol.lower <= 19.3713 + 1e-3 and sol.upper >= 19.3712 - 1e-3
    # float32: the iteration, as before (the policy iteration certifies float64 only)
    info = {}
    _, step = as_solver_model(model, dtype=torch.float32).fib_start(1e-5, NEVER, info)
    assert step is not None and "method" not in info
