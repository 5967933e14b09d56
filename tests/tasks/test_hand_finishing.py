import math
from dataclasses import replace

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.experiments.hand_finishing import cluster_preferences
from torchhrc.mixture import fit_mixture
from torchhrc.pomdp.belief import momdp_update
from torchhrc.pomdp.observation import discretize_positions
from torchhrc.solvers import SARSOPConfig, solve
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.tasks.hand_finishing import ACTIONS, HandFinishingTask, count_states
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
from torchhrc.tasks.hand_finishing.person import (
    HandMotion,
    hand_trajectories,
    simulate_demonstrations,
    simulate_episodes,
    simulate_hand_tracks,
)
from torchhrc.tasks.hand_finishing.sensing import observation_grid

GEOMETRY = BoxGeometry(horizontal=(-0.3, 0.0, 0.3), vertical=(0.2,), tilt=(-0.5, 0.0, 0.5))


def _feasible() -> torch.Tensor:
    # left comfortable for tilt >= 0, right for tilt <= 0 (as the kinematic check finds)
    f = torch.zeros(3, 1, 3, 2, dtype=torch.bool)
    f[:, :, 1:, 0] = True
    f[:, :, :2, 1] = True
    return f


def _task(work_units: int = 2, sides=("left", "right")) -> HandFinishingTask:
    return HandFinishingTask.build(
        feasible=_feasible(), geometry=GEOMETRY, work_units=work_units, first_sides=sides
    )


def test_count_formula_and_paper_size():
    task = _task(work_units=3)
    assert task.num_states == count_states(task.num_configurations, 3) == 9 * 7 * 2
    # the default geometry keeps 75 of 100 configurations (test_hand_finishing_geometry):
    assert count_states(75, 6) == 1950
    assert abs(count_states(75, 6) - 2000) / 2000 < 0.05


def test_presents_start_and_neighbours():
    task = _task()
    # start: centre, tilt 0, comfortable for both sides -> presents neither
    assert task.kept[task.start].tolist() == [1, 0, 1]
    assert not task.presents[task.start].any()
    # left side presented at tilt +0.5 with h >= 0; right at tilt -0.5 with h <= 0
    kept = task.kept.tolist()
    assert task.presents[kept.index([2, 0, 2]), 0] and not task.presents[kept.index([0, 0, 2]), 0]
    assert task.presents[kept.index([0, 0, 0]), 1]
    assert task.distance[task.start].tolist() == [1, 1]
    # moving h+ from the right edge is blocked: stays
    right_edge = kept.index([2, 0, 1])
    assert int(task.neighbour[ACTIONS.index("h+"), right_edge]) == right_edge


def test_transitions_and_rewards_by_hand():
    task = _task()
    m = task.momdp()
    P = task.num_progress
    x0 = task.x0
    a = ACTIONS.index("tilt+")
    target = task.kept.tolist().index([1, 0, 2]) * P
    rw = task.rewards
    # left-first (y=0): the move presents its side: works with probability 0.8
    assert m.Tx[a, x0, 0, target + 1].item() == pytest.approx(rw.work_probability)
    assert m.Tx[a, x0, 0, target].item() == pytest.approx(1 - rw.work_probability)
    assert m.R[a, x0, 0].item() == pytest.approx(
        rw.work_reward * rw.work_probability - rw.move_cost
    )
    # right-first (y=1): the same move is unwanted
    assert m.Tx[a, x0, 1, target].item() == pytest.approx(1.0)
    assert m.R[a, x0, 1].item() == pytest.approx(-rw.move_cost - task.unwanted_cost)
    assert m.R[0, x0].tolist() == [0.0, 0.0]  # waiting costs nothing but time
    # progress "done" is absorbing (the box may still move) with zero reward
    done = task.start * P + P - 1
    next_progress = torch.arange(task.num_observed) % P
    mass_done = (m.Tx[:, done] * (next_progress == P - 1)).sum(-1)
    assert torch.allclose(mass_done, torch.ones_like(mass_done))
    assert torch.all(m.R[:, done] == 0)


