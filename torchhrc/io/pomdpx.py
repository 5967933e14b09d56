"""Write a MOMDP as APPL's factored ``.pomdpx`` XML (Ong et al. 2010), for APPL's MOMDP solver.

APPL SARSOP treats state variables declared ``fullyObs="true"`` as the observed part ``x``
and solves the factored model (alpha vectors per ``x`` over ``y``). A :class:`MOMDP` maps to
two state variables ``x`` (observed) and ``y`` (hidden), one observation variable, one action
variable and one reward variable, each function a full table::

    x_1 | action x_0 y_0            Tx  (A, X, Y, X)
    y_1 | action x_0 y_0 [x_1]      Ty  (A, X, Y[, X], Y); "identity" on y_0 when static
    obs | action x_1 y_1            Z   (A, X, Y, O)
    reward(action x_0 y_0)          R   (A, X, Y)

Tables list the values in row-major order of (parents..., variable), the ``-`` instance of the
POMDPX format. ``x_1`` is a parent of ``y_1`` only when ``Ty`` depends on it (where ``x_1`` is
reachable). Checked with APPL SARSOP's ``pomdpsol``: Tiger and RockSample(4, 4) written this
way solve to the same values as their flat ``.pomdp`` files.

Example:
    >>> from torchhrc.testing import random_momdp
    >>> text = format_pomdpx(random_momdp(2, 3, 2, 2, seed=0))
    >>> '<StateVar vnamePrev="x_0" vnameCurr="x_1" fullyObs="true">' in text
    True
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from torchhrc.errors import ModelError
from torchhrc.io._atomic import atomic_write_bytes
from torchhrc.pomdp import MOMDP

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


def format_pomdpx(model: MOMDP, *, description: str = "written by torchhrc") -> str:
    """The ``.pomdpx`` text of an unbatched :class:`MOMDP`.

    Args:
        model: the MOMDP (no batch dims).
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
    if not isinstance(model, MOMDP):
        raise TypeError(f"expected a MOMDP, got {type(model).__name__}")
    if len(model.batch_shape):
        raise ModelError(f"write one problem at a time: got batch shape {tuple(model.batch_shape)}")
    A, X, Y, O = model.num_actions, model.num_observed, model.num_hidden, model.num_observations
    x0 = torch.zeros(X, dtype=torch.float64)
    x0[model.x0] = 1.0
    lines = [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        '<pomdpx version="1.0" id="torchhrc" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="pomdpx.xsd">',
        f"<Description>{_escape(description)}</Description>",
        f"<Discount>{model.discount!r}</Discount>",
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
        _cond_prob("x_0", "null", "-", _values(x0)),
        _cond_prob("y_0", "null", "-", _values(model.b0)),
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
        "<RewardFunction>",
        '<Func><Var>reward</Var><Parent>action x_0 y_0</Parent><Parameter type="TBL">'
        f"<Entry><Instance>- - -</Instance><ValueTable>{_values(model.R)}</ValueTable></Entry>"
        "</Parameter></Func>",
        "</RewardFunction>",
        "</pomdpx>",
    ]
    return "\n".join(lines) + "\n"


def write_pomdpx(
    model: MOMDP, path: str | os.PathLike[str], *, description: str = "written by torchhrc"
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
