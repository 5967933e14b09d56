"""Tests of torchhrc.io.pomdpx: the written tables are the model's tensors; the reader against
hand-worked models, a brute-force reference, round trips and corruptions."""

from __future__ import annotations

import dataclasses
import itertools
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import torch
from _fuzz import corrupt
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from torchhrc.errors import ParseError
from torchhrc.io import pomdpx as pomdpx_module
from torchhrc.io.pomdpx import (
    format_pomdpx,
    parse_pomdpx,
    read_pomdpx,
    read_pomdpx_variables,
    write_pomdpx,
)
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.sparse import SparsePOMDP
from torchhrc.pomdp.sparse_momdp import SparseMOMDP
from torchhrc.tasks.classic import rock_sample, tiger
from torchhrc.testing import random_momdp, random_pomdp


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
    m = rock_sample(3, 2, seed=1, form="momdp")  # sampling spoils a rock whatever x_1 is
    t = _tables(write_pomdpx(m, tmp_path / "rs.pomdpx").read_text(encoding="iso-8859-1"))
    assert t["y_1"][0] == "action x_0 y_0"
    table = _numbers(t["y_1"][2]).reshape(m.num_actions, m.num_observed, m.num_hidden, -1)
    # Ty[a, x, y, x2, :] equals the written row for every reachable x2
    reachable = m.Tx > 0
    expanded = table[:, :, :, None, :].expand_as(m.Ty)
    assert torch.equal(expanded[reachable], m.Ty[reachable])
    # read back, that Ty is a view over x_1 (no copy per next x), equal to the written rows
    back = read_pomdpx(tmp_path / "rs.pomdpx")
    assert back.Ty.stride()[3] == 0 and torch.equal(back.Ty, expanded)


def test_names_become_value_enums_and_bad_inputs_raise():
    m = rock_sample(2, 1, form="momdp")
    root = ET.fromstring(format_pomdpx(m).encode("iso-8859-1"))
    actions = root.find("Variable/ActionVar").findtext("ValueEnum").split()
    assert tuple(actions) == m.actions
    with pytest.raises(ValueError, match="one problem at a time"):
        format_pomdpx(random_momdp(2, 2, 1, 1, batch_shape=(2,), seed=0))
    with pytest.raises(TypeError, match="MOMDP, POMDP or SparsePOMDP"):
        format_pomdpx(m.Tx)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"write its to_sparse_pomdp\(\)"):
        format_pomdpx(SparseMOMDP.from_dense(m))


