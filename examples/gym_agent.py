"""A SARSOP robot and a random robot in the gymnasium environment torchhrc/PlaceAndDrill-v0.

The robot's model is the hand-coded expert MOMDP of the place-and-drill task; SARSOP solves
it, and :class:`torchhrc.envs.BeliefAgent` acts with the solved policy and its belief filter
in the environment, where a simulated human (type drawn per episode) places screws and
deviates from its order with probability epsilon. Prints each robot's mean return (the
paper's accumulated reward, undiscounted) with a 95% confidence interval. Seeded; runs in
seconds. Needs the ``gym`` extra (``pip install 'torchhrc[gym]'``).

    python examples/gym_agent.py
"""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import torch

import torchhrc.envs  # noqa: F401  (registers torchhrc/PlaceAndDrill-v0)
from torchhrc.envs import BeliefAgent, RandomAgent, rollout
from torchhrc.solvers import SARSOPConfig, solve

EPISODES = 200


def summary(name: str, returns: np.ndarray) -> str:
    half = 1.959963984540054 * returns.std(ddof=1) / math.sqrt(returns.size)
    mean = returns.mean()
    return f"{name:>6} robot: mean return {mean:7.2f} +- {half:.2f} (95% CI, n={returns.size})"


def main() -> None:
    torch.set_num_threads(1)  # tiny tensors: threads only add overhead
    env = gymnasium.make("torchhrc/PlaceAndDrill-v0", epsilon=0.1)
    model = env.unwrapped.model
    solution = solve(model, SARSOPConfig(time_limit=10.0, precision=0.01, seed=0))
    print(f"SARSOP on the expert MOMDP: lower {solution.lower:.3f} upper {solution.upper:.3f}")
    sarsop = rollout(env, BeliefAgent(model, solution.policy), episodes=EPISODES, seed=0)
    random = rollout(env, RandomAgent(env.action_space, seed=0), episodes=EPISODES, seed=0)
    print(summary("SARSOP", sarsop))
    print(summary("random", random))


if __name__ == "__main__":
    main()
