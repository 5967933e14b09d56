"""APPL's factored ``.pomdpx`` XML format (Ong et al. 2010): reader and writer.

This package's front: :func:`read_pomdpx`, :func:`parse_pomdpx` and
:func:`read_pomdpx_variables` choose the model's form; the parts live in
:mod:`~torchhrc.io.pomdpx.xml_tree` (the element tree), :mod:`~torchhrc.io.pomdpx.variables`,
:mod:`~torchhrc.io.pomdpx.reader` (elements to checked tables),
:mod:`~torchhrc.io.pomdpx.builder` (tables to tensors) and :mod:`~torchhrc.io.pomdpx.writer`.

The format of APPL SARSOP (``doc/POMDPX/PomdpxFileFormat-v1.0.pdf`` and ``pomdpx.xsd`` in
https://github.com/AdaCompNUS/sarsop): a POMDP as a dynamic Bayesian network over named
variables.

Reading (:func:`read_pomdpx`), covered as APPL accepts it:

* ``<StateVar vnamePrev vnameCurr fullyObs>``, ``<ObsVar>``, ``<ActionVar>``, ``<RewardVar>``,
  each with ``<ValueEnum>`` names or ``<NumValues>`` (APPL's implicit names ``s0 s1 ...``,
  ``o0 ...``, ``a0 ...`` are accepted in instances, as are 0-based numbers);
* ``<InitialStateBelief>``, ``<StateTransitionFunction>``, ``<ObsFunction>`` (``<CondProb>``)
  and ``<RewardFunction>`` (``<Func>``, several summed), ``<Parameter type="TBL">`` tables:
  an ``<Entry>``'s ``<Instance>`` has one token per parent and (for a ``CondProb``) the
  variable; a value name fixes it, ``*`` means "every value, the same numbers", ``-`` means
  "every value, numbers listed" (row-major over the ``-`` positions); ``<ProbTable>identity``
  (one ``-`` parent and a ``-`` variable of the same size) and ``uniform`` (``1 / |var|``);
  later entries override earlier ones; cells no entry covers are 0;
* the DBN APPL solves: an observed (``fullyObs="true"``) variable depends on the action and
  the previous slice, a hidden one also on observed variables of the current slice;
  observations depend on the action and the current slice; rewards on the action, both slices
  and observations (reduced to the expected ``R[a, s]``). ``type="DD"`` (decision diagrams)
  is not supported (a :class:`~torchhrc.errors.ParseError` says so), as in APPL.

Several variables form one index, row-major in declaration order (the first varies slowest):
observed state variables give ``x``, hidden ones ``y``, action variables ``a``, observation
variables ``o``; a value's name is its variables' value names joined by ``","``.
:func:`read_pomdpx_variables` returns the variables and decodes an index. A model with
an observed variable is returned as a :class:`~torchhrc.pomdp.MOMDP`
(``Tx (A, X, Y, X)``, ``Ty (A, X, Y, X, Y)`` or ``None`` when every hidden variable keeps its
value, ``Z (A, X, Y, O)``, ``R (A, X, Y)``; an initial belief spread over several ``x`` as its
``initial (X, Y)``, APPL's ``TagAvoid.pomdpx``), or as a
:class:`~torchhrc.pomdp.sparse_momdp.SparseMOMDP` when its dense ``Tx``/``Ty`` would be too large;
otherwise as a flat
:class:`~torchhrc.pomdp.POMDP` over ``s = x * Y + y`` (names ``"x|y"``; observations
``x2 * O + o`` when some variable is observed, as :meth:`~torchhrc.pomdp.MOMDP.to_pomdp`,
unless ``x`` is a function of the actions taken: one initial ``x`` and deterministic observed
variables that depend on no hidden one), or as a
:class:`~torchhrc.pomdp.sparse.SparsePOMDP` when the dense tensors would be too large
(RockSample(7, 8): ``Ty`` would hold 2e9 entries). Tables are parsed with numpy and combined
by broadcasting (dense forms) or by expanding the nonzero successors of every ``(a, s)``
(sparse form); no Python loop runs over states. XML is parsed by expat with document type
declarations and entities refused (no entity expansion, no external fetch). Any malformed
input raises :class:`~torchhrc.errors.ParseError` with the file, line, element and reason.

Writing (:func:`write_pomdpx`): a :class:`MOMDP` as two state variables ``x`` (observed) and
``y`` (hidden), a :class:`POMDP` as one hidden state variable, one observation, action and
reward variable, each function a full table (a random start: ``x_0`` with ``P(x)`` and
``y_0 | x_0``)::

    x_1 | action x_0 y_0            Tx  (A, X, Y, X)
    y_1 | action x_0 y_0 [x_1]      Ty  (A, X, Y[, X], Y); "identity" on y_0 when static
    obs | action x_1 y_1            Z   (A, X, Y, O)
    reward(action x_0 y_0)          R   (A, X, Y)

``x_1`` is a parent of ``y_1`` only when ``Ty`` depends on it (where ``x_1`` is reachable).
Checked with APPL SARSOP's ``pomdpsol``: Tiger and RockSample(4, 4) written this way solve to
the same values as their flat ``.pomdp`` files; a flat POMDP (``state_1 | action state_0``,
``obs | action state_1``, ``reward(action state_0)``) too (Tiger: 19.3711 / 19.3721).
A :class:`~torchhrc.pomdp.sparse.SparsePOMDP` is written with the same variables, each
function as one ``<Entry>`` per nonzero (its instance the value names, repeated coordinates
summed: in a table a later entry of one instance replaces an earlier one), so that the file
grows with the nonzeros: the 100,000-state random model of ``make_suite --check-set scale``
is 209 MB. ``pomdpsol`` solves Tiger written so to the same trace as its ``.pomdp``. The
reader takes a transition or observation table too large to hold densely (more than
:data:`~torchhrc.pomdp.sparse.MAX_DENSE_ENTRIES` cells) as its entries, one value of every
variable each (the later of two for one cell wins), into the sparse form.

Example:
    >>> from torchhrc.testing import random_momdp
    >>> m = random_momdp(2, 3, 2, 2, seed=0)
    >>> text = format_pomdpx(m)
    >>> '<StateVar vnamePrev="x_0" vnameCurr="x_1" fullyObs="true">' in text
    True
    >>> bool((read_pomdpx(text).Tx == m.Tx).all())
    True
"""

