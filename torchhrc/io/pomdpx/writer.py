"""Writing a :class:`~torchhrc.pomdp.MOMDP`, :class:`~torchhrc.pomdp.POMDP` or
:class:`~torchhrc.pomdp.sparse.SparsePOMDP` as ``.pomdpx`` XML (:func:`format_pomdpx`,
:func:`write_pomdpx`); the layout is in :mod:`torchhrc.io.pomdpx`."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from torchhrc._atomic import atomic_write_bytes
from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP, POMDP, split_initial
from torchhrc.pomdp.sparse import SparsePOMDP, coalesce

__all__ = ["format_pomdpx", "write_pomdpx"]


def _values(t: torch.Tensor) -> str:
    flat = t.detach().double().cpu().numpy().reshape(-1)
    return " ".join("0" if v == 0 else "1" if v == 1 else repr(float(v)) for v in flat)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _enum(names: tuple[str, ...] | None, count: int) -> str:
    if names is not None and all(n.isidentifier() for n in names):
        return f"<ValueEnum>{' '.join(names)}</ValueEnum>"
    return f"<NumValues>{count}</NumValues>"


def _cond_prob(var: str, parents: str, instance: str, table: str) -> str:
    return (
        f'<CondProb><Var>{var}</Var><Parent>{parents}</Parent><Parameter type="TBL">'
        f"<Entry><Instance>{instance}</Instance><ProbTable>{table}</ProbTable></Entry>"
        "</Parameter></CondProb>"
    )


def _header(discount: float, description: str) -> list[str]:
    return [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        '<pomdpx version="1.0" id="torchhrc" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="pomdpx.xsd">',
        f"<Description>{_escape(description)}</Description>",
        f"<Discount>{discount!r}</Discount>",
    ]


def _reward(parents: str, instance: str, R: torch.Tensor) -> list[str]:
    return [
        "<RewardFunction>",
        f'<Func><Var>reward</Var><Parent>{parents}</Parent><Parameter type="TBL">'
        f"<Entry><Instance>{instance}</Instance><ValueTable>{_values(R)}</ValueTable></Entry>"
        "</Parameter></Func>",
        "</RewardFunction>",
        "</pomdpx>",
    ]


def _flat_head(model: POMDP | SparsePOMDP, description: str) -> list[str]:
    """A flat model's lines up to its functions: the header, one hidden state variable, the
    observation, action and reward variables, and the initial belief as one table."""
    A, S, O = model.num_actions, model.num_states, model.num_observations
    return [
        *_header(model.discount, description),
        "<Variable>",
        '<StateVar vnamePrev="state_0" vnameCurr="state_1" fullyObs="false">'
        f"{_enum(model.states, S)}</StateVar>",
        f'<ObsVar vname="obs">{_enum(model.observations, O)}</ObsVar>',
        f'<ActionVar vname="action">{_enum(model.actions, A)}</ActionVar>',
        '<RewardVar vname="reward"/>',
        "</Variable>",
        "<InitialStateBelief>",
        _cond_prob("state_0", "null", "-", _values(model.b0)),
        "</InitialStateBelief>",
    ]


def _format_pomdp(model: POMDP, description: str) -> str:
    A, S = model.num_actions, model.num_states
    lines = [
        *_flat_head(model, description),
        "<StateTransitionFunction>",
        _cond_prob("state_1", "action state_0", "- - -", _values(model.T)),
        "</StateTransitionFunction>",
        "<ObsFunction>",
        _cond_prob("obs", "action state_1", "- - -", _values(model.Z)),
        "</ObsFunction>",
    ]
    return "\n".join(lines + _reward("action state_0", "- -", model.R.expand(A, S))) + "\n"


def _names(names: tuple[str, ...] | None, count: int, prefix: str) -> list[str]:
    """The value names an ``<Instance>`` uses: the ``<ValueEnum>`` names :func:`_enum` wrote,
    else APPL's ``s0 s1 ...`` (``a``, ``o``) of ``<NumValues>``."""
    if names is not None and all(n.isidentifier() for n in names):
        return list(names)
    return [f"{prefix}{i}" for i in range(count)]


