"""Small CPU tensors through numpy (internal).

A process's first call of each libtorch operation maps that kernel's code into memory:
0.1-1.7 MB each, shared pages but counted in the process's resident set. A small model's
solve on the CPU (Tiger: a few milliseconds) ran some sixty distinct operations in its checks
and its setup, about 12 MB, three times APPL's whole process (docs/benchmarks.md, "A small
solve without libtorch's kernels"). The model checks and SARSOP's setup therefore read and
allocate CPU tensors through numpy, whose kernels the search runs anyway; a tensor made by
:func:`alloc` is a numpy array's memory seen by torch, so every later torch operation on
it works as on any other tensor.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

__all__ = ["alloc", "arange", "as_host", "copy_front", "host_view", "rows", "to_numpy"]

_NUMPY_DTYPES = {
    torch.float64: np.float64,
    torch.float32: np.float32,
    torch.int64: np.int64,
    torch.int32: np.int32,
    torch.bool: np.bool_,
}


def host_view(value: torch.Tensor) -> np.ndarray | None:
    """A numpy view of ``value`` where it is a CPU tensor of a dtype numpy shares (float64,
    float32, int64, int32, bool) that does not require grad; ``None`` otherwise (the caller
    then uses torch).

    Example:
        >>> host_view(torch.arange(3)).tolist(), host_view(torch.zeros(2, dtype=torch.float16))
        ([0, 1, 2], None)
    """
    if value.device.type != "cpu" or value.dtype not in _NUMPY_DTYPES or value.requires_grad:
        return None
    return value.numpy()


def alloc(shape: int | Sequence[int], dtype: torch.dtype, device: torch.device | str,
          fill: float | None = 0) -> torch.Tensor:  # fmt: skip
    """A new tensor of ``shape`` filled with ``fill`` (``None``: not initialised, as
    :func:`torch.empty`), made by numpy on the CPU and by torch elsewhere.

    Example:
        >>> t = alloc((2, 3), torch.float64, "cpu", fill=1.5)
        >>> t.shape, t.dtype, float(t.sum())
        (torch.Size([2, 3]), torch.float64, 9.0)
    """
    np_dtype = _NUMPY_DTYPES.get(dtype)
    if _kind(device) != "cpu" or np_dtype is None:
        if fill is None:
            return torch.empty(shape, dtype=dtype, device=device)
        size = (shape,) if isinstance(shape, int) else tuple(shape)
        return torch.full(size, fill, dtype=dtype, device=device)
    if fill is None:
        return torch.from_numpy(np.empty(shape, dtype=np_dtype))
    if fill == 0:
        return torch.from_numpy(np.zeros(shape, dtype=np_dtype))
    return torch.from_numpy(np.full(shape, fill, dtype=np_dtype))


def arange(n: int, device: torch.device | str) -> torch.Tensor:
    """``(n,)`` int64 ``0, 1, ..., n - 1`` (:func:`torch.arange`), by numpy on the CPU.

    Example:
        >>> arange(3, "cpu").tolist()
        [0, 1, 2]
    """
    if _kind(device) == "cpu":
        return torch.from_numpy(np.arange(n, dtype=np.int64))
    return torch.arange(n, device=device)


def as_host(value: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """``value.to("cpu", dtype).contiguous()``, converted by numpy where ``value`` is a CPU
    tensor it can view (the tensor itself where nothing changes).

    Example:
        >>> t = as_host(torch.tensor([[1, 2], [3, 4]]).T, torch.float64)
        >>> t.dtype, t.is_contiguous(), t.tolist()
        (torch.float64, True, [[1.0, 3.0], [2.0, 4.0]])
    """
    v, np_dtype = host_view(value), _NUMPY_DTYPES.get(dtype)
    if v is None or np_dtype is None:
        return value.to("cpu", dtype).contiguous()
    out = np.ascontiguousarray(v, dtype=np_dtype)
    return value if out is v else torch.from_numpy(out)


def copy_front(new: torch.Tensor, old: torch.Tensor, n: int) -> None:
    """``new[:n] = old[:n]`` (by numpy where both are CPU tensors numpy can view).

    Example:
        >>> new = alloc(4, torch.float64, "cpu")
        >>> copy_front(new, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64), 2)
        >>> new.tolist()
        [1.0, 2.0, 0.0, 0.0]
    """
    dst, src = host_view(new), host_view(old)
    if dst is not None and src is not None:
        dst[:n] = src[:n]
    else:
        new[:n] = old[:n]


def to_numpy(value: torch.Tensor) -> np.ndarray:
    """``value`` as a numpy array: a view where :func:`host_view` gives one, else a detached
    CPU copy.

    Example:
        >>> to_numpy(torch.tensor([1, 2])).tolist()
        [1, 2]
    """
    v = host_view(value)
    return v if v is not None else value.detach().cpu().numpy()


def rows(value: torch.Tensor) -> list[torch.Tensor]:
    """The rows of ``value`` (:meth:`torch.Tensor.unbind` along the first dimension), as
    tensors over numpy's views on the CPU.

    Example:
        >>> [r.tolist() for r in rows(torch.eye(2, dtype=torch.float64))]
        [[1.0, 0.0], [0.0, 1.0]]
    """
    v = host_view(value)
    if v is None:
        return list(value.unbind(0))
    return [torch.from_numpy(r) for r in v]


def _kind(device: torch.device | str) -> str:
    return device.type if isinstance(device, torch.device) else str(device).split(":")[0]