def _split_in_two(m: POMDP) -> SparsePOMDP:
    """``m`` as a SparsePOMDP whose every nonzero of T and Z is given as two entries of
    half its value, in reverse order (a coordinate list sums repeats)."""

    def halves(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        index = torch.nonzero(t)
        value = t[tuple(index.t())] / 2
        return torch.cat([index, index]).flip(0), torch.cat([value, value]).flip(0)

    def numbers(names, n):  # a numbered model's names: not identifiers, so <NumValues>
        return names if names is not None else tuple(str(i) for i in range(n))

    return SparsePOMDP(transitions=halves(m.T), observations_=halves(m.Z), R=m.R.expand(
        m.num_actions, m.num_states), b0=m.b0, discount=m.discount,
        states=numbers(m.states, m.num_states), actions=numbers(m.actions, m.num_actions),
        observations=numbers(m.observations, m.num_observations))  # fmt: skip


@pytest.mark.parametrize("names", [False, True])
def test_a_sparse_pomdp_is_written_one_entry_a_nonzero(names):
    m = random_pomdp(6, 3, 4, seed=5, sparsity=0.6)
    if names:
        m = dataclasses.replace(m, states=tuple(f"s_{i}" for i in range(6)),
                                actions=("go", "stay", "look"),
                                observations=tuple(f"o{i}x" for i in range(4)))  # fmt: skip
    sp = _split_in_two(m)
    text = format_pomdpx(sp)
    back = read_pomdpx(text, sparse=False)
    for name in ("T", "Z", "R", "b0"):
        torch.testing.assert_close(getattr(back, name), getattr(m, name).expand_as(
            getattr(back, name)), msg=name)  # fmt: skip
    assert back.actions == (m.actions if names else None)  # <NumValues>: unnamed
    torch.testing.assert_close(read_pomdpx(text, sparse=True).to_dense().T, m.T)
    # the file grows with the nonzeros: one entry each (repeats summed) and none for zeros
    nonzeros = int((m.T != 0).sum() + (m.Z != 0).sum() + (m.R.expand(3, 6) != 0).sum())
    assert text.count("<Entry>") == nonzeros + 1  # + the initial belief's one table


def _small_dense_limit(monkeypatch, cells: int) -> None:
    """Tables of more than ``cells`` cells are read as their nonzeros (as those of more than
    2e8 are: a flat model of more than about 7,000 states)."""
    import torchhrc.io.pomdpx.reader as reader

    monkeypatch.setattr(reader, "MAX_DENSE_ENTRIES", cells)


def test_a_table_too_large_to_hold_is_read_as_its_nonzeros(monkeypatch):
    m = random_pomdp(6, 3, 4, seed=5, sparsity=0.6)
    text = format_pomdpx(_split_in_two(m))
    _small_dense_limit(monkeypatch, 50)  # T (108 cells) and Z (72) as nonzeros; R, b0 dense
    back = read_pomdpx(text, sparse=True)
    assert isinstance(back, SparsePOMDP)
    dense = back.to_dense()
    for name in ("T", "Z", "R", "b0"):
        torch.testing.assert_close(getattr(dense, name), getattr(m, name).expand_as(
            getattr(dense, name)), msg=name)  # fmt: skip
    # a later entry of a cell replaces an earlier one, as APPL reads them: a wrong first
    # value, then the right one, reads as the model
    first = text.index("<Entry><Instance>", text.index("<StateTransitionFunction>"))
    end = text.index("</Entry>", first) + len("</Entry>")
    right = text[first:end]
    wrong = re.sub(r"<ProbTable>[^<]*</ProbTable>", "<ProbTable>0.999</ProbTable>", right)
    again = text[:first] + wrong + text[first:]
    torch.testing.assert_close(read_pomdpx(again, sparse=True).to_dense().T, m.T)


def test_entries_of_a_table_read_as_nonzeros_name_every_value(monkeypatch):
    m = random_pomdp(6, 3, 4, seed=5, sparsity=0.6)
    text = format_pomdpx(_split_in_two(m))
    _small_dense_limit(monkeypatch, 50)
    start = text.index("<Entry><Instance>", text.index("<StateTransitionFunction>"))
    inst = text[start + len("<Entry><Instance>") : text.index("</Instance>", start)]
    spanned = text.replace(
        f"<Instance>{inst}</Instance>", f"<Instance>{' '.join(inst.split()[:2])} *</Instance>", 1
    )
    with pytest.raises(
        ParseError,
        match=r"read as its entries, each naming one value of "
        r"every variable; '\*' spans 'state_1'",
    ):
        read_pomdpx(spanned, sparse=True)
    end = text.index("</Entry>", start) + len("</Entry>")
    with pytest.raises(
        ParseError,
        match=r"<CondProb> of 'state_1': the probabilities for "
        r"'a0 s0' sum to 0\.28",
    ):
        read_pomdpx(text[:start] + text[end:], sparse=True)  # a row without one entry


# ============================================================================= reader

# Tiger written by hand in APPL's layout: named values, "-" and "*" instances, identity, an
# override (the open-* rows first set to 0.9/0.1, then overridden by uniform).
TIGER_PX = """<?xml version="1.0" encoding="ISO-8859-1"?>
<pomdpx version="1.0" id="tiger">
  <Description>Tiger (Kaelbling, Littman, Cassandra 1998)</Description>
  <Discount>0.95</Discount>
  <Variable>
    <StateVar vnamePrev="tiger_0" vnameCurr="tiger_1" fullyObs="false">
      <ValueEnum>tiger-left tiger-right</ValueEnum>
    </StateVar>
    <ObsVar vname="hear"><ValueEnum>tiger-left tiger-right</ValueEnum></ObsVar>
    <ActionVar vname="act"><ValueEnum>listen open-left open-right</ValueEnum></ActionVar>
    <RewardVar vname="gain"/>
  </Variable>
  <InitialStateBelief>
    <CondProb><Var>tiger_0</Var><Parent>null</Parent>
      <Parameter type="TBL"><Entry><Instance>-</Instance><ProbTable>uniform</ProbTable></Entry>
      </Parameter></CondProb>
  </InitialStateBelief>
  <StateTransitionFunction>
    <CondProb><Var>tiger_1</Var><Parent>act tiger_0</Parent>
      <Parameter>
        <Entry><Instance>listen - -</Instance><ProbTable>identity</ProbTable></Entry>
        <Entry><Instance>open-left * -</Instance><ProbTable>0.5 0.5</ProbTable></Entry>
        <Entry><Instance>open-right * *</Instance><ProbTable>0.5</ProbTable></Entry>
      </Parameter></CondProb>
  </StateTransitionFunction>
  <ObsFunction>
    <CondProb><Var>hear</Var><Parent>act tiger_1</Parent>
      <Parameter type="TBL">
        <Entry><Instance>* - -</Instance><ProbTable>0.9 0.1 0.1 0.9</ProbTable></Entry>
        <Entry><Instance>listen - -</Instance><ProbTable>0.85 0.15 0.15 0.85</ProbTable></Entry>
        <Entry><Instance>open-left * -</Instance><ProbTable>uniform</ProbTable></Entry>
        <Entry><Instance>2 * *</Instance><ProbTable>0.5</ProbTable></Entry>
      </Parameter></CondProb>
  </ObsFunction>
  <RewardFunction>
    <Func><Var>gain</Var><Parent>act tiger_0</Parent>
      <Parameter type="TBL">
        <Entry><Instance>listen *</Instance><ValueTable>-1</ValueTable></Entry>
        <Entry><Instance>open-left -</Instance><ValueTable>-100 10</ValueTable></Entry>
        <Entry><Instance>open-right tiger-left</Instance><ValueTable>10</ValueTable></Entry>
        <Entry><Instance>open-right tiger-right</Instance><ValueTable>-100</ValueTable></Entry>
      </Parameter></Func>
  </RewardFunction>
</pomdpx>
"""


def _same_pomdp(a: POMDP, b: POMDP) -> None:
    for name in ("T", "Z", "R", "b0"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), rtol=0, atol=1e-12)
    assert a.discount == b.discount


def test_tiger_by_hand_equals_tasks_classic_tiger():
    m = read_pomdpx(TIGER_PX)
    assert isinstance(m, POMDP)
    _same_pomdp(m, tiger())
    assert m.states == tiger().states and m.actions == tiger().actions
    assert m.observations == ("tiger-left", "tiger-right")
    sp = read_pomdpx(TIGER_PX, sparse=True)
    assert isinstance(sp, SparsePOMDP)
    _same_pomdp(sp.to_dense(), tiger())


