"""Tests of Monte Carlo policy evaluation: exact references, determinism, MOMDP == flat."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import POMDP
from torchhrc.solvers import evaluate_policy, qmdp_policy, value_iteration
from torchhrc.solvers.blind import blind_policy
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.tasks.classic import tiger
from torchhrc.testing import random_momdp, random_pomdp


def test_always_listening_is_deterministic():
    result = evaluate_policy(tiger(), blind_policy(tiger()), episodes=50, seed=0)
    expected = -(1 - 0.95**result.horizon) / (1 - 0.95)
    assert result.mean == pytest.approx(expected)
    assert result.std_error == pytest.approx(0.0, abs=1e-12)
    assert result.truncation <= 1e-3
    assert result.returns.shape == (50,)


def test_fully_observable_pomdp_matches_the_mdp_value():
    base = random_pomdp(4, 2, 4, discount=0.9, seed=1)
    eye = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)  # the observation is the state
    model = POMDP(T=base.T, Z=eye, R=base.R, b0=base.b0, discount=0.9)
    exact = float(value_iteration(model.T, model.R, 0.9, tol=1e-10).values @ model.b0)
    result = evaluate_policy(model, qmdp_policy(model), episodes=4000, seed=2)
    assert result.ci_low - result.std_error <= exact <= result.ci_high + result.std_error
    assert abs(result.mean - exact) < 5 * result.std_error + result.truncation


def test_seeded_and_generator():
    model, policy = tiger(), qmdp_policy(tiger())
    a = evaluate_policy(model, policy, episodes=64, horizon=30, seed=3)
    b = evaluate_policy(model, policy, episodes=64, horizon=30, seed=3)
    c = evaluate_policy(model, policy, episodes=64, horizon=30, seed=4)
    assert torch.equal(a.returns, b.returns)
    assert not torch.equal(a.returns, c.returns)
    g = torch.Generator().manual_seed(3)
    assert torch.equal(
        evaluate_policy(model, policy, episodes=64, horizon=30, generator=g).returns, a.returns
    )


def test_momdp_and_flat_simulations_agree():
    model = random_momdp(3, 2, 2, 2, static=False, discount=0.8, seed=5)
    policy = qmdp_policy(model)
    factored = evaluate_policy(model, policy, episodes=3000, seed=6)
    # the same policy acting on the flat model: the flat belief is x-one-hot times b_y
    flat_model = model.to_pomdp()

    def act(belief):
        b = belief.view(-1, 3, 2)
        x = b.sum(-1).argmax(-1)
        return policy.action(x, b[torch.arange(b.shape[0]), x] / b.sum(-1).amax(-1, keepdim=True))

    flat = evaluate_policy(flat_model, act, episodes=3000, seed=7)
    spread = 5 * (factored.std_error**2 + flat.std_error**2) ** 0.5 + 2 * factored.truncation
    assert abs(factored.mean - flat.mean) < spread


def test_bad_input():
    with pytest.raises(ModelError, match="batch_shape"):
        evaluate_policy(random_pomdp(2, 2, 2, batch_shape=(2,), seed=8), qmdp_policy(tiger()))
    momdp_policy = AlphaVectorPolicy(
        torch.zeros(1, 2, dtype=torch.float64), torch.tensor([0]), observed=torch.tensor([0])
    )
    with pytest.raises(ModelError, match="cannot act in a flat POMDP"):
        evaluate_policy(tiger(), momdp_policy)
    with pytest.raises(ValueError, match="episodes"):
        evaluate_policy(tiger(), qmdp_policy(tiger()), episodes=1)


# -- every model form simulates the same process -----------------------------------------------
def test_sparse_form_draws_what_the_dense_form_draws():
    """Tiger's rows have their successors in the same order in both forms: the same seed
    gives the same returns (the sparse form steps the true state as the dense one does)."""
    from torchhrc.pomdp import SparsePOMDP

    model, policy = tiger(), qmdp_policy(tiger())
    dense = evaluate_policy(model, policy, episodes=200, horizon=40, seed=5)
    sparse = evaluate_policy(
        SparsePOMDP.from_dense(model), policy, episodes=200, horizon=40, seed=5
    )
    torch.testing.assert_close(sparse.returns, dense.returns, rtol=0, atol=1e-9)


def test_sparse_momdp_agrees_with_the_dense_momdp():
    from torchhrc.pomdp import SparseMOMDP
    from torchhrc.tasks.classic import rock_sample

    model = rock_sample(4, 2, form="momdp")
    policy = qmdp_policy(model)
    dense = evaluate_policy(model, policy, episodes=1500, seed=1)
    sparse = evaluate_policy(SparseMOMDP.from_dense(model), policy, episodes=1500, seed=2)
    spread = (dense.std_error**2 + sparse.std_error**2) ** 0.5
    assert abs(dense.mean - sparse.mean) <= 4 * spread + dense.truncation


def test_absorbing_states_end_an_episode():
    """From s0 every action earns 1 and moves to s1, which every action keeps with reward 0:
    the return is exactly 1 and the simulation stops after one step."""
    T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]], dtype=torch.float64).expand(2, 2, 2)
    model = POMDP(
        T=T,
        Z=torch.full((2, 2, 2), 0.5, dtype=torch.float64),
        R=torch.tensor([[1.0, 0.0], [1.0, 0.0]], dtype=torch.float64),
        b0=torch.tensor([1.0, 0.0], dtype=torch.float64),
        discount=0.9,
    )
    steps = []
    result = evaluate_policy(model, qmdp_policy(model), episodes=8, seed=0, on_step=steps.append)
    assert result.returns.tolist() == [1.0] * 8
    assert len(steps) == 1 and bool(steps[0].active.all())
    assert steps[0].y.tolist() == [0] * 8 and steps[0].next_x.tolist() == [0] * 8


def test_sparse_belief_paths_match_the_dense_bayes_filter():
    """Beliefs of 300 states with 3 nonzeros take the support-only products (CSR): the
    same updates as torchhrc.pomdp.belief.update, the same actions as the dense scores."""
    from torchhrc.pomdp import SparsePOMDP
    from torchhrc.pomdp.belief import update
    from torchhrc.solvers.evaluate import _form_and_chooser
    from torchhrc.solvers.forms import as_solver_model
    from torchhrc.solvers.sampling import flat_step, mostly_zero

    model = random_pomdp(300, 3, 4, seed=11)
    g = torch.Generator().manual_seed(0)
    belief = torch.zeros(40, 300, dtype=torch.float64)
    belief.scatter_(1, torch.randint(0, 300, (40, 3), generator=g), 1.0)
    belief /= belief.sum(-1, keepdim=True)
    assert mostly_zero(belief)
    state = torch.multinomial(belief, 1, generator=g).squeeze(1)
    action = torch.randint(0, 3, (40,), generator=g)
    step = flat_step(model, state, belief, action, torch.Generator().manual_seed(1))
    expected = update(model, belief, action, step.observation, on_zero="ninf").belief
    torch.testing.assert_close(step.belief, expected, rtol=1e-12, atol=1e-15)
    sparse = as_solver_model(SparsePOMDP.from_dense(model))
    out = sparse.step(
        torch.zeros_like(state), state, belief, action, torch.Generator().manual_seed(1)
    )
    torch.testing.assert_close(out.belief, expected, rtol=1e-12, atol=1e-15)
    policy = qmdp_policy(model)
    _, choose = _form_and_chooser(model, policy)
    assert torch.equal(choose(None, belief), policy.action(belief))


def test_a_solver_form_is_evaluated_as_its_model():
    """``evaluate_policy`` takes whatever ``as_solver_model`` takes, a form too: the same
    draws, so the same returns as the model it adapts."""
    from torchhrc.solvers.forms import as_solver_model

    model = tiger()
    policy = qmdp_policy(model)
    direct = evaluate_policy(model, policy, episodes=50, horizon=20, seed=3)
    via_form = evaluate_policy(as_solver_model(model), policy, episodes=50, horizon=20, seed=3)
    torch.testing.assert_close(via_form.returns, direct.returns, rtol=0, atol=1e-12)
