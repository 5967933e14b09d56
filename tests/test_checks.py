"""The internal validation helpers: broadcast_shapes agrees with torch's."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchhrc._checks import broadcast_shapes

_shape = st.lists(st.integers(0, 3), max_size=4)


@settings(deadline=None)  # torch.broadcast_shapes imports sympy on its first call
@given(st.lists(_shape, max_size=4))
def test_broadcast_shapes_agrees_with_torch(shapes: list[list[int]]) -> None:
    try:
        expected = torch.broadcast_shapes(*shapes)
    except RuntimeError:
        with pytest.raises(RuntimeError, match="do not broadcast"):
            broadcast_shapes(*shapes)
    else:
        assert broadcast_shapes(*shapes) == expected


def test_broadcast_shapes_worked_example() -> None:
    assert broadcast_shapes((5, 1, 4), (3, 1), ()) == torch.Size([5, 3, 4])
    assert broadcast_shapes() == torch.Size([])
    with pytest.raises(RuntimeError, match="size 3 against 2 at dimension -1"):
        broadcast_shapes((2,), (3,))
