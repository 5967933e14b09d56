"""The third task (examples/your_own_task.py, not from the paper) through the public API: the
learned type-aware robot beats the type-agnostic one beyond the 95% confidence intervals."""

from __future__ import annotations

import importlib.util
import sys
import warnings
from pathlib import Path

import pytest
import torch

from torchhrc.tasks import check_task

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "your_own_task.py"


@pytest.fixture(scope="module")
def kitchen():
    spec = importlib.util.spec_from_file_location("your_own_task", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules["your_own_task"] = module
    spec.loader.exec_module(module)
    return module


def test_the_example_is_short_and_uses_only_the_public_api():
    text = EXAMPLE.read_text()
    assert len(text.splitlines()) <= 150
    imports = [line for line in text.splitlines() if "import" in line and "torchhrc" in line]
    assert imports and all(
        line.startswith(("from torchhrc import", "from torchhrc.tasks import")) for line in imports
    )


def test_kitchen_dynamics(kitchen):
    task = kitchen.Kitchen()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every state reachable: no TaskWarning
        check_task(task)
    fetch_stir, do_stir, do_chop = 2, 1, 0
    x = task.step(torch.tensor(0), torch.tensor(do_chop), torch.tensor(fetch_stir))
    assert task.state_names[int(x)] == "chop|2"  # stir's ingredient waits on the counter
    x = task.step(x, torch.tensor(do_stir), torch.tensor(0))
    assert task.state_names[int(x)] == "chop+stir|0"  # the cook used it
    assert int(task.terminal.sum()) == 1  # everything done, nothing left on the counter
    assert task.step(0, 0, 0) == task.state_names.index("chop|0")  # ints in, int out


@pytest.mark.slow
def test_type_aware_robot_beats_the_type_agnostic_one_beyond_the_cis(kitchen, capsys):
    results = kitchen.main(seed=0, runs=300)
    aware, agnostic = results["type-aware"], results["type-agnostic"]
    assert aware[0] - aware[1] > agnostic[0] + agnostic[1]
    out = capsys.readouterr().out
    assert "types found: 3" in out and "95% CI" in out