from __future__ import annotations

import math
import os
from typing import Any, Literal

import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.io import cassandra
from torchhrc.io._budget import check_budget, resolve_budget
from torchhrc.io._gc import gc_paused
from torchhrc.io.pomdpx.builder import _Builder
from torchhrc.io.pomdpx.reader import _Reader
from torchhrc.io.pomdpx.variables import PomdpxVariable, PomdpxVariables
from torchhrc.io.pomdpx.writer import format_pomdpx, write_pomdpx
from torchhrc.io.pomdpx.xml_tree import _parse_xml, _parse_xml_fast
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.sparse import MAX_DENSE_ENTRIES, SparsePOMDP
from torchhrc.pomdp.sparse_momdp import SparseMOMDP

__all__ = [
    "AUTO_SPARSE_ENTRIES",
    "AUTO_SPARSE_MOMDP_ENTRIES",
    "PomdpxVariable",
    "PomdpxVariables",
    "format_pomdpx",
    "parse_pomdpx",
    "read_pomdpx",
    "read_pomdpx_variables",
    "write_pomdpx",
]

#: ``read_pomdpx(..., sparse="auto")`` reads a model sparsely when a dense tensor (``Tx``, ``Ty``
#: and ``Z`` of the MOMDP form, then ``T (A, S, S)`` and ``Z`` of the flat form) would have more
#: entries than this (``torchhrc solve`` with SARSOP uses it).
AUTO_SPARSE_ENTRIES = MAX_DENSE_ENTRIES

#: ``read_pomdpx(..., sparse="auto")`` keeps a MOMDP's transitions as their nonzeros (a
#: :class:`~torchhrc.pomdp.sparse_momdp.SparseMOMDP`) when its dense ``Tx`` or ``Ty`` would
#: have more entries than this (10^7, 80 MB in float64). Measured on RockSample(6, 6) as a MOMDP
#: (a dense ``Ty`` of 6.2e7 entries): read in 1.0 instead of 3.6 CPU-s, peak memory 443 instead of
#: 1,222 MB, and a tighter gap after 10 CPU-s of SARSOP (1.82 against 1.94).
AUTO_SPARSE_MOMDP_ENTRIES = 10_000_000

#: Bytes of memory a byte of the file takes as XML elements (measured: a 6 MB RockSample(6,
#: 6) file peaked 127 MB above the process, tables included).
_XML_BYTES = 20


def _read_source(source: str | os.PathLike[str]) -> tuple[bytes | str, str]:
    if isinstance(source, os.PathLike) or (isinstance(source, str) and "<" not in source):
        path = os.fspath(source)
        try:
            with open(path, "rb") as f:
                return f.read(), path
        except OSError as e:
            raise ParseError(f"cannot read file: {e.strerror}", path=path) from None
    if not isinstance(source, str):
        raise TypeError(f"expected a path or the file's text, got {type(source).__name__}")
    return source, "<string>"


