"""The internal validation helpers: broadcast_shapes agrees with torch's."""

from __future__ import annotations

import numpy as np
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


def test_check_index_takes_every_integer_form_and_refuses_the_rest() -> None:
    # one rule for every index the library takes (belief updates, the Controller): ints,
    # NumPy integers, integer tensors, arrays and lists are indices; floats and bools are not
    from torchhrc._checks import check_index
    from torchhrc.errors import ModelError

    short = torch.tensor([2, 1], dtype=torch.int16)
    for value, expected in ((2, [2]), (np.int32(1), [1]), (np.array([0, 2]), [0, 2]),
                            ([1, 0], [1, 0]), (short, [2, 1])):  # fmt: skip
        out = check_index("x", value, 3)
        assert out.dtype == torch.long and out.reshape(-1).tolist() == expected
    for value in (2.0, 0.5, True, np.float64(1.0), torch.tensor([0.0]), [0.0, 1.0], "1", None):
        with pytest.raises(TypeError, match="expected x to be an integer index"):
            check_index("x", value, 3)
    with pytest.raises(ModelError, match=r"expected o in \[0, 3\) \(signals\), got 3"):
        check_index("o", np.array([0, 3, 5]), 3, what="signals")
    with pytest.raises(ModelError, match=r"got -1"):
        check_index("o", [-1], 3)
    assert check_index("x", 7, None).item() == 7  # size unknown: no range check
