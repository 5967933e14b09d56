"""Tests of torchhrc.io.pomdpx: the written tables are the model's tensors."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
import torch

from torchhrc.io.pomdpx import format_pomdpx, write_pomdpx
from torchhrc.tasks.classic import rock_sample_momdp
from torchhrc.testing import random_momdp


def _tables(text: str) -> dict[str, tuple[str, str, str]]:
    """``var -> (parents, instance, table text)`` of every CondProb / Func."""
    root = ET.fromstring(text.encode("iso-8859-1"))
    out = {}
    for node in root.iter():
        if node.tag in ("CondProb", "Func"):
            entry = node.find("Parameter/Entry")
            table = entry.find("ProbTable")
            if table is None:
                table = entry.find("ValueTable")
            out[node.findtext("Var")] = (
                node.findtext("Parent"),
                entry.findtext("Instance"),
                table.text,
            )
    return out


def _numbers(text: str) -> torch.Tensor:
    return torch.tensor([float(v) for v in text.split()], dtype=torch.float64)


@pytest.mark.parametrize("static", [True, False])
def test_tables_are_the_model_tensors(static):
    m = random_momdp(3, 4, 2, 3, static=static, seed=0, discount=0.9)
    text = format_pomdpx(m)
    root = ET.fromstring(text.encode("iso-8859-1"))
    assert float(root.findtext("Discount")) == 0.9
    observed = [v.get("fullyObs") for v in root.iter("StateVar")]
    assert observed == ["true", "false"]
    t = _tables(text)
    x0 = torch.zeros(3, dtype=torch.float64)
    x0[m.x0] = 1
    assert torch.equal(_numbers(t["x_0"][2]), x0)
    assert torch.equal(_numbers(t["y_0"][2]), m.b0)
    assert t["x_1"][0] == "action x_0 y_0"
    assert torch.equal(_numbers(t["x_1"][2]).reshape(m.Tx.shape), m.Tx)
    if static:
        assert t["y_1"] == ("y_0", "- -", "identity")
    else:  # random Ty depends on x_1: the full table with x_1 as a parent
        assert t["y_1"][0] == "action x_0 y_0 x_1"
        assert torch.equal(_numbers(t["y_1"][2]).reshape(m.Ty.shape), m.Ty)
    assert t["obs"][0] == "action x_1 y_1"
    assert torch.equal(_numbers(t["obs"][2]).reshape(m.Z.shape), m.Z)
    assert torch.equal(_numbers(t["reward"][2]).reshape(m.R.shape), m.R)


def test_hidden_transition_independent_of_next_x_drops_that_parent(tmp_path):
    m = rock_sample_momdp(3, 2, seed=1)  # sampling spoils a rock whatever x_1 is
    t = _tables(write_pomdpx(m, tmp_path / "rs.pomdpx").read_text(encoding="iso-8859-1"))
    assert t["y_1"][0] == "action x_0 y_0"
    table = _numbers(t["y_1"][2]).reshape(m.num_actions, m.num_observed, m.num_hidden, -1)
    # Ty[a, x, y, x2, :] equals the written row for every reachable x2
    reachable = m.Tx > 0
    expanded = table[:, :, :, None, :].expand_as(m.Ty)
    assert torch.equal(expanded[reachable], m.Ty[reachable])


def test_names_become_value_enums_and_bad_inputs_raise():
    m = rock_sample_momdp(2, 1)
    root = ET.fromstring(format_pomdpx(m).encode("iso-8859-1"))
    actions = root.find("Variable/ActionVar").findtext("ValueEnum").split()
    assert tuple(actions) == m.actions
    with pytest.raises(ValueError, match="one problem at a time"):
        format_pomdpx(random_momdp(2, 2, 1, 1, batch_shape=(2,), seed=0))
    with pytest.raises(TypeError, match="MOMDP"):
        format_pomdpx(m.to_pomdp())  # type: ignore[arg-type]
