"""Tests of torchhrc.tasks.place_and_drill.hand_coded: the expert JSON model, its validation,
its MOMDP."""

from __future__ import annotations

import json

import pytest
import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.tasks.place_and_drill.hand_coded import (
    DEFAULT_EXPERT_PATH,
    build_expert_momdp,
    expert_initial_belief,
    load_expert_model,
)
from torchhrc.tasks.place_and_drill.model import FEATURE_NAMES


def _write(tmp_path, data):
    path = tmp_path / "expert.json"
    path.write_text(json.dumps(data))
    return path


def test_shipped_model_states_the_two_types():
    expert = load_expert_model()
    assert expert.type_names == ("safe", "efficient")
    w = dict(zip(FEATURE_NAMES, expert.weights[0].tolist()))
    assert w["drill_early"] < 0 < w["drill_ready"]  # safe: no drilling before all placed
    w = dict(zip(FEATURE_NAMES, expert.weights[1].tolist()))
    assert w["drill_early"] > 0 > w["wait_early"]  # efficient: drill right away


def test_expert_momdp_human_is_uniform_and_uninformative():
    expert = load_expert_model()
    m = build_expert_momdp(expert)
    assert m.R.shape == (4, 27, 2)
    torch.testing.assert_close(m.Tx[..., 0, :], m.Tx[..., 1, :])  # no type information
    # from the empty bench after a wait: each position with probability 1/3
    assert sorted(m.Tx[0, 0, 0].unique().tolist()) == pytest.approx([0.0, 1 / 3])


def test_initial_belief_from_labels():
    expert = load_expert_model()
    b0 = expert_initial_belief(expert, ["safe", "efficient", "safe"])
    assert b0[:, 0].tolist() == pytest.approx([0.95, 0.05, 0.95])
    with pytest.raises(ModelError, match="'careful' is not a type"):
        expert_initial_belief(expert, ["careful"])


def test_malformed_json_names_file_and_line(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{\n  "format": "torchhrc.expert_momdp",\n  "version": 1,,\n}')
    with pytest.raises(ParseError) as info:
        load_expert_model(path)
    assert str(path) in str(info.value) and info.value.line == 3


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda d: d.pop("discount"), "'discount': missing"),
        (lambda d: d.update(discount=1.5), "'discount'"),
        (
            lambda d: d["types"]["safe"]["reward"].pop("drill_ready"),
            "types.safe.reward.drill_ready",
        ),
        (lambda d: d["types"]["safe"]["reward"].update(fly=1.0), "types.safe.reward.fly"),
        (lambda d: d["types"]["efficient"]["reward"].update(wait_idle="x"), "wait_idle"),
        (lambda d: d["initial_belief"].update(labelled_type_probability=0.2), "labelled_type"),
        (lambda d: d["human"].update(placement="learned"), "human.placement"),
        (lambda d: d.update(format="other"), "'format'"),
    ],
)
def test_invalid_fields_are_named(tmp_path, edit, field):
    data = json.loads(DEFAULT_EXPERT_PATH.read_text())
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(ModelError) as info:
        load_expert_model(path)
    assert str(path) in str(info.value) and field in str(info.value)
