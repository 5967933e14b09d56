import math

import pytest
import torch

from torchhrc.belief import momdp_update
from torchhrc.errors import ModelError
from torchhrc.experiments.hand_finishing import cluster_preferences, observation_grid
from torchhrc.kinematics import BoxGeometry
from torchhrc.mixture import fit_mixture
from torchhrc.solvers import SARSOPConfig, solve
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.tasks.hand_finishing import ACTIONS, HandFinishingTask, count_states
from torchhrc.tasks.hand_finishing.person import simulate_demonstrations, simulate_episodes

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
    # the default geometry keeps 75 of 100 configurations (kinematics, see test_kinematics):
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
    assert m.R[a, x0, 1].item() == pytest.approx(-rw.move_cost - rw.unwanted_cost)
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
    fit = fit_mixture(demos, k_min=1, k_max=4, seed=0, initial=True)
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
    sol = solve(m, SARSOPConfig(time_limit=20, precision=0.02,
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