# A corridor c0 c1 c2 (observed robot) and a door (hidden) that a push at c2 opens with
# probability 0.8; the camera sees the door's state reliably (0.9) only from c2.
CORRIDOR_PX = """<?xml version="1.0"?>
<pomdpx version="1.0">
<Discount>0.9</Discount>
<Variable>
  <StateVar vnamePrev="robot_0" vnameCurr="robot_1" fullyObs="true">
    <ValueEnum>c0 c1 c2</ValueEnum></StateVar>
  <StateVar vnamePrev="door_0" vnameCurr="door_1"><ValueEnum>open closed</ValueEnum></StateVar>
  <ObsVar vname="seen"><ValueEnum>see-open see-closed</ValueEnum></ObsVar>
  <ActionVar vname="move"><ValueEnum>left right push</ValueEnum></ActionVar>
  <RewardVar vname="r"/>
</Variable>
<InitialStateBelief>
  <CondProb><Var>robot_0</Var><Parent>null</Parent><Parameter>
    <Entry><Instance>-</Instance><ProbTable>1 0 0</ProbTable></Entry></Parameter></CondProb>
  <CondProb><Var>door_0</Var><Parent>null</Parent><Parameter>
    <Entry><Instance>-</Instance><ProbTable>0.3 0.7</ProbTable></Entry></Parameter></CondProb>
</InitialStateBelief>
<StateTransitionFunction>
  <CondProb><Var>robot_1</Var><Parent>move robot_0</Parent><Parameter>
    <Entry><Instance>push - -</Instance><ProbTable>identity</ProbTable></Entry>
    <Entry><Instance>left - -</Instance><ProbTable>1 0 0 1 0 0 0 1 0</ProbTable></Entry>
    <Entry><Instance>right c0 c1</Instance><ProbTable>1</ProbTable></Entry>
    <Entry><Instance>right c1 c2</Instance><ProbTable>1</ProbTable></Entry>
    <Entry><Instance>right c2 c2</Instance><ProbTable>1</ProbTable></Entry>
  </Parameter></CondProb>
  <CondProb><Var>door_1</Var><Parent>move robot_0 door_0</Parent><Parameter>
    <Entry><Instance>* * - -</Instance><ProbTable>1 0 0 1</ProbTable></Entry>
    <Entry><Instance>push c2 closed -</Instance><ProbTable>0.8 0.2</ProbTable></Entry>
  </Parameter></CondProb>
</StateTransitionFunction>
<ObsFunction>
  <CondProb><Var>seen</Var><Parent>move robot_1 door_1</Parent><Parameter>
    <Entry><Instance>* * * -</Instance><ProbTable>0.5 0.5</ProbTable></Entry>
    <Entry><Instance>* c2 - -</Instance><ProbTable>0.9 0.1 0.1 0.9</ProbTable></Entry>
  </Parameter></CondProb>
</ObsFunction>
<RewardFunction>
  <Func><Var>r</Var><Parent>move robot_0 door_0</Parent><Parameter>
    <Entry><Instance>* * *</Instance><ValueTable>-1</ValueTable></Entry>
    <Entry><Instance>push c2 open</Instance><ValueTable>10</ValueTable></Entry>
  </Parameter></Func>
</RewardFunction>
</pomdpx>
"""


def _corridor() -> MOMDP:
    """The corridor MOMDP worked by hand (x: c0 c1 c2; y: open closed; a: left right push)."""
    A, X, Y, O = 3, 3, 2, 2
    Tx = torch.zeros(A, X, Y, X, dtype=torch.float64)
    for x in range(X):
        Tx[0, x, :, max(x - 1, 0)] = 1  # left
        Tx[1, x, :, min(x + 1, 2)] = 1  # right
        Tx[2, x, :, x] = 1  # push
    Ty = torch.eye(Y, dtype=torch.float64).view(1, 1, Y, 1, Y).repeat(A, X, 1, X, 1)
    Ty[2, 2, 1] = torch.tensor([0.8, 0.2], dtype=torch.float64)  # push at c2, door closed
    Z = torch.full((A, X, Y, O), 0.5, dtype=torch.float64)
    Z[:, 2] = torch.tensor([[0.9, 0.1], [0.1, 0.9]], dtype=torch.float64)
    R = torch.full((A, X, Y), -1.0, dtype=torch.float64)
    R[2, 2, 0] = 10.0
    return MOMDP(
        Tx=Tx,
        Ty=Ty,
        Z=Z,
        R=R,
        x0=0,
        b0=torch.tensor([0.3, 0.7], dtype=torch.float64),
        discount=0.9,
        observed_states=("c0", "c1", "c2"),
        hidden_states=("open", "closed"),
        actions=("left", "right", "push"),
        observations=("see-open", "see-closed"),
    )


