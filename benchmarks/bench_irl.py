"""IRL quality and speed: torchhrc (Abbeel-Ng projection / QP, MaxEnt) vs imitation's MCE IRL.

Workload: 8x8 gridworlds (``torchhrc.tasks.gridworld``) with a goal and 6 hazards at seeded
random cells, slip 0.05, discount 0.9; 1000 expert demonstrations of 60 steps per world
(the expert is optimal for the true reward); reward features: goal and hazard indicators and
the distance to the goal (``features("semantic")``, F = 3). Every method gets the same
demonstrations and the same features, and learns a linear reward ``w . phi(s)``:

* ``torchhrc projection`` / ``torchhrc qp``: :func:`torchhrc.irl.apprenticeship_learning`
  (the paper's algorithm; horizon 60, epsilon 0.02; reward = its default rule "closest", the
  w whose policy's feature expectations are nearest the expert's; docs/irl.md).
* ``torchhrc maxent``: :func:`torchhrc.irl.maxent_irl` (soft value iteration with implicit
  gradients, L-BFGS; infinite horizon; l2 = 1e-3, gradient tolerance 1e-6).
* ``imitation MCE IRL``: ``imitation.algorithms.mce_irl.MCEIRL`` (finite-horizon MCE IRL,
  Adam, its defaults: lr 1e-2, linf_eps 1e-3, grad_l2_eps 1e-4, max_iter 1000) with a
  linear reward net (``BasicRewardNet(hid_sizes=[])``) on the same features (its
  ``observation_matrix``), horizon 59 (60 time steps), and as demonstrations the empirical
  discounted state-occupancy measure of the same trajectories (its documented input for
  discount < 1).

Measured per world: agreement of the optimal policy for the learned reward with the
expert's optimal actions (``policy_agreement``, near ties within 0.01 of the true value count
as agreement; ``strict`` = within 1e-6), the true expected return of that policy from the
demonstrations' start distribution, and the wall time of the learning call (one thread for
every method; torchhrc best of ``--repeats``, imitation once as it takes minutes).

Usage::

    python benchmarks/bench_irl.py [--worlds 5] [--repeats 2] [--threads 1]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch
import torch.optim  # imported up front: first-call imports are not part of the timings

from torchhrc.irl import (
    apprenticeship_learning,
    empirical_feature_expectations,
    expected_return,
    maxent_irl,
    policy_agreement,
    start_distribution,
)
from torchhrc.tasks.gridworld import Gridworld

DISCOUNT = 0.9
HORIZON = 60


def _best_time(
    fn: Callable[..., torch.Tensor], args: tuple, repeats: int
) -> tuple[torch.Tensor, float]:
    best, out = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - start)
    assert out is not None
    return out, best


def imitation_mce(world: Gridworld, phi: torch.Tensor, demos, seed: int) -> torch.Tensor:
    """imitation's MCE IRL on the same data; returns the learned state reward ``(S,)``."""
    from imitation.algorithms.mce_irl import MCEIRL
    from imitation.rewards.reward_nets import BasicRewardNet
    from imitation.util.logger import configure
    from seals.base_envs import TabularModelPOMDP

    S = world.num_states
    env = TabularModelPOMDP(
        transition_matrix=world.transition.permute(1, 0, 2).numpy(),  # (S, A, S)
        observation_matrix=phi.numpy().astype(np.float32),
        reward_matrix=world.reward[0].numpy(),
        horizon=HORIZON - 1,
        initial_state_dist=start_distribution(demos, S).numpy(),
    )
    occupancy = empirical_feature_expectations(torch.eye(S, dtype=torch.float64), demos, DISCOUNT)
    torch.manual_seed(seed)
    net = BasicRewardNet(env.observation_space, env.action_space, hid_sizes=[], use_action=False)
    mce = MCEIRL(
        occupancy.numpy(),
        env,
        net,
        rng=np.random.default_rng(seed),
        discount=DISCOUNT,
        log_interval=None,
        custom_logger=configure(format_strs=[]),
    )
    mce.train(max_iter=1000)
    with torch.no_grad():
        obs = torch.as_tensor(env.observation_matrix, dtype=net.dtype)
        return net(obs, None, None, None).squeeze(-1).double()


