"""Solve the Tiger problem (Kaelbling, Littman, Cassandra 1998) and check the policy.

Runs PBVI, prints the bounds against the known optimal value (about 19.371 at the uniform
belief, discount 0.95), estimates the policy's value by Monte Carlo, and prints the policy's
actions at a few beliefs. Seeded; takes a few seconds.

    python examples/solve_tiger.py
"""

from __future__ import annotations

import torch

from torchhrc.solvers import PBVIConfig, evaluate_policy, solve
from torchhrc.tasks.classic import tiger

OPTIMUM = 19.371  # V*(uniform), checked by an exact solver in tests/solvers/_exact_pomdp.py


def main() -> None:
    torch.set_num_threads(1)  # tiny tensors: threads only add overhead
    model = tiger()
    solution = solve(model, PBVIConfig(time_limit=30, expansions=10, seed=0))
    print(
        f"PBVI: lower {solution.lower:.4f}  upper (FIB) {solution.upper:.4f}  "
        f"alpha vectors {solution.policy.num_vectors}  "
        f"time {solution.history[-1]['time_s']:.2f}s"
    )
    print(f"known optimum {OPTIMUM}: relative error {abs(solution.lower - OPTIMUM) / OPTIMUM:.2e}")

    mc = evaluate_policy(model, solution.policy, episodes=2000, seed=1)
    print(f"Monte Carlo value {mc.mean:.3f}  95% CI [{mc.ci_low:.3f}, {mc.ci_high:.3f}]")

    assert model.actions is not None
    for p_left in (0.5, 0.85, 0.97, 0.03):
        belief = torch.tensor([p_left, 1 - p_left], dtype=torch.float64)
        action = model.actions[int(solution.policy.action(belief))]
        print(f"P(tiger left) = {p_left:.2f}: {action}")


if __name__ == "__main__":
    main()
