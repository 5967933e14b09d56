"""``torchhrc._threads.torch_threads`` and ``blas_threads``: the count inside the block,
restored after (also after an exception), bad counts refused, the BLAS libraries looked up
once per process; and SARSOP's search runs with one intra-op thread and one BLAS thread."""

from __future__ import annotations

import pytest
import torch
from threadpoolctl import threadpool_info, threadpool_limits

import torchhrc._threads as threads
from torchhrc._threads import blas_threads, torch_threads
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


def _blas_counts() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_sarsop_searches_with_one_thread(two_threads: None) -> None:
    seen: list[tuple[int, list[int]]] = []

    def callback(entry: dict) -> bool:
        seen.append((torch.get_num_threads(), _blas_counts()))
        return len(seen) >= 3

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_counts()
        sol = sarsop(tiger(), SARSOPConfig(time_limit=30.0, callback=callback))
        assert _blas_counts() == before
    assert sol.info["stop_reason"] == "callback" and len(seen) == 3
    assert all(n == 1 and blas and set(blas) == {1} for n, blas in seen), seen
    assert torch.get_num_threads() == 2


def test_blas_threads_sets_and_restores_and_looks_the_libraries_up_once(monkeypatch) -> None:
    made: list[object] = []
    real = threads.ThreadpoolController

    def counted() -> object:
        made.append(1)
        return real()

    monkeypatch.setattr(threads, "ThreadpoolController", counted)
    monkeypatch.setattr(threads, "_CONTROLLER", [])
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_counts()
        for _ in range(3):
            with blas_threads(1):
                assert set(_blas_counts()) == {1}
            assert _blas_counts() == before
        with pytest.raises(RuntimeError, match="inside"):
            with blas_threads(1):
                raise RuntimeError("inside")
        assert _blas_counts() == before
    assert len(made) == 1
    for bad in (0, -1, 1.5, True, "1"):
        with pytest.raises(ValueError, match="expected n to be an int of at least 1"):
            blas_threads(bad)  # type: ignore[arg-type]