def read_pomdpx_variables(source: str | os.PathLike[str]) -> PomdpxVariables:
    """The variables of a ``.pomdpx`` file (a path or the XML text), grouped as
    :func:`read_pomdpx` combines them (see :class:`PomdpxVariables`).

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> v = read_pomdpx_variables(format_pomdpx(random_momdp(2, 3, 2, 2, seed=0)))
        >>> [x.name for x in v.observed], [y.name for y in v.hidden], v.size("hidden")
        (['x_1'], ['y_1'], 3)
    """
    data, path = _read_source(source)

    def variables(root: Any) -> PomdpxVariables:
        reader = _Reader(root, path)
        if root.tag != "pomdpx":
            raise reader.error(f"expected the root element <pomdpx>, got <{root.tag}>", root)
        node = root.find("Variable")
        if node is None:
            raise reader.error("<pomdpx> has no <Variable>", root)
        reader._variables(node)
        return reader.variables

    root = _parse_xml_fast(data)
    if root is not None:
        try:
            return variables(root)
        except ParseError:
            pass
    return variables(_parse_xml(data, path))  # errors with their line


def read_pomdpx(
    source: str | os.PathLike[str],
    *,
    sparse: bool | Literal["auto"] = "auto",
    momdp: bool = True,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    memory_budget: float | None = None,
) -> POMDP | MOMDP | SparseMOMDP | SparsePOMDP:
    """Read a ``.pomdpx`` file (a path, or the XML text itself); see the module docstring.

    Args:
        source: a path (``str`` without ``<``, or ``os.PathLike``) or the XML text.
        sparse: ``True``: a flat :class:`~torchhrc.pomdp.sparse.SparsePOMDP`; ``False``: a dense
            model (:class:`ParseError` when a tensor would exceed
            :data:`~torchhrc.pomdp.sparse.MAX_DENSE_ENTRIES`, 2e8 entries); ``"auto"``: dense when
            every dense tensor is within :data:`AUTO_SPARSE_ENTRIES` (by default the same
            2e8) and a MOMDP's ``Tx`` and ``Ty`` within :data:`AUTO_SPARSE_MOMDP_ENTRIES`
            (1e7), else sparse (a MOMDP's transitions as a
            :class:`~torchhrc.pomdp.sparse_momdp.SparseMOMDP` when its ``Z`` fits); a flat
            model is also read sparsely where :func:`~torchhrc.io.cassandra.read_pomdp` would
            read it so (``T`` or ``Z`` above 1e6 entries, under a tenth of ``T`` nonzero).
        momdp: return a :class:`~torchhrc.pomdp.MOMDP` when the file has an observed
            (``fullyObs="true"``) state variable and the dense ``Tx``, ``Ty`` (unless
            static) and ``Z`` fit, a :class:`~torchhrc.pomdp.sparse_momdp.SparseMOMDP` when only
            ``Z`` fits (either with :attr:`~torchhrc.pomdp.MOMDP.initial` when the initial
            belief spreads over several observed values); ``False``: always flat.
        dtype, device: of the returned tensors (a sparse model stays on the CPU).
        memory_budget: bytes the read may take (default ``None``: the machine's available
            memory, ``MemAvailable``; ``math.inf``: no limit). Checked before each
            allocation of the model's size: the XML elements (about 20 bytes a byte of the
            file) before parsing, each ``<NumValues>``'s names and each table as it is
            declared, the chosen form's tensors (dense at 10 bytes a cell, nonzeros of the
            sparse forms as estimated from the tables) before it is built; ``"auto"``
            picks a sparse form when the dense one would not fit.

    Returns:
        :class:`~torchhrc.pomdp.MOMDP`, :class:`~torchhrc.pomdp.sparse_momdp.SparseMOMDP`,
        :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.sparse.SparsePOMDP`.

    Raises:
        ParseError: the file is malformed, a table is inconsistent (wrong number of values, a
            row not summing to 1, an unknown value), the DBN is not one APPL solves, the
            model is too large for ``sparse=False`` (file, line, element and reason), or it
            would take more than ``memory_budget`` (the message gives the cells, the bytes
            and the budget).

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = read_pomdpx(format_pomdpx(random_momdp(2, 3, 2, 2, seed=0)))
        >>> type(m).__name__, m.num_observed, m.num_hidden
        ('MOMDP', 2, 3)
    """
    budget = resolve_budget(memory_budget)
    data, path = _read_source(source)
    return parse_pomdpx(data, path=path, sparse=sparse, momdp=momdp, dtype=dtype, device=device,
                        memory_budget=budget)  # fmt: skip