def test_hand_offset_follows_progress():
    task = _task(work_units=2)
    off = task.hand_offset()  # (X, Y, 2)
    x = task.x0
    # at the start the left-first hand is at the left surface (+y), the right-first at -y
    assert off[x, 0, 1] > 0 > off[x, 1, 1]
    # after W units they swap sides
    assert off[x + 2, 0, 1] < 0 < off[x + 2, 1, 1]


def test_bad_inputs_are_reported():
    with pytest.raises(ModelError, match="feasible"):
        HandFinishingTask.build(
            feasible=torch.ones(2, 2, 2, 2, dtype=torch.bool), geometry=GEOMETRY
        )
    with pytest.raises(ModelError, match="first_sides"):
        _task(sides=("up",))
    with pytest.raises(ModelError, match="no box configuration"):
        HandFinishingTask.build(
            feasible=torch.zeros(3, 1, 3, 2, dtype=torch.bool), geometry=GEOMETRY
        )


def test_impossible_observation_raises_clear_error():
    task = _task()
    m = task.momdp(task.observation_model(observation_grid(), loc=torch.zeros(2),
                                          scale=torch.full((2,), 0.2)))  # fmt: skip
    # waiting cannot move the box to another configuration
    far = task.kept.tolist().index([0, 0, 0]) * task.num_progress
    with pytest.raises(ModelError, match="x_next"):
        momdp_update(m, task.x0, m.b0, 0, far, 0)


def test_demonstrations_cluster_into_the_two_preferences():
    demos = simulate_demonstrations(["left"] * 3 + ["right"] * 3, seed=0)
    assert demos.num_sequences == 18
    # the types are side preferences: objects (left, right) must stay raw
    fit = fit_mixture(demos, k_min=1, k_max=4, seed=0, initial=True, objects="raw")
    assert fit.k == 2
    sides = cluster_preferences(fit, demos.vocabulary)
    assert sorted(sides) == ["left", "right"]
    predicted = [sides[c] for c in fit.assignments.tolist()]
    assert predicted == list(demos.types)


def _solve_small(noise: float):
    task = _task()
    grid = observation_grid()
    obs = task.observation_model(grid, loc=torch.tensor([0.1, 0.0]),
                                 scale=torch.tensor([noise, noise]))  # fmt: skip
    m = task.momdp(obs)
    # deterministic stop (precision or iterations; the time limit is a safety net)
    sol = solve(m, SARSOPConfig(time_limit=300, precision=0.02, max_iterations=10,
                                lower_bound_init=type_policy_lower_bound))  # fmt: skip
    ep = simulate_episodes(m, sol.policy, m, obs, torch.arange(100) % 2, steps=10, seed=3)
    return ep


def test_beliefs_stay_distributions_and_waiting_grows_with_noise():
    low = _solve_small(0.05)
    high = _solve_small(0.5)
    for ep in (low, high):
        assert torch.all(ep.beliefs >= 0)
        assert torch.allclose(ep.beliefs.sum(-1), torch.ones(()).double())
        assert not torch.isnan(ep.beliefs).any()
    assert high.wait_steps().double().mean() > low.wait_steps().double().mean()
    # with a precise hand position the robot moves after one observation, correctly
    assert torch.all(low.wait_steps() == 1)
    guess = low.belief_at_first_move().argmax(-1)
    assert torch.equal(guess, low.types)


def test_simulated_demonstrations_are_seeded():
    a = simulate_demonstrations(["left", "right"], seed=4)
    b = simulate_demonstrations(["left", "right"], seed=4)
    assert a == b
    assert math.isclose(float(a.lengths.float().mean()), float(b.lengths.float().mean()))


@pytest.mark.slow
def test_default_task_has_about_2000_states():
    task = HandFinishingTask.build()  # kinematic checks of the default 5 x 4 x 5 grid
    assert task.num_states == count_states(task.num_configurations, task.work_units)
    assert 1800 <= task.num_states <= 2200
    assert task.num_configurations < 100  # some configurations were removed
    assert task.presents.any(0).all()  # both sides can be presented
    assert (task.distance[task.start] < task.num_configurations).all()