@pytest.mark.parametrize("overlap", [True, False])
def test_numeric_entries_read_in_one_pass_later_ones_win(overlap, monkeypatch):
    """Entries of numbers only are read in one numpy pass (never per entry); where two name
    the same cell the later one wins, as APPL reads them."""
    first = "* - -" if overlap else "open-left - -"
    obs = f"""<Entry><Instance>{first}</Instance><ProbTable>0.5 0.5 0.5 0.5</ProbTable></Entry>
        <Entry><Instance>listen - -</Instance><ProbTable>0.85 0.15 0.15 0.85</ProbTable></Entry>
        <Entry><Instance>open-right - -</Instance><ProbTable>0.5 0.5 0.5 0.5</ProbTable></Entry>"""
    if overlap:  # and an earlier, overridden value of the listen rows
        obs = obs.replace("</Entry>", "</Entry><Entry><Instance>listen - -</Instance>"
                          "<ProbTable>1 0 0 1</ProbTable></Entry>", 1)  # fmt: skip
        obs += """<Entry><Instance>listen - -</Instance>
            <ProbTable>0.85 0.15 0.15 0.85</ProbTable></Entry>"""
    start = TIGER_PX.index("<ObsFunction>")
    end = TIGER_PX.index("</ObsFunction>")
    text = (TIGER_PX[:start] + '<ObsFunction><CondProb><Var>hear</Var><Parent>act tiger_1</Parent>'
            f'<Parameter type="TBL">{obs}</Parameter></CondProb>' + TIGER_PX[end:])  # fmt: skip

    batched = pomdpx_module._Reader._entries_batched
    took: dict[str, bool] = {}

    def spy(self, param, table, axes, kind, value_tag):
        took[kind] = batched(self, param, table, axes, kind, value_tag)
        return took[kind]

    monkeypatch.setattr(pomdpx_module._Reader, "_entries_batched", spy)
    m = read_pomdpx(text)
    assert took["observation"]  # (the transitions name "identity": read per entry)
    _same_pomdp(m, tiger())


def test_two_variable_momdp_by_hand():
    m, want = read_pomdpx(CORRIDOR_PX), _corridor()
    assert isinstance(m, MOMDP)
    for name in ("Tx", "Ty", "Z", "R", "b0"):
        assert torch.equal(getattr(m, name), getattr(want, name)), name
    assert (m.x0, m.discount) == (0, 0.9)
    assert (m.observed_states, m.hidden_states) == (want.observed_states, want.hidden_states)
    assert (m.actions, m.observations) == (want.actions, want.observations)
    # the flat forms (dense and sparse) are the MOMDP's flat form; the robot's cell is a
    # function of the actions (deterministic moves from one start), so the flat observations
    # need not carry it: O = 2 instead of X * O = 6
    want_flat = want.to_pomdp()
    want_z = want_flat.Z.reshape(3, 6, 3, 2).sum(-2)
    for flat in (
        read_pomdpx(CORRIDOR_PX, momdp=False),
        read_pomdpx(CORRIDOR_PX, sparse=True).to_dense(),
    ):
        for name in ("T", "R", "b0"):
            assert torch.equal(getattr(flat, name), getattr(want_flat, name)), name
        assert torch.equal(flat.Z, want_z)
        assert flat.states == want_flat.states and flat.states[1] == "c0|closed"
        assert flat.observations == ("see-open", "see-closed")


def test_static_hidden_variables_give_ty_none():
    text = CORRIDOR_PX.replace(
        "<Entry><Instance>push c2 closed -</Instance><ProbTable>0.8 0.2</ProbTable></Entry>", ""
    )
    m = read_pomdpx(text)
    assert m.Ty is None
    assert torch.equal(m.Tx, _corridor().Tx)


def test_initial_belief_over_several_x_is_a_random_start():
    text = CORRIDOR_PX.replace("<ProbTable>1 0 0</ProbTable>", "<ProbTable>0.5 0.5 0</ProbTable>")
    m = read_pomdpx(text)
    assert isinstance(m, MOMDP) and m.random_start
    want = torch.tensor([[0.15, 0.35], [0.15, 0.35], [0, 0]], dtype=torch.float64)
    torch.testing.assert_close(m.initial, want, rtol=0, atol=1e-15)
    assert m.x0 == 0 and torch.allclose(m.b0, torch.tensor([0.3, 0.7], dtype=torch.float64))
    corridor = _corridor()
    for name in ("Tx", "Ty", "Z", "R"):
        assert torch.equal(getattr(m, name), getattr(corridor, name)), name
    # written and read again: the same start (x_0's P(x), y_0 given x_0)
    back = read_pomdpx(format_pomdpx(m))
    assert torch.equal(back.initial, m.initial) and back.x0 == m.x0


def test_a_large_random_start_reads_as_a_sparse_momdp(monkeypatch):
    import torchhrc.io.pomdpx as px

    text = CORRIDOR_PX.replace("<ProbTable>1 0 0</ProbTable>", "<ProbTable>0.5 0.5 0</ProbTable>")
    dense = read_pomdpx(text)
    monkeypatch.setattr(px, "AUTO_SPARSE_MOMDP_ENTRIES", 1)  # no dense Tx fits
    m = read_pomdpx(text)
    assert isinstance(m, SparseMOMDP) and m.random_start
    assert torch.equal(m.initial, dense.initial) and m.x0 == dense.x0
    assert torch.equal(m.to_dense().Tx, dense.Tx)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(st.integers(2, 5), st.integers(1, 3), st.integers(0, 2**31 - 1))
def test_random_starts_round_trip(X, Y, seed):
    g = torch.Generator().manual_seed(seed)
    joint = torch.rand(X, Y, generator=g, dtype=torch.float64)
    if X > 2:
        joint[0] = 0.0  # an x without mass
    m = random_momdp(X, Y, 2, 2, seed=seed).with_initial(joint / joint.sum())
    back = read_pomdpx(format_pomdpx(m))
    assert back.random_start and back.x0 == m.x0
    torch.testing.assert_close(back.initial, m.initial, rtol=0, atol=1e-15)
    torch.testing.assert_close(back.b0, m.b0, rtol=0, atol=1e-15)


