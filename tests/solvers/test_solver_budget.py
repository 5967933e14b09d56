"""Tests of torchhrc.solvers._budget (a name apart from tests/io/test_budget.py: test file
names are unique): the budget fields every solver config shares are declared and checked once,
in SolverBudget, and each config keeps them and their checks."""

from __future__ import annotations

import dataclasses

import pytest

from torchhrc.solvers import PBVIConfig, SARSOPConfig
from torchhrc.solvers._budget import SolverBudget

BUDGET = {"clock", "memory_limit", "memory_reserve", "policy_interval", "checkpoint"}


@pytest.mark.parametrize("config", [SARSOPConfig, PBVIConfig])
def test_each_config_takes_the_budget_fields_from_the_one_base(config) -> None:
    assert issubclass(config, SolverBudget)
    assert {f.name for f in dataclasses.fields(SolverBudget)} == BUDGET
    assert not BUDGET & set(config.__annotations__)  # declared once, in the base
    defaults = {f.name: f.default for f in dataclasses.fields(config) if f.name in BUDGET}
    assert defaults == {"clock": "wall", "memory_limit": None, "memory_reserve": 1.5,
                        "policy_interval": None, "checkpoint": None}  # fmt: skip


@pytest.mark.parametrize("config", [SolverBudget, SARSOPConfig, PBVIConfig])
@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"clock": "cpu"}, "expected clock 'wall', 'process' or a callable, got 'cpu'"),
        ({"memory_limit": 0}, "expected memory_limit to be None or a positive number of bytes"),
        ({"memory_limit": True}, "expected memory_limit to be None or a positive number"),
        ({"memory_reserve": float("nan")}, "expected memory_reserve to be a non-negative"),
        ({"checkpoint": print}, "checkpoint was given without policy_interval"),
    ],
)
def test_every_config_checks_its_budget(config, kwargs: dict, error: str) -> None:
    with pytest.raises(ValueError, match=error):
        config(**kwargs)
    config(clock="process", memory_limit=2**30, policy_interval=5.0, checkpoint=print)
