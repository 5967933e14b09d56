"""Build a small MOMDP in Python, solve it, and follow its policy and belief.

A toy version of the paper's setting (Nikolaidis et al.): the task step ``x`` is observed,
the human's type ``y`` ("safe" or "efficient") is hidden and never changes. At each step the
robot either waits or drills; a "safe" human prefers the robot to wait, an "efficient" one to
drill. The human's hand motion, observed each step, hints at the type. PBVI solves the MOMDP
with factored backups (alpha vectors over the type, one set per task step), then one
simulated execution prints the robot's first actions and its belief about the type. Last,
the same task when the robot may join at step 0 or step 1 (``MOMDP.with_initial``: a random
first observed value), solved by SARSOP. Seeded; takes a few seconds.

    python examples/momdp_small.py
"""

from __future__ import annotations

import torch

from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.belief import momdp_update
from torchhrc.solvers import PBVIConfig, SARSOPConfig, solve
from torchhrc.solvers.sampling import sample_categorical

STEPS = 4  # task steps 0..3, then "done" (absorbing)
TYPES = ("safe", "efficient")
ACTIONS = ("wait", "drill")
OBSERVATIONS = ("reaching", "idle")


def build_model() -> MOMDP:
    X, Y, A, O = STEPS + 1, len(TYPES), len(ACTIONS), len(OBSERVATIONS)
    dt = torch.float64
    # Tx[a, x, y, x2]: the task advances with probability 0.9 whatever the robot does
    Tx = torch.zeros(A, X, Y, X, dtype=dt)
    for x in range(STEPS):
        Tx[:, x, :, x + 1] = 0.9
        Tx[:, x, :, x] = 0.1
    Tx[:, STEPS, :, STEPS] = 1.0
    # Z[a, x2, y, o]: safe humans keep reaching for the next part, efficient ones pause
    Z = torch.zeros(A, X, Y, O, dtype=dt)
    Z[..., 0, :] = torch.tensor([0.75, 0.25], dtype=dt)
    Z[..., 1, :] = torch.tensor([0.3, 0.7], dtype=dt)
    # R[a, x, y]: waiting suits the safe type, drilling the efficient one; nothing once done
    R = torch.zeros(A, X, Y, dtype=dt)
    R[0, :STEPS] = torch.tensor([0.5, -0.5], dtype=dt)
    R[1, :STEPS] = torch.tensor([-1.0, 1.0], dtype=dt)
    return MOMDP(
        Tx=Tx,
        Ty=None,
        Z=Z,
        R=R,
        x0=0,
        b0=torch.tensor([0.5, 0.5], dtype=dt),
        discount=0.95,
        observed_states=(*(f"step{i}" for i in range(STEPS)), "done"),
        hidden_states=TYPES,
        actions=ACTIONS,
        observations=OBSERVATIONS,
    )


def main() -> None:
    torch.set_num_threads(1)
    model = build_model()
    solution = solve(model, PBVIConfig(time_limit=30, expansions=6, seed=0))
    policy = solution.policy
    print(
        f"PBVI (factored): lower {solution.lower:.4f}  upper {solution.upper:.4f}  "
        f"alpha vectors {policy.num_vectors} over Y={model.num_hidden}"
    )

    generator = torch.Generator().manual_seed(3)
    true_type = 1  # an "efficient" human
    x = torch.tensor([model.x0])
    belief = model.b0.unsqueeze(0)
    print(f"true type: {TYPES[true_type]}")
    for t in range(10):
        if int(x) == STEPS:
            print(f"t={t} {model.observed_states[int(x)]}: task done")
            break
        action = policy.action(x, belief)
        x_next = sample_categorical(model.Tx[action, x, true_type], generator)
        obs = sample_categorical(model.Z[action, x_next, true_type], generator)
        print(
            f"t={t} {model.observed_states[int(x)]}: P(efficient)={belief[0, 1]:.3f} -> "
            f"{ACTIONS[int(action)]}, then sees '{OBSERVATIONS[int(obs)]}'"
        )
        belief = momdp_update(model, x, belief, action, x_next, obs).belief
        x = x_next

    # a random start: the robot joins at step 0 or step 1 (it sees which), the type unknown
    joint = torch.zeros(model.num_observed, model.num_hidden, dtype=torch.float64)
    joint[0], joint[1] = 0.3 * model.b0, 0.7 * model.b0
    joining = model.with_initial(joint)
    late = solve(joining, SARSOPConfig(time_limit=30, precision=1e-3))
    print(
        f"joining at step 0 or 1 (P = 0.3 / 0.7), SARSOP: lower {late.lower:.4f}  upper "
        f"{late.upper:.4f} (the two starts' values weighted)"
    )


if __name__ == "__main__":
    main()