def _entries(names: list[list[str]], index: torch.Tensor, values: torch.Tensor,
             tag: str) -> str:  # fmt: skip
    """One ``<Entry>`` per nonzero: ``index (M, k)`` into the ``k`` variables' ``names``."""
    columns = [[axis[i] for i in col] for axis, col in zip(names, index.t().tolist())]
    text = _values(values).split(" ")
    return "".join(
        f"<Entry><Instance>{' '.join(parts)}</Instance><{tag}>{v}</{tag}></Entry>"
        for *parts, v in zip(*columns, text)
    )


def _coalesced(coo: tuple[torch.Tensor, torch.Tensor],
               sizes: tuple[int, int, int]) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """A coordinate list with one entry per cell (repeats summed, zeros dropped, sorted): in a
    ``.pomdpx`` table a later entry of the same instance replaces an earlier one."""
    index, values = coo
    _, n1, n2 = sizes
    keys = ((index[:, 0] * n1 + index[:, 1]) * n2 + index[:, 2]).numpy()
    cells, summed = coalesce(keys, values.detach().double().cpu().numpy())
    cells_t = torch.from_numpy(cells)
    index = torch.stack([cells_t // (n1 * n2), cells_t // n2 % n1, cells_t % n2], 1)
    return index, torch.from_numpy(summed)


def _sparse_table(var: str, parents: str, entries: str) -> str:
    return (f'<CondProb><Var>{var}</Var><Parent>{parents}</Parent><Parameter type="TBL">'
            f"{entries}</Parameter></CondProb>")  # fmt: skip


def _format_sparse_pomdp(model: SparsePOMDP, description: str) -> str:
    """A flat :class:`SparsePOMDP`: the functions as one ``<Entry>`` per nonzero (APPL reads
    an instance of value names), so that the file grows with the nonzeros, not ``A S^2``."""
    A, S, O = model.num_actions, model.num_states, model.num_observations
    states = _names(model.states, S, "s")
    actions = _names(model.actions, A, "a")
    observations = _names(model.observations, O, "o")
    T_index, T_prob = _coalesced(model.transitions, (A, S, S))
    Z_index, Z_prob = _coalesced(model.observations_, (A, S, O))
    R = model.R.expand(A, S)
    r_index = torch.nonzero(R)
    lines = [
        *_flat_head(model, description),
        "<StateTransitionFunction>",
        _sparse_table("state_1", "action state_0",
                      _entries([actions, states, states], T_index, T_prob, "ProbTable")),
        "</StateTransitionFunction>",
        "<ObsFunction>",
        _sparse_table("obs", "action state_1",
                      _entries([actions, states, observations], Z_index, Z_prob, "ProbTable")),
        "</ObsFunction>",
        "<RewardFunction>",
        '<Func><Var>reward</Var><Parent>action state_0</Parent><Parameter type="TBL">'
        + _entries([actions, states], r_index, R[r_index[:, 0], r_index[:, 1]], "ValueTable")
        + "</Parameter></Func>",
        "</RewardFunction>",
        "</pomdpx>",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def format_pomdpx(model: MOMDP | POMDP | SparsePOMDP, *,
                  description: str = "written by torchhrc") -> str:  # fmt: skip
    """The ``.pomdpx`` text of an unbatched :class:`MOMDP` or :class:`POMDP`.

    Args:
        model: the MOMDP (observed ``x_0/x_1`` and hidden ``y_0/y_1``) or flat POMDP (one
            hidden ``state_0/state_1``), no batch dims; or a flat
            :class:`~torchhrc.pomdp.sparse.SparsePOMDP`, written as one ``<Entry>`` per
            nonzero of ``T``, ``Z`` and ``R`` (a sparse MOMDP: write its
            ``to_sparse_pomdp()``). APPL's ``pomdpsol`` and
            :func:`~torchhrc.io.pomdpx.read_pomdpx` read it at any size (a table of more
            than :data:`~torchhrc.pomdp.sparse.MAX_DENSE_ENTRIES` cells is read as its
            entries).
        description: the ``<Description>`` text.

    Returns:
        The XML text.

    Raises:
        ModelError: the model has batch dims.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> format_pomdpx(random_momdp(2, 2, 1, 1, seed=0)).count("<CondProb>")
        5
    """
    if isinstance(model, SparsePOMDP):
        return _format_sparse_pomdp(model, description)
    if not isinstance(model, (MOMDP, POMDP)):
        hint = " (a sparse MOMDP: write its to_sparse_pomdp())" if hasattr(
            model, "to_sparse_pomdp") else ""  # fmt: skip
        raise TypeError(f"expected a MOMDP, POMDP or SparsePOMDP, got "
                        f"{type(model).__name__}{hint}")  # fmt: skip
    if len(model.batch_shape):
        raise ModelError(f"write one problem at a time: got batch shape {tuple(model.batch_shape)}")
    if isinstance(model, POMDP):
        return _format_pomdp(model, description)
    A, X, Y, O = model.num_actions, model.num_observed, model.num_hidden, model.num_observations
    mass = torch.zeros(X, dtype=torch.float64)  # P(x)
    mass[model.x0] = 1.0
    hidden = _cond_prob("y_0", "null", "-", _values(model.b0))
    if model.initial is not None:  # a random start: P(x), and P(y | x) (uniform at no mass)
        mass, given = split_initial(model.initial.double())
        given = torch.where(mass[:, None] > 0, given, 1.0 / Y)
        hidden = _cond_prob("y_0", "x_0", "- -", _values(given))
    lines = [
        *_header(model.discount, description),
        "<Variable>",
        '<StateVar vnamePrev="x_0" vnameCurr="x_1" fullyObs="true">'
        f"{_enum(model.observed_states, X)}</StateVar>",
        '<StateVar vnamePrev="y_0" vnameCurr="y_1" fullyObs="false">'
        f"{_enum(model.hidden_states, Y)}</StateVar>",
        f'<ObsVar vname="obs">{_enum(model.observations, O)}</ObsVar>',
        f'<ActionVar vname="action">{_enum(model.actions, A)}</ActionVar>',
        '<RewardVar vname="reward"/>',
        "</Variable>",
        "<InitialStateBelief>",
        _cond_prob("x_0", "null", "-", _values(mass)),
        hidden,
        "</InitialStateBelief>",
        "<StateTransitionFunction>",
        _cond_prob("x_1", "action x_0 y_0", "- - - -", _values(model.Tx)),
    ]
    if model.Ty is None:
        lines.append(_cond_prob("y_1", "y_0", "- -", "identity"))
    else:
        Ty = model.Ty
        # Does Ty depend on x_1 where x_1 is reachable (Tx > 0)? If not, drop that parent.
        reachable = model.Tx > 0  # (A, X, Y, X2)
        pick = reachable.double().argmax(-1)  # a reachable x2 per (a, x, y)
        rows = Ty.gather(-2, pick[..., None, None].expand(A, X, Y, 1, Y))  # (A, X, Y, 1, Y)
        same = (Ty == rows).all(-1) | ~reachable
        if bool(same.all()):
            lines.append(_cond_prob("y_1", "action x_0 y_0", "- - - -", _values(rows[..., 0, :])))
        else:
            lines.append(_cond_prob("y_1", "action x_0 y_0 x_1", "- - - - -", _values(Ty)))
    lines += [
        "</StateTransitionFunction>",
        "<ObsFunction>",
        _cond_prob("obs", "action x_1 y_1", "- - - -", _values(model.Z)),
        "</ObsFunction>",
    ]
    return "\n".join(lines + _reward("action x_0 y_0", "- - -", model.R)) + "\n"


def write_pomdpx(
    model: MOMDP | POMDP | SparsePOMDP,
    path: str | os.PathLike[str],
    *,
    description: str = "written by torchhrc",
) -> Path:
    """Write ``model`` as ``.pomdpx`` XML, atomically. See :func:`format_pomdpx`.

    Example:
        >>> import os, tempfile
        >>> from torchhrc.testing import random_momdp
        >>> path = os.path.join(tempfile.mkdtemp(), "m.pomdpx")
        >>> write_pomdpx(random_momdp(2, 2, 1, 1, seed=0), path).suffix
        '.pomdpx'
    """
    text = format_pomdpx(model, description=description)
    return atomic_write_bytes(path, text.encode("iso-8859-1", errors="xmlcharrefreplace"))