def test_initial_belief_over_several_x_is_read_flat_when_asked():
    text = CORRIDOR_PX.replace("<ProbTable>1 0 0</ProbTable>", "<ProbTable>0.5 0.5 0</ProbTable>")
    m = read_pomdpx(text, momdp=False)
    assert isinstance(m, POMDP)
    # the robot's cell is now uncertain: the flat observations carry it ("x|o", x2 * O + o)
    assert m.num_observations == 6 and m.observations[3] == "c1|see-closed"
    flat = _corridor().to_pomdp()
    _same_pomdp(m, POMDP(T=flat.T, Z=flat.Z, R=flat.R, b0=m.b0, discount=0.9))
    want = torch.tensor([0.15, 0.35, 0.15, 0.35, 0, 0], dtype=torch.float64)
    torch.testing.assert_close(m.b0, want, rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------- brute force

_SIZES = {
    "a1": 2,
    "a2": 2,
    "x_0": 2,
    "x_1": 2,
    "u_0": 2,
    "u_1": 2,
    "v_0": 3,
    "v_1": 3,
    "o1": 2,
    "o2": 2,
}


def _factored(seed: int) -> tuple[str, dict[str, tuple[list[str], np.ndarray]]]:
    """A random factored model (two action variables, observed x, hidden u and v where v
    depends on the next x, two observation variables, rewards on the previous slice, the
    next slice and an observation) as ``.pomdpx`` text, and its tables."""
    rng = np.random.default_rng(seed)

    def cpt(parents: list[str], var: str) -> np.ndarray:
        t = rng.dirichlet(np.ones(_SIZES[var]), size=[_SIZES[p] for p in parents])
        t[t < 0.1] = 0.0  # some zeros: the sparse expansion drops them
        return t / t.sum(-1, keepdims=True)

    tables = {
        "x_0": ([], np.eye(2)[1]),
        "u_0": ([], cpt([], "u_0")),
        "v_0": (["u_0"], cpt(["u_0"], "v_0")),  # a belief with a parent
        "x_1": (["a1", "x_0", "u_0"], cpt(["a1", "x_0", "u_0"], "x_1")),
        "u_1": (["a2", "u_0", "v_0"], cpt(["a2", "u_0", "v_0"], "u_1")),
        "v_1": (["a1", "a2", "v_0", "x_1"], cpt(["a1", "a2", "v_0", "x_1"], "v_1")),
        "o1": (["a1", "x_1", "u_1"], cpt(["a1", "x_1", "u_1"], "o1")),
        "o2": (["v_1"], cpt(["v_1"], "o2")),
        "r#0": (["a1", "x_0", "v_0"], rng.normal(size=(2, 2, 3))),
        "r#1": (["a2", "u_1"], rng.normal(size=(2, 2))),
        "r#2": (["x_0", "o1"], rng.normal(size=(2, 2))),
    }

    def entry(parents: list[str], values: np.ndarray, tag: str) -> str:
        inst = " ".join(["-"] * values.ndim)
        nums = " ".join(repr(float(v)) for v in values.reshape(-1))
        return (
            f"<Parent>{' '.join(parents) or 'null'}</Parent><Parameter><Entry>"
            f"<Instance>{inst}</Instance><{tag}>{nums}</{tag}></Entry></Parameter>"
        )

    def cond(var: str) -> str:
        parents, values = tables[var]
        return f"<CondProb><Var>{var}</Var>{entry(parents, values, 'ProbTable')}</CondProb>"

    funcs = "".join(
        f"<Func><Var>r</Var>{entry(tables[k][0], tables[k][1], 'ValueTable')}</Func>"
        for k in ("r#0", "r#1", "r#2")
    )
    text = f"""<pomdpx version="1.0"><Discount>0.9</Discount><Variable>
<StateVar vnamePrev="x_0" vnameCurr="x_1" fullyObs="true"><NumValues>2</NumValues></StateVar>
<StateVar vnamePrev="u_0" vnameCurr="u_1"><ValueEnum>p q</ValueEnum></StateVar>
<ObsVar vname="o1"><NumValues>2</NumValues></ObsVar>
<StateVar vnamePrev="v_0" vnameCurr="v_1"><ValueEnum>k l m</ValueEnum></StateVar>
<ActionVar vname="a1"><ValueEnum>go stop</ValueEnum></ActionVar>
<ObsVar vname="o2"><ValueEnum>lo hi</ValueEnum></ObsVar>
<ActionVar vname="a2"><NumValues>2</NumValues></ActionVar>
<RewardVar vname="r"/></Variable>
<InitialStateBelief>{cond("x_0")}{cond("u_0")}{cond("v_0")}</InitialStateBelief>
<StateTransitionFunction>{cond("x_1")}{cond("u_1")}{cond("v_1")}</StateTransitionFunction>
<ObsFunction>{cond("o1")}{cond("o2")}</ObsFunction>
<RewardFunction>{funcs}</RewardFunction></pomdpx>"""
    return text, tables


def _brute_force(tables: dict) -> tuple[np.ndarray, ...]:
    """Flat T, Z (observations x2 * O + o), R and b0 by loops over every combination."""

    def p(var: str, val: dict) -> float:
        parents, t = tables[var]
        return float(t[(*(val[q] for q in parents), val[var])])

    def r(key: str, val: dict) -> float:
        parents, t = tables[key]
        return float(t[tuple(val[q] for q in parents)])

    states = list(itertools.product(range(2), range(2), range(3)))  # (x, u, v) row-major
    actions = list(itertools.product(range(2), range(2)))  # (a1, a2)
    obs = list(itertools.product(range(2), range(2)))  # (o1, o2)
    S, A, O = len(states), len(actions), len(obs)
    T, Z, R = np.zeros((A, S, S)), np.zeros((A, S, 2 * O)), np.zeros((A, S))
    b0 = np.array(
        [
            p("x_0", {"x_0": x}) * p("u_0", {"u_0": u}) * p("v_0", {"u_0": u, "v_0": v})
            for x, u, v in states
        ]
    )
    for (i, (a1, a2)), (s, (x, u, v)) in itertools.product(enumerate(actions), enumerate(states)):
        for s2, (x2, u2, v2) in enumerate(states):
            val = {
                "a1": a1,
                "a2": a2,
                "x_0": x,
                "u_0": u,
                "v_0": v,
                "x_1": x2,
                "u_1": u2,
                "v_1": v2,
            }
            T[i, s, s2] = p("x_1", val) * p("u_1", val) * p("v_1", val)
            for k, (o1, o2) in enumerate(obs):
                val.update(o1=o1, o2=o2)
                z = p("o1", val) * p("o2", val)
                Z[i, s2, x2 * O + k] = z
                R[i, s] += T[i, s, s2] * z * r("r#2", val)
            R[i, s] += T[i, s, s2] * r("r#1", val)
        R[i, s] += r("r#0", {"a1": a1, "x_0": x, "v_0": v})
    return T, Z, R, b0


@pytest.mark.parametrize("seed", [0, 1])
def test_combined_variables_and_expected_rewards_equal_brute_force(seed):
    text, tables = _factored(seed)
    T, Z, R, b0 = (torch.from_numpy(a) for a in _brute_force(tables))
    flat = read_pomdpx(text, momdp=False)
    for got, want in ((flat.T, T), (flat.Z, Z), (flat.R, R), (flat.b0, b0)):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    sparse = read_pomdpx(text, sparse=True).to_dense()
    for got, want in ((sparse.T, T), (sparse.Z, Z), (sparse.R, R)):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    m = read_pomdpx(text)
    assert isinstance(m, MOMDP) and (m.num_observed, m.num_hidden, m.num_actions) == (2, 6, 4)
    back = m.to_pomdp()
    torch.testing.assert_close(back.T, T, rtol=0, atol=1e-12)
    torch.testing.assert_close(back.Z, Z, rtol=0, atol=1e-12)
    torch.testing.assert_close(back.R, R, rtol=0, atol=1e-12)
    # names: NumValues-only groups are unnamed, mixed groups use APPL's implicit names
    assert m.observed_states is None and m.hidden_states[:4] == ("p,k", "p,l", "p,m", "q,k")
    assert m.actions == ("go,a0", "go,a1", "stop,a0", "stop,a1")
    assert m.observations == ("o0,lo", "o0,hi", "o1,lo", "o1,hi")
    v = read_pomdpx_variables(text)
    assert [x.name for x in v.hidden] == ["u_1", "v_1"] and v.size("states") == 12
    assert v.decode("hidden", 5) == {"u_1": "q", "v_1": "m"}
    assert v.encode("actions", {"a1": "stop", "a2": "a1"}) == 3


def test_sparse_auto_above_the_dense_threshold(monkeypatch):
    import torchhrc.io.pomdpx as px

    text, _ = _factored(0)
    monkeypatch.setattr(px, "AUTO_SPARSE_ENTRIES", 100)  # T has 4 * 12 * 12 = 576 entries
    m = read_pomdpx(text)
    assert isinstance(m, SparsePOMDP)
    monkeypatch.setattr(px, "MAX_DENSE_ENTRIES", 200)  # the largest table has 72
    with pytest.raises(ParseError, match="sparse=True"):
        read_pomdpx(text, sparse=False)
    monkeypatch.undo()
    _same_pomdp(m.to_dense(), read_pomdpx(text, momdp=False))


@pytest.mark.parametrize("limit", [None, 10])
def test_sparse_auto_reads_a_flat_model_as_read_pomdp_does(limit, tmp_path, monkeypatch):
    """A flat model's ``sparse="auto"`` form is the one ``read_pomdp`` gives the same model
    from a ``.pomdp`` file: sparse above ``io.cassandra.AUTO_SPARSE_ENTRIES`` entries (1e6;
    ``limit``: 10) unless a tenth of ``T`` is nonzero (Tiger: 12 entries, 83 %), so that the
    two files solve the same way. RockSample(4, 4) flat (594,441 entries of ``T``, 0.4 %
    nonzero) is dense at 1e6 and sparse at 10."""
    from torchhrc.io import cassandra

    if limit is not None:
        monkeypatch.setattr(cassandra, "AUTO_SPARSE_ENTRIES", limit)
    for name, model in (("tiger", tiger()), ("rs44", rock_sample(4, 4))):
        write_pomdpx(model, tmp_path / f"{name}.pomdpx")
        cassandra.write_pomdp(model, tmp_path / f"{name}.pomdp")
        got = read_pomdpx(tmp_path / f"{name}.pomdpx")
        assert type(got) is type(cassandra.read_pomdp(tmp_path / f"{name}.pomdp", sparse="auto"))
        sparse = name == "rs44" and limit is not None
        assert isinstance(got, SparsePOMDP if sparse else POMDP), name
        if sparse:
            _same_pomdp(got.to_dense(), model)


# ----------------------------------------------------------------------------- round trips


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    st.integers(1, 4),
    st.integers(1, 4),
    st.integers(1, 3),
    st.integers(1, 3),
    st.booleans(),
    st.integers(0, 2**31 - 1),
    st.floats(0.01, 1.0),
)
def test_random_momdps_round_trip(X, Y, A, O, static, seed, discount):
    m = random_momdp(X, Y, A, O, static=static, seed=seed, discount=discount)
    back = read_pomdpx(format_pomdpx(m))
    assert isinstance(back, MOMDP)
    for name in ("Tx", "Z", "R", "b0"):
        assert torch.equal(getattr(back, name), getattr(m, name)), name
    if static or Y == 1:
        assert back.Ty is None or torch.equal(back.Ty, m.hidden_transition())
    else:
        assert torch.equal(back.Ty, m.Ty)
    assert (back.x0, back.discount) == (m.x0, m.discount)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    st.integers(1, 5),
    st.integers(1, 3),
    st.integers(1, 3),
    st.integers(0, 2**31 - 1),
    st.sampled_from([0.0, 0.5]),
    st.booleans(),
)
def test_random_pomdps_round_trip(S, A, O, seed, sparsity, names):
    m = random_pomdp(S, A, O, seed=seed, sparsity=sparsity)
    if names:
        m = POMDP(
            T=m.T,
            Z=m.Z,
            R=m.R,
            b0=m.b0,
            discount=m.discount,
            states=tuple(f"s_{i}" for i in range(S)),
            actions=tuple(f"act{i}" for i in range(A)),
            observations=tuple(f"o{i}x" for i in range(O)),
        )
    back = read_pomdpx(format_pomdpx(m))
    assert isinstance(back, POMDP)
    for name in ("T", "Z", "R", "b0"):
        assert torch.equal(getattr(back, name), getattr(m, name)), name
    assert (back.states, back.actions, back.observations) == (m.states, m.actions, m.observations)
    assert torch.equal(read_pomdpx(format_pomdpx(m), sparse=True).to_dense().T, m.T)


