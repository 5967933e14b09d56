"""Adding a solver (docs/architecture.md, "Where to add ... a solver"): a config type and a
function ``(model, config) -> Solution`` written once against the solver form
(``as_solver_model``), registered with ``register_solver``; ``solve()`` then runs it on every
model form. Checked against values worked by hand (Tiger, RockSample(4, 4))."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pytest

from torchhrc.solvers import Solution, register_solver, solve
from torchhrc.solvers.forms import as_solver_model
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.tasks.classic import rock_sample, tiger

TIGER_OPTIMUM = 19.3714  # discount 0.95 (tests/solvers/sarsop/test_sarsop.py)


@dataclass(frozen=True, kw_only=True)
class BlindConfig:
    """Settings of :func:`blind` (keyword-only).

    Attributes:
        tol: accuracy of the Fast Informed Bound's iteration.
        max_iterations: cap on the blind policies' evaluation and on the FIB iteration.
    """

    tol: float = 1e-8
    max_iterations: int = 10_000


def blind(model: Any, config: BlindConfig) -> Solution:
    """The best blind policy ("always do a", Hauskrecht 2000) under the Fast Informed Bound.

    Written once against the solver form: any model ``solve()`` takes is solved alike.
    """
    form = as_solver_model(model)
    policy = form.blind_policy(config.max_iterations)
    vectors, _ = form.fib_vectors(config.tol, max_iterations=config.max_iterations)
    upper = AlphaVectorPolicy.from_action_vectors(vectors, momdp=form.factored)
    return Solution(
        policy,
        lower=form.value_at_roots(policy),
        upper=form.value_at_roots(upper),
        info={"solver": "blind"},
    )


register_solver(BlindConfig, blind)


def test_a_registered_solver_is_reached_through_solve() -> None:
    @dataclass(frozen=True)
    class Unregistered:
        pass

    with pytest.raises(TypeError, match="no solver for config of type Unregistered"):
        solve(tiger(), Unregistered())
    sol = solve(tiger(), BlindConfig())
    # listening forever earns -1 a step: -1 / (1 - 0.95) = -20; opening a door blindly is
    # worse (-45 a step on average)
    assert sol.lower == pytest.approx(-20.0, abs=1e-9)
    assert sol.info["solver"] == "blind"
    # FIB lies between the optimum and QMDP's 189 (solvers/__init__.py's example)
    assert TIGER_OPTIMUM - 1e-3 <= sol.upper <= 189.0 + 1e-6


@pytest.mark.parametrize("form", ["dense", "sparse", "momdp", "sparse_momdp"])
def test_a_registered_solver_solves_every_model_form_alike(form: str) -> None:
    sol = solve(rock_sample(4, 4, form=form), BlindConfig())
    # the robot starts at (0, 2) of the 4 x 4 grid: the best blind policy walks east and
    # leaves on the 4th move for +10, 10 * 0.95^3 = 8.57375
    assert sol.lower == pytest.approx(10 * 0.95**3, abs=1e-6)
    # the same upper bound on every form as on the dense one (22.4101)
    dense = solve(rock_sample(4, 4), BlindConfig())
    assert sol.upper == pytest.approx(dense.upper, abs=1e-6)
    assert sol.lower - 1e-9 <= sol.upper