def parse_pomdpx(
    text: str | bytes,
    *,
    path: str = "<string>",
    sparse: bool | Literal["auto"] = "auto",
    momdp: bool = True,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    memory_budget: float | None = None,
) -> POMDP | MOMDP | SparseMOMDP | SparsePOMDP:
    """Parse the text of a ``.pomdpx`` file (``path`` is used in error messages only); see
    :func:`read_pomdpx`.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> parse_pomdpx(format_pomdpx(random_pomdp(3, 2, 2, seed=0))).num_states
        3
    """
    if sparse not in (True, False, "auto"):
        raise ValueError(f"expected sparse to be True, False or 'auto', got {sparse!r}")
    budget = resolve_budget(memory_budget)
    check_budget(_XML_BYTES * len(text), budget, f"the XML elements of {len(text)} bytes of "
                 "text", path=path)  # fmt: skip
    # ElementTree's C builder first (no line numbers); a file it cannot read or that turns out
    # malformed is read again through the expat tree, whose errors carry the line
    with gc_paused():  # the elements are many, freed by reference counting (see _gc)
        root = _parse_xml_fast(text)
        if root is not None:
            try:
                return _parse_tree(root, path, sparse, momdp, dtype, device, budget)
            except ParseError:
                pass
        return _parse_tree(_parse_xml(text, path), path, sparse, momdp, dtype, device, budget)


def _parse_tree(
    root: Any,
    path: str,
    sparse: bool | Literal["auto"],
    momdp: bool,
    dtype: torch.dtype,
    device: torch.device | str | None,
    budget: float = math.inf,
) -> POMDP | MOMDP | SparseMOMDP | SparsePOMDP:
    reader = _Reader(root, path, budget)
    reader.read()
    b = _Builder(reader)
    b0 = b.initial_belief()
    limit = AUTO_SPARSE_ENTRIES if sparse == "auto" else MAX_DENSE_ENTRIES

    def fits(form: str) -> bool:
        return reader.held + b.form_bytes(form)[0] <= budget

    def check(form: str) -> None:  # the form's estimate with the tables held, or refused
        need, what = b.form_bytes(form)
        if reader.held + need > budget:
            check_budget(reader.held + need, budget, f"{what}, with the tables read "
                         f"({reader.held:.3g} bytes),", path=path)  # fmt: skip

    if momdp and sparse is not True and b.xc:
        tx, ty, z, static = b.momdp_sizes()
        dense_limit = min(AUTO_SPARSE_MOMDP_ENTRIES, limit) if sparse == "auto" else limit
        if max(tx, ty) <= dense_limit and z <= limit and (sparse is False or fits("momdp")):
            check("momdp")  # a random first x gives `initial`
            return _wrap(lambda: b.momdp(b0, static, dtype, device), path)
        if z <= limit and sparse == "auto":  # Tx Ty kept as its nonzeros
            check("sparse_momdp")
            return _wrap(lambda: b.sparse_momdp(b0, dtype), path)
    b.set_initial_x(b0)
    dense = max(b.A * b.S * b.S, b.A * b.S * b.flat_observations)
    if sparse is False and dense > MAX_DENSE_ENTRIES:
        raise ParseError(
            f"the dense T (A={b.A}, S={b.S}, S) would have {b.A * b.S * b.S:.3g} entries "
            f"(more than {MAX_DENSE_ENTRIES:.3g}); read it with sparse=True or 'auto'",
            path=path,
        )
    use_sparse = sparse is True or (
        sparse == "auto" and (dense > limit or not fits("dense") or _sparse_as_pomdp(b, dense))
    )
    check("sparse" if use_sparse else "dense")
    return _wrap(lambda: b.flat(b0, use_sparse, dtype, device), path)


def _sparse_as_pomdp(b: _Builder, dense: int) -> bool:
    """Whether ``read_pomdp(..., sparse="auto")`` would read this flat model sparsely: ``T`` or
    ``Z`` above :data:`torchhrc.io.cassandra.AUTO_SPARSE_ENTRIES` entries (1e6) and under
    :data:`~torchhrc.io.cassandra.AUTO_DENSE_FRACTION` of ``T`` nonzero (here estimated from
    the tables), so that a model solves the same way from either file."""
    if dense <= cassandra.AUTO_SPARSE_ENTRIES:
        return False
    return b.transition_nonzeros() < cassandra.AUTO_DENSE_FRACTION * b.A * b.S * b.S


def _wrap(build: Any, path: str) -> Any:
    try:
        return build()
    except ModelError as e:  # the tables were checked; this is a safety net
        raise ParseError(f"the model is invalid: {e}", path=path) from None