def test_sparse_momdp_round_trips_through_its_flat_form(tmp_path):
    m = random_momdp(3, 4, 2, 2, static=False, seed=3, sparsity=0.5)
    back = read_pomdpx(write_pomdpx(m, tmp_path / "m.pomdpx"))
    _same_pomdp(back.to_pomdp(), m.to_pomdp())


# ----------------------------------------------------------------------------- errors


def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


_ERRORS = [
    # (replace this, with this, the line of this element, reason)
    (
        "<ProbTable>0.3 0.7</ProbTable>",
        "<ProbTable>0.3 0.7 0</ProbTable>",
        "<ProbTable>0.3 0.7 0",
        "has 3 numbers, expected 2",
    ),
    (
        "<Entry><Instance>push c2 closed -</Instance>",
        "<Entry><Instance>push c9 closed -</Instance>",
        "<Instance>push c9",
        "'c9' is not a value of 'robot_0'",
    ),
    (
        "<ProbTable>0.8 0.2</ProbTable>",
        "<ProbTable>0.8 0.3</ProbTable>",
        "<CondProb><Var>door_1",
        "sum to 1.1, expected 1",
    ),
    (
        "<ProbTable>0.8 0.2</ProbTable>",
        "<ProbTable>1.8 -0.8</ProbTable>",
        "<ProbTable>1.8",
        "outside",
    ),
    (
        "<ProbTable>0.8 0.2</ProbTable>",
        "<ProbTable>0.8 x</ProbTable>",
        "<ProbTable>0.8 x",
        "'x' is not a number",
    ),
    (
        "<Parameter>\n    <Entry><Instance>push - -",
        '<Parameter type="DD">\n    <Entry><Instance>push - -',
        '<Parameter type="DD">',
        "DD.*not supported",
    ),
    (
        "<Entry><Instance>* * * -</Instance>",
        "<Entry><Instance>* * -</Instance>",
        "<Instance>* * -</Instance>",
        "has 3 tokens, expected 4",
    ),
    (
        "<Parent>move robot_1 door_1</Parent>",
        "<Parent>move robot_0 door_1</Parent>",
        "<Parent>move robot_0 door_1",
        "cannot be a parent",
    ),
    (
        "<Entry><Instance>right c2 c2</Instance><ProbTable>1</ProbTable></Entry>",
        "",
        "<CondProb><Var>robot_1",
        "no <Entry> covers them",
    ),
    (
        "<Instance>push - -</Instance><ProbTable>identity",
        "<Instance>push * -</Instance><ProbTable>identity",
        "<Instance>push * -</Instance><ProbTable>identity",
        "identity needs",
    ),
    ("<Var>seen</Var>", "<Var>heard</Var>", "<Var>heard", "'heard' is undeclared"),
    ("<RewardFunction>", "<Bogus/><RewardFunction>", "<Bogus/>", "<Bogus> is unknown"),
    ("<Discount>0.9</Discount>", "<Discount>1.5</Discount>", "<Discount>1.5", r"\(0, 1\]"),
    ("<ObsFunction>", "<ObsFunction><CondProb>", "<ObsFunction><CondProb>", "malformed XML"),
    (
        '<?xml version="1.0"?>',
        '<?xml version="1.0"?><!DOCTYPE p [<!ENTITY e "x">]>',
        "<!DOCTYPE",
        "document type declarations",
    ),
    (
        '<StateVar vnamePrev="door_0" vnameCurr="door_1">',
        '<StateVar vnamePrev="door_0" vnameCurr="robot_1">',
        '<StateVar vnamePrev="door_0"',
        "declared twice",
    ),
]


