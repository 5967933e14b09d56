"""Learn a gridworld reward from expert demonstrations (Abbeel & Ng IRL, as in the paper).

Prints the margin ``t = ||mu_hat - mu(mixture)||`` per iteration, the learned policy's
agreement with the expert, and writes a PNG heat map of the true and learned rewards.

    python examples/irl_gridworld.py [--out reward.png] [--method projection|qp]
                                     [--features indicator|semantic] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import tempfile

import torch

from torchhrc.irl import apprenticeship_learning, expected_return, policy_agreement
from torchhrc.tasks.gridworld import Gridworld


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="PNG path (default: a temp dir)")
    parser.add_argument("--method", choices=["projection", "qp"], default="projection")
    parser.add_argument("--features", choices=["indicator", "semantic"], default="indicator")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)  # tiny problems: one thread is fastest

    world = Gridworld.random(8, 6, seed=args.seed, slip=0.05)
    phi = world.features(args.features)
    demos = world.demonstrations(1000, 60, seed=args.seed)
    print(f"8x8 gridworld, goal {world.goal}, hazards {list(world.hazards)}, slip {world.slip}")
    print(f"{demos.num_trajectories} expert demonstrations of {demos.max_length} steps")

    result = apprenticeship_learning(
        world.transition,
        phi,
        demos,
        discount=world.discount,
        horizon=60,
        epsilon=0.05,
        method=args.method,
        max_iterations=40,
        seed=args.seed,
    )
    for i, t in enumerate(result.margins.tolist(), start=1):
        print(f"iteration {i:2d}  margin t = {t:.4f}")
    print(
        f"converged: {result.converged} after {result.num_iterations} RL steps "
        f"(stop: {result.stop_reason}; reward rule: {result.rule})"
    )

    truth = world.solve()
    learned = world.solve(result.reward(phi, world.num_actions))
    start = world.uniform_start()
    agreement = policy_agreement(truth.q_values, learned.policy, tol=1e-2).item()
    expert = expected_return(world.transition, world.reward, world.discount, truth.policy, start)
    ours = expected_return(world.transition, world.reward, world.discount, learned.policy, start)
    print(f"agreement with the expert's optimal actions: {agreement:.1%}")
    print(f"true expected return: expert {expert.item():.3f}, learned reward's {ours.item():.3f}")

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is missing (pip install torchhrc[full]): no heat map")
        return
    n = world.size
    learned_reward = result.reward(phi, world.num_actions)[0].reshape(n, n)
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.6))
    for ax, values, title in [
        (axes[0], world.reward[0].reshape(n, n), "true reward"),
        (axes[1], learned_reward, f"learned reward ({args.method}, {args.features})"),
    ]:
        image = ax.imshow(values.numpy(), cmap="RdYlGn")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(image, ax=ax, fraction=0.046)
    fig.tight_layout()
    out = args.out or os.path.join(tempfile.mkdtemp(prefix="torchhrc_irl_"), "reward.png")
    directory = os.path.dirname(os.path.abspath(out))
    with tempfile.NamedTemporaryFile(dir=directory, suffix=".png", delete=False) as handle:
        temporary = handle.name
    fig.savefig(temporary, dpi=120)
    os.replace(temporary, out)  # atomic: never a half-written PNG
    plt.close(fig)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
