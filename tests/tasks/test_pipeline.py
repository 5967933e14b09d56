"""The task pipeline: same model as the hand-assembled place-and-drill one, consistency
checks on type-dependent pieces, save / load, and one code path for every task."""

from __future__ import annotations

import inspect
import json
from dataclasses import dataclass

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.mixture import fit_mixture
from torchhrc.tasks import pipeline
from torchhrc.tasks.controller import Controller
from torchhrc.tasks.interface import TypeEvidence
from torchhrc.tasks.pipeline import LearnedModel, build_model, learn
from torchhrc.tasks.place_and_drill.demos import simulate_study
from torchhrc.tasks.place_and_drill.model import (
    PlaceAndDrillTask,
    build_momdp,
    demonstration_steps,
    interpret_clusters,
    learn_type_weights,
    placement_probabilities,
    placement_transition,
)


@pytest.fixture(scope="module")
def study():
    demos = simulate_study(n_subjects=6, n_demos=3, seed=0)
    fit = fit_mixture(demos, k_min=2, k_max=3, restarts=4, seed=0)
    return demos, fit


def test_build_model_equals_the_hand_assembled_place_and_drill_model(study):
    demos, fit = study
    task = PlaceAndDrillTask(3)
    chains = fit.transition_over(demos).detach().double()  # over the recorded symbols
    model = build_model(task, demos, chains, fit.assignments, irl_iterations=5, seed=0)
    # reference: the place-and-drill functions, assembled by hand
    Tx = placement_transition(task, placement_probabilities(task, chains, demos.vocabulary),
                              noise=0.05, pause=0.01)  # fmt: skip
    w = learn_type_weights(task, Tx, demonstration_steps(task, demos), fit.assignments,
                           max_iterations=5, seed=0)  # fmt: skip
    names = interpret_clusters(task, chains, demos.vocabulary)
    ref = build_momdp(task, Tx, task.reward(w), torch.full((fit.k,), 1.0 / fit.k,
                      dtype=torch.float64), type_names=names)  # fmt: skip
    assert torch.equal(model.momdp.Tx, ref.Tx) and torch.equal(model.momdp.R, ref.R)
    assert torch.equal(model.weights, w) and model.type_names == names
    assert set(names) == {"safe", "efficient"}


@dataclass(frozen=True)
class _WrongReward(PlaceAndDrillTask):
    def known_reward(self, evidence: TypeEvidence) -> torch.Tensor:
        return torch.zeros(self.num_actions, self.num_states, evidence.num_types + 1,
                           dtype=torch.float64)  # fmt: skip


@dataclass(frozen=True)
class _WrongBehaviour(PlaceAndDrillTask):
    def human_policy(self, evidence: TypeEvidence) -> torch.Tensor:
        return super().human_policy(evidence)[:1]


@dataclass(frozen=True)
class _WrongObservation(PlaceAndDrillTask):
    def observation(self, model):
        return torch.ones(self.num_actions, self.num_states, 1, 1, dtype=torch.float64)


@pytest.mark.parametrize(
    "task, piece",
    [
        (_WrongReward(3), "known_reward"),
        (_WrongBehaviour(3), "human_policy"),
        (_WrongObservation(3), "observation"),
    ],
)
def test_a_type_dependent_piece_with_the_wrong_number_of_types_is_rejected(study, task, piece):
    demos, fit = study
    with pytest.raises(ModelError, match=rf"the task's {piece}\(\) has \d+ types .*Y=2"):
        build_model(task, demos, fit.model.transition, fit.assignments, irl_iterations=2)


def test_inconsistent_inputs_are_rejected(study):
    demos, fit = study
    task = PlaceAndDrillTask(3)
    with pytest.raises(ModelError, match="expected assignments of shape"):
        build_model(task, demos, fit.model.transition, fit.assignments[:-1])
    with pytest.raises(ModelError, match=r"expected assignments in \[0, 2\)"):
        build_model(task, demos, fit.model.transition, fit.assignments + 5)
    with pytest.raises(ModelError, match="not an action of the task"):
        build_model(PlaceAndDrillTask(2), demos, fit.model.transition, fit.assignments)


def test_learn_save_load_roundtrip_and_controller(tmp_path):
    demos = simulate_study(n_subjects=4, n_demos=2, seed=1)
    model = learn(PlaceAndDrillTask(3), demos, k_min=2, k_max=2, restarts=2,
                  irl_iterations=3, solver_time=2.0, seed=0)  # fmt: skip
    assert model.policy is not None and model.lower <= model.upper + 1e-9
    path = model.save(tmp_path / "pd")
    again = LearnedModel.load(path)
    for name in ("Tx", "R", "Z", "b0"):
        assert torch.equal(getattr(model.momdp, name), getattr(again.momdp, name))
    assert torch.equal(model.policy.alphas, again.policy.alphas)
    assert again.type_names == model.type_names and again.info == model.info
    assert again.vocabulary == model.vocabulary and again.lower == model.lower
    a, b = Controller.from_model(model), Controller.from_model(again)
    a.reset(), b.reset()
    x = 0
    for h in (0, 1, 2):  # the human places A, B, C
        act = a.act(x)
        assert act == b.act(x)
        x = int(PlaceAndDrillTask(3).step(torch.tensor(x), torch.tensor(h), torch.tensor(act)))
    assert torch.allclose(a.belief, b.belief)
    # saving again replaces the directory atomically
    model.save(path)
    assert sorted(p.name for p in path.iterdir()) == ["model.json", "model.safetensors"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_load_reports_the_bad_file(tmp_path):
    with pytest.raises(ModelError, match=r"model\.json: no such file"):
        LearnedModel.load(tmp_path)
    (tmp_path / "model.json").write_text('{"format": "torchhrc.learned_task_model",\n oops}')
    (tmp_path / "model.safetensors").write_bytes(b"")
    with pytest.raises(ModelError, match=r"model.json: line 2"):
        LearnedModel.load(tmp_path)
    (tmp_path / "model.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(ModelError, match="field 'format'"):
        LearnedModel.load(tmp_path)


def test_controller_needs_a_solved_model(study):
    demos, fit = study
    model = build_model(PlaceAndDrillTask(3), demos, fit.model.transition, fit.assignments,
                        irl_iterations=2)  # fmt: skip
    with pytest.raises(ModelError, match="solve it first"):
        Controller.from_model(model)


def test_the_pipeline_does_not_dispatch_on_task_classes():
    source = inspect.getsource(pipeline)
    assert "isinstance(task" not in source and "type(task)" not in source
    for name in ("PlaceAndDrill", "HandFinishing", "Kitchen"):
        assert name not in source.split('"""', 2)[2]  # beyond the module docstring