@pytest.mark.parametrize("old, new, where, reason", _ERRORS)
def test_malformed_files_name_the_element_line_and_reason(old, new, where, reason, tmp_path):
    assert old in CORRIDOR_PX
    text = CORRIDOR_PX.replace(old, new, 1)
    path = tmp_path / "bad.pomdpx"
    path.write_text(text)
    with pytest.raises(ParseError, match=reason) as info:
        read_pomdpx(path)
    assert info.value.path == str(path)
    if reason != "malformed XML":  # expat reports where the document stops matching
        assert info.value.line == _line_of(text, where)
    assert str(info.value).startswith(f"{path}:")


def test_missing_file_and_missing_function():
    with pytest.raises(ParseError, match="cannot read file") as info:
        read_pomdpx("/nonexistent/m.pomdpx")
    assert info.value.path == "/nonexistent/m.pomdpx"
    start = CORRIDOR_PX.index("<ObsFunction>")
    end = CORRIDOR_PX.index("</ObsFunction>") + len("</ObsFunction>")
    with pytest.raises(ParseError, match="no <CondProb> for 'seen'"):
        read_pomdpx(CORRIDOR_PX[:start] + CORRIDOR_PX[end:])


_PX_BASES = [
    CORRIDOR_PX,
    TIGER_PX,
    _factored(0)[0],
    format_pomdpx(random_momdp(2, 2, 2, 2, seed=1)),
]
_PX_JUNK = [
    "-",
    "*",
    "identity",
    "uniform",
    "0.5",
    "2",
    "nan",
    "1e999",
    "null",
    "c2",
    "</Entry>",
    "<Entry>",
    '"',
    "<",
    "&e;",
    "push",
    "true",
]


