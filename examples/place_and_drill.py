"""Learn a place-and-drill MOMDP from a small simulated study and watch the type belief.

Clusters 8 simulated subjects' demonstrations into human types, learns a reward per type by
IRL, solves the MOMDP with SARSOP, then runs the task with a new subject, once starting from
the type belief its own 3 demonstrations give (the paper's offline inference) and once from a
uniform belief, printing the belief over the type step by step.
Runs in well under a minute on a CPU.
"""

from __future__ import annotations

import torch

from torchhrc.mixture import fit_mixture, infer_type
from torchhrc.solvers.sarsop import SARSOPConfig
from torchhrc.tasks.pipeline import build_model, solve_model
from torchhrc.tasks.place_and_drill.demos import simulate_study
from torchhrc.tasks.place_and_drill.model import PlaceAndDrillTask
from torchhrc.tasks.place_and_drill.simulate import MOMDPController, run_executions

SEED = 0

# 1. A small study: 8 subjects x 3 demonstrations; the last subject is the new teammate.
demos = simulate_study(n_subjects=8, n_demos=3, seed=SEED)
new_subject = demos.unique_subjects[-1]
train = demos.select_subjects([new_subject], exclude=True)
fit = fit_mixture(train, k_min=2, k_max=4, restarts=5, seed=SEED)
print(f"clusters selected by BIC: k = {fit.k}")

# 2. The learned MOMDP through the task pipeline (Tx from each cluster's chain, reward by
#    the paper's IRL), solved by SARSOP (from the best per-type policy as lower bound).
task = PlaceAndDrillTask(3)
chains = fit.transition_over(train)  # each type's chain over the recorded symbols
learned = build_model(task, train, chains, fit.assignments, seed=SEED)
print("cluster interpretations:", learned.type_names)
learned = solve_model(learned, config=SARSOPConfig(time_limit=3.0, precision=1e-3, seed=SEED))
print(f"SARSOP bounds at b0: [{learned.lower:.3f}, {learned.upper:.3f}]")

# 3. The new subject: its type from its 3 demonstrations (paper Eq. 1), or no prior at all.
truth = dict(zip(demos.subjects, demos.types))[new_subject]
mine = demos.select_subjects([new_subject])
mine = fit.model.prepare(mine)  # in the form the model is over (fit.objects)
inferred = infer_type(fit.model, mine.sequences, mine.lengths).double()
uniform = torch.full_like(inferred, 1.0 / len(inferred))
print(f"new subject {new_subject} is truly '{truth}'")
for title, b0 in (("belief from its demonstrations", inferred), ("uniform belief", uniform)):
    robot = MOMDPController(learned.momdp, learned.policy, b0[None].clone(), record=True)
    trace = run_executions(
        task,
        {"learned": robot},
        orders=torch.tensor([[2, 0, 1]]),  # it places C, then A, then B
        epsilon=torch.tensor([0.3], dtype=torch.float64),
        score=torch.zeros(task.num_actions, task.num_states, dtype=torch.float64),
        horizon=6,
        generator=torch.Generator().manual_seed(SEED),
    )
    print(f"execution starting from the {title} (epsilon = 0.3):")
    for t in range(trace.actions["learned"].shape[0]):
        x = task.state_names[int(trace.states["learned"][t, 0])]
        a = task.actions[int(trace.actions["learned"][t, 0])]
        b = ", ".join(
            f"{name}={p:.3f}" for name, p in zip(learned.type_names, robot.beliefs[t][0].tolist())
        )
        print(f"  step {t}: bench {x}  belief [{b}]  robot {a}")
