"""torchhrc._host: CPU tensors read and made through numpy, and the same tensors elsewhere."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc._host import alloc, arange, copy_front, host_view, rows, to_numpy


def test_host_view_is_a_view_of_plain_cpu_tensors_only() -> None:
    t = torch.arange(6, dtype=torch.float64).reshape(2, 3)
    v = host_view(t)
    assert v is not None and v.shape == (2, 3)
    v[1, 2] = -1.0  # the same memory
    assert float(t[1, 2]) == -1.0
    for dtype in (torch.float32, torch.int64, torch.int32, torch.bool):
        assert host_view(torch.zeros(2, dtype=dtype)) is not None
    # torch then: a dtype numpy has not, a tensor that requires grad, another device
    assert host_view(torch.zeros(2, dtype=torch.float16)) is None
    assert host_view(torch.zeros(2, dtype=torch.float64, requires_grad=True)) is None
    assert host_view(torch.zeros(2, device="meta")) is None


@pytest.mark.parametrize("fill", [0, 2.5, None])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32, torch.int64, torch.bool])
def test_alloc_matches_torch_on_the_cpu(fill, dtype) -> None:
    t = alloc((3, 2), dtype, "cpu", fill=fill)
    assert t.shape == (3, 2) and t.dtype == dtype and t.device.type == "cpu"
    if fill is not None:
        assert torch.equal(t, torch.full((3, 2), fill, dtype=dtype))
    t[0, 0] = 1  # writable, and a numpy view of it sees the write
    assert host_view(t)[0, 0] == 1
    assert alloc(4, torch.long, torch.device("cpu")).shape == (4,)


def test_alloc_elsewhere_is_torch_s() -> None:
    # float16 has no numpy twin here, and the meta device no memory: both go to torch
    half = alloc(3, torch.float16, "cpu", fill=1.5)
    assert half.dtype == torch.float16 and half.tolist() == [1.5, 1.5, 1.5]
    meta = alloc((2, 2), torch.float64, "meta", fill=None)
    assert meta.device.type == "meta" and meta.shape == (2, 2)
    assert alloc(2, torch.float64, "meta", fill=0).device.type == "meta"


def test_arange_copy_front_rows_to_numpy() -> None:
    assert arange(4, "cpu").tolist() == [0, 1, 2, 3] and arange(4, "cpu").dtype == torch.long
    assert arange(3, "meta").device.type == "meta"
    new = alloc(5, torch.float64, "cpu")
    copy_front(new, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64), 2)
    assert new.tolist() == [1.0, 2.0, 0.0, 0.0, 0.0]
    grad = torch.tensor([4.0, 5.0], dtype=torch.float64, requires_grad=True)
    copy_front(new, grad.detach() * 1.0, 1)  # a plain copy either way
    assert new.tolist()[:2] == [4.0, 2.0]
    m = torch.eye(3, dtype=torch.float64)
    assert [r.tolist() for r in rows(m)] == m.tolist()
    assert [r.tolist() for r in rows(m.requires_grad_(True))] == m.tolist()
    assert np.array_equal(to_numpy(torch.tensor([1, 2])), [1, 2])
    assert np.array_equal(to_numpy(grad), [4.0, 5.0])  # detached, copied
