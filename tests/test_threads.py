"""``torchhrc._threads.torch_threads``: the count inside the block, restored after (also after
an exception), bad counts refused; and SARSOP's search runs with one intra-op thread."""

from __future__ import annotations

import pytest
import torch

from torchhrc._threads import torch_threads
from torchhrc.solvers import SARSOPConfig, sarsop
from torchhrc.tasks.classic import tiger


@pytest.fixture
def two_threads():
    """The process at 2 intra-op threads for the test (the CI runs at 1), restored after."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def test_the_count_is_set_inside_and_restored_after(two_threads: None) -> None:
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2
    with pytest.raises(RuntimeError, match="inside"):
        with torch_threads(1):
            raise RuntimeError("inside")
    assert torch.get_num_threads() == 2
    with torch_threads(2):  # the same count: nothing to change
        assert torch.get_num_threads() == 2


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "1"])
def test_bad_counts_are_refused(bad: object) -> None:
    with pytest.raises(ValueError, match="expected n to be an int of at least 1"):
        with torch_threads(bad):  # type: ignore[arg-type]
            pass


def test_sarsop_searches_with_one_thread(two_threads: None) -> None:
    seen: list[int] = []

    def callback(entry: dict) -> bool:
        seen.append(torch.get_num_threads())
        return len(seen) >= 3

    sol = sarsop(tiger(), SARSOPConfig(time_limit=30.0, callback=callback))
    assert sol.info["stop_reason"] == "callback" and seen == [1, 1, 1]
    assert torch.get_num_threads() == 2
