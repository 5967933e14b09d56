"""Regenerate the learned models shipped in models/ (a user may start from them).

    python models/make_learned_models.py            # writes models/place_and_drill_learned/

``place_and_drill_learned``: :func:`torchhrc.tasks.learn` on the simulated place-and-drill
study of the reproduction (18 subjects x 3 demonstrations, seed 0): two types ("safe",
"efficient"), IRL rewards over the task's six features (the paper's projection IRL), the
MOMDP solved by SARSOP.
Load it with ``torchhrc.LearnedModel.load(torchhrc.shipped_path("models",
"place_and_drill_learned/model.json").parent)``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from torchhrc.mixture import ClusterConfig
from torchhrc.tasks import learn
from torchhrc.tasks.pipeline import IRLConfig
from torchhrc.tasks.place_and_drill import PlaceAndDrillTask, simulate_study

#: Settings of the shipped model (tests/test_resources.py rebuilds it with these). The IRL is
#: the paper's (Abbeel & Ng's projection, rule "dominant", 10 iterations), stated here since
#: ``learn()``'s default became maximum-entropy IRL (issue 31; docs/your_own_task.md); so are
#: the paper's first-order chains (``order=1``), since ``learn()``'s default became
#: ``order="auto"`` (docs/clustering.md, "Second-order chains"); and the uniform prior over the
#: types, since ``learn()``'s default became the types' shares of the demonstrations; and
#: the rewards as IRL gives them (``wrong_moves="learned"``), since ``learn()``'s default
#: became pricing a wrong move where the types' partners disagree (docs/your_own_task.md).
PLACE_AND_DRILL = dict(cluster=ClusterConfig(k_min=2, k_max=10, restarts=20, order=1),
                       irl=IRLConfig(rule="dominant", epsilon=0.05, iterations=10,
                                     wrong_moves="learned"),
                       solver_time=60.0, solver_precision=1e-4, prior="uniform",
                       seed=0)  # fmt: skip


def place_and_drill_learned():
    demos = simulate_study(n_subjects=18, n_demos=3, seed=0)
    return learn(PlaceAndDrillTask(3), demos, **PLACE_AND_DRILL)


def main(out: Path) -> None:
    model = place_and_drill_learned()
    path = model.save(out / "place_and_drill_learned")
    print(f"{path}: types {model.type_names}, bounds [{model.lower:.4f}, {model.upper:.4f}]")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)
