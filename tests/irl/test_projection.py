"""Tests of torchhrc.irl.projection (Abbeel & Ng 2004 as in the paper) and torchhrc.irl.qp."""

from __future__ import annotations

import math
import warnings

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.irl.features import reward_from_weights
from torchhrc.irl.metrics import expected_return, normalized_return, policy_agreement
from torchhrc.irl.projection import IRLConvergenceWarning, apprenticeship_learning
from torchhrc.irl.qp import QPError, solve_simplex_qp
from torchhrc.irl.trajectories import Trajectories
from torchhrc.solvers.value_iteration import value_iteration
from torchhrc.tasks.gridworld import ColourGridworld, Gridworld


def _fork() -> torch.Tensor:
    """(A=2, S=3, S=3): from state 0 action a goes to state a + 1; states 1, 2 absorb."""
    T = torch.zeros(2, 3, 3, dtype=torch.float64)
    T[0, 0, 1] = T[1, 0, 2] = 1.0
    T[:, 1, 1] = T[:, 2, 2] = 1.0
    return T


# Half the expert's demonstrations go left, half right: mu_hat = (1, 7/16, 7/16) with
# discount 1/2 and horizon 4 (0.5 + 0.25 + 0.125 = 0.875 on the absorbing state).
FORK_DEMOS = Trajectories.from_pairs(
    [[(0, 0), (1, 0), (1, 0), (1, 0)], [(0, 1), (2, 0), (2, 0), (2, 0)]]
)
PHI3 = torch.eye(3, dtype=torch.float64)


@pytest.mark.parametrize("method", ["projection", "qp"])
def test_hand_worked_fork(method):
    # pi0 = "left": mu0 = (1, .875, 0); t1 = .4375 sqrt(2); w1 = (0, -1, 1) / sqrt(2);
    # pi1 = "right": mu1 = (1, 0, .875); the midpoint is mu_hat: t2 = 0 <= eps, M = 1.
    result = apprenticeship_learning(
        _fork(),
        PHI3,
        FORK_DEMOS,
        discount=0.5,
        horizon=4,
        epsilon=1e-6,
        method=method,
        initial_policy=torch.tensor([0, 0, 0]),
    )
    w1 = torch.tensor([0.0, -1.0, 1.0], dtype=torch.float64) / math.sqrt(2)
    assert result.num_iterations == 1 and result.converged
    torch.testing.assert_close(
        result.expert_feature_expectations, torch.tensor([1.0, 0.4375, 0.4375], dtype=torch.float64)
    )
    assert result.margins.shape == (2,)
    assert result.margins[0].item() == pytest.approx(0.4375 * math.sqrt(2))
    assert result.margins[1].item() == pytest.approx(0.0, abs=1e-6)
    torch.testing.assert_close(result.weight_history, w1.unsqueeze(0))
    torch.testing.assert_close(result.weights, w1)  # mean over the second half = {w1}
    torch.testing.assert_close(result.last_weights, w1)
    assert result.policies[:, 0].tolist() == [0, 1]
    torch.testing.assert_close(
        result.mixture_weights, torch.tensor([0.5, 0.5], dtype=torch.float64), atol=1e-6, rtol=0
    )
    torch.testing.assert_close(
        result.feature_expectations,
        torch.tensor([[1.0, 0.875, 0.0], [1.0, 0.0, 0.875]], dtype=torch.float64),
    )