# ------------------------------------------------------------------ the person's hand motion
def _waiting_policy(task):
    from torchhrc.solvers import AlphaVectorPolicy

    X = task.num_observed
    alphas = torch.zeros(X, task.num_types, dtype=torch.float64)
    return AlphaVectorPolicy(alphas, torch.zeros(X, dtype=torch.long), observed=torch.arange(X))


@pytest.mark.parametrize("batch", [(), (2,), (2, 3)])
def test_hand_trajectories_match_the_recursion(batch):
    gen = torch.Generator().manual_seed(0)
    targets = torch.randn(*batch, 7, 2, generator=gen, dtype=torch.float64)
    motion = HandMotion(approach=0.35, start=(1.1, -0.2))
    hands = hand_trajectories(targets, motion)
    assert hands.shape == targets.shape
    hand = torch.tensor([1.1, -0.2], dtype=torch.float64).expand(*batch, 2)
    for t in range(7):  # reference: the recursion, one step at a time
        hand = hand + 0.35 * (targets[..., t, :] - hand)
        assert torch.allclose(hands[..., t, :], hand, atol=1e-12)
    # approach 1: the hand is at its target at every step
    assert torch.equal(hand_trajectories(targets, HandMotion(approach=1.0)), targets)


def test_hand_motion_rejects_bad_settings():
    with pytest.raises(ModelError, match="approach"):
        HandMotion(approach=0.0)
    with pytest.raises(ModelError, match="approach"):
        HandMotion(approach=1.5)
    with pytest.raises(ModelError, match="start"):
        HandMotion(start=(0.0, float("nan")))
    with pytest.raises(ModelError, match="targets"):
        hand_trajectories(torch.zeros(3), HandMotion())


def test_hand_walks_towards_the_side_worked_on():
    # A waiting robot: the box stays at the start (presenting neither side), the target of
    # each person stays the surface of their first side. The hand's distance to it shrinks by
    # (1 - approach) per step: a path from the start, not noise around a point.
    task = _task()
    noise = 0.2
    obs = task.observation_model(observation_grid(), loc=torch.tensor([0.1, 0.0]),
                                 scale=torch.tensor([noise, noise]))  # fmt: skip
    m = task.momdp(obs)
    motion = HandMotion(approach=0.6, start=(1.2, 0.0))
    types = torch.arange(400) % 2
    ep = simulate_episodes(m, _waiting_policy(task), m, obs, types, steps=6, motion=motion,
                           seed=1)  # fmt: skip
    assert ep.hands is not None and ep.hands.shape == (400, 7, 2)
    assert torch.allclose(ep.hands[:, 0], torch.tensor([1.2, 0.0], dtype=torch.float64))
    target = obs.mean()[task.x0, types]  # (N, 2)
    dist = (ep.hands - target.unsqueeze(1)).norm(dim=-1)  # (N, L + 1)
    assert torch.allclose(dist[:, 1:], dist[:, :-1] * 0.4, atol=1e-12)
    # left-first hands go to +y (the left surface), right-first to -y, monotonically
    lateral = ep.hands[..., 1]
    assert torch.all(lateral[types == 0].diff(dim=-1) > 0)
    assert torch.all(lateral[types == 1].diff(dim=-1) < 0)
    # the sensor adds the model's noise around the hand, unbiased
    err = (ep.positions - ep.hands[:, 1:]).reshape(-1, 2)  # (N L, 2)
    se = noise / math.sqrt(err.shape[0])
    assert err.mean(0).abs().max() < 4 * se
    assert torch.allclose(err.std(0), torch.full((2,), noise, dtype=torch.float64), rtol=0.05)


