"""Validation helpers shared by the model containers (internal).

Each helper raises :class:`~torchhrc.errors.ModelError` (a ``ValueError``) or ``TypeError``
with a message naming the argument, what was expected and what was given.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from torchhrc._host import host_view
from torchhrc.errors import ModelError

__all__ = [
    "all_finite",
    "broadcast_shapes",
    "check_discount",
    "check_index",
    "check_probabilities",
    "check_shape",
    "check_tensor",
    "format_index",
]

DEFAULT_ATOL = 1e-6


def broadcast_shapes(*shapes: Sequence[int]) -> torch.Size:
    """The broadcast of ``shapes`` (NumPy/PyTorch rules), as :func:`torch.broadcast_shapes`.

    Pure Python: ``torch.broadcast_shapes`` imports torch's symbolic-shape machinery (sympy
    and the meta registrations, about 0.6 s) on its first call, which every model
    constructor would otherwise pay once per process. Raises ``RuntimeError`` (as torch does)
    when two sizes differ and neither is 1.

    Example:
        >>> broadcast_shapes((2, 1), (3,), ())
        torch.Size([2, 3])
    """
    ndim = max((len(shape) for shape in shapes), default=0)
    out = [1] * ndim
    for shape in shapes:
        for i, size in enumerate(shape, start=ndim - len(shape)):
            size = int(size)
            if size < 0:
                raise RuntimeError(f"shape {tuple(shape)} has a negative size")
            if out[i] == 1:
                out[i] = size
            elif size not in (1, out[i]):
                raise RuntimeError(
                    f"shapes {[tuple(s) for s in shapes]} do not broadcast: "
                    f"size {size} against {out[i]} at dimension {i - ndim}"
                )
    return torch.Size(out)


def format_index(index: Sequence[int] | torch.Tensor) -> str:
    """Format a multi-index as ``[i, j, k]``."""
    values = index.tolist() if isinstance(index, torch.Tensor) else list(index)
    return "[" + ", ".join(str(int(v)) for v in values) + "]"


def check_index(
    name: str,
    value: object,
    size: int | None,
    *,
    device: torch.device | str | None = None,
    what: str = "",
    low: int = 0,
) -> torch.Tensor:
    """``value`` as an int64 index tensor, checked to be integer and in ``[low, size)``
    (``low = -1`` where ``-1`` means "none").

    Accepted: a Python ``int``, a NumPy integer, or an integer tensor / NumPy array / list
    (any shape, e.g. a batch). Refused with ``TypeError``: ``bool``, floats (``3.0`` too: an
    index is not a measurement), anything else. Out of range: ``ModelError`` naming the
    first bad value; ``size=None`` skips the range check. ``what`` is added to both messages
    (e.g. ``"the model's states"``).

    Example:
        >>> import numpy as np
        >>> check_index("x", np.int64(2), 3).item()
        2
        >>> check_index("x", 3, 3)
        Traceback (most recent call last):
        ...
        torchhrc.errors.ModelError: expected x in [0, 3), got 3
    """
    hint = f" ({what})" if what else ""
    if isinstance(value, torch.Tensor):
        t = value
    elif isinstance(value, bool) or not isinstance(
        value, (int, np.integer, np.ndarray, list, tuple)
    ):
        raise TypeError(f"expected {name} to be an integer index (an int, or an integer "
                        f"tensor or array){hint}, got {type(value).__name__} "
                        f"{value!r}")  # fmt: skip
    else:
        t = torch.as_tensor(value)
    if t.is_floating_point() or t.is_complex() or t.dtype == torch.bool:
        raise TypeError(f"expected {name} to be an integer index (an int, or an integer "
                        f"tensor or array){hint}, got {t.dtype} {value!r}")  # fmt: skip
    if size is not None and t.numel() and bool(((t < low) | (t >= size)).any()):
        bad = int(t[(t < low) | (t >= size)].reshape(-1)[0])
        raise ModelError(f"expected {name} in [{low}, {size}){hint}, got {bad}")
    return t.to(device=device if device is not None else t.device, dtype=torch.long)


def check_tensor(name: str, value: object, *, floating: bool = True) -> torch.Tensor:
    """Check that ``value`` is a tensor (floating point unless ``floating=False``)."""
    if not isinstance(value, torch.Tensor):
        raise TypeError(f"expected {name} to be a torch.Tensor, got {type(value).__name__}")
    if floating and not value.is_floating_point():
        raise TypeError(f"expected {name} to have a floating dtype, got {value.dtype}")
    return value


def check_shape(name: str, value: torch.Tensor, expected: Sequence[int | None], doc: str) -> None:
    """Check the trailing dims of ``value`` against ``expected`` (None = any size).

    Args:
        name: the argument's name, used in the message.
        value: the tensor.
        expected: the trailing sizes; leading (batch) dims are free.
        doc: the shape's documentation, e.g. ``"(..., A, S, S)"``.
    """
    n = len(expected)
    if value.dim() < n:
        raise ModelError(
            f"expected {name} to have shape {doc} (at least {n} dims), "
            f"actual shape = {tuple(value.shape)}"
        )
    tail = value.shape[value.dim() - n :]
    for got, want in zip(tail, expected):
        if want is not None and got != want:
            raise ModelError(
                f"expected {name} to have shape {doc} with trailing dims "
                f"{tuple('*' if w is None else w for w in expected)}, "
                f"actual shape = {tuple(value.shape)}"
            )


def check_probabilities(
    name: str,
    value: torch.Tensor,
    *,
    dims: int = 1,
    atol: float = DEFAULT_ATOL,
    sums_to_one: bool = True,
) -> None:
    """Check entries in [0, 1] and that the last ``dims`` dims sum to one.

    The error names the tensor, the first offending index and its value.
    """
    v = host_view(value)
    if v is not None:  # the common case on the CPU, by numpy (see host_view)
        ok = not v.size or (float(v.min()) >= -atol and float(v.max()) <= 1 + atol)
        if ok and sums_to_one:
            tol = max(atol, 1e-4 if v.dtype == np.float32 else atol)
            ok = bool((np.abs(v.sum(axis=tuple(range(-dims, 0))) - 1) <= tol).all())
        if ok:
            return
    # one pass for the common case: every entry in range (NaN fails both comparisons), so
    # the full masks below are built only to locate an offending entry
    if value.numel():
        lowest, highest = torch.aminmax(value)
        in_range = bool(lowest >= -atol) and bool(highest <= 1 + atol)
    else:
        in_range = True
    if not in_range and not torch.isfinite(value).all():
        bad = torch.nonzero(~torch.isfinite(value))[0]
        raise ModelError(f"{name}{format_index(bad)} = {value[tuple(bad)].item()} is not finite")
    if not in_range:
        bad = torch.nonzero((value < -atol) | (value > 1 + atol))[0]
        raise ModelError(
            f"{name}{format_index(bad)} = {value[tuple(bad)].item():.6g} is not a probability "
            "(expected a value in [0, 1])"
        )
    if sums_to_one:
        total = value.sum(dim=tuple(range(-dims, 0)))
        off = (total - 1).abs() > max(atol, 1e-4 if value.dtype == torch.float32 else atol)
        if off.any():
            bad = torch.nonzero(off)[0]
            over = "row" if dims == 1 else "slice"
            raise ModelError(
                f"{name}{format_index(bad)} {over} sums to {total[tuple(bad)].item():.6g}, "
                "expected 1 (within tolerance)"
            )


def all_finite(value: torch.Tensor) -> bool:
    """Whether every entry of ``value`` is finite (on the CPU by numpy: see :func:`host_view`).

    Example:
        >>> all_finite(torch.tensor([0.0, 1.0])), all_finite(torch.tensor([0.0, float("nan")]))
        (True, False)
    """
    v = host_view(value)
    if v is not None:
        return bool(np.isfinite(v).all())
    return bool(torch.isfinite(value).all())


def check_discount(discount: object) -> float:
    """Check a discount factor: a real number in (0, 1]; returns it as a float."""
    if isinstance(discount, torch.Tensor):
        discount = discount.item()
    if not isinstance(discount, (int, float)) or isinstance(discount, bool):
        raise TypeError(f"expected discount to be a float, got {type(discount).__name__}")
    if not 0.0 < float(discount) <= 1.0:
        raise ModelError(f"expected discount in (0, 1], got {discount}")
    return float(discount)