def learn(name: str, world: Gridworld, phi: torch.Tensor, demos, seed: int) -> torch.Tensor:
    """Run one method; return the learned reward ``(A, S)``."""
    A = world.num_actions
    if name == "imitation MCE IRL":
        return imitation_mce(world, phi, demos, seed).expand(A, -1)
    if name == "torchhrc maxent":
        result = maxent_irl(world.transition, phi, demos, discount=DISCOUNT, l2=1e-3, tol=1e-6)
        return result.reward(phi, A)
    method = "qp" if name == "torchhrc qp" else "projection"
    result = apprenticeship_learning(
        world.transition,
        phi,
        demos,
        discount=DISCOUNT,
        horizon=HORIZON,
        epsilon=0.02,
        method=method,
        seed=seed,
    )
    return result.reward(phi, A)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    try:  # import everything first: first-call imports are not part of the timings
        import cvxpy  # noqa: F401
        import imitation.algorithms.mce_irl  # noqa: F401
        import seals.base_envs  # noqa: F401
    except ImportError as error:
        raise SystemExit(
            f"bench_irl needs {error.name}: pip install 'torchhrc[bench-imitation]' "
            "(in a virtual environment of its own: imitation pins gymnasium ~= 0.29)"
        ) from None

    methods = ["torchhrc projection", "torchhrc qp", "torchhrc maxent", "imitation MCE IRL"]
    rows: dict[str, list[tuple[float, float, float, float]]] = {m: [] for m in methods}
    for seed in range(args.worlds):
        world = Gridworld.random(8, 6, seed=seed, slip=0.05)
        phi = world.features("semantic")
        demos = world.demonstrations(1000, HORIZON, seed=seed)
        truth = world.solve()
        d0 = start_distribution(demos, world.num_states)
        expert_return = expected_return(world.transition, world.reward, DISCOUNT, truth.policy, d0)
        for name in methods:
            # imitation takes minutes per world: timed once; torchhrc best of --repeats
            repeats = 1 if name.startswith("imitation") else args.repeats
            reward, seconds = _best_time(learn, (name, world, phi, demos, seed), repeats)
            policy = world.solve(reward).policy
            rows[name].append(
                (
                    policy_agreement(truth.q_values, policy, tol=1e-2).item(),
                    policy_agreement(truth.q_values, policy, tol=1e-6).item(),
                    (
                        expected_return(world.transition, world.reward, DISCOUNT, policy, d0)
                        / expert_return
                    ).item(),
                    seconds,
                )
            )
        print(
            f"world {seed}: "
            + ", ".join(
                f"{m.split()[-1]} {rows[m][-1][0]:.3f}/{rows[m][-1][3]:.2f}s" for m in methods
            ),
            flush=True,
        )

    print()
    print(
        f"{args.worlds} gridworlds 8x8, 6 hazards, slip 0.05, 1000 demos x {HORIZON} steps, "
        f"{args.threads} thread(s)"
    )
    header = (
        f"{'method':22s} {'agreement':>10s} {'strict':>8s} {'min agr':>8s} "
        f"{'return/expert':>14s} {'time s':>8s}"
    )
    print(header)
    summary = {}
    for name in methods:
        values = np.array(rows[name])
        mean = values.mean(0)
        summary[name] = mean
        print(
            f"{name:22s} {mean[0]:10.3f} {mean[1]:8.3f} {values[:, 0].min():8.3f} "
            f"{mean[2]:14.4f} {mean[3]:8.3f}"
        )
    peer = summary["imitation MCE IRL"]
    print()
    for name in methods[:3]:
        ours = summary[name]
        print(
            f"{name} vs imitation MCE IRL: speed-up {peer[3] / ours[3]:.1f}x, "
            f"agreement {ours[0]:.3f} vs {peer[0]:.3f} (diff {ours[0] - peer[0]:+.3f}), "
            f"return ratio {ours[2] / peer[2]:.4f}"
        )


if __name__ == "__main__":
    main()
