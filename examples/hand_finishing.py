"""Hand-finishing: the robot infers the person's preferred side from their hand position.

A small version of the paper's second task (9 box configurations, 2 work units per side,
90 states), solved with SARSOP in the factored MOMDP form (stopping on its precision or an
iteration cap, so the output is the same on any machine); one episode per true type,
printing the robot's belief and action at every step and where the person's hand is (it walks
from where the person stands towards the side they work on; the robot sees it with noise).
Seeded; runs in seconds on a CPU (no kinematics:
the comfort of each configuration is given by hand here, see
``torchhrc reproduce hand-finishing`` for the full pipeline with the arm checks).

Run: ``python examples/hand_finishing.py``
"""

from __future__ import annotations

import torch

from torchhrc.solvers import SARSOPConfig, solve
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.tasks.hand_finishing import ACTIONS, HandFinishingTask
from torchhrc.tasks.hand_finishing.geometry import BoxGeometry
from torchhrc.tasks.hand_finishing.person import simulate_episodes
from torchhrc.tasks.hand_finishing.sensing import observation_grid


def main(seed: int = 0) -> None:
    geometry = BoxGeometry(horizontal=(-0.3, 0.0, 0.3), vertical=(0.2,), tilt=(-0.5, 0.0, 0.5))
    comfortable = torch.zeros(3, 1, 3, 2, dtype=torch.bool)  # (H, V, T, [left, right])
    comfortable[:, :, 1:, 0] = True  # left side comfortable when tilted towards the person
    comfortable[:, :, :2, 1] = True
    task = HandFinishingTask.build(feasible=comfortable, geometry=geometry, work_units=2)
    hand = task.observation_model(
        observation_grid(), loc=torch.tensor([0.1, 0.0]), scale=torch.tensor([0.25, 0.25])
    )
    model = task.momdp(hand)
    print(f"MOMDP: {task.num_observed} observed x {task.num_types} types = {task.num_states}")
    config = SARSOPConfig(
        precision=0.05,
        max_iterations=100,
        time_limit=300,  # a safety net: the solve stops on precision within a few iterations
        seed=seed,
        lower_bound_init=type_policy_lower_bound,
    )
    sol = solve(model, config)
    print(
        f"SARSOP: lower {sol.lower:.3f}, upper {sol.upper:.3f} "
        f"({sol.info['iterations']} iterations, stopped on {sol.info['stop_reason']})"
    )
    episodes = simulate_episodes(
        model, sol.policy, model, hand, torch.tensor([0, 1]), steps=8, seed=seed
    )
    for n, name in enumerate(task.first_sides):
        print(f"\ntrue type: {name}-first")
        for t in range(episodes.actions.shape[1]):
            b = episodes.beliefs[n, t]
            cell = int(episodes.cells[n, t])
            action = ACTIONS[int(episodes.actions[n, t])]
            hx, hy = episodes.hands[n, t + 1].tolist()  # the hand after the step (m)
            print(
                f"  step {t}: P(left-first) = {b[0]:.3f} -> {action:6s} "
                f"(then hand at x {hx:.2f}, y {hy:+.2f}; seen in cell {cell})"
            )
        print(f"  waited {int(episodes.wait_steps()[n])} step(s) before the first move")


if __name__ == "__main__":
    main()
