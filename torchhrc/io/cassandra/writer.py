"""Writing a :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.sparse.SparsePOMDP` as
Cassandra ``.pomdp`` text (:func:`format_pomdp`, :func:`write_pomdp`): the sparse
single-entry form, names where the grammar accepts them, floats at ``repr`` precision."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from torchhrc._atomic import atomic_write_bytes
from torchhrc.errors import ModelError
from torchhrc.io.cassandra.tokens import _NAME, _RESERVED
from torchhrc.pomdp import POMDP
from torchhrc.pomdp.sparse import SparsePOMDP, coalesce

__all__ = ["format_pomdp", "write_pomdp"]


def _names_or_none(names: Sequence[str] | None) -> tuple[str, ...] | None:
    if names is None:
        return None
    names = tuple(names)
    if all(_NAME.match(n) and n not in _RESERVED for n in names) and len(set(names)) == len(names):
        return names
    return None


def _fmt(values: np.ndarray) -> list[str]:
    return [repr(float(v)) for v in values]


def format_pomdp(
    model: POMDP | SparsePOMDP, *, comment: str | None = None, names: bool = True
) -> str:
    """The ``.pomdp`` text of an unbatched model (sparse single-entry form).

    Names are written when every name of a kind is a valid identifier (letters, digits,
    ``_``, ``-``, starting with a letter, not a keyword); otherwise counts and 0-based numbers.
    Rewards are written as ``R: a : s : * : * v`` (the expected reward), exact for the reader.

    Args:
        model: a :class:`POMDP` (no batch dims) or a :class:`SparsePOMDP`.
        comment: an optional comment for the first lines.
        names: write names (when valid); ``False`` writes counts and numbers (smaller files).

    Returns:
        The file's text.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> format_pomdp(tiger()).splitlines()[1]
        'discount: 0.95'
    """
    if isinstance(model, POMDP):
        if len(model.batch_shape):
            raise ModelError(
                f"write one problem at a time: got batch shape {tuple(model.batch_shape)}"
            )
        sparse = SparsePOMDP.from_dense(model)
        state_names = _names_or_none(model.states)
        action_names = _names_or_none(model.actions)
        obs_names = _names_or_none(model.observations)
    elif isinstance(model, SparsePOMDP):
        sparse = model
        state_names = _names_or_none(model.states)
        action_names = _names_or_none(model.actions)
        obs_names = _names_or_none(model.observations)
    else:
        raise TypeError(f"expected a POMDP or SparsePOMDP, got {type(model).__name__}")
    if not names:
        state_names = action_names = obs_names = None
    A, S, O = sparse.num_actions, sparse.num_states, sparse.num_observations
    sn = state_names or tuple(str(i) for i in range(S))
    an = action_names or tuple(str(i) for i in range(A))
    on = obs_names or tuple(str(i) for i in range(O))
    lines = [f"# {line}" for line in (comment or "written by torchhrc").splitlines()]
    lines.append(f"discount: {sparse.discount!r}")
    lines.append("values: reward")
    lines.append("states: " + (" ".join(state_names) if state_names else str(S)))
    lines.append("actions: " + (" ".join(action_names) if action_names else str(A)))
    lines.append("observations: " + (" ".join(obs_names) if obs_names else str(O)))
    lines.append("start: " + " ".join(_fmt(sparse.b0.double().cpu().numpy())))
    lines.append("")
    lines.extend(_entries("T", sparse.transitions, an, sn, sn, A, S))
    lines.append("")
    lines.extend(_entries("O", sparse.observations_, an, sn, on, A, S))
    lines.append("")
    R = sparse.R.double().cpu().numpy()
    if A > 1 and (R == R[:1]).all():
        cols = np.flatnonzero(R[0])
        lines.extend(f"R: * : {sn[s]} : * : * {r}" for s, r in zip(cols, _fmt(R[0, cols])))
    else:
        rows, cols = np.nonzero(R)
        lines.extend(
            f"R: {an[a]} : {sn[s]} : * : * {r}" for a, s, r in zip(rows, cols, _fmt(R[rows, cols]))
        )
    lines.append("")
    return "\n".join(lines)


def _entries(
    kind: str,
    coo: tuple[torch.Tensor, torch.Tensor],
    an: Sequence[str],
    first: Sequence[str],
    second: Sequence[str],
    A: int,
    S: int,
) -> list[str]:
    """Single-entry lines for the nonzeros; ``*`` for the state when every row of an action
    is the same, and for the action when every action has the same entries."""
    index, prob = coo
    index = index.cpu().numpy().astype(np.int64, copy=False)
    N = len(second)
    # one line per cell, sorted by (a, s, j): repeated coordinates are summed, as the solvers
    # read a coordinate list (a file's later line would override an earlier one instead)
    cells, prob = coalesce((index[:, 0] * S + index[:, 1]) * N + index[:, 2],
                           prob.double().cpu().numpy())  # fmt: skip
    index = np.stack([cells // (S * N), (cells // N) % S, cells % N], 1)
    bounds = np.searchsorted(index[:, 0], np.arange(A + 1))
    payloads = []
    for a in range(A):
        rows = index[bounds[a] : bounds[a + 1], 1:]
        p = prob[bounds[a] : bounds[a + 1]]
        m = len(p)
        k = m // S if S else 0
        same_rows = (
            S > 1
            and k > 0
            and m == k * S
            and np.array_equal(rows[:, 0], np.repeat(np.arange(S), k))
            and np.array_equal(rows[:, 1], np.tile(rows[:k, 1], S))
            and np.array_equal(p, np.tile(p[:k], S))
        )
        payloads.append((True, rows[:k, 1], p[:k]) if same_rows else (False, rows, p))

    def lines(action: str, payload: tuple) -> list[str]:
        star, rows, p = payload
        if star:
            return [
                f"{kind}: {action} : * : {second[j]} {v}" for j, v in zip(rows.tolist(), _fmt(p))
            ]
        return [
            f"{kind}: {action} : {first[i]} : {second[j]} {v}"
            for (i, j), v in zip(rows.tolist(), _fmt(p))
        ]

    def equal(x: tuple, y: tuple) -> bool:
        return x[0] == y[0] and np.array_equal(x[1], y[1]) and np.array_equal(x[2], y[2])

    if A > 1 and all(equal(payloads[0], q) for q in payloads[1:]):
        return lines("*", payloads[0])
    out: list[str] = []
    for a in range(A):
        out.extend(lines(an[a], payloads[a]))
    return out


def write_pomdp(
    model: POMDP | SparsePOMDP,
    path: str | os.PathLike[str],
    *,
    comment: str | None = None,
    names: bool = True,
) -> Path:
    """Write ``model`` to ``path`` in ``.pomdp`` format, atomically (temp file + rename).

    Args:
        model: a :class:`POMDP` (no batch dims) or a :class:`SparsePOMDP`.
        path: the destination.
        comment: optional comment lines at the top.
        names: write names (when valid identifiers) or only counts and numbers.

    Returns:
        The path written.

    Example:
        >>> import tempfile, os
        >>> from torchhrc.io.cassandra import read_pomdp
        >>> from torchhrc.tasks.classic import tiger
        >>> d = tempfile.mkdtemp()
        >>> read_pomdp(write_pomdp(tiger(), os.path.join(d, "tiger.pomdp"))).num_states
        2
    """
    text = format_pomdp(model, comment=comment, names=names)
    return atomic_write_bytes(path, text.encode("utf-8"))
