"""Shared by the readers' fuzz tests: a valid file damaged by a few random edits."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Any

from hypothesis import strategies as st


def corrupt(
    draw: Callable[[st.SearchStrategy[Any]], Any],
    text: str,
    junk: Sequence[str],
    separator: str = r"(\s+)",
) -> str:
    """``text`` cut at ``separator`` (kept) and given 1-3 edits: a piece deleted, doubled,
    replaced by one of ``junk``, or the text truncated there."""
    pieces = re.split(separator, text)
    for _ in range(draw(st.integers(1, 3))):
        if not pieces:
            break
        op = draw(st.sampled_from(["delete", "duplicate", "replace", "truncate"]))
        k = draw(st.integers(0, len(pieces) - 1))
        if op == "delete":
            pieces[k] = ""
        elif op == "duplicate":
            pieces[k] = pieces[k] + " " + pieces[k]
        elif op == "replace":
            pieces[k] = draw(st.sampled_from(list(junk)))
        else:
            pieces = pieces[:k]
    return "".join(pieces)