def test_hand_crosses_to_the_second_side():
    # left-first person: once the left side is done the target switches to the right surface
    task = _task()
    obs = task.observation_model(observation_grid(), loc=torch.tensor([0.1, 0.0]),
                                 scale=torch.tensor([0.1, 0.1]))  # fmt: skip
    m = task.momdp(obs)
    sol = solve(m, SARSOPConfig(time_limit=60, precision=0.02, max_iterations=200,
                                lower_bound_init=type_policy_lower_bound))  # fmt: skip
    ep = simulate_episodes(m, sol.policy, m, obs, torch.zeros(20, dtype=torch.long), steps=12,
                           seed=2)  # fmt: skip
    progress = ep.observed % task.num_progress
    lateral = ep.hands[..., 1]
    for n in range(20):
        done_left = int(torch.nonzero(progress[n] >= task.work_units)[0])  # first such step
        assert lateral[n, :done_left].max() > 0.1  # was on the left (+y) side
        assert lateral[n, -1] < -0.05  # ends on the right (-y) side


def test_hand_tracks_follow_the_motion_and_are_seeded():
    task = _task()
    noise = 0.15
    obs = task.observation_model(observation_grid(), loc=torch.tensor([0.1, 0.0]),
                                 scale=torch.tensor([noise, noise]))  # fmt: skip
    m = task.momdp(obs)
    motion = HandMotion(approach=0.5, start=(1.2, 0.0))
    n = 2000
    waits = torch.zeros(n, 5, dtype=torch.long)
    tracks = simulate_hand_tracks(m, obs, num_tracks=n, length=5, motion=motion, actions=waits,
                                  seed=3)  # fmt: skip
    again = simulate_hand_tracks(m, obs, num_tracks=n, length=5, motion=motion, actions=waits,
                                 seed=3)  # fmt: skip
    assert torch.equal(tracks.positions, again.positions) and torch.equal(tracks.cells,
                                                                          again.cells)  # fmt: skip
    assert tracks.types is not None and tracks.positions is not None
    # box fixed at the start, no work: hand_t = g + 0.5^(t+1) (start - g) for each type
    start = torch.tensor([1.2, 0.0], dtype=torch.float64)
    for y in range(2):
        g = obs.mean()[task.x0, y]
        sel = tracks.types == y
        expected = g + 0.5 ** torch.arange(1, 6, dtype=torch.float64).unsqueeze(-1) * (start - g)
        mean = tracks.positions[sel].mean(0)  # (L, 2)
        se = noise / math.sqrt(int(sel.sum()))
        assert (mean - expected).abs().max() < 4.5 * se
    # the cells are those of the sensed positions
    assert torch.equal(tracks.cells, discretize_positions(obs.grid, tracks.positions))


def test_unwanted_cost_priced_from_the_risk_tolerance_by_hand():
    """W = 1, the 3 x 1 x 3 grid: from the centre, tilt+ presents left, tilt- right.

    Left-first, known type (r = work_reward * work_probability = 0.8, c = 0.05, g = 0.95,
    q = 0.8): presenting right at p = 1, V_R1 = r / (1 - g (1 - q)); at the centre,
    p = 1, V_C1 = r - c + g (1 - q) V_R1; presenting left at p = 1, V_L1 = -c + g V_C1;
    presenting left at p = 0, V_L0 = (r + g q V_L1) / (1 - g (1 - q)); at the start,
    V_C0 = Q(tilt+) = V_L0 - c and Q(wait) = g V_C0, so the gain of moving is
    (1 - g) V_C0. For a right-first person tilt+ is unwanted: Q(wait) - Q(tilt+) =
    g V_C0 - (-c - U + g (-c + g V_C0)) = g (1 - g) V_C0 + c (1 + g) + U. The break-even
    belief 1 - b = tol gives U = (1 - tol) / tol (1 - g) V_C0 - g (1 - g) V_C0 - c (1 + g).
    """
    from torchhrc.tasks.hand_finishing import RewardSettings, unwanted_cost_for_risk

    r, c, g, q = 0.8, 0.05, 0.95, 0.8
    v_r1 = r / (1 - g * (1 - q))
    v_c1 = r - c + g * (1 - q) * v_r1
    v_l1 = -c + g * v_c1
    v_l0 = (r + g * q * v_l1) / (1 - g * (1 - q))
    v_c0 = v_l0 - c
    for tol in (0.05, 0.02, 0.01):
        expected = (1 - tol) / tol * (1 - g) * v_c0 - g * (1 - g) * v_c0 - c * (1 + g)
        task = HandFinishingTask.build(feasible=_feasible(), geometry=GEOMETRY, work_units=1,
                                       rewards=RewardSettings(risk_tolerance=tol))  # fmt: skip
        assert task.unwanted_cost == pytest.approx(expected, rel=1e-9)
        assert task.unwanted_cost_for_risk(tol) == pytest.approx(expected, rel=1e-9)
    # the numbers: V_C0 = 1.72653, and at tol = 0.02, U = 49 * 0.086326 - 0.179510 = 4.05048
    assert v_c0 == pytest.approx(1.72653, abs=1e-5)
    two = HandFinishingTask.build(feasible=_feasible(), geometry=GEOMETRY, work_units=1)
    assert two.rewards.risk_tolerance == 0.02
    assert two.unwanted_cost == pytest.approx(4.05048, abs=1e-5)
    # the closed form of the rule and its clamp
    assert unwanted_cost_for_risk(0.1, 0.2, 0.02) == pytest.approx(0.1 * 49 - 0.2)
    assert unwanted_cost_for_risk(0.1, 10.0, 0.02) == 0.0
    with pytest.raises(ModelError, match="risk_tolerance"):
        unwanted_cost_for_risk(0.1, 0.2, 0.0)


