"""Tests of torchhrc.pomdp.base: the fields, checks and random start that MOMDP and SparseMOMDP
share are the same in both forms, with values worked by hand."""

from __future__ import annotations

import dataclasses
import inspect

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, MOMDPBase, SparseMOMDP
from torchhrc.testing import random_momdp

D = torch.float64


def _forms() -> list[MOMDPBase]:
    dense = random_momdp(3, 2, 4, 5, seed=0)  # X = 3, Y = 2, A = 4, O = 5
    return [dense, SparseMOMDP.from_dense(dense)]


@pytest.mark.parametrize("form", [0, 1], ids=["dense", "sparse"])
def test_sizes_come_from_the_shared_fields(form):
    m = _forms()[form]
    assert isinstance(m, MOMDPBase)
    assert (m.num_actions, m.num_observed, m.num_hidden, m.num_observations) == (4, 3, 2, 5)


@pytest.mark.parametrize("form", [0, 1], ids=["dense", "sparse"])
def test_the_start_is_checked_once_for_both_forms(form):
    m = _forms()[form]
    with pytest.raises(ModelError, match=r"expected x0 in \[0, 3\), got 3"):
        dataclasses.replace(m, x0=3)
    with pytest.raises(TypeError, match="expected x0 to be an int"):
        dataclasses.replace(m, x0=True)
    assert dataclasses.replace(m, x0=torch.tensor(2)).x0 == 2  # a 0-dim tensor is stored as int
    with pytest.raises(ModelError):
        dataclasses.replace(m, discount=1.5)
    with pytest.raises(ModelError, match="expected 3 observed_states"):
        dataclasses.replace(m, observed_states=("a", "b"))


@pytest.mark.parametrize("form", [0, 1], ids=["dense", "sparse"])
def test_with_initial_by_hand(form):
    m = _forms()[form]
    joint = torch.tensor([[0.125, 0.125], [0.0, 0.0], [0.25, 0.5]], dtype=D)
    s = m.with_initial(joint)
    assert type(s) is type(m)
    # P(x) = (0.25, 0, 0.75): x0 = 2, b0 = P(y | x = 2) = (1/3, 2/3)
    assert s.x0 == 2 and s.random_start
    torch.testing.assert_close(s.b0, torch.tensor([1 / 3, 2 / 3], dtype=D))
    torch.testing.assert_close(s.initial_distribution(), joint)
    with pytest.raises(ModelError, match="b0 must be initial's"):
        dataclasses.replace(s, b0=torch.tensor([0.5, 0.5], dtype=D))
    # all the mass on one x: no random start, b0 = P(y | x)
    one = m.with_initial(torch.tensor([[0.0, 0.0], [0.25, 0.75], [0.0, 0.0]], dtype=D))
    assert one.x0 == 1 and not one.random_start and one.initial is None
    torch.testing.assert_close(one.b0, torch.tensor([0.25, 0.75], dtype=D))


def test_names_keep_each_forms_strictness():
    dense = random_momdp(2, 2, 2, 2, seed=1)
    names = {"hidden_states": ("same", "same")}
    with pytest.raises(ModelError, match="must be distinct"):
        MOMDP(**{**{f.name: getattr(dense, f.name) for f in dataclasses.fields(dense)}, **names})
    sparse = dataclasses.replace(SparseMOMDP.from_dense(dense), **names)  # lengths only, as before
    assert sparse.hidden_states == ("same", "same")


def test_fields_are_declared_once_and_keep_each_forms_order():
    shared = [f.name for f in dataclasses.fields(MOMDPBase)]
    assert shared == ["Z", "R", "x0", "b0", "discount", "observed_states", "hidden_states",
                      "actions", "observations", "initial"]  # fmt: skip
    # the order of the fields before the base existed: the transition first, so that
    # MOMDP(Tx, Ty, Z, R, x0, b0, discount) positionally still works
    assert MOMDP.__match_args__ == ("Tx", "Ty", *shared, "validate_probabilities")
    assert SparseMOMDP.__match_args__ == ("transitions", *shared)
    for form in (MOMDP, SparseMOMDP):  # neither form declares a shared field again
        assert not set(shared) & set(inspect.get_annotations(form))
    dense = random_momdp(2, 2, 2, 2, seed=2)
    again = MOMDP(dense.Tx, dense.Ty, dense.Z, dense.R, dense.x0, dense.b0, dense.discount)
    assert again == dataclasses.replace(dense)