@st.composite
def corrupted(draw):
    return corrupt(draw, draw(st.sampled_from(_PX_BASES)), _PX_JUNK, r"(\s+|>)")


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
@given(corrupted())
def test_corrupted_files_raise_parse_error_or_parse_to_a_valid_model(text):
    for sparse in ("auto", True):
        try:
            m = parse_pomdpx(text, sparse=sparse)
        except ParseError as e:
            assert e.path == "<string>" and e.reason
            continue
        if isinstance(m, SparsePOMDP):
            m = m.to_dense()
        m.validate()  # a file that still parses gives a valid model
        assert torch.isfinite(m.R).all()


def test_cyclic_initial_belief_is_refused():
    text = CORRIDOR_PX.replace(
        "<Var>robot_0</Var><Parent>null</Parent><Parameter>\n"
        "    <Entry><Instance>-</Instance><ProbTable>1 0 0</ProbTable>",
        "<Var>robot_0</Var><Parent>door_0</Parent><Parameter>\n"
        "    <Entry><Instance>* -</Instance><ProbTable>1 0 0</ProbTable>",
    ).replace(
        "<Var>door_0</Var><Parent>null</Parent><Parameter>\n    <Entry><Instance>-</Instance>",
        "<Var>door_0</Var><Parent>robot_0</Parent><Parameter>\n    <Entry><Instance>* -</Instance>",
    )
    assert text.count("<Parent>door_0</Parent>") == 1
    assert text.count("<Parent>robot_0</Parent>") == 1
    with pytest.raises(ParseError, match="form a cycle"):
        read_pomdpx(text)


def test_numvalues_implicit_names_and_indices_in_instances():
    # APPL names counted values s0 s1 ... (states), o0 ... (observations), a0 ... (actions)
    text = """<pomdpx version="1.0"><Discount>0.5</Discount><Variable>
<StateVar vnamePrev="p" vnameCurr="q"><NumValues>3</NumValues></StateVar>
<ObsVar vname="z"><NumValues>2</NumValues></ObsVar>
<ActionVar vname="u"><NumValues>2</NumValues></ActionVar><RewardVar vname="r"/></Variable>
<InitialStateBelief><CondProb><Var>p</Var><Parent>null</Parent><Parameter>
<Entry><Instance>s2</Instance><ProbTable>1</ProbTable></Entry></Parameter></CondProb>
</InitialStateBelief>
<StateTransitionFunction><CondProb><Var>q</Var><Parent>u p</Parent><Parameter>
<Entry><Instance>* - -</Instance><ProbTable>identity</ProbTable></Entry>
<Entry><Instance>a1 s0 *</Instance><ProbTable>uniform</ProbTable></Entry>
</Parameter></CondProb></StateTransitionFunction>
<ObsFunction><CondProb><Var>z</Var><Parent>q</Parent><Parameter>
<Entry><Instance>* o1</Instance><ProbTable>1</ProbTable></Entry>
<Entry><Instance>1 -</Instance><ProbTable>0.25 0.75</ProbTable></Entry>
</Parameter></CondProb></ObsFunction>
<RewardFunction><Func><Var>r</Var><Parent>u q</Parent><Parameter>
<Entry><Instance>a1 s2</Instance><ValueTable>4</ValueTable></Entry>
</Parameter></Func></RewardFunction></pomdpx>"""
    m = read_pomdpx(text)
    assert isinstance(m, POMDP) and m.states is None and m.actions is None
    third = torch.full((3,), 1 / 3, dtype=torch.float64)
    T = torch.eye(3, dtype=torch.float64).repeat(2, 1, 1)
    T[1, 0] = third
    assert torch.equal(m.T, T)
    Z = torch.tensor([[0, 1], [0.25, 0.75], [0, 1]], dtype=torch.float64).expand(2, 3, 2)
    assert torch.equal(m.Z, Z)
    # the reward depends on the next state q: R[a1, s] = sum_s2 T[a1, s, s2] * 4 [s2 = s2]
    want_R = torch.zeros(2, 3, dtype=torch.float64)
    want_R[1] = 4 * T[1, :, 2]
    torch.testing.assert_close(m.R, want_R, rtol=0, atol=1e-15)
    assert torch.equal(m.b0, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