@pytest.mark.parametrize("tol", [0.05, 0.02, 0.01])
def test_priced_cost_makes_qmdp_break_even_at_the_tolerance(tol):
    """Reference: the solvers' QMDP values of the task MOMDP (an independent value
    iteration). With the priced cost, at the start the best move for a type and waiting are
    worth the same at belief 1 - tol on that type; the move wins above, waiting below."""
    from torchhrc.solvers.qmdp import mdp_q_values
    from torchhrc.tasks.hand_finishing import RewardSettings

    task = HandFinishingTask.build(feasible=_feasible(), geometry=GEOMETRY, work_units=2,
                                   rewards=RewardSettings(risk_tolerance=tol))  # fmt: skip
    Q, _ = mdp_q_values(task.momdp())
    q = Q[:, task.x0]  # (A, Y)
    move, wait = ACTIONS.index("tilt+"), ACTIONS.index("wait")  # right for left-first (y = 0)
    for risk, sign in ((tol, 0), (tol / 2, 1), (2 * tol, -1)):
        b = torch.tensor([1 - risk, risk], dtype=torch.float64)
        diff = float((q[move] - q[wait]) @ b)
        if sign == 0:
            assert diff == pytest.approx(0.0, abs=1e-9)
        else:
            assert diff * sign > 0


def test_unwanted_cost_set_directly_and_errors():
    from torchhrc.tasks.hand_finishing import RewardSettings

    task = HandFinishingTask.build(feasible=_feasible(), geometry=GEOMETRY, work_units=2,
                                   rewards=RewardSettings(unwanted_cost=2.0))  # fmt: skip
    assert task.unwanted_cost == 2.0
    # a larger tolerance prices a wrong move lower
    low = HandFinishingTask.build(feasible=_feasible(), geometry=GEOMETRY, work_units=2,
                                  rewards=RewardSettings(risk_tolerance=0.1))  # fmt: skip
    assert 0 < low.unwanted_cost < _task().unwanted_cost
    # a task derived with other types is priced for them (one type: no risky first move)
    assert replace(_task(), first_sides=("left",)).unwanted_cost == 0.0
    assert replace(_task(sides=("left",)), first_sides=("left", "right")).unwanted_cost == (
        pytest.approx(_task().unwanted_cost)
    )
    with pytest.raises(ModelError, match="risk_tolerance"):
        RewardSettings(risk_tolerance=1.0)
    with pytest.raises(ModelError, match="unwanted_cost"):
        RewardSettings(unwanted_cost=-1.0)