@pytest.mark.parametrize("method", ["projection", "qp"])
@pytest.mark.parametrize("max_iterations", [1, 4, 5])
def test_stopping_rule_and_reward_rules(method, max_iterations):
    # Infinite-horizon mu of any policy has total mass 2 while the 4-step demonstrations'
    # has 1.875: mu_hat is out of reach, so the loop runs until max_iterations or until the
    # RL step repeats a policy (the fork has two useful policies): never "margin".
    with pytest.warns(IRLConvergenceWarning, match="without reaching epsilon"):
        result = apprenticeship_learning(
            _fork(),
            PHI3,
            FORK_DEMOS,
            discount=0.5,
            epsilon=1e-9,
            method=method,
            max_iterations=max_iterations,
            seed=0,
        )
    M = result.num_iterations
    assert not result.converged
    if M == max_iterations:
        assert result.stop_reason in ("max_iterations", "stalled")
    else:
        assert M < max_iterations and result.stop_reason == "stalled"
    if result.stop_reason == "stalled":
        # a fixed point: the next direction's optimal policy is one already in the set
        mixture = result.mixture_weights @ result.feature_expectations
        w_next = result.expert_feature_expectations - mixture
        R = w_next @ PHI3.T
        nxt = value_iteration(_fork(), R.expand(2, 3), 0.5).policy
        known = result.policies if method == "qp" else result.policies[-1:]
        assert (known == nxt).all(-1).any()
    assert result.policies.shape == (M + 1, 3) and result.margins.shape == (M + 1,)
    # every rule's pick, computed here from the history
    torch.testing.assert_close(result.paper_weights, result.weight_history[M // 2 :].mean(0))
    torch.testing.assert_close(result.last_weights, result.weight_history[-1])
    dominant = int(result.mixture_weights[1:].argmax())
    torch.testing.assert_close(result.dominant_weights, result.weight_history[dominant])
    gaps = (result.feature_expectations[1:] - result.expert_feature_expectations).norm(dim=-1)
    torch.testing.assert_close(result.closest_weights, result.weight_history[int(gaps.argmin())])
    assert result.rule == "closest"
    torch.testing.assert_close(result.weights, result.closest_weights)
    for rule, attribute in [("paper", "paper_weights"), ("last", "last_weights"),
                            ("dominant", "dominant_weights")]:  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IRLConvergenceWarning)
            other = apprenticeship_learning(
                _fork(), PHI3, FORK_DEMOS, discount=0.5, epsilon=1e-9, method=method,
                max_iterations=max_iterations, seed=0, rule=rule,
            )  # fmt: skip
        assert other.rule == rule
        torch.testing.assert_close(other.weights, getattr(result, attribute))
    assert (result.margins[1:] <= result.margins[:-1] + 1e-9).all()  # never increases
    assert result.margin > 1e-9
    # each w^(i) is a unit vector and the margin is the mixture's distance to mu_hat
    torch.testing.assert_close(
        result.weight_history.norm(dim=-1), torch.ones(M, dtype=torch.float64)
    )
    mixture = result.mixture_weights @ result.feature_expectations
    assert (result.mixture_weights >= 0).all()
    assert result.mixture_weights.sum().item() == pytest.approx(1.0)
    assert (result.expert_feature_expectations - mixture).norm().item() == pytest.approx(
        result.margin, abs=1e-6
    )
    # the sampling error of mu_hat: two trajectories, per-trajectory sums (1, .875, 0) and
    # (1, 0, .875): unbiased variances (0, .875^2 / 2, .875^2 / 2), over n = 2, summed:
    # .875^2 / 2, so ||std(mu_hat)|| = .875 / sqrt(2)
    assert result.expert_standard_error == pytest.approx(0.875 / math.sqrt(2))


def test_stops_at_the_first_margin_below_epsilon():
    world = Gridworld.random(6, 4, seed=3, slip=0.1)
    demos = world.demonstrations(300, 50, seed=3)
    phi = world.features("indicator")
    full = apprenticeship_learning(
        world.transition, phi, demos, discount=0.9, horizon=50, epsilon=0.0, max_iterations=12
    )
    epsilon = float(full.margins[5])  # the margin after 6 policies
    early = apprenticeship_learning(
        world.transition,
        phi,
        demos,
        discount=0.9,
        horizon=50,
        epsilon=epsilon,
        max_iterations=12,
    )
    first = int(torch.nonzero(full.margins <= epsilon)[0])
    assert early.converged and early.num_iterations == first
    torch.testing.assert_close(early.margins, full.margins[: first + 1])
    torch.testing.assert_close(early.policies, full.policies[: first + 1])


GRID_SEEDS = [0, 1, 2]


@pytest.mark.parametrize("method", ["projection", "qp"])
@pytest.mark.parametrize("seed", GRID_SEEDS)
def test_gridworld_reward_recovers_the_expert(method, seed):
    world = Gridworld.random(8, 6, seed=seed, slip=0.05)
    phi = world.features("semantic")
    demos = world.demonstrations(1000, 60, seed=seed)
    result = apprenticeship_learning(
        world.transition,
        phi,
        demos,
        discount=0.9,
        horizon=60,
        epsilon=0.02,
        method=method,
        max_iterations=40,
        seed=seed,
    )
    assert result.converged and result.margin <= 0.02
    truth = world.solve()
    learned = world.solve(result.reward(phi, world.num_actions))
    # Agreement with the expert's optimal actions; near ties whose true values differ by
    # less than 0.01 (0.05% of the value range [-10, 10]) count as agreement.
    assert policy_agreement(truth.q_values, learned.policy, tol=1e-2) >= 0.95
    # Abbeel & Ng's guarantee on the mixture: |w* . (mu_mix - mu_hat)| <= ||w*|| t
    w_true = world.true_weights("semantic")
    mixture = result.mixture_weights @ result.feature_expectations
    gap = (w_true @ (mixture - result.expert_feature_expectations)).abs()
    assert gap <= w_true.norm() * result.margin + 1e-9
    # the learned policy's true return is close to the expert's
    start = world.uniform_start()
    expert_return = expected_return(world.transition, world.reward, 0.9, truth.policy, start)
    learned_return = expected_return(world.transition, world.reward, 0.9, learned.policy, start)
    assert learned_return >= expert_return - 0.05 * expert_return.abs()


def test_deterministic_under_a_seed():
    world = Gridworld.random(6, 4, seed=1, slip=0.1)
    demos = world.demonstrations(100, 40, seed=1)
    phi = world.features("indicator")
    kwargs = dict(discount=0.9, horizon=40, epsilon=0.05, max_iterations=8)
    a = apprenticeship_learning(world.transition, phi, demos, seed=7, **kwargs)
    b = apprenticeship_learning(world.transition, phi, demos, seed=7, **kwargs)
    c = apprenticeship_learning(world.transition, phi, demos, seed=8, **kwargs)
    assert torch.equal(a.policies, b.policies) and torch.equal(a.margins, b.margins)
    assert torch.equal(a.weights, b.weights)
    assert not torch.equal(a.policies[0], c.policies[0])
    mc1 = apprenticeship_learning(world.transition, phi, demos, seed=7, monte_carlo=50, **kwargs)
    mc2 = apprenticeship_learning(world.transition, phi, demos, seed=7, monte_carlo=50, **kwargs)
    assert torch.equal(mc1.feature_expectations, mc2.feature_expectations)


def test_monte_carlo_equals_exact_on_a_deterministic_mdp():
    kwargs = dict(discount=0.5, horizon=4, epsilon=1e-6, initial_policy=torch.tensor([0, 0, 0]))
    exact = apprenticeship_learning(_fork(), PHI3, FORK_DEMOS, **kwargs)
    sampled = apprenticeship_learning(_fork(), PHI3, FORK_DEMOS, monte_carlo=3, **kwargs)
    torch.testing.assert_close(sampled.feature_expectations, exact.feature_expectations)
    torch.testing.assert_close(sampled.weights, exact.weights)


def test_state_action_features():
    # reward on (state 0, action 1) only: the expert always takes action 1 in state 0
    phi = torch.zeros(3, 2, 2, dtype=torch.float64)
    phi[0, 0, 0] = phi[0, 1, 1] = 1.0
    demos = Trajectories.from_pairs([[(0, 1), (2, 0), (2, 0)]])
    result = apprenticeship_learning(
        _fork(),
        phi,
        demos,
        discount=0.9,
        horizon=3,
        epsilon=1e-6,
        initial_policy=torch.tensor([0, 0, 0]),
    )
    assert result.converged and result.policies[-1, 0].item() == 1
    assert result.weights[1] > result.weights[0]


def test_errors():
    T = _fork()
    with pytest.raises(
        ModelError, match=r"features of shape \(S=3, F\) to match the MDP's 3 states"
    ):
        apprenticeship_learning(T, torch.eye(4, dtype=torch.float64), FORK_DEMOS, discount=0.5)
    empty = Trajectories(
        torch.zeros(0, 1, dtype=torch.long),
        torch.zeros(0, 1, dtype=torch.long),
        torch.zeros(0, dtype=torch.long),
    )
    with pytest.raises(ModelError, match="demonstrations is empty"):
        apprenticeship_learning(T, PHI3, empty, discount=0.5)
    impossible = Trajectories.from_pairs([[(0, 0), (2, 0)]])
    with pytest.raises(ModelError, match=r"demonstrations\[0\] step 0 visits an impossible"):
        apprenticeship_learning(T, PHI3, impossible, discount=0.5)
    with pytest.raises(ValueError, match="method 'projection' or 'qp'"):
        apprenticeship_learning(T, PHI3, FORK_DEMOS, discount=0.5, method="svm")
    with pytest.raises(ValueError, match="epsilon >= 0"):
        apprenticeship_learning(T, PHI3, FORK_DEMOS, discount=0.5, epsilon=-1.0)
    with pytest.raises(ModelError, match="discount"):
        apprenticeship_learning(T, PHI3, FORK_DEMOS, discount=1.5)
    with pytest.raises(ModelError, match="sums to"):
        apprenticeship_learning(T * 0.5, PHI3, FORK_DEMOS, discount=0.5)
    with pytest.raises(ModelError, match=r"transition of shape \(A, S, S\)"):
        apprenticeship_learning(T.expand(2, 2, 3, 3), PHI3, FORK_DEMOS, discount=0.5)
    with pytest.raises(TypeError, match="unexpected keyword"):
        apprenticeship_learning(T, PHI3, FORK_DEMOS, discount=0.5, epsilom=0.1)


def test_qp_failure_names_solver_and_status():
    world = Gridworld.random(6, 4, seed=0, slip=0.1)
    demos = world.demonstrations(50, 40, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(QPError, match="solver SCS reported status 'optimal_inaccurate'"):
            apprenticeship_learning(
                world.transition,
                world.features("indicator"),
                demos,
                discount=0.9,
                horizon=40,
                method="qp",
                qp_solver="SCS",
                qp_options={"max_iters": 2},
            )
        with pytest.raises(QPError, match="solver OSQP reported status 'user_limit'"):
            solve_simplex_qp(
                torch.rand(6, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0)),
                torch.full((4,), 20.0, dtype=torch.float64),
                solver="OSQP",
                solver_options={"max_iter": 1},
            )
    with pytest.raises(QPError, match="solver NOT_A_SOLVER raised"):
        solve_simplex_qp(
            torch.eye(2, dtype=torch.float64),
            torch.ones(2, dtype=torch.float64),
            solver="NOT_A_SOLVER",
        )


def test_qp_matches_brute_force_projection():
    # nearest point of a segment, worked by hand: target (1, 1), points (0, 0), (2, 0)
    lam = solve_simplex_qp(
        torch.tensor([[0.0, 0.0], [2.0, 0.0]], dtype=torch.float64),
        torch.tensor([1.0, 1.0], dtype=torch.float64),
    )
    torch.testing.assert_close(
        lam, torch.tensor([0.5, 0.5], dtype=torch.float64), atol=1e-7, rtol=0
    )
    # random hull: the QP's point is no farther than any of 2000 random mixtures
    g = torch.Generator().manual_seed(0)
    points = torch.randn(5, 3, generator=g, dtype=torch.float64)
    target = torch.randn(3, generator=g, dtype=torch.float64) * 3
    best = (target - solve_simplex_qp(points, target) @ points).norm()
    mixtures = torch.distributions.Dirichlet(torch.ones(5, dtype=torch.float64)).sample((2000,))
    assert best <= (target - mixtures @ points).norm(dim=-1).min() + 1e-7


def test_float32_input_gives_float32_results():
    result = apprenticeship_learning(
        _fork().float(),
        PHI3.float(),
        FORK_DEMOS,
        discount=0.5,
        horizon=4,
        epsilon=1e-5,
        initial_policy=torch.tensor([0, 0, 0]),
    )
    assert result.weights.dtype == torch.float32 and result.margins.dtype == torch.float32
    assert result.converged and result.num_iterations == 1


# Colour worlds of issue 12 (10x10, 5 actions, slip 0.1, discount 0.9, 6 one-hot colours, 3
# rewarded; 100 expert trajectories of 40 steps from uniform starts), with horizon=None so
# that mu_hat is out of every policy's reach (the margin floor 0.060 = 0.148 / sqrt(6)) and
# the loop runs to max_iterations. The rule was chosen on seeds 0-39 and 100-119 (closest
# >= 0.980 there); these seeds were first run by this test. Measured on them (docs/irl.md):
# "closest" >= 0.978 on every world (margin 0.028 over the 0.95 bar), the paper's rule
# below 0.95 on 6 of 20 (as low as -0.48, worse than a random policy).
COLOUR_SEEDS = range(200, 220)


def test_default_reward_scores_on_unseen_colour_worlds():
    scores, paper = [], []
    for seed in COLOUR_SEEDS:
        world = ColourGridworld.random(10, seed=seed)
        demos = world.demonstrations(100, 40, seed=seed + 10_000)
        T, phi = world.transition, world.features()
        with pytest.warns(IRLConvergenceWarning, match="max_iterations = 50 reached"):
            result = apprenticeship_learning(T, phi, demos, discount=0.9, seed=seed)
        assert result.stop_reason == "max_iterations" and not result.converged
        assert result.margin > 0.0603  # above the mass-deficit floor 0.148 / sqrt(6)
        start = world.uniform_start()
        for weights, out in ((result.weights, scores), (result.paper_weights, paper)):
            policy = world.solve(reward_from_weights(phi, weights, 5)).policy
            out.append(float(normalized_return(T, world.reward, 0.9, policy, start)))
    assert min(scores) >= 0.95, scores
    # the paper's rule, still available by name, fails on some of the same worlds
    assert sum(s < 0.95 for s in paper) >= 1, paper
